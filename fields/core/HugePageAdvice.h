/// @file HugePageAdvice.h
/// @brief Whether large blocks held for a while ask Linux for transparent huge pages.
#pragma once

#include <atomic>
#include <cstddef>

#if defined(__linux__)
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

/// Turns the advice on or off for the whole process (on unless set). The command line turns it
/// off with malloc's huge pages, the Python module where the machine reports its free memory to
/// its host (tools/HugePages.h, freePagesReportedToHost(): there a fresh huge page costs more than
/// its 4 KB pages).
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
