/// @file SystemInfo.h
/// @brief Memory figures of this process and this machine.
#pragma once

#include <cstdint>

namespace voxlat {

/// Peak resident set size of this process in bytes (VmHWM).
std::uint64_t peakMemoryBytes();
/// Memory the machine can still give this process in bytes (MemAvailable).
std::uint64_t availableMemoryBytes();

}  // namespace voxlat
