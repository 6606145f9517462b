// Shared by the `voxlat` launcher and the engine program: how they ask for huge pages.
#pragma once

#include <cstdlib>
#include <cstring>
#include <string>

namespace voxlat {

/// Asks glibc's malloc to back its large blocks with transparent huge pages, through the
/// GLIBC_TUNABLES variable, for the next program this process executes (glibc reads tunables
/// only at start-up). Why: a job touches gigabytes of freshly allocated memory (grid leaves, the
/// mesh), and where THP is `madvise` (Debian's default) each 4 KiB page is a fault of its own: a
/// fifth of the acceptance gyroid's CPU time went to page faults, and huge pages cut its CPU
/// time by a quarter. Nothing computed changes. Returns false, changing nothing, when
/// `VOXLAT_NO_HUGEPAGES` is set or the tunable is already there. @a previous receives the old
/// value (empty if none) so a failed exec can put it back.
inline bool requestHugePages(std::string& previous, bool& hadPrevious)
{
    constexpr const char* kTunable = "glibc.malloc.hugetlb=1";
    const char* tunables = std::getenv("GLIBC_TUNABLES");
    hadPrevious = tunables != nullptr;
    previous = tunables ? tunables : "";
    if (std::getenv("VOXLAT_NO_HUGEPAGES") || (tunables && std::strstr(tunables, "glibc.malloc.hugetlb"))) return false;
    const std::string value = tunables && *tunables ? previous + ":" + kTunable : std::string(kTunable);
    return ::setenv("GLIBC_TUNABLES", value.c_str(), 1) == 0;
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
