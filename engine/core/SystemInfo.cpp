#include "engine/core/SystemInfo.h"

#include "engine/core/Errors.h"

#include <cstdlib>
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
    // A cap of the user's (a machine shared with other jobs) or a test's, in place of the free memory.
    if (const char* cap = std::getenv("VOXLAT_MEMORY_MB"); cap && *cap) {
        char* end = nullptr;
        const double mb = std::strtod(cap, &end);
        if (end != cap && *end == '\0' && mb > 0.0 && mb < 1e12) return std::uint64_t(mb * 1024.0 * 1024.0);
        throw InputError(
            std::string("VOXLAT_MEMORY_MB=") + cap +
            " is not a positive number of MB: set it to the memory the job may take (e.g. 4000), or unset it");
    }
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
