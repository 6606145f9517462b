// The caller's job context: progress, warnings and cancellation reach the caller, never the terminal.
#include "TestUtil.h"
#include "engine/core/Errors.h"
#include "engine/core/GridMeasure.h"
#include "engine/core/JobContext.h"
#include "engine/density/Coverage.h"
#include "engine/frames/StrutFrames.h"
#include "engine/jobs/Job.h"
#include "fields/struts/StrutConvolution.h"

#include <gtest/gtest.h>

#include <map>
#include <thread>

using namespace voxlat;
using namespace voxlat::coverage;

namespace {

const char* kGyroid =
    "voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n"
    "  s: {tpms: gyroid, cell: 8, solid: network, density: 0.3}\nresult: s\n"
    "outputs: {mesh: part.stl}\n";

Recipe parse(const std::string& text, const test::TempDir& dir)
{
    return parseRecipe(text, (dir.path / "r.yaml").string(), dir.path);
}

}  // namespace

TEST(JobContext, StagesReportProgressUpToTheirTotal)
{
    test::TempDir dir;
    JobContext context;
    std::map<std::string, std::pair<std::uint64_t, std::uint64_t>> last;  // stage -> (done, total)
    context.setProgressCallback([&](const std::string& stage, std::uint64_t done, std::uint64_t total) {
        EXPECT_LE(done, total) << stage;
        if (last.count(stage)) {
            EXPECT_GE(done, last[stage].first) << stage << " went backwards";
        }
        last[stage] = {done, total};
    });
    Job job(parse(kGyroid, dir), &context);
    job.mesh();
    for (const char* stage : {"solving density", "evaluating s", "meshing"}) {
        ASSERT_TRUE(last.count(stage)) << stage;
        EXPECT_EQ(last[stage].first, last[stage].second) << stage << " did not report completion";
    }
}

TEST(JobContext, WarningsGoToTheSinkAndTheReportNotTheTerminal)
{
    test::TempDir dir;
    JobContext context;
    std::vector<std::string> seen;
    context.setWarningSink([&](const Warning& w) { seen.push_back(w.code); });
    Job job(parse("voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n"
                  "  s: {tpms: gyroid, cell: 8, solid: sheet, thickness: 1.2}\nresult: s\n",
                  dir),
            &context);
    ASSERT_EQ(seen, std::vector<std::string>{"thick_walls"});
    const auto report = job.report();
    ASSERT_EQ(report["warnings"].size(), 1u);
    EXPECT_EQ(report["warnings"][0]["code"], "thick_walls");
    EXPECT_DOUBLE_EQ(report["warnings"][0]["cell_mm"].get<double>(), 8.0);
}

TEST(JobContext, CancelStopsTheJobAndWritesNothing)
{
    test::TempDir dir;
    JobContext context;
    // Cancel as soon as the evaluation completes: the next stage must not start.
    context.setProgressCallback([&](const std::string& stage, std::uint64_t done, std::uint64_t total) {
        if (stage.rfind("evaluating", 0) == 0 && done == total) context.cancel();
    });
    Job job(parse(kGyroid, dir), &context);
    const auto out = dir.path / "out";
    EXPECT_THROW(job.writeOutputs(out), Cancelled);
    std::size_t files = 0;
    if (std::filesystem::exists(out))
        for ([[maybe_unused]] const auto& f : std::filesystem::recursive_directory_iterator(out)) ++files;
    EXPECT_EQ(files, 0u) << "a cancelled job left files behind";
}

TEST(JobContext, CancelFromAnotherThreadStopsTheJob)
{
    test::TempDir dir;
    JobContext context;
    std::atomic<bool> started{false};
    // The first progress report hands over to another thread and waits until it has cancelled, so
    // the cancellation lands while a stage is under way, whatever the machine's speed.
    context.setProgressCallback([&](const std::string&, std::uint64_t, std::uint64_t) {
        started = true;
        while (!context.cancelled()) std::this_thread::yield();
    });
    Job job(parse(kGyroid, dir), &context);
    std::thread canceller([&] {
        while (!started) std::this_thread::yield();
        context.cancel();
    });
    EXPECT_THROW(job.grid(), Cancelled);
    canceller.join();
}

