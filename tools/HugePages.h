// Shared by the `voxlat` launcher, the engine program and the Python module: how they ask for huge
// pages.
#pragma once

#if defined(__linux__)
#include <dirent.h>
#include <sys/mman.h>
#include <time.h>
#endif

#include <algorithm>
#include <cstdint>
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

/// The time in milliseconds to fault in one 2 MB-aligned region of 2 MB as a fresh transparent
/// huge page (advised MADV_HUGEPAGE) and as 4 KB pages (MADV_NOHUGEPAGE), touched once per 4 KB
/// and unmapped: the quicker of @a trials of each; negative where none was measured (no trial, a
/// failed mapping or advice, or not Linux).
struct HugePageFaultTimes {
    double huge = -1.0, small = -1.0;
};

inline HugePageFaultTimes hugePageFaultTimes(int trials = 2)
{
    HugePageFaultTimes best;
#if defined(__linux__) && defined(MADV_HUGEPAGE) && defined(MADV_NOHUGEPAGE)
    constexpr std::size_t kHuge = std::size_t(2) << 20;
    auto milliseconds = [] {
        timespec t{};
        ::clock_gettime(CLOCK_MONOTONIC, &t);
        return double(t.tv_sec) * 1e3 + double(t.tv_nsec) * 1e-6;
    };
    auto touch = [&](int advice) {
        void* mapped = ::mmap(nullptr, 2 * kHuge, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
        if (mapped == MAP_FAILED) return -1.0;
        const auto start = (reinterpret_cast<std::uintptr_t>(mapped) + kHuge - 1) & ~std::uintptr_t(kHuge - 1);
        volatile char* region = reinterpret_cast<volatile char*>(start);
        double took = -1.0;
        if (::madvise(reinterpret_cast<void*>(start), kHuge, advice) == 0) {
            const double t0 = milliseconds();
            for (std::size_t at = 0; at < kHuge; at += 4096) region[at] = 1;
            took = milliseconds() - t0;
        }
        ::munmap(mapped, 2 * kHuge);
        return took;
    };
    for (int trial = 0; trial < trials; ++trial) {
        const double h = touch(MADV_HUGEPAGE), s = touch(MADV_NOHUGEPAGE);
        if (h < 0.0 || s < 0.0) return HugePageFaultTimes{};
        best.huge = best.huge < 0.0 ? h : std::min(best.huge, h);
        best.small = best.small < 0.0 ? s : std::min(best.small, s);
    }
#else
    (void)trials;
#endif
    return best;
}

/// What a huge page the host must back again costs on a machine that reports its free memory to
/// its host, in milliseconds: 4.5-5.2 ms on the PVM guest (64 MB-1 GB touched after 20-45 s idle,
/// against 0.06-0.3 ms for the probe's one page, which the guest had just freed), 7-10 ms on the
/// Firecracker guest. 2 MB of 4 KB pages costs the same fresh or not (0.43-0.9 ms there).
inline constexpr double kColdHugePageMs = 4.5;

/// Whether @a times show huge pages faulting in faster: the probe's huge page at under half the
/// 4 KB pages' time (a machine without them, THP `never`, times both alike), and the 4 KB pages
/// slower than a huge page the host must back again (kColdHugePageMs): the probe's one huge page
/// is one the guest has just freed, while a job of hundreds of megabytes soon takes pages the host
/// took back (the 50 mm trimmed strut frame of W2g on the PVM guest with 4 KB pages at 0.6-0.9 ms
/// per 2 MB: 4.8-5.1 s with huge pages, 2.6-2.7 s of it in the kernel, against 3.8-4.6 s without).
/// Both measured.
inline bool hugePagesFaster(const HugePageFaultTimes& times)
{
    return times.huge >= 0.0 && times.small >= 0.0 && 2.0 * times.huge < times.small && times.small > kColdHugePageMs;
}

/// hugePagesFaster() of this machine, measured (a few milliseconds; at most about 50 on the slow
/// kinds). Why measured, not known from the machine: a Firecracker guest reporting its free memory
/// to its host took 7-10 ms for a huge page against 1.0-1.4 ms for 2 MB of 4 KB pages, a PVM guest
/// that reports it too took 0.12-0.20 ms against 5.2-14.6 ms one day (each 4 KB fault a trip to
/// its host; the acceptance gyroid there 2.74-3.16 s of wall without huge pages, 1.67-2.14 s
/// with) and 0.06-0.3 ms against 0.6-0.9 ms on another (the gyroid 0.66-0.78 s without, 1.00 s
/// with: a job's fresh huge pages cost 4.5-5.2 ms there, kColdHugePageMs).
inline bool hugePagesFaultFaster(int trials = 2)
{
    return hugePagesFaster(hugePageFaultTimes(trials));
}

/// Whether this process should back its memory with huge pages: everywhere, except on a machine
/// that reports its free memory to its host (freePagesReportedToHost()) where they do not fault in
/// faster than 4 KB pages (hugePagesFaultFaster(), measured only there).
/// @a measured, when given, receives the probe's times (left unmeasured where there was no probe).
inline bool hugePagesPay(HugePageFaultTimes* measured = nullptr)
{
    if (!freePagesReportedToHost()) return true;
    const HugePageFaultTimes times = hugePageFaultTimes();
    if (measured) *measured = times;
    return hugePagesFaster(times);
}

/// Asks glibc's malloc to back its large blocks with transparent huge pages, through the
/// GLIBC_TUNABLES variable, for the next program this process executes (glibc reads tunables
/// only at start-up). Why: a job touches gigabytes of freshly allocated memory (grid leaves, the
/// mesh), and where THP is `madvise` (Debian's default) each 4 KiB page is a fault of its own: a
/// fifth of the acceptance gyroid's CPU time went to page faults, and huge pages cut its CPU
/// time by a quarter. Except where the machine reports its free memory to its host
/// (freePagesReportedToHost()) and a fresh huge page does not fault in faster than its 4 KB pages
/// there (hugePagesPay(): a Firecracker guest, 7-10 ms against 1.0-1.4 ms for 2 MB; the 50 mm
/// trimmed frame run alone 9.2-9.6 s against 6.9-8.2 s; `bench/history.md`, twenty-seventh
/// round), where glibc.malloc.hugetlb=0 is added instead (the engine then neither asks again nor advises its
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
    const bool ask = (forced && std::strcmp(forced, "1") == 0) || hugePagesPay();
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
