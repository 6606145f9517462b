/// @file SystemInfo.h
/// @brief Memory figures of this process and this machine.
#pragma once

#include <cstdint>

namespace voxlat {

/// Peak resident set size of this process in bytes (VmHWM).
std::uint64_t peakMemoryBytes();
/// Memory the machine can still give this process in bytes (MemAvailable), or the cap
/// `VOXLAT_MEMORY_MB` (a positive number of MB) sets in its place: every refusal on an estimate
/// (70 % of it, or half for a frame's struts and a 3MF) then reads the cap.
std::uint64_t availableMemoryBytes();
/// Gives the memory freed into malloc's heaps back to the system (glibc's malloc_trim; nothing
/// elsewhere). The command line keeps freed memory in the heaps for the next stage's arrays
/// (keepFreedMemory()), but a stage that frees many small blocks (a solve's grid leaves, the raw
/// values kept for the grid) hands its next stage nothing it can reuse when that stage's arrays
/// are larger than those blocks: without this, both are resident at once (a 50 mm strut frame's
/// solve held its freed grid's 0.4 GB beside the bisection's samples, and the freed raw values'
/// 0.85 GB beside the mesh). Call it after such a free, between stages.
void releaseFreedMemory();

}  // namespace voxlat
