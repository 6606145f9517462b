// Shared by the `voxlat` launcher and the engine program: how they ask for huge pages.
#pragma once

#include "fields/core/HugePageAdvice.h"

#include <cstdlib>
#include <cstring>
#include <string>

namespace voxlat {

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
/// own blocks). `VOXLAT_HUGEPAGES=1` asks even there. Nothing computed changes. Returns false, changing nothing, when
/// `VOXLAT_NO_HUGEPAGES` is set or a hugetlb tunable is already there, and false after adding
/// hugetlb=0. @a previous receives the old value (empty if none) so a failed exec can put it back.
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
