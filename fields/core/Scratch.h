/// @file Scratch.h
/// @brief Per-thread scratch memory for batch evaluation without an allocation per leaf.
#pragma once

#include <cstddef>
#include <memory>
#include <vector>

namespace voxlat {

/// Takes the next level of a per-thread stack of buffers for as long as it lives. Nested
/// evaluations (an equation whose input is another equation) take deeper levels, so they never
/// share memory; after the first leaf a thread allocates nothing.
class ScratchLease {
public:
    /// At least @a doubles doubles (8-byte aligned, uninitialised).
    explicit ScratchLease(std::size_t doubles)
    {
        State& s = state();
        if (s.levels.size() <= s.depth) s.levels.emplace_back();
        std::vector<double>& level = s.levels[s.depth++];
        if (level.size() < doubles) level.resize(doubles);
        mData = level.data();
    }
    ~ScratchLease() { --state().depth; }
    ScratchLease(const ScratchLease&) = delete;
    ScratchLease& operator=(const ScratchLease&) = delete;

    double* data() const { return mData; }
    /// The memory viewed as an array of @a T (T must be made of doubles).
    template <typename T>
    T* as() const
    {
        static_assert(sizeof(T) % sizeof(double) == 0);
        return reinterpret_cast<T*>(mData);
    }

private:
    struct State {
        std::vector<std::vector<double>> levels;
        std::size_t depth = 0;
    };
    static State& state()
    {
        thread_local State s;
        return s;
    }
    double* mData;
};

}  // namespace voxlat
