/// @file HugePageAdvice.h
/// @brief Whether large blocks held for a while ask Linux for transparent huge pages, and whether
/// the machine's host makes fresh huge pages cost more than 4 KB pages.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdio>
#include <cstring>
#include <string>

#if defined(__linux__)
#include <dirent.h>
#include <sys/mman.h>
#endif

namespace voxlat {

namespace detail {
inline std::atomic<bool>& hugePageAdviceFlag()
{
    static std::atomic<bool> flag{true};
    return flag;
}
}  // namespace detail

/// Whether this machine is a virtual machine that reports its free memory to its host
/// (virtio-balloon with VIRTIO_BALLOON_F_REPORTING, feature bit 5, negotiated): a device under
/// @a drivers whose `features` string (one '0' or '1' per bit) has bit 5 set. The host then takes
/// freed guest memory back, and the first touch of a huge page is a 2 MB block it must back again.
inline bool freePagesReportedToHost(const char* drivers = "/sys/bus/virtio/drivers/virtio_balloon")
{
#if defined(__linux__)
    DIR* folder = ::opendir(drivers);
    if (!folder) return false;
    bool reported = false;
    while (const dirent* entry = ::readdir(folder)) {
        if (std::strncmp(entry->d_name, "virtio", 6) != 0) continue;
        const std::string path = std::string(drivers) + "/" + entry->d_name + "/features";
        if (std::FILE* file = std::fopen(path.c_str(), "r")) {
            char bits[8] = {};
            const std::size_t read = std::fread(bits, 1, 6, file);
            std::fclose(file);
            reported = reported || (read == 6 && bits[5] == '1');
        }
    }
    ::closedir(folder);
    return reported;
#else
    (void)drivers;
    return false;
#endif
}

/// Turns the advice on or off for the whole process (on unless set). The command line turns it
/// off with malloc's huge pages (tools/HugePages.h), the Python module where
/// freePagesReportedToHost(): there a fresh huge page costs more than its 4 KB pages.
inline void setHugePageAdvice(bool on)
{
    detail::hugePageAdviceFlag().store(on, std::memory_order_relaxed);
}

/// Whether adviseHugePages() asks for huge pages.
inline bool hugePageAdvice()
{
    return detail::hugePageAdviceFlag().load(std::memory_order_relaxed);
}

/// Asks for transparent huge pages (MADV_HUGEPAGE) over [@a data, @a data + @a bytes) where the
/// advice is on; nothing elsewhere (other systems, the advice off). Nothing computed changes.
inline void adviseHugePages(void* data, std::size_t bytes)
{
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    if (hugePageAdvice()) ::madvise(data, bytes, MADV_HUGEPAGE);
#else
    (void)data;
    (void)bytes;
#endif
}

}  // namespace voxlat
