#include "engine/Progress.h"

#include <cstdio>
#include <unistd.h>

namespace voxlat {

namespace {
std::atomic<bool> gQuiet{false};
}

bool Progress::terminalEnabled() { return !gQuiet && isatty(STDERR_FILENO); }
void Progress::setQuiet(bool quiet) { gQuiet = quiet; }

Progress::Progress(std::string stage, std::uint64_t total, bool enabled)
    : mStage(std::move(stage)), mTotal(total ? total : 1), mEnabled(enabled && terminalEnabled()),
      mStart(std::chrono::steady_clock::now())
{
}

Progress::~Progress() { finish(); }

void Progress::add(std::uint64_t done)
{
    const std::uint64_t now = mDone.fetch_add(done) + done;
    if (!mEnabled) return;
    const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - mStart).count();
    std::int64_t last = mLastDrawNs.load();
    if (ns - last < 100'000'000) return;
    if (!mLastDrawNs.compare_exchange_strong(last, ns)) return;  // another thread draws
    draw(now);
}

void Progress::draw(std::uint64_t done)
{
    std::lock_guard<std::mutex> lock(mDrawMutex);
    const double f = std::min(1.0, double(done) / double(mTotal));
    constexpr int kWidth = 30;
    const int filled = int(f * kWidth);
    std::fprintf(stderr, "\r%-24s [%.*s%*s] %5.1f%%", mStage.c_str(), filled, "##############################",
                 kWidth - filled, "", 100.0 * f);
    std::fflush(stderr);
}

void Progress::finish()
{
    if (!mEnabled || mFinished) return;
    mFinished = true;
    draw(mTotal);
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - mStart).count();
    std::fprintf(stderr, " %.2f s\n", s);
}

}  // namespace voxlat
