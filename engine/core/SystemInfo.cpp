#include "engine/core/SystemInfo.h"

#include <fstream>
#include <string>

#if defined(__GLIBC__)
#include <malloc.h>
#endif

namespace voxlat {

namespace {
/// Reads "Key:   123 kB" from a /proc file; 0 if absent.
std::uint64_t readKiloBytes(const char* path, const std::string& key)
{
    std::ifstream in(path);
    std::string line;
    while (std::getline(in, line))
        if (line.compare(0, key.size(), key) == 0) return std::stoull(line.substr(key.size())) * 1024;
    return 0;
}
}  // namespace

std::uint64_t peakMemoryBytes()
{
    return readKiloBytes("/proc/self/status", "VmHWM:");
}

std::uint64_t availableMemoryBytes()
{
    const std::uint64_t available = readKiloBytes("/proc/meminfo", "MemAvailable:");
    return available ? available : (std::uint64_t(4) << 30);
}

void releaseFreedMemory()
{
#if defined(__GLIBC__)
    ::malloc_trim(0);
#endif
}

}  // namespace voxlat
