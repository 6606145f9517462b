/// @file Progress.h
/// @brief A thread-safe progress bar for long stages, drawn only on a terminal.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <mutex>
#include <string>

namespace voxlat {

/// One stage's progress. add() may be called from any thread; the bar is redrawn at most ten
/// times a second and only when standard error is a terminal, so logs and CI stay clean.
class Progress {
public:
    Progress(std::string stage, std::uint64_t total, bool enabled);
    ~Progress();

    void add(std::uint64_t done = 1);
    void finish();

    /// Whether bars are drawn at all (stderr is a TTY and not disabled by the user).
    static bool terminalEnabled();
    static void setQuiet(bool quiet);

private:
    void draw(std::uint64_t done);

    std::string mStage;
    std::uint64_t mTotal;
    bool mEnabled;
    bool mFinished = false;
    std::atomic<std::uint64_t> mDone{0};
    std::atomic<std::int64_t> mLastDrawNs{0};
    std::mutex mDrawMutex;
    std::chrono::steady_clock::time_point mStart;
};

}  // namespace voxlat
