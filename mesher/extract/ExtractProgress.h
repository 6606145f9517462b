#pragma once
/// @file ExtractProgress.h
/// @brief Whole-percent progress from the parallel passes of the extractors (MarchingCubes,
/// BccTetrahedra): any thread may advance it, the callback sees each percent once, in order.

#include "mesher/extract/MarchingCubes.h"

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <mutex>
#include <utility>

namespace voxlat {

/// Counts finished units of work and calls the ProgressFn when a new whole percent is reached
/// (never 100 % before finish(), so the caller's last report is the completion).
class ExtractProgress {
public:
    ExtractProgress(ProgressFn fn, std::size_t total) : mFn(std::move(fn)), mTotal(std::max<std::size_t>(total, 1)) {}

    /// @a n more units done.
    void advance(std::size_t n = 1)
    {
        if (!mFn) return;
        const std::size_t done = mDone += n;
        const int percent = int(done * 100 / mTotal);
        if (percent <= mReported.load(std::memory_order_relaxed) || percent >= 100) return;
        std::lock_guard<std::mutex> lock(mMutex);
        if (percent <= mReported.load(std::memory_order_relaxed)) return;
        mReported.store(percent, std::memory_order_relaxed);
        mFn(percent / 100.0);
    }

    /// All done: reports 1.
    void finish()
    {
        if (mFn) mFn(1.0);
    }

private:
    ProgressFn mFn;
    std::size_t mTotal;
    std::atomic<std::size_t> mDone{0};
    std::atomic<int> mReported{0};
    std::mutex mMutex;
};

/// @a fn's progress over the part [@a from, @a to] of [0, 1]: one phase of a function that reports
/// over [0, 1] (empty when @a fn is).
inline ProgressFn progressPart(const ProgressFn& fn, double from, double to)
{
    if (!fn) return {};
    return [fn, from, to](double fraction) { fn(from + (to - from) * fraction); };
}

}  // namespace voxlat
