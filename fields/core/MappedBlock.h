/// @file MappedBlock.h
/// @brief A block of memory mapped on its own, in whole transparent huge pages.
#pragma once

#include "fields/core/HugePageAdvice.h"

#include <cstddef>
#include <new>

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace voxlat {

/// At least @a bytes of uninitialised memory, 2 MB aligned and mapped on their own (mmap, not
/// malloc's heaps), with transparent huge pages asked for (adviseHugePages()); unmapped whole when
/// the block goes. Why: memory held for a while beside a stage that frees many small blocks
/// (a strut lattice's kept raw values beside a solve's grid) stays in whole huge pages. In
/// malloc's heaps, the stage's malloc_trim (releaseFreedMemory()) cut the free gaps between
/// them out of their huge pages; on a virtual machine each 4 KB page of those then costs a
/// fault of the host's when next read (the 50 mm trimmed frame: 1.2 s of CPU to read its 0.9 GB
/// of kept values once, 0.02 s in whole huge pages).
class MappedBlock {
public:
    static constexpr std::size_t kHugePage = std::size_t(2) << 20;

    MappedBlock() = default;
    explicit MappedBlock(std::size_t bytes) : mBytes((bytes + kHugePage - 1) / kHugePage * kHugePage)
    {
        if (mBytes == 0) return;
#if defined(__linux__)
        // Mapped with a huge page's slack, then trimmed to a 2 MB boundary.
        void* p = ::mmap(nullptr, mBytes + kHugePage, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
        if (p == MAP_FAILED) throw std::bad_alloc();
        char* raw = static_cast<char*>(p);
        char* aligned =
            reinterpret_cast<char*>((reinterpret_cast<std::size_t>(raw) + kHugePage - 1) / kHugePage * kHugePage);
        if (aligned > raw) ::munmap(raw, std::size_t(aligned - raw));
        const std::size_t tail = std::size_t(raw + mBytes + kHugePage - (aligned + mBytes));
        if (tail > 0) ::munmap(aligned + mBytes, tail);
        adviseHugePages(aligned, mBytes);
        mData = aligned;
#else
        mData = ::operator new(mBytes, std::align_val_t(kHugePage));
#endif
    }
    ~MappedBlock()
    {
        release();
    }
    MappedBlock(MappedBlock&& other) noexcept : mData(other.mData), mBytes(other.mBytes)
    {
        other.mData = nullptr;
        other.mBytes = 0;
    }
    MappedBlock& operator=(MappedBlock&& other) noexcept
    {
        if (this != &other) {
            release();
            mData = other.mData;
            mBytes = other.mBytes;
            other.mData = nullptr;
            other.mBytes = 0;
        }
        return *this;
    }
    MappedBlock(const MappedBlock&) = delete;
    MappedBlock& operator=(const MappedBlock&) = delete;

    /// The block's memory (null when empty).
    void* data() const
    {
        return mData;
    }
    /// Its size: the bytes asked for, rounded up to whole huge pages.
    std::size_t size() const
    {
        return mBytes;
    }

private:
    void release()
    {
        if (!mData) return;
#if defined(__linux__)
        ::munmap(mData, mBytes);
#else
        ::operator delete(mData, std::align_val_t(kHugePage));
#endif
        mData = nullptr;
    }
    void* mData = nullptr;
    std::size_t mBytes = 0;
};

}  // namespace voxlat
