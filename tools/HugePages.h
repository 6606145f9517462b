// Shared by the `voxlat` launcher, the engine program and the Python module: how they ask for huge
// pages.
#pragma once

#if defined(__linux__)
#include <dirent.h>
#endif

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

namespace voxlat {

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

/// Asks glibc's malloc to back its large blocks with transparent huge pages, through the
/// GLIBC_TUNABLES variable, for the next program this process executes (glibc reads tunables
/// only at start-up). Why: a job touches gigabytes of freshly allocated memory (grid leaves, the
/// mesh), and where THP is `madvise` (Debian's default) each 4 KiB page is a fault of its own: a
/// fifth of the acceptance gyroid's CPU time went to page faults, and huge pages cut its CPU
/// time by a quarter. Except where the machine reports its free memory to its host
/// (freePagesReportedToHost()): there a fresh huge page costs more than its 4 KB pages (a
/// Firecracker guest: 7-10 ms against 1.0-1.4 ms for 2 MB; the 50 mm trimmed frame run alone
/// 9.2-9.6 s against 6.9-8.2 s; `bench/history.md`, twenty-seventh round), so
/// glibc.malloc.hugetlb=0 is added instead (the engine then neither asks again nor advises its
/// own blocks). `VOXLAT_HUGEPAGES=1` asks even there. Nothing computed changes. Returns true only
/// when it added hugetlb=1 (the engine then runs itself again); false after adding hugetlb=0, and
/// false changing nothing when `VOXLAT_NO_HUGEPAGES` is set or a hugetlb tunable is already
/// there. @a previous receives the old value (empty if none) so a failed exec can put it back.
inline bool requestHugePages(std::string& previous, bool& hadPrevious)
{
    const char* tunables = std::getenv("GLIBC_TUNABLES");
    hadPrevious = tunables != nullptr;
    previous = tunables ? tunables : "";
    if (std::getenv("VOXLAT_NO_HUGEPAGES") || (tunables && std::strstr(tunables, "glibc.malloc.hugetlb"))) return false;
    const char* forced = std::getenv("VOXLAT_HUGEPAGES");
    const bool ask = (forced && std::strcmp(forced, "1") == 0) || !freePagesReportedToHost();
    const char* tunable = ask ? "glibc.malloc.hugetlb=1" : "glibc.malloc.hugetlb=0";
    const std::string value = tunables && *tunables ? previous + ":" + tunable : std::string(tunable);
    return ::setenv("GLIBC_TUNABLES", value.c_str(), 1) == 0 && ask;
}

/// Whether this program's malloc was started on huge pages: GLIBC_TUNABLES holds
/// glibc.malloc.hugetlb with a value other than 0 (the last entry wins, as glibc reads them). The
/// engine's own mapped blocks follow it (setHugePageAdvice()), so an opt-out is whole.
inline bool mallocOnHugePages()
{
    const char* tunables = std::getenv("GLIBC_TUNABLES");
    constexpr const char* kKey = "glibc.malloc.hugetlb=";
    const char* last = nullptr;
    for (const char* at = tunables ? std::strstr(tunables, kKey) : nullptr; at; at = std::strstr(at + 1, kKey))
        last = at;
    return last && last[std::strlen(kKey)] != '0';
}

/// Puts GLIBC_TUNABLES back as requestHugePages() found it.
inline void restoreTunables(const std::string& previous, bool hadPrevious)
{
    if (hadPrevious)
        ::setenv("GLIBC_TUNABLES", previous.c_str(), 1);
    else
        ::unsetenv("GLIBC_TUNABLES");
}

}  // namespace voxlat
