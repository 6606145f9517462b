/// @file InputFiles.h
/// @brief Checks before reading a user's file: a regular file of a plausible size, so `/dev/zero`,
/// a FIFO or a 2 GB file posing as a recipe is refused at once instead of read forever.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>

namespace voxlat {

/// The largest value, wireframe or cell file read (text of numbers).
inline constexpr std::uintmax_t kMaxDataFileBytes = std::uintmax_t(256) << 20;

/// Throws InputError naming @a what and @a path unless @a path is a regular file (after symlinks)
/// of at most @a maxBytes. Returns its size.
std::uintmax_t checkInputFile(const std::filesystem::path& path, std::uintmax_t maxBytes, const std::string& what);

/// The whole of a checked input file (checkInputFile first).
std::string readInputFile(const std::filesystem::path& path, std::uintmax_t maxBytes, const std::string& what);

}  // namespace voxlat
