/// @file Sha256.h
/// @brief SHA-256 (FIPS 180-4, computed by Nettle) of a byte string, for the recipe hash in report.json.
#pragma once

#include <string>
#include <string_view>

namespace voxlat {

/// The SHA-256 digest of @a data as 64 lowercase hex digits.
std::string sha256Hex(std::string_view data);

}  // namespace voxlat
