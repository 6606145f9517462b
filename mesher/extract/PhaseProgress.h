#pragma once
/// @file PhaseProgress.h
/// @brief Progress of a function made of phases whose share of the work is not known ahead.

#include "mesher/extract/MarchingCubes.h"

#include <cstddef>
#include <functional>

namespace voxlat {

/// Reports a function's progress phase by phase through a ProgressFn: begin() reports where a
/// phase starts, check() reports it again from the phase's loops (from any thread), so that a
/// caller's ProgressFn that throws stops a long phase (the job's checks its cancel flag on every
/// call). Phases begin between parallel loops, never during one.
class PhaseProgress {
public:
    explicit PhaseProgress(const ProgressFn& fn) : mFn(fn) {}

    /// A phase starts at @a fraction of the work.
    void begin(double fraction)
    {
        mPhase = fraction;
        check();
    }
    /// Reports the current phase again.
    void check() const
    {
        if (mFn) mFn(mPhase);
    }
    /// check() at every 65 536th item @a i of a loop.
    void checkEvery(std::size_t i) const
    {
        if ((i & 0xffff) == 0) check();
    }
    /// check() as a callable, for helpers that take one.
    std::function<void()> checker() const
    {
        return [this] { check(); };
    }

private:
    const ProgressFn& mFn;
    double mPhase = 0.0;
};

}  // namespace voxlat
