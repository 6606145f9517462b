#include "tools/TerminalProgress.h"

#include "mesher/writers/AtomicFile.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <string>

namespace voxlat::cli {

namespace {

std::atomic<JobContext*> gCancelTarget{nullptr};
volatile std::sig_atomic_t gSignal = 0;

extern "C" void onSignal(int signal)
{
    if (gSignal != 0) {
        // A second signal: the job did not stop (blocked in a system call?); end now, the default
        // way, leaving no temporary file behind.
        removeTemporaries();
        std::signal(signal, SIG_DFL);
        std::raise(signal);
        return;
    }
    gSignal = signal;
    // A lock-free atomic store: safe in a signal handler.
    if (JobContext* context = gCancelTarget.load()) context->cancel();
}

/// One bar at a time, redrawn in place; a stage that completes gets its time and a new line.
struct Bars {
    std::string stage;
    std::chrono::steady_clock::time_point start;

    void draw(const std::string& name, std::uint64_t done, std::uint64_t total)
    {
        const auto now = std::chrono::steady_clock::now();
        if (name != stage) {
            stage = name;
            start = now;
        }
        const double f = std::min(1.0, double(done) / double(std::max<std::uint64_t>(total, 1)));
        constexpr int kWidth = 30;
        const int filled = int(f * kWidth);
        std::fprintf(stderr, "\r%-24s [%.*s%*s] %5.1f%%", name.c_str(), filled, "##############################",
                     kWidth - filled, "", 100.0 * f);
        if (done >= total) {
            std::fprintf(stderr, " %.2f s\n", std::chrono::duration<double>(now - start).count());
            stage.clear();
        }
        std::fflush(stderr);
    }
};

}  // namespace

void attachTerminal(JobContext& context, bool quiet)
{
    if (!quiet && isatty(STDERR_FILENO)) {
        auto bars = std::make_shared<Bars>();
        context.setProgressCallback([bars](const std::string& stage, std::uint64_t done, std::uint64_t total) {
            bars->draw(stage, done, total);
        });
    }
    context.setWarningSink([](const Warning& w) {
        std::fprintf(stderr, "warning%s: %s\n", w.replaces ? " (updated, in place of the one above)" : "",
                     w.message.c_str());
        std::fflush(stderr);
    });
}

void cancelOnSignals(JobContext& context)
{
    gCancelTarget = &context;
    std::signal(SIGINT, onSignal);
    std::signal(SIGTERM, onSignal);
}

int receivedSignal()
{
    return gSignal;
}

}  // namespace voxlat::cli
