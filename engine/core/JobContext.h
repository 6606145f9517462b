/// @file JobContext.h
/// @brief What the caller hands the library for a job: a progress callback, a cancel flag and a
/// warning sink. The library never prints; it reports through this (OpenVDB's interrupter and
/// libfive's render settings play the same part there).
#pragma once

#include <nlohmann/json.hpp>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <vector>

namespace voxlat {

/// A warning for the user: a short stable code (`pieces`, `thin_struts`, ...), a message that says
/// what is wrong with numbers and what to do, and the numbers again for report.json.
struct Warning {
    std::string code;
    std::string message;
    nlohmann::json details = nlohmann::json::object();
    /// Set by JobContext::warnAgain() where it replaced an earlier warning of the same code and
    /// field (the sink may say the numbers above are superseded).
    bool replaces = false;
};

/// The caller's side of a job. Callbacks may be called from worker threads, one at a time (the
/// context serialises them). cancel() is lock-free and safe from a signal handler.
class JobContext {
public:
    /// @a stage names what runs ("evaluating lattice"); @a done of @a total units.
    using ProgressFn = std::function<void(const std::string& stage, std::uint64_t done, std::uint64_t total)>;
    using WarningFn = std::function<void(const Warning&)>;

    JobContext() = default;
    JobContext(const JobContext&) = delete;
    JobContext& operator=(const JobContext&) = delete;

    void setProgressCallback(ProgressFn fn) { mProgress = std::move(fn); }
    void setWarningSink(WarningFn fn) { mWarningSink = std::move(fn); }

    /// Asks the job to stop at its next check; the job then throws Cancelled and leaves no output.
    void cancel() noexcept { mCancelled.store(true, std::memory_order_relaxed); }
    bool cancelled() const noexcept { return mCancelled.load(std::memory_order_relaxed); }
    /// Throws Cancelled once cancel() was called.
    void checkCancelled() const;

    /// Keeps @a w for report.json and passes it to the sink.
    void warn(Warning w) const;
    void warn(std::string code, std::string message, nlohmann::json details = nlohmann::json::object()) const
    {
        warn(Warning{std::move(code), std::move(message), std::move(details)});
    }
    /// A warning about one field's state that may change after it was raised (a level moved for
    /// the mesh): replaces the kept warning of the same code whose details name the same `field`
    /// (report.json then holds the numbers that hold now), or keeps @a w as a new one; either
    /// way it goes to the sink.
    void warnAgain(Warning w) const;
    /// Drops the kept warning of @a code about @a field (its state no longer warrants it), if any.
    void withdraw(const std::string& code, const std::string& field) const;
    /// Every warning so far, in the order raised.
    std::vector<Warning> warnings() const;

    /// Reports progress of a stage (serialised; no-op without a callback).
    void progress(const std::string& stage, std::uint64_t done, std::uint64_t total) const;
    bool wantsProgress() const { return bool(mProgress); }

    /// A context that reports nothing and is never cancelled (the default for library calls).
    static JobContext& silent();

private:
    ProgressFn mProgress;
    WarningFn mWarningSink;
    std::atomic<bool> mCancelled{false};
    mutable std::mutex mMutex;
    mutable std::vector<Warning> mWarnings;
};

/// One stage's progress, reported through a context. add() may be called from any thread; the
/// callback runs at most ten times a second and once at the end. add() also checks cancellation,
/// so a long loop that reports progress stops promptly (it throws Cancelled).
class StageProgress {
public:
    StageProgress(const JobContext* context, std::string stage, std::uint64_t total);
    ~StageProgress();
    StageProgress(const StageProgress&) = delete;
    StageProgress& operator=(const StageProgress&) = delete;

    void add(std::uint64_t done = 1);
    /// Reports the stage complete (also done by the destructor unless the stage was cancelled).
    void finish();

private:
    const JobContext* mContext;
    std::string mStage;
    std::uint64_t mTotal;
    std::atomic<std::uint64_t> mDone{0};
    std::atomic<std::int64_t> mLastNs{0};
    std::chrono::steady_clock::time_point mStart;
    bool mFinished = false;
};

}  // namespace voxlat
