#include "engine/core/JobContext.h"

#include "engine/core/Errors.h"

#include <algorithm>

namespace voxlat {

void JobContext::checkCancelled() const
{
    if (cancelled()) throw Cancelled("cancelled");
}

void JobContext::warn(Warning w) const
{
    std::lock_guard<std::mutex> lock(mMutex);
    mWarnings.push_back(std::move(w));
    if (mWarningSink) mWarningSink(mWarnings.back());
}

namespace {

bool aboutField(const Warning& w, const std::string& code, const nlohmann::json& field)
{
    return w.code == code && w.details.is_object() && w.details.contains("field") && w.details["field"] == field;
}

}  // namespace

void JobContext::warnAgain(Warning w) const
{
    std::lock_guard<std::mutex> lock(mMutex);
    const nlohmann::json field = w.details.is_object() && w.details.contains("field") ? w.details["field"] : nullptr;
    auto kept = std::find_if(mWarnings.begin(), mWarnings.end(),
                             [&](const Warning& k) { return !field.is_null() && aboutField(k, w.code, field); });
    if (kept == mWarnings.end()) {
        mWarnings.push_back(std::move(w));
        kept = mWarnings.end() - 1;
    } else {
        *kept = std::move(w);
        kept->replaces = true;
    }
    if (mWarningSink) mWarningSink(*kept);
}

void JobContext::withdraw(const std::string& code, const std::string& field) const
{
    std::lock_guard<std::mutex> lock(mMutex);
    std::erase_if(mWarnings, [&](const Warning& k) { return aboutField(k, code, field); });
}

std::vector<Warning> JobContext::warnings() const
{
    std::lock_guard<std::mutex> lock(mMutex);
    return mWarnings;
}

void JobContext::progress(const std::string& stage, std::uint64_t done, std::uint64_t total) const
{
    if (!mProgress) return;
    std::lock_guard<std::mutex> lock(mMutex);
    mProgress(stage, done, total);
}

JobContext& JobContext::silent()
{
    static JobContext context;
    return context;
}

StageProgress::StageProgress(const JobContext* context, std::string stage, std::uint64_t total)
    : mContext(context), mStage(std::move(stage)), mTotal(total ? total : 1), mStart(std::chrono::steady_clock::now())
{
    if (mContext) mContext->checkCancelled();
}

StageProgress::~StageProgress()
{
    if (!mContext || mContext->cancelled() || mFinished) return;
    mFinished = true;
    mContext->progress(mStage, mTotal, mTotal);
}

void StageProgress::add(std::uint64_t done)
{
    const std::uint64_t now = mDone.fetch_add(done, std::memory_order_relaxed) + done;
    if (!mContext) return;
    mContext->checkCancelled();
    if (!mContext->wantsProgress()) return;
    const auto ns =
        std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - mStart).count();
    std::int64_t last = mLastNs.load(std::memory_order_relaxed);
    if (ns - last < 100'000'000) return;
    if (!mLastNs.compare_exchange_strong(last, ns)) return;  // another thread reports this tick
    mContext->progress(mStage, std::min(now, mTotal), mTotal);
}

void StageProgress::finish()
{
    if (!mContext || mFinished) return;
    mFinished = true;
    mContext->progress(mStage, mTotal, mTotal);
}

}  // namespace voxlat