TEST(JobContext, ACancelledJobStopsWhileItsStrutFrameIsLaid)
{
    // A 200 x 110 x 20 mm plate of 2 mm BCC cells: 4.4e5 struts, seconds of frame, symmetry and
    // strut-table work before the first evaluation (the build stage had no cancel check).
    test::TempDir dir;
    JobContext context;
    context.cancel();
    EXPECT_THROW(Job(parse("voxel: 0.1\ndomain: {box: [[0, 0, 0], [200, 110, 20]]}\nfields:\n"
                           "  s: {struts: {cell: bcc, size: 2}, kernel: {gaussian: {sigma: 0.2}}, density: 0.2}\n"
                           "result: s\noutputs: {mesh: part.stl}\n",
                           dir),
                     &context),
                 Cancelled);
}

TEST(JobContext, FramesAndStrutTablesCallTheirInterrupter)
{
    // The interrupter is called once per row of cells and the first throw stops the frame.
    int rows = 0;
    EXPECT_THROW(boxFrame(presetUnitCell("bcc"), Vec3d(0.0), Vec3d(2.0), {40, 30, 20},
                          [&] {
                              if (++rows == 3) throw Cancelled("stop");
                          }),
                 Cancelled);
    EXPECT_EQ(rows, 3);
    int calls = 0;
    const Frame whole = boxFrame(presetUnitCell("bcc"), Vec3d(0.0), Vec3d(2.0), {40, 30, 20}, [&] { ++calls; });
    EXPECT_EQ(calls, 40 * 30);
    // The strut table: every 2^14 struts and before its index.
    std::vector<ConvolutionStrut> struts;
    for (const auto& s : whole.struts) struts.push_back({whole.nodes[s[0]], whole.nodes[s[1]], 0.2, 1.0, 1.0});
    ASSERT_GT(struts.size(), std::size_t(3) << 14);
    int checks = 0;
    EXPECT_THROW(StrutConvolution(struts, 1e-4,
                                  [&] {
                                      if (++checks == 3) throw Cancelled("stop");
                                  }),
                 Cancelled);
    EXPECT_EQ(checks, 3);
}

TEST(JobContext, TheDensitySolvesBandPassesCallTheirInterrupter)
{
    // The passes a coverage solve makes over its band after the evaluation (a plate's band holds
    // 10^7 voxels: seconds) call the interrupter, and its throw stops them.
    openvdb::FloatGrid grid(1.0f);
    const openvdb::CoordBBox box(openvdb::Coord(0), openvdb::Coord(63));
    for (auto it = box.begin(); it; ++it) grid.tree().setValue(*it, 0.01f * float((*it).x() - 32));
    auto throwing = [] { throw Cancelled("stop"); };
    EXPECT_THROW(splitByBand(grid, box, -0.1f, 0.1f, throwing), Cancelled);
    EXPECT_THROW(coverageSamples(grid, box, -0.1f, 0.1f, throwing), Cancelled);
    // Uninterrupted, the same passes give what they give without an interrupter.
    int calls = 0;
    const BandSplit split = splitByBand(grid, box, -0.1f, 0.1f, [&] { ++calls; });
    EXPECT_GT(calls, 0);
    EXPECT_EQ(split.below, splitByBand(grid, box, -0.1f, 0.1f).below);
    const CoverageSamples samples = coverageSamples(grid, box, -0.1f, 0.1f);
    ASSERT_FALSE(samples.empty());
    int steps = 0;
    const double level = bisectCoverage(samples, double(split.below),
                                        double(split.below) + 0.5 * double(samples.size()), -0.1, 0.1, [&] { ++steps; })
                             .level;
    EXPECT_GT(steps, 0);
    EXPECT_LE(steps, 60);
    EXPECT_EQ(level, bisectCoverage(samples, double(split.below), double(split.below) + 0.5 * double(samples.size()),
                                    -0.1, 0.1)
                         .level);
    EXPECT_THROW(bisectCoverage(samples, double(split.below), double(split.below) + 0.5 * double(samples.size()), -0.1,
                                0.1, throwing),
                 Cancelled);
}
