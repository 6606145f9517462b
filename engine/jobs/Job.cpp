#include "engine/jobs/Job.h"

#include "engine/jobs/MeshOffset.h"

#include "engine/checks/Pieces.h"
#include "engine/checks/SheetWalls.h"
#include "engine/checks/SurfaceThickness.h"
#include "engine/core/Format.h"
#include "engine/core/GridMeasure.h"
#include "engine/core/HeldGridField.h"
#include "engine/core/KeptGridLeaves.h"
#include "engine/core/SparseEvaluator.h"
#include "engine/core/SystemInfo.h"
#include "engine/core/Version.h"
#include "engine/core/VolumeSample.h"
#include "engine/density/DensitySolver.h"
#include "engine/jobs/Drains.h"
#include "engine/jobs/OutputPaths.h"
#include "engine/jobs/PiecesAdvice.h"
#include "engine/jobs/PropertiesJob.h"
#include "engine/jobs/PropertyDesign.h"
#include "engine/jobs/ReportPage.h"
#include "engine/jobs/SliceJob.h"
#include "engine/jobs/TrialRecipe.h"
#include "engine/recipe/RecipeParams.h"
#include "fields/core/BlockLattice.h"
#include "fields/core/GridValueMemo.h"
#include "fields/levels/GradedLevel.h"
#include "fields/shapes/Boolean.h"
#include "fields/shapes/BoxField.h"
#include "fields/shapes/Cylinder.h"
#include "fields/shapes/DrainChannels.h"
#include "fields/shapes/SurfaceDistance.h"
#include "fields/shapes/Unary.h"
#include "mesher/checks/MeshCheck.h"
#include "mesher/extract/BccTetrahedra.h"
#include "mesher/extract/MarchingCubes.h"
#include "mesher/extract/SignWords.h"
#include "mesher/tolerance/AdaptiveRefinement.h"
#include "mesher/tolerance/ClusterDecimation.h"
#include "mesher/tolerance/CreaseRefinement.h"
#include "mesher/tolerance/CreaseSplit.h"
#include "mesher/tolerance/Decimation.h"
#include "mesher/tolerance/ProjectedVolume.h"
#include "mesher/tolerance/SurfaceProjection.h"
#include "mesher/writers/AtomicFile.h"
#include "mesher/writers/MeshPreview.h"
#include "mesher/writers/MeshWriters.h"

#include <openvdb/io/Stream.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/global_control.h>
#include <tbb/info.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <climits>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <optional>
#include <sstream>
#include <thread>

namespace voxlat {

namespace {
/// A sheet's measured walls may miss `thickness:` by this share on average, and its thinnest 1 %
/// by this share, before the job warns.
constexpr double kWallMeanTolerance = 0.02;
constexpr double kWallThinTolerance = 0.10;
}  // namespace

namespace {
/// Voxels of margin around the result's box when the recipe gives no domain (room for the
/// mesher's cap and the blend of a smooth union).
constexpr int kAutoDomainMargin = 3;
/// How much coarser the density box is sampled for a trial whose result's level the homogenized
/// cell solves again (CellLevelTrial): it only places the level near the cell's.
constexpr double kCoarseLevelFactor = 3.0;

/// The bytes a GridValueMemo may keep of a solved lattice's raw values: a quarter of the memory
/// available, at most 1 GB.
std::size_t memoBudget()
{
    return std::size_t(std::min<double>(double(std::uint64_t(1) << 30), 0.25 * double(availableMemoryBytes())));
}

/// A stream buffer that gathers a file's bytes in memory, kWriteChunkBytes at a time, and calls
/// the write interrupter before each chunk: a .vdb is made in memory (its header's UUID is set
/// before the file is written), which takes seconds for a large grid; a cancel stops it.
class CheckedStringBuffer : public std::streambuf {
public:
    CheckedStringBuffer() : mChunk(kWriteChunkBytes) { setp(mChunk.data(), mChunk.data() + mChunk.size()); }
    /// Every byte written so far.
    std::string take()
    {
        gather();
        return std::move(mBytes);
    }

protected:
    int_type overflow(int_type c) override
    {
        checkWriteInterrupt();
        gather();
        if (!traits_type::eq_int_type(c, traits_type::eof())) {
            *pptr() = traits_type::to_char_type(c);
            pbump(1);
        }
        return traits_type::not_eof(c);
    }

private:
    void gather()
    {
        mBytes.append(pbase(), pptr());
        setp(mChunk.data(), mChunk.data() + mChunk.size());
    }
    std::vector<char> mChunk;
    std::string mBytes;
};

/// OpenVDB stamps every file with a random UUID (36 characters after the 21-byte header start),
/// so identical runs would differ. The UUID is replaced by one derived from @a recipeHash: the same
/// recipe gives the same bytes.
void setVdbUuid(std::string& data, const std::string& recipeHash)
{
    constexpr std::size_t kAt = 21, kLength = 36;
    const bool looksLikeUuid = data.size() > kAt + kLength && data[kAt + 8] == '-' && data[kAt + 13] == '-' &&
                               data[kAt + 18] == '-' && data[kAt + 23] == '-';
    if (!looksLikeUuid) throw JobError("unexpected OpenVDB file header: cannot make the .vdb output reproducible");
    const std::string h = recipeHash.substr(0, 32);
    const std::string uuid =
        h.substr(0, 8) + "-" + h.substr(8, 4) + "-" + h.substr(12, 4) + "-" + h.substr(16, 4) + "-" + h.substr(20, 12);
    data.replace(kAt, kLength, uuid);
}

/// The recipe's domain, or without `domain:` the result's box plus a margin, with its voxel
/// centres on the lattice (k + 1/2) * voxel, where a part's distance grid has its samples (and
/// where the faces of a part drawn in whole or half millimetres never lie).
Domain domainOf(const Recipe& recipe, const FieldNode& result)
{
    if (recipe.domainBox) return Domain::fromBox(*recipe.domainBox, recipe.voxel);
    const std::optional<Box3> support = result.support();
    if (!support)
        throw InputError(recipe.source->path + ": no `domain:` given and the result `" + recipe.result +
                         "` is unbounded (a lattice fills all space): add `domain: {box: [[x0, y0, z0], [x1, y1, z1]]}`"
                         " or intersect the result with a part or a shape");
    const double v = recipe.voxel;
    Box3 box;
    for (int a = 0; a < 3; ++a) {
        if (!(support->max[a] > support->min[a]))
            throw InputError(recipe.source->path + ": no `domain:` given and the result `" + recipe.result +
                             "` is empty (its operands do not overlap): check the result or give a domain");
        box.min[a] = (std::floor(support->min[a] / v) - kAutoDomainMargin) * v;
        box.max[a] = box.min[a] + (std::ceil((support->max[a] - box.min[a]) / v) + kAutoDomainMargin) * v;
    }
    return Domain::fromBox(box, v);
}

nlohmann::json vec(const Vec3d& v)
{
    return {v[0], v[1], v[2]};
}

/// The height of the lowest point of the solid {@a f < 0} inside @a box, when a support box is
/// conservative (a part's box grows by its grid's margin): samples at spacing @a h rise slab by
/// slab (eight samples deep) from the box's floor until one is solid; the lowest solid sample's
/// column is then bisected between it and the void sample below it. The box's floor when the
/// solid reaches it or none is found. The same for any thread count (the lowest sample is the
/// first in lattice order among the slab's lowest). Stops when @a context is cancelled.
double lowestSolidZ(const FieldNode& f, const Box3& box, double h, const JobContext& context)
{
    BlockLattice lattice;
    lattice.base = box.min;
    lattice.step = Vec3d(h);
    lattice.offset = Vec3d(0.5);
    for (int a = 0; a < 2; ++a) lattice.count[a] = std::max(1, int(std::ceil(box.extent()[a] / h)));
    lattice.count[2] = 8;
    const int slabs = std::max(1, int(std::ceil(box.extent().z() / (8.0 * h))));
    for (int s = 0; s < slabs; ++s) {
        lattice.base.z() = box.min.z() + 8.0 * h * s;
        std::vector<std::array<int, 3>> lowest(lattice.blockCount(), {INT_MAX, INT_MAX, INT_MAX});
        sampleBlocks(f, lattice,
                     [&](std::size_t b, const GridBatch& batch, const std::array<int, 3>& first,
                         std::span<const double> values) {
                         context.checkCancelled();
                         std::size_t n = 0;
                         for (int i = 0; i < batch.nx; ++i)
                             for (int j = 0; j < batch.ny; ++j)
                                 for (int k = 0; k < batch.nz; ++k, ++n)
                                     if (values[n] < 0.0) {
                                         const std::array<int, 3> at{first[2] + k, first[0] + i, first[1] + j};
                                         lowest[b] = std::min(lowest[b], at);
                                     }
                     });
        const std::array<int, 3> low = *std::min_element(lowest.begin(), lowest.end());
        if (low[0] == INT_MAX) continue;
        const double x = box.min.x() + (low[1] + 0.5) * h, y = box.min.y() + (low[2] + 0.5) * h;
        double solid = lattice.base.z() + (low[0] + 0.5) * h, empty = solid - h;
        if (empty <= box.min.z()) return box.min.z();
        for (int it = 0; it < 40; ++it) {
            const double mid = 0.5 * (solid + empty);
            (f.value(Vec3d(x, y, mid)) < 0.0 ? solid : empty) = mid;
        }
        return empty;
    }
    return box.min.z();
}

/// Target (mean of the density field over the slab's voxel centres, sampled with a stride) and
/// achieved (inside voxels of the grid) density per slab of @a slab mm along @a axis.
nlohmann::json densityBySlab(const openvdb::FloatGrid& grid, const Domain& domain, const FieldNode& density, int axis,
                             double slab)
{
    const int perSlab = std::max(1, int(std::lround(slab / domain.voxel)));
    const int n = domain.dims[axis];
    nlohmann::json slabs = nlohmann::json::array();
    double worst = 0.0;
    for (int first = 0; first < n; first += perSlab) {
        openvdb::CoordBBox region = domain.indexBox();
        region.min()[axis] = first;
        region.max()[axis] = std::min(n, first + perSlab) - 1;
        const double achieved = double(countBelow(grid, region, 0.0f)) / double(region.volume());
        // About 2e5 samples per slab, in a fixed order.
        const int stride = std::max(1, int(std::cbrt(double(region.volume()) / 2e5)));
        std::vector<Vec3d> points;
        const int skip = (stride - 1) / 2;  // centre the strided samples in the slab
        for (int i = region.min().x() + skip; i <= region.max().x(); i += stride)
            for (int j = region.min().y() + skip; j <= region.max().y(); j += stride)
                for (int k = region.min().z() + skip; k <= region.max().z(); k += stride)
                    points.push_back(domain.worldOf(openvdb::Coord(i, j, k)));
        std::vector<double> rho(points.size());
        density.values(points, rho);
        double sum = 0.0;
        for (double r : rho) sum += r;
        const double target = sum / double(rho.size());
        worst = std::max(worst, std::abs(achieved - target));
        slabs.push_back({{"from_mm", domain.box.min[axis] + first * domain.voxel},
                         {"to_mm", domain.box.min[axis] + (region.max()[axis] + 1) * domain.voxel},
                         {"target", target},
                         {"achieved", achieved}});
    }
    return {{"axis", std::string(1, "xyz"[axis])}, {"slabs", slabs}, {"max_abs_error", worst}};
}

/// A mesher's progress (a fraction, from any thread) fed into a stage of 1000 units.
ProgressFn feed(StageProgress& progress, std::atomic<std::uint64_t>& last)
{
    return [&progress, &last](double fraction) {
        // Every call checks the cancel flag (add(0) too): a phase that reports the same
        // fraction again still stops.
        const auto now = std::uint64_t(std::clamp(fraction, 0.0, 1.0) * 1000);
        std::uint64_t before = last.load(std::memory_order_relaxed);
        while (now > before && !last.compare_exchange_weak(before, now, std::memory_order_relaxed)) {
        }
        progress.add(now > before ? now - before : 0);
    };
}

/// Runs @a work with a ProgressFn that reports @a label's progress through @a context and stops
/// it (Cancelled) once the job is cancelled.
template <class Work>
auto reporting(const JobContext* context, const std::string& label, Work&& work)
{
    StageProgress progress(context, label, 1000);
    std::atomic<std::uint64_t> last{0};
    return work(feed(progress, last));
}

/// A test hook for bench/cancel_latency.py: VOXLAT_TEST_CANCEL_AT=STAGE cancels the job the way a
/// signal does, VOXLAT_TEST_CANCEL_AFTER_MS after the stage of that name (a key of report.json's
/// `timings_s`) begins (at once by default), and VOXLAT_TEST_CANCEL_STAMP=FILE records when
/// (steady clock, CLOCK_MONOTONIC, in ns), so the time the stage takes to stop can be measured
/// from outside.
void cancelAtTestStage(const std::string& stage, JobContext& context)
{
    static const char* const at = std::getenv("VOXLAT_TEST_CANCEL_AT");
    if (at == nullptr || stage != at || context.cancelled()) return;
    const char* after = std::getenv("VOXLAT_TEST_CANCEL_AFTER_MS");
    const int delayMs = after ? std::atoi(after) : 0;
    const char* stamp = std::getenv("VOXLAT_TEST_CANCEL_STAMP");
    auto cancel = [&context, stamp, delayMs] {
        if (delayMs > 0) std::this_thread::sleep_for(std::chrono::milliseconds(delayMs));
        if (stamp)
            std::ofstream(stamp) << std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::steady_clock::now().time_since_epoch())
                                        .count()
                                 << '\n';
        context.cancel();
    };
    if (delayMs > 0)
        std::thread(cancel).detach();  // the context outlives the job (the command line's)
    else
        cancel();
}
}  // namespace

template <typename Fn>
auto Job::timed(const std::string& stage, Fn&& fn)
{
    cancelAtTestStage(stage, *mContext);
    const auto start = std::chrono::steady_clock::now();
    struct Record {
        nlohmann::json& timings;
        const std::string& stage;
        std::chrono::steady_clock::time_point start;
        ~Record() { timings[stage] = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(); }
    } record{mTimings, stage, start};
    return fn();
}

Job::Job(Recipe recipe, JobContext* context)
    : mOwnContext(context ? nullptr : std::make_unique<JobContext>()),
      mContext(context ? context : mOwnContext.get()),
      mRecipe(std::move(recipe)),
      mBuilder(mRecipe, *mContext)
{
    // `stiffness:` and `optimize:` become a `density:` and a `sigma:` before anything is built.
    {
        const auto start = std::chrono::steady_clock::now();
        mDesign = resolvePropertyTargets(mRecipe, mContext);
        if (!mDesign.empty()) mReport["design"] = mDesign;
        if (!mDesign.empty())
            mTimings["design from properties"] =
                std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    }
    timed("build fields", [&] {
        // Build every field, so a mistake anywhere in the recipe is reported before any work.
        mResult = mBuilder.buildAll();
        drainForSlices();
        return 0;
    });
    try {
        mDomain = domainOf(mRecipe, *mResult);
    } catch (const InputError& e) {
        const std::string message = e.what();
        if (message.rfind(mRecipe.source->path + ":", 0) == 0) throw;  // placed already
        throw InputError(mRecipe.voxelWhere + ": voxel: " + message);  // the voxel against the part's box
    }
    if (double(mDomain.voxelCount()) > kMaxDomainVoxels) {
        const std::string message = "the domain holds " + formatNumber(double(mDomain.voxelCount())) +
                                    " voxels, more than the " + formatNumber(kMaxDomainVoxels) +
                                    " a job can cull in reasonable memory: raise `voxel:` or shrink the domain";
        // A job this machine cannot run (exit 3), said before any allocation.
        throw JobError(mRecipe.voxelWhere + ": " + message);
    }
    // Grids, meshes and slices keep coordinates in single precision (24 bits): a part far from
    // the origin against its voxel loses its shape (at 1e9 mm every vertex had one x). Refused
    // with the limit rather than written wrong.
    {
        double far = 0.0;
        for (int a = 0; a < 3; ++a) far = std::max({far, std::abs(mDomain.box.min[a]), std::abs(mDomain.box.max[a])});
        if (far > kMaxVoxelsFromOrigin * mDomain.voxel)
            throw InputError(mRecipe.domainWhere + ": the part lies " + formatNumber(far) +
                             " mm from the origin, more than " + formatNumber(kMaxVoxelsFromOrigin) + " voxels (" +
                             formatNumber(kMaxVoxelsFromOrigin * mDomain.voxel) +
                             " mm at this voxel): single-precision vertices would lose its shape; model it near the "
                             "origin and move it in the slicer or CAD tool");
    }
    for (const OutputSpec& out : mRecipe.outputs)
        if (out.kind == "frame" && mBuilder.strutFrames().empty())
            throw InputError(
                out.where +
                ": outputs: a frame output writes the struts of a `struts:` field, and this recipe has none");
    for (const FieldBuilder::Preparation& p : mBuilder.preparations())
        timed(p.stage, [&] {
            p.run();
            return 0;
        });
    mReport["recipe"] = mRecipe.source->path;
    mReport["voxlat_version"] = versionString();
    // The recipe as run (includes merged, parameters and --set applied), so any part can be re-made.
    mReport["recipe_canonical"] = canonicalRecipe(mRecipe);
    mReport["recipe_sha256"] = recipeHash(mRecipe);
    mReport["domain"] = {{"from", mRecipe.domainBox ? "recipe" : "result's bounding box plus a margin"},
                         {"min", vec(mDomain.box.min)},
                         {"max", vec(mDomain.box.max)},
                         {"voxel", mDomain.voxel},
                         {"dims", {mDomain.dims.x(), mDomain.dims.y(), mDomain.dims.z()}},
                         {"voxels", mDomain.voxelCount()}};
    if (mRecipe.domainBox) {
        for (int a = 0; a < 3; ++a)
            if (std::abs(mDomain.box.max[a] - mRecipe.domainBox->max[a]) > 1e-6 * mDomain.voxel)
                mContext->warn(
                    "domain_snapped",
                    "the domain is snapped to a whole number of voxels: " + formatNumber(mDomain.box.max[a]) +
                        " instead of " + formatNumber(mRecipe.domainBox->max[a]) + " on axis " + "xyz" [a],
                    {
                        {"axis", std::string(1, "xyz"[a])}, {"snapped_mm", mDomain.box.max[a]},
                        {
                            "recipe_mm", mRecipe.domainBox->max[a]
                        }
                    });
    }
}

namespace {

/// @a node's level in @a entry: `level` as the recipe's key means it and, for a Gaussian lattice
/// (whose solid's own level is the iso-radius rho, signed), `level_radius_mm`, the radius of an
/// isolated strut at that iso-value, only where one exists: above an isolated strut's peak P
/// (rho < 0: a dense frame whose struts show only where they overlap) no strut has a radius, and
/// `level_above_strut_peak` says so instead of a negative number under a radius's name.
void reportLevel(const LevelNode& node, double level, nlohmann::json& entry)
{
    entry["level"] = node.recipeLevel ? node.recipeLevel(level) : level;
    if (!node.recipeLevel) return;
    if (level >= 0.0) {
        entry["level_radius_mm"] = level;
        entry.erase("level_above_strut_peak");
    } else {
        entry.erase("level_radius_mm");
        entry["level_above_strut_peak"] =
            "the iso-value is above an isolated strut's peak P (in `type`): no isolated strut has a radius at it; "
            "the solid is where struts overlap";
    }
}

}  // namespace

void Job::checkSheetWalls(const LevelNode& node, nlohmann::json& entry)
{
    const LevelNode::WallCheck& w = *node.wallCheck;
    const SheetWallStats s =
        timed("measure walls " + node.name, [&] { return measureSheetWalls(*w.mid, *w.sheet, w.cell, w.thickness); });
    if (s.samples == 0) return;
    entry["walls_measured"] = {
        {"thickness_mm", w.thickness},
        {"mean_mm", s.mean},
        {"p01_mm", s.p01},
        {"min_mm", s.min},
        {"max_mm", s.max},
        {"samples", s.samples},
        {"measure",
         "the chord along the mid-surface's normal between the sheet's faces, at mid-surface points of "
         "one cell"}};
    const double meanGap = s.mean / w.thickness - 1.0, thin = s.p01 / w.thickness - 1.0;
    if (std::abs(meanGap) > kWallMeanTolerance || thin < -kWallThinTolerance) {
        char numbers[200];
        std::snprintf(numbers, sizeof numbers,
                      "the walls of `%s` measure %.3g mm on average (%+.1f %%), the thinnest 1 %% under %.3g mm, for "
                      "`thickness: %g`",
                      node.name.c_str(), s.mean, 100.0 * meanGap, s.p01, w.thickness);
        mContext->warn("wall_thickness",
                       std::string(numbers) +
                           ": the shift along the gradient is exact only where the walls are thin against their "
                           "curvature; a larger `cell:`, a thinner wall, or `density:` (solved on the voxels) instead",
                       {{"field", node.name}, {"thickness_mm", w.thickness}, {"mean_mm", s.mean}, {"p01_mm", s.p01}});
    }
}

void Job::drainForSlices()
{
    bool drained = false;
    for (const OutputSpec& out : mRecipe.outputs) {
        if (out.kind != "slices") continue;
        const SliceSettings& settings = *out.slices;
        if (!settings.drainDiameter) continue;
        const double diameter = *settings.drainDiameter;
        const std::string where = settings.drainWhere + ": outputs `drain`: ";
        if (drained)
            throw InputError(where + "the result is drained once for every output: give `drain:` on one slices output");
        for (const DrainRequest& d : mBuilder.drains())
            if (d.name == mRecipe.result)
                throw InputError(where + "the result `" + d.name + "` drains its traps already (`drain:` at " +
                                 d.where + "): remove one of the two");
        if (diameter < 2.0 * mRecipe.voxel)
            throw InputError(settings.drainDiameterWhere + ": outputs `drain` `diameter`: a drain channel of " +
                             formatNumber(diameter) + " mm is less than two voxels (" +
                             formatNumber(2.0 * mRecipe.voxel) +
                             " mm) across: it would not show on the grid; use 1.5 mm or more (resin drains through "
                             "1.5-3 mm holes)");
        auto node = std::make_shared<DrainedSolid>(mResult);
        // No part here: a channel ends in the void the trap search reaches from outside; walls
        // are searched at the recipe's voxel.
        mBuilder.addDrain({mRecipe.result, settings.drainWhere, node, nullptr, diameter, 2.0 * mRecipe.voxel});
        mResult = node;
        drained = true;
    }
}

void Job::reportThinnest(const LevelNode& node, double level, nlohmann::json& entry)
{
    if (!node.thinnest) return;
    // Known before any evaluation of the result: a strut or wall thinner than two voxels breaks up
    // or vanishes on the grid (and in the mesh and slices made from it). Told again when the level
    // moves for the mesh (aimLevelsAtMesh): the warning gives the numbers of the level the outputs
    // are made at, as `thinnest_*_mm` does.
    const bool wall = node.thinnestKind == "wall";
    const std::string features = wall ? "walls" : "struts";
    const double thinnest = node.thinnest(level);
    entry[wall ? "thinnest_wall_mm" : "thinnest_strut_mm"] = thinnest;
    if (thinnest <= 0.0)
        mContext->warnAgain({"sub_voxel_features",
                             "field `" + node.name +
                                 "`: at its level some struts vanish between their joints (the iso-value is "
                                 "above their peak): only the joints remain there; lower sigma or raise the "
                                 "density or radius",
                             {{"field", node.name}, {"thinnest_mm", 0.0}, {"voxel_mm", mDomain.voxel}}});
    else if (thinnest < 2.0 * mDomain.voxel)
        mContext->warnAgain({"sub_voxel_features",
                             "field `" + node.name + "`: its thinnest " + features + " are " + formatNumber(thinnest) +
                                 " mm across, less than two voxels (" + formatNumber(2.0 * mDomain.voxel) +
                                 " mm): on the grid they break apart or vanish; use `voxel: " +
                                 formatNumber(std::max(thinnest, 1e-3) / 2.0) + "` or less, or thicken them (" +
                                 (wall ? "thickness, level, density" : "radius, density") + ")",
                             {{"field", node.name},
                              {"thinnest_mm", thinnest},
                              {"voxel_mm", mDomain.voxel},
                              {"voxel_needed_mm", thinnest / 2.0}}});
    else
        mContext->withdraw("sub_voxel_features", node.name);
}

void Job::solveLevels()
{
    if (mSolved) return;
    nlohmann::json fields = nlohmann::json::object();
    for (const LevelNode& node : mBuilder.levelNodes()) {
        // The result's grids in the stacks its lattices ask for, their levels solved or given; a
        // solve on the recipe's lattice in the same stacks (one height per node: the memo serves
        // the grids the solve's batches only when both ask for the same).
        const int nodeStackLeaves = stackLeavesFor(mDomain, node.stackLeaves);
        mStackLeaves = std::max(mStackLeaves, nodeStackLeaves);
        nlohmann::json entry{{"type", node.description}};
        if (node.density) {
            // A trial's result whose level the homogenized cell solves again: a coarse solve
            // places it (CellLevelTrial).
            const double coarse =
                CellLevelTrial::active() && node.name == mRecipe.result && !node.densityMask ? kCoarseLevelFactor : 1.0;
            const std::vector<DensityPiece> pieces =
                node.densityPeriod && node.densityBox && node.densityVoxel
                    ? periodicPieces(*node.densityBox, *node.densityPeriod, node.densityReach,
                                     *node.densityVoxel * coarse, node.densityMirror, node.densitySwapXY)
                    : std::vector<DensityPiece>{};
            // A frame box measured on the job's own voxels (densityOnJobVoxels): the box with its
            // faces moved to the nearest faces of the job's voxels (at most half a voxel: no voxel
            // centre on a face, where a face through a plane of centres counted that plane whole,
            // 1 % of an 8 mm box), as a mask of the job's domain where it leaves out some of the
            // domain's voxels, the domain's lattice continued past its faces where the box pokes
            // out (a wireframe's moved nodes): boxMargin voxels.
            std::optional<Box3> jobVoxelBox;
            int boxMargin = 0;
            bool wholeDomain = true;
            if (pieces.empty() && coarse == 1.0 && node.densityBox && !node.densityMask && node.densityOnJobVoxels) {
                Box3 snapped;
                bool empty = false;
                std::array<int, 3> lo{}, hi{};
                for (int a = 0; a < 3; ++a) {
                    // Halves rounded up on both sides (std::round's ties away from zero would widen a
                    // box whose faces lie on planes of centres either side of the domain's corner).
                    lo[a] = int(std::floor((node.densityBox->min[a] - mDomain.box.min[a]) / mDomain.voxel + 0.5));
                    hi[a] = int(std::floor((node.densityBox->max[a] - mDomain.box.min[a]) / mDomain.voxel + 0.5));
                    empty = empty || !(hi[a] > lo[a]);
                    snapped.min[a] = mDomain.box.min[a] + lo[a] * mDomain.voxel;
                    snapped.max[a] = mDomain.box.min[a] + hi[a] * mDomain.voxel;
                    boxMargin = std::max({boxMargin, -lo[a], hi[a] - mDomain.dims[a]});
                }
                // The solve measures the domain's voxels and boxMargin more on every side: that
                // is the box only where the box pokes out by boxMargin on every face; else the box
                // is a mask (a box poking out of one face by 0.3 mm and another by 0.2 mm was
                // measured 0.1 mm past the second: an 8 mm frame 2.9 % denser than asked).
                for (int a = 0; a < 3; ++a)
                    wholeDomain = wholeDomain && lo[a] == -boxMargin && hi[a] == mDomain.dims[a] + boxMargin;
                if (!empty) jobVoxelBox = snapped;
            }
            const bool onJobVoxels = jobVoxelBox.has_value();
            const std::unique_ptr<BoxField> boxMask =
                onJobVoxels && !wholeDomain ? std::make_unique<BoxField>(*jobVoxelBox) : nullptr;
            // A solve on the recipe's own lattice evaluates the band's leaves as the grid will:
            // asked by a mesh (mKeepSolvedValues), the raw field's values are kept for it
            // (GridValueMemo, the same values), so each band leaf is evaluated once.
            const bool recipeLattice = pieces.empty() && coarse == 1.0 && (!node.densityBox || onJobVoxels);
            // Once the solve knows the band its level lies in, the values a grid at such a level
            // does not read are dropped (a 50 mm trimmed frame: a fifth of them, 0.17 GB, before
            // the solve's coverage pass, its peak).
            std::function<void(Interval)> levelWithin;
            const auto* memo = dynamic_cast<const GridValueMemo*>(node.solid->raw().get());
            // Solved on the recipe's lattice in the stacks the result's grids are evaluated in:
            // those then ask the memo for the solve's batches.
            const int stackLeaves = recipeLattice ? nodeStackLeaves : 1;
            // A coverage solve (masked or sub-voxel) measures a grid of the memo's own values: it
            // hands that grid over (solveDensity's keepGrid) and the memo keeps nothing of its own
            // meanwhile, so the values are not held twice while the solve measures them (a 50 mm
            // wireframe: 0.55 GB each).
            std::function<void(openvdb::FloatGrid::Ptr)> keepGrid;
            const bool masked = onJobVoxels ? bool(boxMask) : bool(node.densityMask);
            if (memo && recipeLattice && mKeepSolvedValues && node.solid->indicator().get() == memo) {
                const bool gridHandedOver = masked || node.subVoxelDensity;
                memo->keep(true, gridHandedOver ? 0 : memoBudget());
                mSolvedValues.push_back(memo);
                // The dropped values' blocks are unmapped whole (MappedBlock): no heap trim after
                // them, which would split the huge pages of the values kept (every later first read
                // of one of their 4 KB pages then faults in the guest's host: a trimmed 50 mm
                // frame 8.1-8.6 s without, 8.7-9.9 s with; 20 MB more at its peak).
                levelWithin = [memo](Interval levels) { memo->dropOutside(levels); };
                // The grid handed over is kept whole, not dropped to the band its level lies in:
                // the leaves whose values miss the band each needed the field's bound to tell
                // whether a grid in the band reads them, and those bounds cost more than the
                // memory they freed (the drop alone took 0.17 s on W2g's 50 mm cylinder frame and
                // 0.23 s on its trimmed one; their solves 3.48-3.58 -> 3.17-3.40 s and 2.43-3.01 ->
                // 2.23-2.27 s, the trimmed frame's peak 1024-1061 -> 1073-1089 MB, the others' the
                // same). The leaves the next evaluation reads are freed as it reads them
                // (consumeLeaves), the others with the memo.
                if (gridHandedOver)
                    keepGrid = [memo, this](openvdb::FloatGrid::Ptr grid) {
                        memo->keepLeaves(std::make_unique<KeptGridLeaves>(std::move(grid), mDomain), memoBudget());
                    };
            }
            const DensitySolution s = timed("solve " + node.name, [&] {
                if (!pieces.empty())
                    return solveDensity(node.densityIndicator ? *node.densityIndicator : *node.solid->indicator(),
                                        pieces, *node.density, mContext);
                if (onJobVoxels)
                    return solveDensity(*node.solid->indicator(), mDomain, *node.density, boxMask.get(),
                                        node.subVoxelDensity, mContext, boxMargin, levelWithin, stackLeaves, keepGrid);
                const double voxel = node.densityBox && node.densityVoxel ? *node.densityVoxel : mDomain.voxel;
                const Domain measured = node.densityBox && (node.densityVoxel || coarse > 1.0)
                                            ? Domain::fromBox(*node.densityBox, voxel * coarse)
                                        : coarse > 1.0    ? Domain::fromBox(mDomain.box, voxel * coarse)
                                        : node.densityBox ? mDomain.subDomain(*node.densityBox)
                                                          : mDomain;
                // In the stacks its lattice asks for, as tall as the measured domain repays: on the
                // recipe's lattice (measured is mDomain) the grids' own, stackLeaves; on a lattice of
                // its own (a frame's box at its own voxel, no grid of the job's to serve) a strut
                // row's set-up and table then serve sixteen leaves, not one (W2g's cylinder frame
                // at 0.2 mm measures 1.16 times finer than the job, leaf by leaf before).
                return solveDensity(*node.solid->indicator(), measured, *node.density, node.densityMask.get(),
                                    node.subVoxelDensity, mContext, 0, levelWithin,
                                    stackLeavesFor(measured, node.stackLeaves), keepGrid);
            });
            if (node.densityMask) entry["density_measured_in"] = node.densityOf;
            // The region's volume: the mask's voxels, or the box the density is measured over.
            const double measuringVoxel = node.densityBox && node.densityVoxel ? *node.densityVoxel : mDomain.voxel;
            const Box3 box = node.densityBox ? *node.densityBox : mDomain.box;
            mDensityRegionMm3[node.name] = node.densityMask ? s.maskCoverageVoxels * std::pow(measuringVoxel, 3)
                                                            : box.extent()[0] * box.extent()[1] * box.extent()[2];
            // The region whose share `density:` is, in the words a user set it in.
            entry["density_measured_on"] = node.densityOf.empty() ? "the domain box" : node.densityOf;
            node.solid->solve(node.solid->levelFromIndicator(s.level));
            const bool solvedOnJobVoxels = coarse == 1.0 && measuringVoxel == mDomain.voxel && pieces.empty() &&
                                           (!node.densityBox || (onJobVoxels && !boxMask && boxMargin == 0));
            mSolvedDensity[node.name] = {s.level, s.slope, s.achieved, solvedOnJobVoxels, s.coverage};
            if (node.onSolved) node.onSolved(node.solid->level());
            entry["target_density"] = *node.density;
            entry["achieved_density"] = s.achieved;
            // A solve that cannot reach its target (a cell of 1e300 mm: the domain holds no
            // surface) would give an empty or solid part at exit 0: a failed check instead. (A
            // coarse grid's ties may miss by tens of percent; that is the voxel's, and reported.)
            if ((s.achieved <= 0.0 || s.achieved >= 1.0) && *node.density > 0.0 && *node.density < 1.0)
                throw JobError(mRecipe.source->path + ": field `" + node.name + "` reaches a density of " +
                               formatNumber(s.achieved) + ", not the " + formatNumber(*node.density) +
                               " asked: no level of this field holds that share of the domain, the part would be " +
                               (s.achieved <= 0.0 ? "empty" : "solid") +
                               " (check its cell size against the domain, and its equation)");
            entry["solve_rounds"] = s.rounds;
            entry["density_measure"] = s.coverage ? "sub-voxel coverage" : "voxel count";
            entry["evaluated_leaves"] = s.evaluatedLeaves;
            // The solve's own refusal estimate (a solve sampled on one period's pieces keeps no grid
            // of the domain and states none).
            if (s.estimatedBytes > 0) entry["memory_estimate_mb"] = double(s.estimatedBytes) / (1024.0 * 1024.0);
            if (!pieces.empty())
                entry["density_sampling"] =
                    "one period of the interior (" + std::to_string(pieces.size()) + " weighted pieces)";
        }
        if (node.wallCheck) checkSheetWalls(node, entry);
        if (mDesign.contains(node.name)) entry.update(mDesign[node.name]);
        // Under the recipe key's name, what the key means (a Gaussian lattice's iso-value t); the
        // solid's own level (an isolated strut's radius) under its own name.
        reportLevel(node, node.solid->level(), entry);
        reportThinnest(node, node.solid->level(), entry);
        if (const double bound = node.gridNodesBound ? node.gridNodesBound(mDomain.voxel) : 0.0; bound > 0.0)
            entry["grid_values"] = {
                {"from", "exact nodes every second voxel, eight-point Lagrange stencils between them"},
                {"node_spacing_mm", 2.0 * mDomain.voxel},
                {"bound_per_peak", bound},
                {"bound_of",
                 "the struts' summed peaks within reach of a point: the most a value may miss the "
                 "exact field's by"}};
        fields[node.name] = entry;
    }
    for (const GradedNode& node : mBuilder.gradedNodes()) {
        const auto& table = static_cast<const GradedLevel&>(*node.node).table();
        fields[node.name] = {{"type", node.description + " (graded)"},
                             {"target_density", node.density},
                             {"density_table",
                              {{"samples", table.sampleCount()},
                               {"level_at_10_percent", table.levelAt(0.1)},
                               {"level_at_50_percent", table.levelAt(0.5)},
                               {"level_at_90_percent", table.levelAt(0.9)}}}};
    }
    mReport["fields"] = fields;
    // Drain channels need the levels (a trap is the void of the solved solid).
    if (!mBuilder.drains().empty())
        mReport["drain"] = timed("drain holes", [&] { return planDrains(mBuilder.drains(), mDomain.voxel, mContext); });
    // A field infinite everywhere (`1/0`, a number past 1.8e308) is culled as outside before any
    // leaf is evaluated: the evaluator's NaN check never sees it, and the part came out empty at
    // exit 0. 27 voxel centres of the grid (its corners, edge and face middles, middle) catch it;
    // the grid's own points, so a pole between them (1/x at x = 0) is no error.
    for (int i = 0; i < 27; ++i) {
        const int t[3] = {i % 3, i / 3 % 3, i / 9};
        openvdb::Coord ijk;
        for (int a = 0; a < 3; ++a) ijk[a] = t[a] * (std::max(1, mDomain.dims[a]) - 1) / 2;
        const Vec3d p = mDomain.worldOf(ijk);
        const double v = mResult->value(p);
        if (!std::isfinite(v))
            throw JobError(mRecipe.source->path + ": the result `" + mRecipe.result + "` is " + formatNumber(v) +
                           " at (" + formatNumber(p[0]) + ", " + formatNumber(p[1]) + ", " + formatNumber(p[2]) +
                           "), not a finite number: check divisions by zero and numbers past 1.8e308 in its fields");
    }
    mSolved = true;
}

FieldPtr Job::field(const std::string& name)
{
    solveLevels();
    return mBuilder.field(name);
}

const openvdb::FloatGrid& Job::grid()
{
    if (!mGrid) evaluateRecipeGrid(true);
    return *mGrid;
}

bool Job::measureVolume(std::uint64_t maxVoxels)
{
    if (mDomain.voxelCount() <= maxVoxels || mReport.contains("pieces")) {
        grid();
        return false;
    }
    solveLevels();
    // Estimated from random points, one in each of about maxVoxels / 16 cells of the domain's box
    // (a stratified sample: the same points for any thread count), with its standard error. A
    // count on a coarser grid, as before, gave no error it could state: its difference from a
    // count at twice its voxel was no bound (the shipped BCC convolution 173 mm3 off with a
    // difference of 320), and a strut plate took 15 s of CPU for it (W10).
    const std::uint64_t points = std::max<std::uint64_t>(1024, maxVoxels / 16);
    const VolumeSample sample = timed("estimate volume", [&] {
        return sampleVolume(*mResult, mDomain.box, points, 1, [&] { mContext->checkCancelled(); });
    });
    const Vec3d extent = mDomain.box.extent();
    const double volume = extent.x() * extent.y() * extent.z();
    mReport["result"] = {{"field", mRecipe.result},
                         {"volume_fraction", sample.fraction},
                         {"volume_mm3", sample.fraction * volume},
                         {"estimated",
                          {{"method",
                            "random points, one at a uniform place in each cell of a grid over the domain's "
                            "box (stratified); the standard error is the collapsed-strata estimate (cells "
                            "paired), not a bound"},
                           {"points", sample.points},
                           {"cells", {sample.cells[0], sample.cells[1], sample.cells[2]}},
                           {"inside", sample.inside},
                           {"standard_error_mm3", sample.standardError * volume},
                           {"standard_error_fraction", sample.standardError}}}};
    return true;
}

void Job::evaluateRecipeGrid(bool keep)
{
    solveLevels();
    // Measured once: a grid freed and asked for again is the same grid.
    const bool measured = mReport.contains("pieces");
    if (measured && (mGrid || !keep)) return;
    SparseStats stats;
    // Without the grid: each leaf's solid bits, gathered per thread as the leaves are evaluated.
    tbb::enumerable_thread_specific<std::vector<SolidBlock>> leafBits;
    openvdb::FloatGrid::Ptr g;
    if (mAimGrid) {
        // Evaluated at this level already, to measure the mesh's share (aimLevelsAtMesh()).
        g = std::move(mAimGrid);
        stats = mAimStats;
    } else if (keep) {
        g = evaluateResult(stats);
    } else {
        g = evaluateResult(stats, [&](const openvdb::Coord& origin, const float* values) {
            SolidBlock& b = leafBits.local().emplace_back();
            b.origin = origin;
            belowWords(values, 0.0f, b.bits.data());
        });
    }
    if (keep) {
        mGrid = g;
        mGrid->setName(mRecipe.result);
    }
    if (measured) return;
    const std::uint64_t inside = stats.domainVoxelsBelowZero;
    mReport["result"] = {{"field", mRecipe.result},
                         {"volume_fraction", double(inside) / double(mDomain.voxelCount())},
                         {"volume_mm3", double(inside) * std::pow(mDomain.voxel, 3)},
                         {"evaluated_leaves", stats.leaves},
                         {"memory_estimate_mb", double(stats.estimatedBytes) / (1024.0 * 1024.0)},
                         {"inside_tiles", stats.insideTiles}};
    {
        // Gathered into one vector sized once, the cancel checked between the threads' parts.
        std::size_t total = 0;
        for (const std::vector<SolidBlock>& part : leafBits) total += part.size();
        std::vector<SolidBlock> leaves;
        leaves.reserve(total);
        for (std::vector<SolidBlock>& part : leafBits) {
            mContext->checkCancelled();
            leaves.insert(leaves.end(), part.begin(), part.end());
            std::vector<SolidBlock>().swap(part);
        }
        mContext->checkCancelled();
        // solidBlocks checks the cancel to its last step (after its sort), checkPieces from its first.
        checkPieces(solidBlocks(*g, std::move(leaves), [&] { mContext->checkCancelled(); }));
    }
    if (!mBuilder.gradedNodes().empty())
        timed("measure slabs", [&] {
            for (const GradedNode& node : mBuilder.gradedNodes()) {
                // Measure the graded node itself: on the result grid when it is the result, else on
                // a grid of its own.
                openvdb::FloatGrid::ConstPtr own = g;
                if (node.node != mResult) {
                    SparseOptions options;
                    options.clipToDomain = true;
                    options.stage = "measuring " + node.name;
                    options.context = mContext;
                    own = evaluateSparse(*node.node, mDomain, options);
                }
                mReport["fields"][node.name]["slabs"] =
                    densityBySlab(*own, mDomain, *node.densityField, node.axis, node.slab);
            }
            return 0;
        });
}

openvdb::FloatGrid::Ptr Job::evaluateResult(SparseStats& stats,
                                            std::function<void(const openvdb::Coord&, const float*)> leafVisitor)
{
    return timed("evaluate", [&] {
        SparseOptions options;
        options.clipToDomain = true;
        options.stage = "evaluating " + mRecipe.result;
        options.context = mContext;
        options.leafVisitor = std::move(leafVisitor);
        options.stackLeaves = mStackLeaves;
        if (mRecipe.firstOutput("mesh")) options.bytesBeside = kStreamedMeshBytes;
        // The last evaluation to read them: each leaf the solve handed over is freed as it is
        // served, and the grid's new leaves take its memory (not pages fresh to the process).
        for (const GridValueMemo* memo : mSolvedValues) memo->consumeLeaves();
        openvdb::FloatGrid::Ptr grid = evaluateSparse(*mResult, mDomain, options, &stats);
        releaseSolvedValues();  // the grid they were kept for is made
        return grid;
    });
}

void Job::releaseSolvedValues()
{
    // Their blocks are unmapped as they are freed (MappedBlock): the memory is the system's again
    // without a heap trim.
    for (const GridValueMemo* memo : mSolvedValues) memo->keep(false);
    mSolvedValues.clear();
}

namespace {
/// How far from its target the share the first mesh will hold may be before the level is moved
/// for it (half the 1 % the mesh is held to: a move costs an evaluation of the grid).
constexpr double kMeshAimTolerance = 0.005;
/// A projected mesh's share is estimated from about this many of its triangles, taking a grid
/// leaf to hold about kTrianglesPerLeaf (the offset from marching cubes is a mean over the
/// surface: 50 000 triangles give it to well under 0.1 % of the share).
constexpr std::uint64_t kProjectedSampleTriangles = 50000;
constexpr std::uint64_t kTrianglesPerLeaf = 100;
/// The boxes the mesh's share is predicted on (estimateMeshOffset()): about one in
/// boxes / kMeshOffsetBoxes. On the 50 mm trimmed frame the prediction lands within 0.1 % of the
/// share the mesh at the solved level holds (0.08 s; a quarter as many boxes first, 0.02 s).
constexpr std::uint64_t kMeshOffsetBoxes = 1024;
}  // namespace

void Job::aimLevelsAtMesh(const MeshOptions& options, const std::filesystem::path* streamTo)
{
    if (mMeshAimed) return;
    mMeshAimed = true;
    mKeepSolvedValues = !mSolved;
    solveLevels();
    mKeepSolvedValues = false;
    if (!mMeshes.empty() || mGrid || mReport.contains("pieces")) return;  // made at the solved level already
    const LevelNode* aimed = nullptr;
    int candidates = 0;
    for (const LevelNode& node : mBuilder.levelNodes())
        if (node.density && mSolvedDensity.contains(node.name) && meshShareOf(node, 1.0)) {
            aimed = &node;
            ++candidates;
        }
    if (candidates != 1) return;  // one share, one level: several lattices in one mesh are left as solved
    const LevelNode& node = *aimed;
    const SolvedDensity solved = mSolvedDensity.at(node.name);
    const double target = *node.density;
    // The last evaluation's time kept under @a name (the next one is the outputs').
    auto keepEvaluateTiming = [&](const std::string& name) {
        if (!mTimings.contains("evaluate")) return;
        mTimings[name] = mTimings["evaluate"];
        mTimings.erase("evaluate");
    };
    // A moved level is evaluated again on mostly the same leaves: where the solid keeps its raw
    // field's grid values (GridValueMemo), only the level is applied again. Kept for this
    // function's evaluations only, within a quarter of the memory available (at most 1 GB).
    const auto* memo = dynamic_cast<const GridValueMemo*>(node.solid->raw().get());
    struct KeptWhileAiming {
        const GridValueMemo* memo;
        ~KeptWhileAiming()
        {
            if (memo) memo->keep(false);  // its blocks unmapped, as in releaseSolvedValues()
        }
    } kept{memo};
    // A projected mesh of a smooth result is estimated past the box (projectedVolumeInBox()); one
    // with creases of its own (an infill: the lattice meets the skin, the part's edges) is made
    // as the finished mesh is, creases sharpened (the estimate's chamfers: 2.7 % at 0.25 mm).
    const bool projected = options.project && options.extractor == MeshExtractor::MarchingCubes && smoothResult();
    // The solve's values, kept on the recipe's lattice, are taken over as they are when the aim
    // evaluates that lattice (not the grid past the box a projected mesh is estimated on).
    const auto solvedValues = std::find(mSolvedValues.begin(), mSolvedValues.end(), memo);
    const bool takenOver = memo && solvedValues != mSolvedValues.end();
    if (takenOver) mSolvedValues.erase(solvedValues);
    if (memo && (!takenOver || projected)) memo->keep(true, memoBudget());  // keep() starts empty
    const bool creased = options.project && options.extractor == MeshExtractor::MarchingCubes && !projected;
    // The first mesh's file measured as it is written (the same triangles marchingCubesVolume()
    // sums): only a raw marching-cubes mesh of the recipe's grid.
    const bool streamed = streamTo && !options.project && options.extractor == MeshExtractor::MarchingCubes;
    // A projected mesh's share is estimated at twice the recipe's voxel (an eighth of the grid and
    // of the time: W9's estimate took 2.2 s at 0.1 mm) where the thinnest feature still spans
    // three of those voxels, else at the recipe's voxel; so is a lattice in a part, whose sharp
    // edges the estimate chamfers by its voxel (a skinned infill at 0.25 mm: 2.7 % heavy at 0.5).
    double estimateVoxel = mDomain.voxel;
    if (projected && !node.meshShare) {
        estimateVoxel = 2.0 * mDomain.voxel;
        for (const LevelNode& n : mBuilder.levelNodes())
            if (n.thinnest && n.thinnest(n.solid->level()) < 3.0 * estimateVoxel) estimateVoxel = mDomain.voxel;
        for (int a = 0; a < 3; ++a)
            if (mDomain.dims[a] < 32) estimateVoxel = mDomain.voxel;  // too few voxels to halve
    }
    nlohmann::json aim = {
        {"measure", streamed ? "the volume the marching-cubes mesh of the recipe's grid encloses, as its STL is written"
                    : creased ? "the volume the projected mesh of the recipe's grid encloses with its creases "
                                "sharpened, made as the finished mesh is (before decimation)"
                    : projected
                        ? "the solid within the domain box bounded by the marching-cubes mesh of the field "
                          "evaluated past the box, with its vertices projected onto the surface (estimated "
                          "from a sample of its triangles; a mesh to a tolerance keeps chords of the same order)"
                    : options.extractor == MeshExtractor::Bcc
                        ? "the volume the bcc tetrahedra of the recipe's grid enclose, before they are written"
                    : memo ? "the volume the marching-cubes mesh of the recipe's grid encloses, before it is made"
                           : "the volume the marching-cubes mesh of the recipe's grid encloses: the mesh the outputs "
                             "are made from while the level stays"},
        {"tolerance", kMeshAimTolerance},
        {"solved_level", node.recipeLevel ? node.recipeLevel(node.solid->level()) : node.solid->level()}};
    // The share the first mesh will hold at the level as it stands, and the recipe's grid it was
    // measured on (the outputs' grid if the level stays). A projected mesh's is estimated on a
    // grid of its own that runs past the box (freed at once): it holds no grid for the outputs.
    // A file written at a level the aim then moves is not the output: withdrawn from the open
    // transaction, its time kept as the measure's.
    auto withdrawStreamed = [&] {
        if (!mStreamedAim) return;
        OutputTransaction::current()->withdraw(mStreamedAim->path.string());
        const std::string written = "mesh into " + mStreamedAim->path.filename().string();
        mTimings[mStreamedAim->stage] = mTimings[written];
        mTimings.erase(written);
        mStreamedAim.reset();
    };
    struct Measured {
        std::optional<MeshShareMeasure> share;
        openvdb::FloatGrid::Ptr grid;
        SparseStats stats;
        std::unique_ptr<TriangleMesh> mesh;  ///< the raw marching-cubes mesh of @a grid, when made
    };
    auto measure = [&](const std::string& stage) {
        Measured m;
        double volume = 0.0;
        if (projected) {
            const ProjectedVolume pv = timed(stage, [&] {
                const openvdb::FloatGrid::Ptr past = evaluatePastTheBox(estimateVoxel);
                const ProjectionOptions po = projectionAt(estimateVoxel);
                const std::uint64_t every = std::max<std::uint64_t>(
                    1, (past->tree().leafCount() * kTrianglesPerLeaf) / kProjectedSampleTriangles);
                return reporting(mContext, "measuring the projected mesh's volume", [&](const ProgressFn& progress) {
                    return projectedVolumeInBox(*past, *mResult, mDomain.box, po, every, progress);
                });
            });
            // The chords' share of the volume shrinks with the square of the voxel: at twice the
            // recipe's voxel, a quarter of them is what the mesh at the recipe's voxel keeps.
            const double ratio = mDomain.voxel / estimateVoxel;
            volume = pv.surface - ratio * ratio * (pv.surface - pv.volume);
            aim["estimate"] = {{"voxel", estimateVoxel},
                               {"triangles", pv.triangles},
                               {"projected", pv.cut + pv.sampled},
                               {"volume_mm3", volume},
                               {"projected_at_voxel_mm3", pv.volume},
                               {"marching_cubes_past_the_box_mm3", pv.unprojected},
                               {"true_surface_mm3", pv.surface}};
        } else {
            m.grid = evaluateResult(m.stats);
            if (streamed) {
                withdrawStreamed();
                mStreamedAim = StreamedAim{*streamTo, streamStl(*m.grid, *streamTo), stage};
                m.share = meshShareOf(node, mStreamedAim->made.measures.volume);
                return m;
            }
            // The mesh the outputs are made from (variant() takes it if the level stays: most aims
            // keep it), its volume summed as a streamed STL's is (the same double): one
            // marching-cubes pass, not a volume pass and then the mesh's. Not while a memo's kept
            // values are held (until the aim ends): that mesh is made after them (the 50 mm
            // trimmed frame peaked at 1.59 GB against 1.48 with the mesh beside them).
            const bool heldMesh = !creased && options.extractor == MeshExtractor::MarchingCubes && !memo;
            MarchingCubesStats meshed;
            if (heldMesh)
                m.mesh = timed("mesh", [&] {
                    return reporting(mContext, "meshing", [&](const ProgressFn& progress) {
                        return std::make_unique<TriangleMesh>(marchingCubes(*m.grid, 0.0f, progress, &meshed));
                    });
                });
            volume = timed(stage, [&] {
                if (heldMesh) return marchingCubesVolume(*m.mesh, meshed, mDomain.box.center());
                if (creased) {
                    TriangleMesh mesh = reporting(mContext, "meshing to measure", [&](const ProgressFn& progress) {
                        return marchingCubes(*m.grid, 0.0f, progress);
                    });
                    const ProjectionOptions po = projectionAt(mDomain.voxel);
                    reporting(mContext, "projecting vertices to measure", [&](const ProgressFn& progress) {
                        return projectToSurface(mesh, *surfaceField(), po, progress);
                    });
                    nlohmann::json counts;
                    sharpenMeshCreases(mesh, options, mDomain.voxel, po, counts);
                    return mesh.volume();
                }
                return reporting(mContext, "measuring the mesh's volume", [&](const ProgressFn& progress) {
                    if (options.extractor == MeshExtractor::Bcc)
                        return bccTetrahedra(*m.grid, *surfaceField(), 0.0f, progress).volume();
                    return marchingCubesVolume(*m.grid, 0.0f, mDomain.box.center(), progress);
                });
            });
        }
        m.share = meshShareOf(node, volume);
        return m;
    };
    // The share the first mesh will hold, predicted before its grid is made (estimateMeshOffset():
    // marching cubes' offset from the solve's measure of the voxels, sampled on about
    // kMeshOffsetBoxes boxes of the grid): where it misses the target by more than half the
    // tolerance, the level moves along the solve's slope first, so the grid and its mesh are made
    // once at a level whose mesh holds the target, not at the solved level and again (the 50 mm
    // trimmed frame: 1.3 s of 7). Only for a raw marching-cubes mesh measured on the recipe's grid.
    double baseIndicator = solved.indicatorLevel;  // the level the first mesh is made at
    bool predictedMove = false;
    const bool slopeUsable = solved.slope > 0.0 && std::isfinite(solved.slope);
    // (Not with a skin: its voxels' coverage is not the part's volume less the region's.)
    if (!projected && !creased && options.extractor == MeshExtractor::MarchingCubes && slopeUsable &&
        solved.onJobVoxels && !(node.meshShare && node.meshShare->skinned)) {
        // A first sample of a quarter as many boxes decides whether the mesh will miss by enough
        // to move for; only then is the full sample taken.
        auto predict = [&](const std::string& stage, std::uint64_t boxes) {
            return timed(stage, [&] {
                const std::uint64_t every =
                    std::bit_floor(std::max<std::uint64_t>(1, meshOffsetBoxes(mDomain) / boxes));
                return estimateMeshOffset(*mResult, mDomain, int(std::min<std::uint64_t>(every, 1u << 30)),
                                          solved.coverage, [&] {
                                              if (mContext) mContext->checkCancelled();
                                          });
            });
        };
        // The solve's share plus the offset's share of the region (meshShareOf() is affine).
        const auto zero = meshShareOf(node, 0.0);
        auto predictedShare = [&](const MeshOffset& o) -> std::optional<double> {
            const auto shifted = meshShareOf(node, o.volume);
            if (!zero || !shifted) return std::nullopt;
            return solved.achieved + (shifted->measured - zero->measured);
        };
        MeshOffset offset = predict("predict the mesh's share", kMeshOffsetBoxes / 4);
        if (const auto rough = predictedShare(offset);
            rough && std::abs(target - *rough) > 0.25 * kMeshAimTolerance * target)
            offset = predict("predict the mesh's share, refined", kMeshOffsetBoxes);
        if (const auto share = predictedShare(offset); share && offset.crossed > 0) {
            const double predicted = *share;
            const double predictedMissing = target - predicted;
            predictedMove = std::abs(predictedMissing) > 0.5 * kMeshAimTolerance * target &&
                            std::abs(predictedMissing) < 0.25 * target;
            if (predictedMove) {
                baseIndicator = solved.indicatorLevel + predictedMissing / solved.slope;
                node.solid->correct(node.solid->levelFromIndicator(baseIndicator));
            }
            aim["prediction"] = {{"density_from_mesh_at_solved_level", predicted},
                                 {"offset_mm3", offset.volume},
                                 {"boxes", offset.boxes},
                                 {"sampled_boxes", offset.sampled},
                                 {"crossed_boxes", offset.crossed},
                                 {"moved", predictedMove}};
        }
    }
    Measured before =
        measure(predictedMove ? "measure the mesh's share at the predicted level" : "measure the mesh's share");
    aim[predictedMove ? "density_from_mesh_at_predicted_level" : "density_from_mesh_at_solved_level"] =
        before.share ? before.share->measured : 0.0;
    const double missing = before.share ? target - before.share->measured : 0.0;
    // The solve's slope is the share's change with the level on the voxels; the mesh's follows it
    // (the same surface moves), so one step lands within a few percent of the gap.
    const bool move = before.share && std::abs(missing) > kMeshAimTolerance * target && slopeUsable &&
                      std::abs(missing) < 0.25 * target;
    double indicatorLevel = baseIndicator;
    int steps = 0;
    if (!move) {
        mAimGrid = std::move(before.grid);  // the outputs' grid: the level stays
        mAimStats = before.stats;
        mAimMesh = std::move(before.mesh);
    } else {
        const double firstIndicator = baseIndicator + missing / solved.slope;
        node.solid->correct(node.solid->levelFromIndicator(firstIndicator));
        keepEvaluateTiming(predictedMove ? "evaluate at the predicted level" : "evaluate at the solved level");
        before.grid.reset();
        before.mesh.reset();
        // Checked at the moved level (on the outputs' grid when it holds, so nothing is evaluated
        // in vain): a field too flat about its level for one step along the voxels' slope (a points
        // infill: -3 % after one) takes a secant step through the two measured shares.
        indicatorLevel = firstIndicator;
        Measured after = measure("measure the mesh's share at the moved level");
        steps = 1;
        if (after.share) {
            aim["density_from_mesh_at_first_step"] = after.share->measured;
            const double stillMissing = target - after.share->measured;
            const double secant = (firstIndicator - baseIndicator) / (after.share->measured - before.share->measured);
            if (std::abs(stillMissing) > kMeshAimTolerance * target && std::isfinite(secant) && secant > 0.0 &&
                std::abs(stillMissing * secant) <= 4.0 * std::abs(firstIndicator - baseIndicator)) {
                indicatorLevel = firstIndicator + stillMissing * secant;
                node.solid->correct(node.solid->levelFromIndicator(indicatorLevel));
                steps = 2;
                keepEvaluateTiming("evaluate at the first step");
            }
        }
        if (steps == 1) {
            mAimGrid = std::move(after.grid);  // the outputs' grid
            mAimStats = after.stats;
            mAimMesh = std::move(after.mesh);
        } else {
            withdrawStreamed();  // written at the first step
        }
        after.grid.reset();  // at two steps: evaluated again at the final level by the first output that needs it
        after.mesh.reset();
    }
    if (!move && !predictedMove) {
        aim["moved"] = false;
        mReport["fields"][node.name]["mesh_aim"] = aim;
        return;
    }
    nlohmann::json& entry = mReport["fields"][node.name];
    const double level = node.solid->level();
    aim["moved"] = true;
    aim["steps"] = steps;  // moves after a measure (the prediction's not counted)
    aim["slope"] = solved.slope;
    reportLevel(node, level, entry);
    // The level's own warnings, with the numbers of the level the outputs are made at.
    reportThinnest(node, level, entry);
    if (node.onSolved) node.onSolved(level);
    // `achieved_density` stays the solve's (the target met on the voxels at the solved level); the
    // voxels' share at the moved level, along the solve's slope, is what slices of the field hold.
    aim["density_on_voxels_at_level"] = solved.achieved + solved.slope * (indicatorLevel - solved.indicatorLevel);
    entry["mesh_aim"] = aim;
}

namespace {

/// The mesh settings of a `mesh:` output entry (parsed when the recipe was loaded).
const MeshOptions& meshOptions(const OutputSpec& out)
{
    return out.mesh->options;
}

nlohmann::json deviationJson(double max, double rms)
{
    return {{"max_mm", max}, {"rms_mm", rms}};
}
}  // namespace

namespace {
/// The surfaces whose intersection is @a f, for sharp creases: the operands of a sharp
/// intersection (nested ones flattened) or difference (the cut-away operands negated), else
/// @a f itself.
void collectCreaseOperands(const FieldPtr& f, std::vector<FieldPtr>& out)
{
    if (const auto* d = dynamic_cast<const DrainedSolid*>(f.get()); d && d->hasChannels()) {
        // Drain channels cut the solid sharply: each is a surface of its own.
        collectCreaseOperands(d->solid(), out);
        for (const DrainChannel& c : d->channels()) {
            const Vec3d axis = c.to - c.from;
            out.push_back(std::make_shared<UnaryField>(
                std::make_shared<Cylinder>(0.5 * (c.from + c.to), axis, 0.5 * c.diameter, axis.length()),
                UnaryOp::Negate));
        }
        return;
    }
    const auto* b = dynamic_cast<const BooleanField*>(f.get());
    if (b && b->blendRadius() == 0.0 && out.size() < 24) {
        if (b->op() == BooleanOp::Intersection) {
            for (const FieldPtr& o : b->operands()) collectCreaseOperands(o, out);
            return;
        }
        if (b->op() == BooleanOp::Difference) {
            collectCreaseOperands(b->operands().front(), out);
            for (std::size_t i = 1; i < b->operands().size(); ++i)
                out.push_back(std::make_shared<UnaryField>(b->operands()[i], UnaryOp::Negate));
            return;
        }
    }
    out.push_back(f);
}
}  // namespace

FieldPtr Job::surfaceField()
{
    solveLevels();
    if (!mSurfaceField)
        mSurfaceField = std::make_shared<BooleanField>(
            BooleanOp::Intersection, std::vector<FieldPtr>{mResult, std::make_shared<BoxField>(mDomain.box)});
    return mSurfaceField;
}

FieldPtr Job::distanceField()
{
    solveLevels();
    if (!mDistanceField) {
        std::vector<FieldPtr> operands;
        collectCreaseOperands(mResult, operands);
        operands.push_back(std::make_shared<BoxField>(mDomain.box));
        mDistanceField = std::make_shared<SurfaceDistance>(std::move(operands));
    }
    return mDistanceField;
}

const TriangleMesh& Job::mesh(const MeshOptions& options)
{
    return *variant(options).mesh;
}

Job::MeshToleranceMiss Job::toleranceMiss(double strayMm, const MeshOptions& options) const
{
    const double tolerance = *options.tolerance;
    // Where a mesh strays beyond its tolerance, crease edges were left flat across about a voxel:
    // the stray shrinks about in proportion to the voxel, a little slower on fine grids (two
    // crossed cylinders: 0.106, 0.054, 0.030 mm at 0.25, 0.125, 0.0625 mm), hence the margin of
    // 0.8. Both suggestions rounded to 2 digits, the voxel down and the tolerance up.
    auto round2 = [](double v, bool up) {
        const double scale = std::pow(10.0, std::floor(std::log10(v)) - 1.0);
        return (up ? std::ceil(v / scale - 1e-9) : std::floor(v / scale + 1e-9)) * scale;
    };
    const double voxel = round2(0.8 * mDomain.voxel * tolerance / strayMm, false);
    const double atLeast = round2(strayMm, true);
    MeshToleranceMiss miss;
    miss.message =
        "the mesh strays up to " + formatNumber(strayMm) + " mm from the true surface, more than the tolerance " +
        formatNumber(tolerance) + " mm" + (options.toleranceWhere.empty() ? "" : " (" + options.toleranceWhere + ")") +
        ": " + (options.extractor == MeshExtractor::Bcc ? "the bcc extractor's" : "marching cubes'") +
        " triangles already did there (crease edges left flat where a vertex could not be moved onto the "
        "surface, see `creases`); use `voxel: " +
        formatNumber(voxel) + "` (now " + formatNumber(mDomain.voxel) +
        "; the stray shrinks about with the voxel) or a tolerance of at least " + formatNumber(atLeast) + " mm";
    miss.details = {{"max_mm", strayMm},
                    {"tolerance_mm", tolerance},
                    {"voxel_mm", mDomain.voxel},
                    {"suggested_voxel_mm", voxel},
                    {"suggested_tolerance_mm", atLeast}};
    return miss;
}

void Job::sharpenMeshCreases(TriangleMesh& m, const MeshOptions& options, double meshVoxel, const ProjectionOptions& po,
                             nlohmann::json& report)
{
    // Where the solid meets the domain box, a vertex of each edge across the crease goes onto both.
    ProjectionOptions co = po;
    co.maxMove = meshVoxel;
    const CreaseStats c = timed("sharpen creases", [&] {
        return reporting(mContext, "sharpening creases", [&](const ProgressFn& progress) {
            return sharpenCreases(m, *mResult, BoxField(mDomain.box), co, progress);
        });
    });
    // The edges still across a crease (and the box's own edges and corners) are split at
    // the point on both surfaces (on all three at a corner).
    std::vector<FieldPtr> operands;
    collectCreaseOperands(mResult, operands);
    CreaseSurfaces surfaces;
    for (const FieldPtr& f : operands) surfaces.fields.push_back(f.get());
    surfaces.box = mDomain.box;
    const CreaseSplitStats split = timed("split crease edges", [&] {
        return reporting(mContext, "splitting crease edges",
                         [&](const ProgressFn& progress) { return splitCreaseEdges(m, surfaces, co, progress); });
    });
    // Triangles that still cut into the solid or stray out of it (a chamfer across a sharp
    // wedge whose crease runs outside the triangle) are bisected at points on the surface.
    RefinementOptions ro;
    ro.threshold = options.tolerance ? 0.5 * *options.tolerance : 0.05 * mDomain.voxel;
    ro.spacing = 0.25 * meshVoxel;
    ro.maxMove = 2.0 * meshVoxel;
    ro.tolerance = po.tolerance;
    const RefinementStats refined = timed("refine creases", [&] {
        return reporting(mContext, "refining creases",
                         [&](const ProgressFn& progress) { return refineCreases(m, surfaces, ro, progress); });
    });
    report["refinement"] = {
        {"threshold_mm", ro.threshold},
        {"triangles_checked", refined.checked},
        {"triangles_over", refined.over},
        {"vertices_moved_onto_surface", refined.moved},
        {"edges_split", refined.split},
        {"splits_dropped", refined.dropped},
        {"triangles_still_over", refined.remaining},
        {"rounds", refined.rounds},
        {"max_before_mm", refined.maxBefore},
        {"max_after_mm", refined.maxAfter},
    };
    report["creases"] = {
        {"surfaces", std::to_string(operands.size()) + (operands.size() == 1 ? " field" : " operands of the result") +
                         " and the six faces of the domain box"},
        {"edges_across", c.creaseEdges},
        {"vertices_moved_onto_both", c.moved},
        {"edges_split", split.split},
        {"edges_left_flat", split.leftFlat},
        {"edges_left_flat_at_a_vertex", split.coincident}};
}

Job::MeshVariant& Job::variant(const MeshOptions& options)
{
    // A mesh streamed into its file (writeStlWhileMeshing()) was never kept: made again if asked.
    for (const auto& v : mMeshes)
        if (v->options == options && v->mesh) return *v;
    if (options.tolerance) checkTolerance(options);
    // Its pieces and volume go into the report; the meshers below ask for it again. A tolerance
    // mesh tried on a coarser grid first asks for what it needs (coarseMesh()).
    const bool coarseFirst = options.tolerance && options.project && options.extractor == MeshExtractor::MarchingCubes;
    if (!coarseFirst) grid();
    auto v = std::make_unique<MeshVariant>();
    v->options = options;
    const auto raw = std::find_if(mMeshes.begin(), mMeshes.end(), [&](const auto& m) {
        return m->mesh && m->options.raw() && m->options.extractor == options.extractor;
    });
    // A tolerance mesh starts from a coarser grid where that is safe: the field is exact everywhere,
    // so the projected vertices are as accurate, and decimation then starts from a few million
    // triangles instead of tens.
    nlohmann::json extraction;
    double meshVoxel = mDomain.voxel;
    ProjectionStats projected;
    // A smooth result meets only the domain box: meshed past it and cut by its faces, its creases
    // there are exact (no chamfers), at any voxel.
    std::optional<BoxClipStats> boxCut;
    std::optional<MeshTopology> topology;  // a refined mesh's, checked with its crossings
    if (options.project && options.extractor == MeshExtractor::MarchingCubes) {
        if (coarseFirst) v->mesh = coarseMesh(options, extraction, meshVoxel, projected, boxCut, topology);
        if (!v->mesh && smoothResult()) {
            meshVoxel = mDomain.voxel;
            v->mesh = clippedMesh(mDomain.voxel, projected, boxCut);
        }
    }
    const bool isProjected = bool(v->mesh);
    if (isProjected) {
        // Extracted and projected already.
    } else if (!options.raw() && raw != mMeshes.end()) {
        v->mesh = std::make_unique<TriangleMesh>(*(*raw)->mesh);
    } else if (options.extractor == MeshExtractor::Bcc) {
        // The grid's voxels plus the cube centres of the field the grid samples (clipped alike).
        const FieldPtr field = surfaceField();
        v->mesh = timed("mesh", [&] {
            return reporting(mContext, "meshing (bcc)", [&](const ProgressFn& progress) {
                return std::make_unique<TriangleMesh>(bccTetrahedra(grid(), *field, 0.0f, progress));
            });
        });
    } else if (mAimMesh) {
        v->mesh = std::move(mAimMesh);  // made from this grid by the aim's measure
    } else {
        v->mesh = timed("mesh", [&] {
            return reporting(mContext, "meshing", [&](const ProgressFn& progress) {
                return std::make_unique<TriangleMesh>(marchingCubes(grid(), 0.0f, progress));
            });
        });
    }
    TriangleMesh& m = *v->mesh;
    nlohmann::json& report = v->report;
    if (!extraction.is_null()) report["extraction"] = extraction;
    const ProjectionOptions po = projectionAt(meshVoxel);
    if (options.project) {
        const FieldPtr field = surfaceField();
        const ProjectionStats s = isProjected ? projected : timed("project vertices", [&] {
            return reporting(mContext, "projecting vertices onto the surface",
                             [&](const ProgressFn& progress) { return projectToSurface(m, *field, po, progress); });
        });
        report["projection"] = {{"vertices_moved", s.moved},
                                {"vertices_held_back", s.heldBack},
                                {"vertices_held_back_for_crossings", s.heldBackForCrossings},
                                {"crossing_pairs_not_held_back",
                                 mCrossingsUnheld ? nlohmann::json(*mCrossingsUnheld) : nlohmann::json(nullptr)},
                                {"vertices_at_half_voxel_limit", s.limited},
                                {"vertex_deviation_before", deviationJson(s.maxBefore, s.rmsBefore)},
                                {"vertex_deviation_after", deviationJson(s.maxAfter, s.rmsAfter)}};
    }
    if (options.project && boxCut && boxCut->ok) {
        report["creases"] = {{"surfaces", "the result's field and the six faces of the domain box"},
                             {"method", "meshed past the box, cut by its faces and capped"},
                             {"triangles_cut", boxCut->cutTriangles},
                             {"crease_vertices", boxCut->creaseVertices},
                             {"crease_vertices_left_on_edge", boxCut->leftOnEdge},
                             {"box_corners", boxCut->corners},
                             {"cap_triangles", boxCut->capTriangles}};
    } else if (options.project) {
        sharpenMeshCreases(m, options, meshVoxel, po, report);
        if (boxCut) report["creases"]["box_cut_failed"] = boxCut->failure;
    }
    // Counted by the refinement or the decimation on the mesh it leaves.
    std::optional<std::size_t> crossingPairs;
    // A mesh refined from a coarse grid has its triangles where the error asks for them:
    // decimating it would take 40 % of its triangles for 40 % more time (W9).
    const bool refined = extraction.contains("refinement");
    if (refined) crossingPairs = extraction["refinement"]["crossing_pairs"].get<std::size_t>();
    if (options.tolerance && !refined) {
        // The distance to the result's operands, with the domain box taken exactly at every point
        // the check looks at (the kink where a triangle meets the box along a crease).
        std::vector<FieldPtr> operands;
        collectCreaseOperands(mResult, operands);
        const FieldPtr field = std::make_shared<SurfaceDistance>(std::move(operands));
        DecimationOptions d;
        d.box = mDomain.box;
        d.tolerance = *options.tolerance;
        d.voxel = meshVoxel;
        // Only candidates within a quarter of T² by the quadric are tried: on W9 the share 1 spent
        // most of its field checks on 1.7 M refused collapses (21 s of decimation on one thread),
        // a quarter refuses 0.4 M (14 s) for 4 % more triangles; a tenth keeps 30 % more.
        d.quadricShare = 0.25;
        const DecimationStats s = timed("decimate", [&] {
            return reporting(mContext, "decimating to " + formatNumber(d.tolerance) + " mm",
                             [&](const ProgressFn& progress) { return decimateToTolerance(m, *field, d, progress); });
        });
        report["decimation"] = {{"tolerance_mm", d.tolerance},
                                {"triangles_before", s.trianglesBefore},
                                {"collapses", s.collapses},
                                {"refused_collapses", s.refused},
                                {"crossing_pairs_found", s.crossingPairsFound},
                                {"repair_rounds", s.repairRounds},
                                {"vertices_kept_for_crossings", s.verticesKeptForCrossings}};
        crossingPairs = s.crossingPairs;
        if (!s.decimated)
            mContext->warn("mesh_not_decimated",
                           "the mesh could not be decimated (a triangle repeats a corner); it is written "
                           "as marching cubes made it");
    }
    // Projection and decimation move vertices and join triangles: check that no two cross.
    std::size_t crossing = 0;
    if (!options.raw()) {
        crossing = crossingPairs ? *crossingPairs : timed("check self-intersections", [&] {
            return reporting(mContext, "checking self-intersections",
                             [&](const ProgressFn& progress) { return countSelfIntersections(m, progress); });
        });
        if (crossing > 0 && options.project && !mCrossingsUnheld) {
            // Near a sharp crease (a skinned infill's lattice meeting its skin) marching cubes
            // leaves slivers that the projection's small moves fold into each other: the mesh is
            // made again with those moves held back.
            mCrossingsUnheld = crossing;
            return variant(options);
        }
    }
    if (!options.raw()) {
        // Measured on every triangle, so the numbers hold for the file as written. A refined mesh
        // was: the refinement's check of each triangle it leaves is the measure (W9: 0.5 s less,
        // the same largest deviation as sampling every triangle one voxel apart).
        MeshDeviation dev;
        std::string measure;
        if (refined) {
            const nlohmann::json& r = extraction["refinement"];
            dev.max = r["max_deviation_mm"].get<double>();
            dev.rms = r["rms_deviation_mm"].get<double>();
            dev.samples = r["deviation_samples"].get<std::size_t>();
            measure =
                "the refinement's check of every triangle: the quadratic through |max f / |grad f|| over the "
                "result's operands (within the domain box) at its corners and edge midpoints, its largest "
                "value over the triangle plus its miss at the centre (max), its square integrated over the "
                "triangle (rms)";
        } else {
            dev = timed("measure mesh", [&] {
                return reporting(mContext, "measuring the mesh against the surface", [&](const ProgressFn& progress) {
                    return measureDeviation(m, *distanceField(), 0.0, mDomain.voxel, progress);
                });
            });
            measure =
                "|max f / |grad f|| over the result's operands and the domain box, on every triangle sampled "
                "at most one voxel apart";
        }
        report["deviation"] = {
            {"max_mm", dev.max}, {"rms_mm", dev.rms}, {"samples", dev.samples}, {"measure", measure}};
        const MeshTopology t = topology ? *topology : timed("check topology", [&] {
            return reporting(mContext, "checking the mesh's topology",
                             [&](const ProgressFn& progress) { return checkTopology(m, nullptr, progress); });
        });
        // Crease splits can put a vertex where another is: apart by index, one point in the file.
        const std::size_t coincident = countCoincidentVertices(m);
        report["coincident_vertices"] = coincident;
        if (coincident > 0)
            mContext->warn("mesh_coincident_vertices",
                           std::to_string(coincident) +
                               " vertices of the mesh lie exactly on another vertex: read by position (an STL) the "
                               "mesh is not manifold there (edges shared by four triangles); mesh with `project: off` "
                               "or another `voxel:`",
                           {{"vertices", coincident}});
        report["closed_manifold"] = t.closedManifold() && coincident == 0;
        report["euler_characteristic"] = t.eulerCharacteristic;
        report["pieces"] = t.pieces;
        report["closed_pieces"] = t.closedPieces;
        report["genus"] = t.genus;
        report["self_intersections"] = crossing;
        if (crossing > 0)
            mContext->warn("mesh_self_intersections",
                           std::to_string(crossing) +
                               " pairs of triangles of the mesh cross each other; slicers may fill or drop the "
                               "region there: mesh without `tolerance:` (or with `project: off`) or use a smaller "
                               "`voxel:`",
                           {{"pairs", crossing}});
        if (options.tolerance && dev.max > *options.tolerance) {
            const MeshToleranceMiss miss = toleranceMiss(dev.max, options);
            report["tolerance_missed"] = miss.details;
            if (!options.strict) mContext->warn("mesh_tolerance", miss.message, miss.details);
        }
    }
    report["extractor"] = meshExtractorName(options.extractor);
    report["triangles"] = m.triangles.size();
    report["vertices"] = m.points.size();
    mMeshes.push_back(std::move(v));
    return *mMeshes.back();
}

namespace {
/// The coarsest grid a tolerance mesh is tried at: k times the recipe's voxel.
constexpr int kMaxCoarsening = 5;
/// A coarse trial's probe: a cube of this many coarse voxels at the domain's centre.
constexpr int kProbeVoxels = 32;
/// The chord error is measured on at most about this many interior triangles (every n-th).
constexpr std::size_t kChordSampleTriangles = 200000;

/// The largest first-order distance from the surface over triangles of @a mesh whose corners lie
/// all more than @a inset inside @a box (away from the creases, where the chord error of
/// projected triangles is all there is), every n-th of them so that at most about
/// kChordSampleTriangles are sampled, each at @a spacing.
double interiorChordError(TriangleMesh& mesh, const FieldNode& field, const Box3& box, double inset, double spacing)
{
    auto inside = [&](const openvdb::Vec3f& p) {
        for (int a = 0; a < 3; ++a)
            if (p[a] < box.min[a] + inset || p[a] > box.max[a] - inset) return false;
        return true;
    };
    std::vector<std::size_t> interior;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        if (inside(mesh.points[tri[0]]) && inside(mesh.points[tri[1]]) && inside(mesh.points[tri[2]]))
            interior.push_back(t);
    }
    if (interior.empty()) return 0.0;
    const std::size_t stride = std::max<std::size_t>(1, interior.size() / kChordSampleTriangles);
    TriangleMesh sample;
    sample.points = std::move(mesh.points);  // borrowed, given back below
    for (std::size_t i = 0; i < interior.size(); i += stride) sample.triangles.push_back(mesh.triangles[interior[i]]);
    const MeshDeviation d = measureDeviation(sample, field, 0.0, spacing);
    mesh.points = std::move(sample.points);
    return d.max;
}
}  // namespace

bool Job::smoothResult()
{
    solveLevels();
    std::vector<FieldPtr> operands;
    collectCreaseOperands(mResult, operands);
    return operands.size() == 1;
}

openvdb::FloatGrid::Ptr Job::evaluatePastTheBox(double h)
{
    releaseSolvedValues();  // kept for the recipe's lattice, not this one
    Domain d;
    d.voxel = h;
    d.box.min = mDomain.box.min;
    for (int a = 0; a < 3; ++a) {
        d.dims[a] = int(std::ceil(mDomain.box.extent()[a] / h - 1e-9));
        d.box.max[a] = d.box.min[a] + d.dims[a] * h;
    }
    SparseOptions so;
    so.margin = 2;
    so.stage = "evaluating " + mRecipe.result + (h == mDomain.voxel ? "" : " at " + formatNumber(h) + " mm") +
               " past the domain box";
    so.context = mContext;
    return evaluateSparse(*mResult, d, so);
}

std::unique_ptr<TriangleMesh> Job::clippedMesh(double h, ProjectionStats& projection,
                                               std::optional<BoxClipStats>& boxCut, bool checkCut)
{
    solveLevels();
    auto mesh = timed(h == mDomain.voxel ? "mesh" : "mesh (coarse)", [&] {
        // Unclipped: the surface runs on past the faces, where the cut below meets it.
        const openvdb::FloatGrid::Ptr g = evaluatePastTheBox(h);
        StageProgress progress(mContext, "meshing at " + formatNumber(h) + " mm", 1000);
        std::atomic<std::uint64_t> last{0};
        auto m = std::make_unique<TriangleMesh>(marchingCubes(*g, 0.0f, feed(progress, last)));
        // Beyond a voxel past the box: where the grid's samples end, not the surface (cut off below).
        dropTrianglesOutside(*m, mDomain.box, h);
        return m;
    });
    const ProjectionOptions po = projectionAt(h);
    projection = timed("project vertices", [&] {
        return reporting(mContext, "projecting vertices onto the surface",
                         [&](const ProgressFn& progress) { return projectToSurface(*mesh, *mResult, po, progress); });
    });
    BoxClipOptions co{po};  // the crease points' Newton steps as the projection's
    co.checkTopology = checkCut;
    boxCut = timed("cut by the domain box", [&] {
        return reporting(mContext, "cutting by the domain box", [&](const ProgressFn& progress) {
            return clipToBox(*mesh, *mResult, mDomain.box, co, progress);
        });
    });
    if (!boxCut->ok) return nullptr;
    return mesh;
}

AdaptiveRefinementStats Job::refineCoarseMesh(TriangleMesh& mesh, double h, double tolerance)
{
    std::vector<FieldPtr> operands;
    collectCreaseOperands(mResult, operands);
    // One operand (coarseMesh() refines only a smooth result) is its own first-order distance,
    // f / |grad f|, as the refinement takes it: no wrapper normalising every value and gradient
    // first (W9: 3 % of the CPU time).
    const FieldPtr field =
        operands.size() == 1 ? operands.front() : std::make_shared<SurfaceDistance>(std::move(operands));
    AdaptiveRefinementOptions o;
    // A tenth of the tolerance kept back for what the check's quadratic misses, as decimation does.
    o.tolerance = 0.9 * tolerance;
    o.box = mDomain.box;
    o.maxMove = 0.5 * h;
    o.newtonTolerance = 1e-4 * mDomain.voxel;
    return timed("refine to tolerance", [&] {
        return reporting(mContext, "refining to " + formatNumber(tolerance) + " mm",
                         [&](const ProgressFn& progress) { return refineToTolerance(mesh, *field, o, progress); });
    });
}

std::optional<double> Job::probeChordError(double h)
{
    Domain d;
    d.voxel = h;
    double volume = 1.0;
    for (int a = 0; a < 3; ++a) {
        // On the whole domain's coarse grid (clippedMesh(): from the box's corner), so the probe's
        // triangles away from its faces are the full mesh's.
        d.dims[a] = std::min(kProbeVoxels, int(std::floor(mDomain.box.extent()[a] / h)));
        const double start = mDomain.box.center()[a] - 0.5 * d.dims[a] * h;
        d.box.min[a] = mDomain.box.min[a] + std::floor((start - mDomain.box.min[a]) / h) * h;
        d.box.max[a] = d.box.min[a] + d.dims[a] * h;
        volume *= d.box.extent()[a] / mDomain.box.extent()[a];
    }
    if (volume > 0.125) return std::nullopt;
    return timed("probe chord error", [&] {
        SparseOptions so;
        so.margin = 2;
        so.stage = "probing the chord error at " + formatNumber(h) + " mm";
        so.context = mContext;
        const openvdb::FloatGrid::Ptr g = evaluateSparse(*mResult, d, so);
        TriangleMesh mesh = marchingCubes(*g, 0.0f, {});
        ProjectionOptions po = projectionAt(h);
        po.holdBackCrossings = false;  // measured only
        projectToSurface(mesh, *mResult, po, {});
        // Only triangles two voxels inside the probe: its faces end the mesh, they are no crease.
        return interiorChordError(mesh, *distanceField(), d.box, 2.0 * h, 0.5 * h);
    });
}

std::unique_ptr<TriangleMesh> Job::coarseMesh(const MeshOptions& options, nlohmann::json& extraction, double& voxel,
                                              ProjectionStats& projection, std::optional<BoxClipStats>& boxCut,
                                              std::optional<MeshTopology>& topology)
{
    const double tolerance = *options.tolerance;
    voxel = mDomain.voxel;
    solveLevels();
    // The smallest feature a node knows must span at least three coarse voxels (two resolve it
    // on the grid; the third is the margin for its position between the samples).
    int k = kMaxCoarsening;
    std::string limit = "at most " + std::to_string(kMaxCoarsening) + " times the recipe's voxel";
    for (const LevelNode& node : mBuilder.levelNodes()) {
        if (!node.thinnest) continue;
        const double thinnest = node.thinnest(node.solid->level());
        const int byFeature = int(std::floor(thinnest / (3.0 * mDomain.voxel) + 1e-9));
        if (byFeature < k) {
            k = std::max(1, byFeature);
            limit = "the thinnest " + node.thinnestKind + " of `" + node.name + "` (" + formatNumber(thinnest) +
                    " mm) must span 3 voxels";
        }
    }
    // A domain of fewer than 16 coarse voxels along an axis is too small to gain anything.
    for (int a = 0; a < 3; ++a) k = std::max(1, std::min(k, mDomain.dims[a] / 16));
    // A result cut by another surface (an intersection or difference) has creases the crease
    // steps handle, leaving chamfers that grow with the voxel (W9 at 0.2 mm: 0.071 mm against
    // 0.036 mm from 0.1 mm): meshed at the recipe's voxel. Where a smooth result meets the domain
    // box, the mesh is cut by the box's faces (clippedMesh()), exact at any voxel.
    std::vector<FieldPtr> creaseOperands;
    collectCreaseOperands(mResult, creaseOperands);
    if (k > 1 && creaseOperands.size() > 1) {
        k = 1;
        limit = "the result is cut by " + std::to_string(creaseOperands.size() - 1) +
                " other surface(s): its creases need the recipe's voxel (their chamfers grow with the voxel)";
    }
    // The recipe's grid: its pieces are what the coarse mesh must keep. When nothing after this
    // mesh reads it, only its solid's bits are made (asked again, it is evaluated again), or it is
    // freed before the coarse grids and the refinement, which then reuse its memory. Not at k = 1:
    // the mesh is the recipe's grid's then (a result with sharp operands is meshed from it); nor
    // with graded densities, whose slabs are measured on it.
    evaluateRecipeGrid(!(k > 1 && mGridReleasable && mBuilder.gradedNodes().empty()));
    const std::uint64_t finePieces = mReport["pieces"]["count"].get<std::uint64_t>();
    if (k > 1 && mGridReleasable && mGrid)
        timed("free the recipe's grid", [&] {
            mGrid.reset();
            return 0;
        });
    nlohmann::json trials = nlohmann::json::array();
    std::string why = k > 1 ? "" : limit;
    // The next factor after a chord error above the tolerance: the error grows as h squared.
    auto finer = [&](double chord) {
        return std::max(1, std::min(k - 1, int(std::lround(k * std::sqrt(tolerance / chord)))));
    };
    // With refinement, the coarsest grid is refined where its chord error is above the
    // tolerance, and a grid half as coarse should that leave triangles over it or crossing.
    // Without, grids are tried until one's chord error is within the tolerance (probed first).
    bool refine = options.refine;
    while (k > 1) {
        const double h = k * mDomain.voxel;
        if (const std::optional<double> probe = refine ? std::nullopt : probeChordError(h);
            probe && *probe > tolerance) {
            trials.push_back({{"voxel_mm", h},
                              {"probe_chord_error_mm", *probe},
                              {"rejected", "the chord error in a probe of " + std::to_string(kProbeVoxels) +
                                               " voxels at the domain's centre is above the tolerance"}});
            why = "the chord error at " + formatNumber(h) + " mm is " + formatNumber(*probe) +
                  " mm (in a probe at the domain's centre), above the tolerance";
            k = finer(*probe);
            continue;
        }
        // A mesh to be refined is checked once, after (refinement keeps it closed and manifold,
        // and its pieces: the check finds it if not).
        auto mesh = clippedMesh(h, projection, boxCut, !refine);
        nlohmann::json trial{{"voxel_mm", h}};
        if (!mesh) {
            trial["rejected"] = "the cut by the domain box could not be closed: " + boxCut->failure;
            trials.push_back(trial);
            why = "at " + formatNumber(h) + " mm " + trial["rejected"].get<std::string>();
            k /= 2;
            continue;
        }
        trial["triangles"] = mesh->triangles.size();
        // Whether the mesh (topology @a t) is closed and manifold with the recipe's grid's closed
        // pieces; else the trial is rejected and the next grid is half as coarse.
        auto keepsPieces = [&](const MeshTopology& t) {
            trial["closed_pieces"] = t.closedPieces;
            if (!t.closedManifold())
                why = "at " + formatNumber(h) + " mm the mesh is not closed and manifold (" +
                      std::to_string(t.boundaryEdges) + " open edges, " + std::to_string(t.nonManifoldEdges) +
                      " shared by more than two)";
            else if (t.closedPieces != finePieces)
                why = "at " + formatNumber(h) + " mm the mesh has " + std::to_string(t.closedPieces) +
                      " closed pieces, the recipe's grid " + std::to_string(finePieces);
            else
                return true;
            trial["rejected"] = why;
            trials.push_back(trial);
            k /= 2;
            return false;
        };
        if (!refine && !keepsPieces(boxCut->topology)) continue;  // checked by the cut
        // Refined where its triangles stray instead of meshed finer everywhere; its first round
        // checks every triangle, so its largest deviation there is the chord error (with the caps
        // and creases: W9 0.06 s less than measuring it apart).
        std::optional<AdaptiveRefinementStats> refinement;
        if (refine) refinement = refineCoarseMesh(*mesh, h, tolerance);
        const double chord = refinement ? refinement->maxBefore : timed("measure chord error", [&] {
            return interiorChordError(*mesh, *distanceField(), mDomain.box, 2.0 * h, 0.5 * h);
        });
        trial["chord_error_mm"] = chord;
        if (refinement && (refinement->splits > 0 || refinement->flips > 0 || refinement->remaining > 0)) {
            // Kept when no triangle is left above the tolerance and none cross (a mesh it did not
            // change goes on as one whose chord error is within the tolerance).
            const AdaptiveRefinementStats& r = *refinement;
            // Its topology (for the report) first: the fans it walks show most corner-sharing pairs
            // apart for the crossing check.
            std::vector<std::uint8_t> fansApart;
            topology = timed("check topology", [&] {
                return reporting(mContext, "checking the mesh's topology", [&](const ProgressFn& progress) {
                    return checkTopology(*mesh, &fansApart, progress);
                });
            });
            if (!keepsPieces(*topology)) {
                topology.reset();
                continue;
            }
            const std::size_t crossing = timed("check self-intersections", [&] {
                return reporting(mContext, "checking self-intersections", [&](const ProgressFn& progress) {
                    return countSelfIntersections(*mesh, fansApart, progress);
                });
            });
            trial["refinement"] = {{"triangles_before", r.trianglesBefore},
                                   {"triangles_after", r.trianglesAfter},
                                   {"edges_split", r.splits},
                                   {"splits_dropped", r.dropped},
                                   {"edges_flipped", r.flips},
                                   {"corners_moved", r.cornersMoved},
                                   {"rounds", r.rounds},
                                   {"triangles_left_over", r.remaining},
                                   {"abandoned", r.abandoned},
                                   {"crossing_pairs", crossing},
                                   {"max_deviation_mm", r.maxDeviation},
                                   {"rms_deviation_mm", r.rmsDeviation},
                                   {"deviation_samples", r.deviationSamples}};
            trials.push_back(trial);
            if (r.remaining == 0 && crossing == 0) {
                voxel = h;
                extraction = {{"voxel_mm", h},
                              {"recipe_voxel_mm", mDomain.voxel},
                              {"factor", k},
                              {"refinement", trial["refinement"]},
                              {"why", "the coarsest grid (" + limit + ") whose mesh has the recipe's " +
                                          std::to_string(finePieces) +
                                          " closed pieces, its triangles bisected where their chord error (" +
                                          formatNumber(chord) + " mm at most) was above the tolerance"},
                              {"trials", trials}};
                return mesh;
            }
            why = "at " + formatNumber(h) + " mm the refinement left " + std::to_string(r.remaining) +
                  " triangles above the tolerance and " + std::to_string(crossing) + " crossing pairs";
            trials.back()["rejected"] = why;
            topology.reset();
            // Needles and slivers of the coarse mesh along the box's faces that no split or flip
            // mends: a finer grid has fewer. From the coarsest, one step finer first (a gyroid of
            // 6 mm cells in a 12 mm box: over at 0.5 mm, none at 0.4 mm), then half as coarse
            // (cells of 5 and 7 mm need 0.2 mm).
            k = k == kMaxCoarsening ? k - 1 : k / 2;
            continue;
        }
        // A refined mesh the refinement left as it was: checked now.
        if (refine) {
            topology = timed("check topology", [&] {
                return reporting(mContext, "checking the mesh's topology",
                                 [&](const ProgressFn& progress) { return checkTopology(*mesh, nullptr, progress); });
            });
            if (!keepsPieces(*topology)) {
                topology.reset();
                continue;
            }
        }
        trials.push_back(trial);
        if (chord <= tolerance) {
            voxel = h;
            extraction = {{"voxel_mm", h},
                          {"recipe_voxel_mm", mDomain.voxel},
                          {"factor", k},
                          {"why", "the coarsest grid (" + limit +
                                      ") whose projected triangles stay within the tolerance away from the "
                                      "domain box (chord error " +
                                      formatNumber(chord) +
                                      " mm; where the solid meets the box the mesh is cut by its faces, exact "
                                      "at any voxel) and whose mesh has the recipe's " +
                                      std::to_string(finePieces) + " closed pieces"},
                          {"trials", trials}};
            return mesh;
        }
        why = "the chord error at " + formatNumber(h) + " mm is " + formatNumber(chord) + " mm, above the tolerance";
        topology.reset();
        k = finer(chord);
    }
    extraction = {{"voxel_mm", mDomain.voxel},
                  {"recipe_voxel_mm", mDomain.voxel},
                  {"factor", 1},
                  {"why", "the recipe's voxel: " + why},
                  {"trials", trials}};
    return nullptr;
}

/// How many times marching cubes' triangles a tolerance mesh may need (checkTolerance()).
constexpr double kMaxToleranceRefinement = 125.0;

void Job::checkTolerance(const MeshOptions& options)
{
    solveLevels();
    const double tolerance = *options.tolerance;
    const std::string where = options.toleranceWhere.empty() ? mRecipe.source->path : options.toleranceWhere;
    // A tolerance of half the thinnest strut lets decimation lay the strut's two sides onto one
    // another: refused. The struts' diameters are known from their nodes before any evaluation.
    for (const LevelNode& node : mBuilder.levelNodes()) {
        if (!node.thinnest) continue;
        const double thinnest = node.thinnest(node.solid->level());
        if (thinnest > 0.0 && tolerance >= 0.5 * thinnest)
            throw InputError(where + ": the mesh tolerance " + formatNumber(tolerance) +
                             " mm is not below half the thinnest strut of `" + node.name + "` (" +
                             formatNumber(thinnest) +
                             " mm across): decimation could flatten it; use a tolerance "
                             "below " +
                             formatNumber(0.5 * thinnest) + " mm");
    }
    // Edges meeting a tolerance T on a surface curved over about a voxel v are sqrt(8 v T) long:
    // v / (8 T) times the triangles of marching cubes at the voxel. Past kMaxToleranceRefinement
    // the job runs out of memory after minutes (1e-6 mm at 0.1 mm voxels: 6-7 GB, then bad_alloc):
    // refused with the estimate before any work.
    if (const double factor = mDomain.voxel / (8.0 * tolerance); factor > kMaxToleranceRefinement)
        throw JobError(where + ": a mesh tolerance of " + formatNumber(tolerance) +
                       " mm at `voxel: " + formatNumber(mDomain.voxel) + "` needs edges of about " +
                       formatNumber(std::sqrt(8.0 * mDomain.voxel * tolerance)) + " mm, about " +
                       formatNumber(std::round(factor)) + " times the triangles of marching cubes, more than the " +
                       formatNumber(kMaxToleranceRefinement) + " a job can hold: use a tolerance of at least " +
                       formatNumber(mDomain.voxel / (8.0 * kMaxToleranceRefinement)) + " mm");
    // The grid resolves features down to about two voxels; a tolerance above half of that (one
    // voxel) may flatten features the grid kept.
    if (tolerance > mDomain.voxel)
        mContext->warn("mesh_tolerance_coarse",
                       where + ": the mesh tolerance " + formatNumber(tolerance) + " mm is larger than the voxel (" +
                           formatNumber(mDomain.voxel) +
                           " mm, half the thinnest feature the grid resolves): walls and struts down to " +
                           formatNumber(2.0 * tolerance) + " mm across may be flattened",
                       {{"tolerance_mm", tolerance}, {"voxel_mm", mDomain.voxel}});
}

/// A crumb a cut leaves is warned of from this volume on (smaller ones stay in report.json).
constexpr double kCrumbWarningMm3 = 1.0;

void Job::checkPieces(const std::vector<SolidBlock>& blocks)
{
    const PieceCount count =
        timed("count pieces", [&] { return countPieces(blocks, [&] { mContext->checkCancelled(); }); });
    const double voxelVolume = std::pow(mDomain.voxel, 3);
    auto describe = [&](const Piece& p) {
        const Vec3d lo = mDomain.worldOf(p.bounds.min()), hi = mDomain.worldOf(p.bounds.max());
        return nlohmann::json{{"volume_mm3", double(p.voxels) * voxelVolume},
                              {"voxels", p.voxels},
                              {"min", vec(lo)},
                              {"max", vec(hi)},
                              {"center", vec(0.5 * (lo + hi))}};
    };
    nlohmann::json largest = nlohmann::json::array();
    for (std::size_t i = 0; i < std::min<std::size_t>(count.pieces.size(), 5); ++i)
        largest.push_back(describe(count.pieces[i]));
    mReport["pieces"] = {
        {"count", count.pieces.size()}, {"connectivity", "voxels sharing a face (6-connected)"}, {"largest", largest}};
    if (count.pieces.size() <= 1) return;
    // Crumbs: when every other piece is under 1 % of the largest and all together are under 1 %
    // of the solid, they are corners a cut left (the domain box or a trimming shape across a
    // gyroid, a skin layer's inner surface across a sheet): a warning with their count and volume.
    // Otherwise pieces float free (struts lost to their joints, walls below the voxel, separate
    // parts): the job fails unless `allow: [pieces]`.
    const Piece& second = count.pieces[1];
    const std::uint64_t restVoxels = count.solidVoxels - count.pieces[0].voxels;
    const bool onlyCrumbs = double(second.voxels) < 0.01 * double(count.pieces[0].voxels) &&
                            double(restVoxels) < 0.01 * double(count.solidVoxels);
    const std::size_t crumbs = onlyCrumbs ? count.pieces.size() - 1 : 0;
    const std::uint64_t crumbVoxels = onlyCrumbs ? restVoxels : 0;
    const Piece* firstFree = onlyCrumbs ? nullptr : &second;
    const std::size_t free = count.pieces.size() - 1 - crumbs;
    mReport["pieces"]["free"] = free;
    mReport["pieces"]["crumbs"] = {{"count", crumbs}, {"volume_mm3", double(crumbVoxels) * voxelVolume}};
    const Piece& main = count.pieces[0];
    auto centre = [&](const Piece& p) {
        // Six significant digits, as the message's other numbers (a JSON dump gave 16.200000000000003).
        const Vec3d c = 0.5 * (mDomain.worldOf(p.bounds.min()) + mDomain.worldOf(p.bounds.max()));
        return "[" + formatNumber(c.x()) + ", " + formatNumber(c.y()) + ", " + formatNumber(c.z()) + "]";
    };
    std::ostringstream msg;
    msg << "the result `" << mRecipe.result << "` falls apart into " << count.pieces.size()
        << " pieces (voxels sharing a face): the largest holds "
        << formatNumber(100.0 * double(main.voxels) / double(count.solidVoxels)) << " % of the solid";
    if (free == 0) {
        msg << "; the other " << crumbs << " are crumbs a cut leaves (the domain box or a trimming shape across cells: "
            << formatNumber(double(crumbVoxels) * voxelVolume)
            << " mm3 in all), loose in print: move or resize `domain:` (or the trimming shape) to cut the cells "
               "elsewhere";
        // Slivers smaller than a cubic millimetre each are listed (report.json `pieces.crumbs`)
        // but not warned of: nearly every box cut of a TPMS leaves some at its corners.
        const double largestCrumb = double(second.voxels) * voxelVolume;
        mReport["pieces"]["crumbs"]["largest_mm3"] = largestCrumb;
        if (largestCrumb >= kCrumbWarningMm3)
            mContext->warn(
                "crumbs", msg.str(),
                {{"count", crumbs}, {"volume_mm3", double(crumbVoxels) * voxelVolume}, {"largest_mm3", largestCrumb}});
        return;
    }
    msg << "; " << free << " float free inside the domain, the largest of them "
        << formatNumber(double(firstFree->voxels) * voxelVolume) << " mm3 around " << centre(*firstFree);
    // A field whose struts vanish between their joints at its level (thinnest 0: the iso-value
    // above their peak) loses them whatever the voxel: a finer one is no fix there.
    std::vector<std::string> vanishing;
    for (const LevelNode& node : mBuilder.levelNodes())
        if (node.thinnest && node.thinnestKind != "wall" && node.thinnest(node.solid->level()) <= 0.0)
            vanishing.push_back("`" + node.name + "`");
    // Allowed pieces of a size with the largest (the next largest at least a tenth of it) are parts
    // apart by design (a plate of lattices): struts lost to the grid leave small ones.
    const bool partsApart = mRecipe.allows("pieces") && double(second.voxels) >= 0.1 * double(main.voxels);
    if (!vanishing.empty()) {
        msg << ". Struts of " << vanishing.front();
        for (std::size_t k = 1; k < vanishing.size(); ++k)
            msg << (k + 1 == vanishing.size() ? " and " : ", ") << vanishing[k];
        msg << " vanish between their joints at the level (the iso-value is above their peak: "
               "`thinnest_strut_mm` 0 in report.json), which no finer voxel brings back: lower sigma, or raise "
               "the density or radius";
    } else if (partsApart) {
        msg << ". The largest free piece holds " << formatNumber(100.0 * double(second.voxels) / double(main.voxels))
            << " % of the largest piece's volume: parts apart by design, as `allow: [pieces]` says (struts lost "
               "to the grid leave small pieces)";
    } else {
        msg << ". Struts or walls thinner than two voxels (" << formatNumber(2 * mDomain.voxel)
            << " mm) break apart on the grid: use `voxel: " << formatNumber(mDomain.voxel / 2)
            << "` or less, or raise the density, radius or thickness; a convolution lattice at low density "
               "loses its struts to its joints when sigma is large: lower sigma";
    }
    if (mRecipe.allows("pieces")) {
        mContext->warn("pieces", msg.str(), {{"count", count.pieces.size()}, {"free", free}});
        return;
    }
    // A convolution lattice at a fixed density: the sigma that keeps it whole, in numbers.
    const std::optional<double> sigma =
        timed("find a sigma that holds", [&] { return sigmaKeepingOnePiece(mRecipe, mRecipe.result, mContext); });
    if (sigma)
        msg << ". At its density this lattice stays in one piece for sigma <= " << formatNumber(*sigma)
            << " mm (trials over 2 x 2 x 2 of its cells at this voxel)";
    msg << ". A plate of separate parts: add `allow: [pieces]`";
    throw JobError(mRecipe.source->path + ": " + msg.str());
}

MeshMetadata Job::meshMetadata() const
{
    return {{"Application", "voxlat " + versionString()},
            {"voxlat_version", versionString()},
            {"voxlat_recipe_sha256", recipeHash(mRecipe)},
            {"voxlat_recipe", canonicalRecipe(mRecipe).dump()}};
}

void Job::writeMesh(const std::filesystem::path& path, const MeshOptions& options)
{
    // The file's kind and place are checked before any work, not after the mesh is made.
    std::string extension = path.extension().string();
    for (char& c : extension) c = char(std::tolower(static_cast<unsigned char>(c)));
    if (extension != ".stl" && extension != ".3mf" && extension != ".ply" && extension != ".obj")
        throw InputError("`" + path.string() + "`: a mesh file ends in .stl, .3mf, .ply or .obj");
    checkReplaceable(path, mRecipe.source->path + ": mesh output");
    warnStaleTemporaries({path});
    // Written alone (the command line's `mesh`, Python): held back until the file is complete
    // and the job was not cancelled meanwhile, so a cancel keeps the old file.
    std::optional<OutputTransaction> own;
    if (!OutputTransaction::current()) own.emplace(writeInterrupter());
    aimLevelsAtMesh(options);
    MeshVariant& v = variant(options);
    releaseSolvedValues();  // a mesh that did not read the recipe's grid leaves them unused
    if (v.mesh->triangles.empty())
        throw JobError(mRecipe.source->path + ": the result `" + mRecipe.result +
                       "` has no surface in the domain: the mesh would be empty (check the domain, the density or "
                       "level, and the fields' sizes)");
    // `strict: on`: a mesh beyond its tolerance is not written; the job fails (exit 3) with the numbers.
    if (options.strict && v.report.contains("tolerance_missed")) {
        const nlohmann::json& miss = v.report["tolerance_missed"];
        throw JobError(path.string() +
                       ": `strict: on`: " + toleranceMiss(miss["max_mm"].get<double>(), options).message);
    }
    timed("write " + path.filename().string(), [&] {
        voxlat::writeMesh(*v.mesh, path.string(), v.measures ? nullptr : &v.measures, meshMetadata());
        return 0;
    });
    if (own) {
        mContext->checkCancelled();
        own->commit();
    }
    v.files.push_back(path.string());
    mReport["outputs"].push_back(path.string());
    checkDensityFromMesh();
}

void Job::warnStaleTemporaries(const std::vector<std::filesystem::path>& paths) const
{
    for (const std::filesystem::path& path : paths)
        for (const std::string& stale : staleTemporaries(path.string()))
            mContext->warn("stale_temporary",
                           "`" + stale + "` is a temporary file left by a run that was killed before it finished `" +
                               path.filename().string() + "`; it is not used: remove it",
                           {{"file", stale}});
}

StreamedStl Job::streamStl(const openvdb::FloatGrid& g, const std::filesystem::path& path)
{
    checkReplaceable(path, mRecipe.source->path + ": mesh output");
    const std::string name = path.filename().string();
    return timed("mesh into " + name, [&] {
        StageProgress progress(mContext, "meshing into " + name, 1000);
        std::atomic<std::uint64_t> last{0};
        // Volume terms about the domain's centre: near every triangle, so the sums keep their digits.
        return writeMarchingCubesStl(g, 0.0f, path.string(), mDomain.box.center(), feed(progress, last));
    });
}

void Job::writeStlWhileMeshing(const std::filesystem::path& path)
{
    const openvdb::FloatGrid& g = grid();
    auto v = std::make_unique<MeshVariant>();
    StreamedStl made;
    if (mStreamedAim && mStreamedAim->path == path) {
        made = mStreamedAim->made;  // written by aimLevelsAtMesh() at this level
        mStreamedAim.reset();
    } else {
        made = streamStl(g, path);
    }
    v->measures = made.measures;
    const StreamedMeshCounts& counts = made.counts;
    if (counts.triangles == 0)
        throw JobError(mRecipe.source->path + ": the result `" + mRecipe.result +
                       "` has no surface in the domain: the mesh would be empty (check the domain, the density or "
                       "level, and the fields' sizes)");
    v->report["extractor"] = meshExtractorName(MeshExtractor::MarchingCubes);
    v->report["triangles"] = counts.triangles;
    v->report["vertices"] = counts.vertices;
    v->files.push_back(path.string());
    mMeshes.push_back(std::move(v));
    mReport["outputs"].push_back(path.string());
    checkDensityFromMesh();
}

std::optional<Job::MeshShareMeasure> Job::meshShareOf(const LevelNode& node, double meshVolume)
{
    const auto region = mDensityRegionMm3.find(node.name);
    if (!node.density || region == mDensityRegionMm3.end() || !(region->second > 0.0)) return std::nullopt;
    const std::optional<LevelNode::MeshShare>& share = node.meshShare;
    if (mRecipe.result != (share ? share->meshOf : node.name)) return std::nullopt;
    double regionVolume = region->second, latticeVolume = meshVolume;
    std::string regionWords;
    if (share) {
        const double part = share->partVolume ? share->partVolume() : 0.0;
        if (share->skinned) {
            // The skin is the part outside the region: its volume leaves the lattice's.
            if (!(part > regionVolume)) return std::nullopt;
            latticeVolume = meshVolume - (part - regionVolume);
        } else if (part > 0.0) {
            regionVolume = part;  // the part as its mesh encloses it
        }
        regionWords = node.densityOf;
    } else {
        // Alone, over a box: the mesh is cut by the domain, so the box must be the domain's
        // (within a voxel on every face; a snapped domain is measured over what it holds).
        if (node.densityMask) return std::nullopt;
        const Box3 box = node.densityBox ? *node.densityBox : mDomain.box;
        bool same = true;
        for (int a = 0; a < 3; ++a)
            same = same && std::abs(box.min[a] - mDomain.box.min[a]) <= mDomain.voxel &&
                   std::abs(box.max[a] - mDomain.box.max[a]) <= mDomain.voxel;
        if (!same) return std::nullopt;
        const Vec3d e = mDomain.box.extent();
        regionVolume = e[0] * e[1] * e[2];
        regionWords = node.densityOf.empty() ? "the domain box" : node.densityOf;
    }
    return MeshShareMeasure{latticeVolume / regionVolume, regionWords};
}

void Job::checkDensityFromMesh()
{
    if (mDensityChecked || mMeshes.empty() || mMeshes.front()->files.empty()) return;
    mDensityChecked = true;
    const MeshVariant& v = *mMeshes.front();
    if (!v.measures) v.measures = v.mesh->measure();
    const double meshVolume = v.measures->volume;
    for (const LevelNode& node : mBuilder.levelNodes()) {
        const std::optional<MeshShareMeasure> share = meshShareOf(node, meshVolume);
        if (!share) {
            // Said, not left out silently: the share stays the solve's, met on the voxels.
            if (node.density && mSolvedDensity.contains(node.name))
                mDensityFromMesh[node.name] = {
                    {"density_from_mesh_not_measured",
                     "the mesh of `" + mRecipe.result + "` cannot give `" + node.name +
                         "`'s share of its region (it holds more than this lattice, or the region is not one it "
                         "is cut to): `achieved_density` is the solve's, met on the voxels; the mesh's surface "
                         "lies between them (about 1-3 % at 5-10 voxels a cell, less with a finer voxel)"}};
            continue;
        }
        const double measured = share->measured;
        const std::string& regionWords = share->region;
        const double gap = measured / *node.density - 1.0;
        mDensityFromMesh[node.name] = {
            {"density_from_mesh", measured}, {"density_from_mesh_gap", gap}, {"density_from_mesh_of", v.files.front()}};
        if (std::abs(gap) > 0.01) {
            // The gap is the mesh's surface placement between samples, second order in the voxel.
            const double finer = mDomain.voxel * std::sqrt(0.008 / std::abs(gap));
            char numbers[160];
            std::snprintf(numbers, sizeof numbers, " holds %.4f of %s for `%s`, %+.1f %% from its density: %g",
                          measured, regionWords.c_str(), node.name.c_str(), 100.0 * gap, *node.density);
            char fix[160];
            std::snprintf(fix, sizeof fix, "a `voxel:` of about %.2g mm (now %g)", finer, mDomain.voxel);
            mContext->warn("density_from_mesh",
                           "the mesh " + std::filesystem::path(v.files.front()).filename().string() + numbers +
                               " (the solve met it on the voxels; the mesh's surface lies between them): " + fix +
                               " brings the mesh within 1 %, as does a field that varies more about its level",
                           {{"field", node.name},
                            {"density_from_mesh", measured},
                            {"target", *node.density},
                            {"gap", gap},
                            {"suggested_voxel_mm", finer}});
        }
    }
}

void Job::writeOutputs(const std::filesystem::path& outDir, bool preview, bool html)
{
    // Every output's place is checked before any work: inside outDir, onto nothing but files.
    const std::string where = mRecipe.source->path + ": outputs";
    std::error_code made;
    std::filesystem::create_directories(outDir, made);
    if (made)
        throw OutputError("cannot create the output folder `" + outDir.string() + "`: " + made.message() +
                          " (choose another --out)");
    std::vector<std::filesystem::path> paths;
    for (const OutputSpec& out : mRecipe.outputs) {
        paths.push_back(outputPathIn(outDir, out.file, where));
        for (const std::string& side : out.sideFiles) outputPathIn(outDir, side, where);
    }
    std::vector<std::filesystem::path> written = paths;
    for (const OutputSpec& out : mRecipe.outputs)
        for (const std::string& side : out.sideFiles) written.push_back(outDir / side);
    written.push_back(outputPathIn(outDir, "report.json", where));
    // The page's scripts are read before any work: a missing three.js fails the run at once.
    std::vector<std::string> pageScripts;
    if (html) {
        written.push_back(outputPathIn(outDir, "report.html", where));
        pageScripts = reportPageScripts();
    }
    std::optional<std::filesystem::path> materialCard;
    if (mRecipe.properties.exportFile) {
        materialCard = outputPathIn(outDir, *mRecipe.properties.exportFile, mRecipe.properties.where + ": export");
        written.push_back(*materialCard);
    }
    warnStaleTemporaries(written);
    // All or none: every file is written under a temporary name and the renames wait for the
    // report; an output that fails (or a cancel) half-way leaves the folder as it was.
    OutputTransaction transaction(writeInterrupter());
    const OutputSpec* firstMesh = mRecipe.firstOutput("mesh");
    // A raw marching-cubes STL whose mesh nothing else uses (no other output with the same mesh
    // settings, not the preview's) is written as it is made: the mesh is never held.
    auto onlyUse = [&](std::size_t n) {
        const MeshOptions options = meshOptions(mRecipe.outputs[n]);
        if (!options.raw() || options.extractor != MeshExtractor::MarchingCubes) return false;
        std::string extension = paths[n].extension().string();
        for (char& c : extension) c = char(std::tolower(static_cast<unsigned char>(c)));
        if (extension != ".stl") return false;
        if (preview && &mRecipe.outputs[n] == firstMesh) return false;
        for (std::size_t m = 0; m < mRecipe.outputs.size(); ++m)
            if (m != n && mRecipe.outputs[m].kind == "mesh" && meshOptions(mRecipe.outputs[m]) == options) return false;
        return std::none_of(mMeshes.begin(), mMeshes.end(), [&](const auto& v) { return v->options == options; });
    };
    // The first mesh is the one whose share of its region `density:` is held to: its level is aimed
    // at it before any output is made, so every output has the same level (a streamed STL
    // is measured as it is written: aimLevelsAtMesh()).
    if (firstMesh) {
        const auto first = std::size_t(firstMesh - mRecipe.outputs.data());
        aimLevelsAtMesh(meshOptions(*firstMesh), onlyUse(first) ? &paths[first] : nullptr);
    }
    // Whether an output after the n-th may read the recipe's grid: a VDB, or a mesh made otherwise
    // (the preview's mesh is the first one's, held by then).
    auto gridNeededAfter = [&](std::size_t n) {
        const MeshOptions options = meshOptions(mRecipe.outputs[n]);
        for (std::size_t m = n + 1; m < mRecipe.outputs.size(); ++m) {
            const OutputSpec& later = mRecipe.outputs[m];
            if (later.kind == "vdb" || (later.kind == "mesh" && !(meshOptions(later) == options))) return true;
        }
        return false;
    };
    for (std::size_t n = 0; n < mRecipe.outputs.size(); ++n) {
        mContext->checkCancelled();  // a cancel between outputs stops before the next one
        const OutputSpec& out = mRecipe.outputs[n];
        const std::filesystem::path& path = paths[n];
        if (out.kind == "mesh") {
            if (onlyUse(n)) {
                writeStlWhileMeshing(path);
            } else {
                const bool releasable = mGridReleasable;
                mGridReleasable = !gridNeededAfter(n);
                writeMesh(path, meshOptions(out));
                mGridReleasable = releasable;
            }
        } else if (out.kind == "vdb") {
            const openvdb::FloatGrid& g = grid();
            timed("write " + out.file, [&] {
                openvdb::GridCPtrVec grids{g.copyGrid()};
                CheckedStringBuffer buffer;
                std::ostream bytes(&buffer);
                bytes.exceptions(std::ios::badbit);  // the interrupter's Cancelled leaves the writer
                openvdb::io::Stream(bytes).write(grids);
                std::string data = buffer.take();
                setVdbUuid(data, recipeHash(mRecipe));
                AtomicFile file(path.string());
                file.stream().write(data.data(), std::streamsize(data.size()));
                file.commit();
                return 0;
            });
            mReport["outputs"].push_back(path.string());
        } else if (out.kind == "slices") {
            writeSlices(*out.slices, path, html && !mPageLayers);
        } else if (out.kind == "properties") {
            writeProperties(path);
        } else if (out.kind == "frame") {
            writeFrameFile(path);
        }
        releaseSolvedValues();  // an output that read no recipe grid leaves them unused
    }
    if (materialCard) writeMaterialCard(*materialCard);
    // A picture of what was meshed, next to the first mesh, so the part can be checked by eye.
    if (preview && firstMesh) {
        const std::filesystem::path picture = outDir / (firstMesh->file + ".preview.png");
        checkReplaceable(picture, where);
        writePreview(picture, meshOptions(*firstMesh));
    }
    std::optional<TriangleMesh> shown;
    std::optional<PageColouring> colouring;
    if (html) {
        shown = timed("report.html mesh", [&] { return pageMesh(); });
        colouring = timed("report.html walls", [&] { return pageColouring(*shown); });
    }
    writeReport(outDir / "report.json");
    if (html) {
        AtomicFile file((outDir / "report.html").string());
        file.stream() << reportPage(report(), *shown, pageScripts, colouring ? &*colouring : nullptr,
                                    mPageLayers ? &*mPageLayers : nullptr);
        file.commit();
    }
    // A cancel that came while the last files were written still keeps the folder as it was.
    mContext->checkCancelled();
    transaction.commit();
}

TriangleMesh Job::pageMesh()
{
    constexpr std::size_t kTriangles = 60000;
    for (const auto& v : mMeshes)
        if (v->mesh && !v->mesh->triangles.empty()) return clusterDecimate(*v->mesh, kTriangles);
    // No mesh held (slices only, or a mesh streamed to its file): the result on a coarse grid of
    // the domain, at most 2^18 voxels (64^3: a picture).
    solveLevels();
    // A result that repeats (a tiled lattice) is read from its one-period table where the coarse
    // voxel divides each period, else evaluated point by point (W2g's 50 mm frames: 0.10 s
    // against 0.05 s, a fifteenth of the run).
    std::vector<double> periods;
    for (int a = 0; a < 3; ++a) {
        const double p = std::max(mResult->period(a), mResult->axisRepeat(a).period) / mDomain.voxel;
        if (p > 0.0) periods.push_back(p);
    }
    const double factor = pageGridFactor(mDomain.voxelCount(), periods);
    const Domain coarse = Domain::fromBox(mDomain.box, mDomain.voxel * factor);
    SparseOptions options;
    options.clipToDomain = true;
    options.stage = "evaluating " + mRecipe.result + " for report.html";
    options.context = mContext;
    // In stacks as the result's grids (a convolution lattice: a strut's row set-up shared by the
    // leaves of a stack, where a leaf of this grid holds a few points of each of its ~900 struts),
    // as tall as suits the coarse grid's height (a thin plate's stacks of eight, four coarse voxels
    // deep, made seven leaves of points nobody reads: W10's page mesh 0.41-0.49 s, now 0.37 s).
    // The recipe's grid held (a mesh streamed from it) and a result that does not repeat: the
    // grid's values read back where its leaves are, the result evaluated only where it has tiles
    // (the 50 mm wireframe's picture took 0.55 s of strut sums, ~900 struts a coarse leaf; now
    // 0.18 s, most of it the bounds of the leaves at the domain's faces, whose clip the cull
    // takes no held values for). A result that repeats reads its one-period table faster (W1's
    // gyroid: 0.014-0.023 s, read back 0.046 s).
    std::optional<HeldGridField> held;
    if (mGrid && periods.empty()) held.emplace(mResult, mGrid);
    options.stackLeaves = held ? 1 : stackLeavesFor(coarse, mStackLeaves);
    const openvdb::FloatGrid::Ptr g =
        evaluateSparse(held ? static_cast<const FieldNode&>(*held) : *mResult, coarse, options);
    return clusterDecimate(marchingCubes(*g, 0.0f), kTriangles);
}

std::optional<PageColouring> Job::pageColouring(const TriangleMesh& mesh)
{
    // A sheet with graded walls: the walls the part has, measured at each vertex of the page's
    // mesh. (Graded densities are coloured by the page itself, from the slabs in the report.)
    for (const LevelNode& node : mBuilder.levelNodes()) {
        if (node.gradedWalls.empty() || mesh.points.empty()) continue;
        PageColouring c;
        c.by = "wall thickness";
        c.field = node.name;
        c.unit = "mm";
        const double step = mDomain.voxel / 8.0, most = 64.0 * mDomain.voxel;
        c.note = "measured at each vertex: the chord into the part along its normal, to " + formatNumber10(step) +
                 " mm (a wall seen obliquely, or where walls meet, reads thicker); " + node.gradedWalls;
        c.values = surfaceThickness(*mResult, mesh.points, step, most);
        return c;
    }
    return std::nullopt;
}

BeamFrame Job::frame()
{
    solveLevels();
    BeamFrame all;
    for (const StrutFrameRecord& f : mBuilder.strutFrames()) {
        const int offset = int(all.nodes.size());
        all.nodes.insert(all.nodes.end(), f.nodes.begin(), f.nodes.end());
        for (const auto& s : f.struts) all.struts.push_back({s[0] + offset, s[1] + offset});
        const auto radii = f.radii();
        all.radii.insert(all.radii.end(), radii.begin(), radii.end());
    }
    return all;
}

void Job::writeMaterialCard(const std::filesystem::path& path)
{
    checkReplaceable(path, mRecipe.properties.where + ": export");
    for (const GradedNode& node : mBuilder.gradedNodes())
        if (node.name == mRecipe.result) {
            const std::string cards = gradedMaterialCards(node);
            timed("write " + path.filename().string(), [&] {
                AtomicFile file(path.string());
                file.stream() << cards;
                file.commit();
                return 0;
            });
            mReport["outputs"].push_back(path.string());
            return;
        }
    const nlohmann::json& p = properties();
    timed("write " + path.filename().string(), [&] {
        AtomicFile file(path.string());
        file.stream() << abaqusMaterialCard(p, mRecipe.result + "_cell", mRecipe.source->path);
        file.commit();
        return 0;
    });
    mReport["outputs"].push_back(path.string());
}

std::string Job::gradedMaterialCards(const GradedNode& node)
{
    const std::string where = mRecipe.properties.where + ": export";
    const auto facts = mRecipe.fieldFacts.find(node.name);
    if (facts == mRecipe.fieldFacts.end() || !facts->second.hasDensity)
        throw InputError(where + ": the graded lattice `" + node.name +
                         "` has no `density:` map to take slab by slab; export the cards of a lattice of one density");
    const int axis = node.axis;
    const char* axisName = "xyz";
    const Box3 box = mDomain.box;
    const double slab = node.slab;
    const int slabs = std::max(1, int(std::ceil(box.extent()[axis] / slab - 1e-9)));
    // The density field on a lattice of 16 x 16 points across each of 8 planes of a slab: the
    // slab's mean target density, and how much the density varies across the slab (which one
    // material per slab cannot carry).
    constexpr int kAcross = 16, kPlanes = 8;
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;
    std::vector<double> mean(slabs, 0.0), lows(slabs), highs(slabs);
    double worstAcross = 0.0, worstAt = 0.0;
    for (int s = 0; s < slabs; ++s) {
        const double from = box.min[axis] + s * slab, to = std::min(box.max[axis], from + slab);
        std::vector<Vec3d> points;
        for (int k = 0; k < kPlanes; ++k)
            for (int i = 0; i < kAcross; ++i)
                for (int j = 0; j < kAcross; ++j) {
                    Vec3d p;
                    p[axis] = from + (k + 0.5) / kPlanes * (to - from);
                    p[u] = box.min[u] + (i + 0.5) / kAcross * box.extent()[u];
                    p[v] = box.min[v] + (j + 0.5) / kAcross * box.extent()[v];
                    points.push_back(p);
                }
        std::vector<double> rho(points.size());
        node.densityField->values(points, rho);
        double sum = 0.0;
        lows[s] = std::numeric_limits<double>::infinity(), highs[s] = -lows[s];
        for (int k = 0; k < kPlanes; ++k) {
            const auto first = rho.begin() + std::ptrdiff_t(k) * kAcross * kAcross;
            const auto [lo, hi] = std::minmax_element(first, first + kAcross * kAcross);
            if (*hi - *lo > worstAcross)
                worstAcross = *hi - *lo, worstAt = points[std::size_t(k) * kAcross * kAcross][axis];
        }
        for (double r : rho) {
            sum += r;
            lows[s] = std::min(lows[s], r);
            highs[s] = std::max(highs[s], r);
        }
        mean[s] = sum / double(rho.size());
    }
    // One material per slab holds when the density is the same across a slab: 0.005 (half a
    // per cent of density) is below what the density solve itself resolves.
    constexpr double kAcrossTolerance = 0.005;
    if (worstAcross > kAcrossTolerance)
        throw InputError(where + ": the graded lattice `" + node.name + "` is taken in slabs along " + axisName[axis] +
                         " (one cell thick), but its density also varies across them (by " + formatNumber(worstAcross) +
                         " at " + axisName[axis] + " = " + formatNumber(worstAt) +
                         " mm), which one material per slab cannot carry: grade the density along " + axisName[axis] +
                         " only, or export the cards of lattices of one density");
    std::string cards;
    nlohmann::json rows = nlohmann::json::array();
    StageProgress progress(mContext, "material cards of " + node.name, std::uint64_t(slabs));
    for (int s = 0; s < slabs; ++s) {
        mContext->checkCancelled();
        FieldEdit slabDensity;
        slabDensity.density = mean[s];
        Recipe uniform = trialRecipe(mRecipe, node.name, slabDensity);
        JobContext quiet;
        Job job(std::move(uniform), &quiet);
        const nlohmann::json p = timed("homogenize", [&] { return job.properties(); });
        for (const auto& w : quiet.warnings())
            if (w.code == "no_load_path" || w.code == "loose_pieces" || w.code == "not_converged") mContext->warn(w);
        const double from = box.min[axis] + s * slab, to = std::min(box.max[axis], from + slab);
        const std::string name = node.name + "_slab" + std::to_string(s + 1);
        std::string region = std::string(1, axisName[axis]) + " from " + formatNumber(from) + " to " +
                             formatNumber(to) + " mm (slab " + std::to_string(s + 1) + " of " + std::to_string(slabs) +
                             " of the grading, one cell thick); target density " + formatNumber(mean[s]) +
                             " (mean over the slab; " + formatNumber(lows[s]) + " to " + formatNumber(highs[s]) + ")";
        cards += abaqusMaterialCard(p, name, mRecipe.source->path, region);
        std::string upper = name;
        for (char& c : upper) c = char(std::toupper(static_cast<unsigned char>(c)));
        rows.push_back({{"material", upper},
                        {"from_mm", from},
                        {"to_mm", to},
                        {"target_density", mean[s]},
                        {"target_density_range", {lows[s], highs[s]}},
                        {"relative_density", p["relative_density"]},
                        {"E_MPa", p["E_MPa"]},
                        {"resolution", p["cell"]["voxels"]}});
        progress.add();
    }
    progress.finish();
    mReport["material_cards"] = {{"axis", std::string(1, axisName[axis])},
                                 {"slabs", rows},
                                 {"method",
                                  "one material per slab of the grading (one cell thick): the cell "
                                  "homogenized at the slab's mean target density"}};
    return cards;
}

void Job::writeFrameFile(const std::filesystem::path& path)
{
    checkReplaceable(path, mRecipe.source->path + ": frame output");
    const BeamFrame f = frame();
    timed("write " + path.filename().string(), [&] {
        writeFrame(f, path.string(), meshMetadata());
        return 0;
    });
    double rMin = f.radii.empty() ? 0.0 : std::numeric_limits<double>::infinity(), rMax = 0.0;
    for (const auto& r : f.radii)
        for (const double v : r) {
            rMin = std::min(rMin, v);
            rMax = std::max(rMax, v);
        }
    nlohmann::json files = mReport.contains("frame") ? mReport["frame"]["files"] : nlohmann::json::array();
    files.push_back(path.string());
    mReport["frame"] = {{"files", files},
                        {"nodes", f.nodes.size()},
                        {"struts", f.struts.size()},
                        {"radius_min_mm", rMin},
                        {"radius_max_mm", rMax}};
    mReport["outputs"].push_back(path.string());
}

const nlohmann::json& Job::properties()
{
    if (!mReport.contains("properties")) {
        // One period of the result, from the domain's minimum corner unless the recipe says otherwise.
        const Vec3d corner = mRecipe.domainBox ? mRecipe.domainBox->min : mDomain.box.min;
        const FieldPtr result = field(mRecipe.result);
        // A lattice asked for a density: the cell's level is solved on its own voxel model.
        std::optional<CellDensityTarget> target;
        for (const LevelNode& node : mBuilder.levelNodes())
            if (node.name == mRecipe.result && node.density && !node.densityMask)
                target = CellDensityTarget{*node.density, node.solid->level(), node.solid->side(), node.recipeLevel};
        if (const std::optional<RepeatZone> zone = frameWithoutWholeCell(*result, mRecipe.properties);
            zone && unitCellProperties(*zone)) {
            // done: a frame too small to hold a whole repeating cell, homogenized as its cell repeated
        } else {
            PropertiesResult r = timed("homogenize", [&] {
                return computeProperties(*result, mRecipe, corner, mContext, target ? &*target : nullptr);
            });
            mReport["properties"] = std::move(r.report);
            mPropertiesStiffness = r.stiffnessMPa;
        }
    }
    return mReport["properties"];
}

bool Job::unitCellProperties(const RepeatZone& zone)
{
    // Only a box frame (`struts: {cell, size}`, with `count:` and `origin:` or filling the
    // domain) is laid out by keys this can change; any other frame keeps the error that asks
    // for `properties: {cell}`.
    const auto facts = mRecipe.fieldFacts.find(mRecipe.result);
    if (facts == mRecipe.fieldFacts.end() || !facts->second.boxFrame) return false;
    // The same cells, enough of them around the frame's first cell that it sees every strut that
    // reaches it (the reach grows a little when a density is solved over the larger frame).
    std::array<int, 3> count{};
    std::array<double, 3> origin{};
    int cells = 1;
    for (int a = 0; a < 3; ++a) {
        const double p = zone.period[a];
        const int margin = std::max(1, int(std::ceil(1.25 * (zone.box.min[a] - zone.phase[a]) / p - 1e-9)));
        count[a] = 2 * margin + 1;
        origin[a] = zone.phase[a] - margin * p;
        cells *= 2 * margin + 1;
    }
    FieldEdit grown;
    grown.count = count;
    grown.origin = origin;
    Recipe repeated = trialRecipe(mRecipe, mRecipe.result, grown);
    // Its own warnings (a domain the larger frame overhangs) are not about the recipe's part.
    JobContext quiet;
    followCancel(quiet, mContext);
    mContext->checkCancelled();
    // Only its properties are asked of it, and its cell solves its own level on its voxel model
    // when the lattice has a density: its density box is solved coarse (CellLevelTrial).
    const CellLevelTrial trial;
    Job job(std::move(repeated), &quiet);
    nlohmann::json report = timed("homogenize", [&] { return job.properties(); });
    report["cell"]["from"] = "the frame's cell, repeated (the infinite lattice of that cell)";
    report["cell"]["frame_cells_homogenized"] = cells;
    for (const auto& w : quiet.warnings())
        if (w.code == "no_load_path" || w.code == "loose_pieces") mContext->warn(w);
    mReport["properties"] = std::move(report);
    mPropertiesStiffness = job.mPropertiesStiffness;
    return true;
}

void Job::writeProperties(const std::filesystem::path& path)
{
    checkReplaceable(path, mRecipe.source->path + ": properties output");
    const nlohmann::json& p = properties();
    std::filesystem::path picture = path;
    picture.replace_extension(".png");
    checkReplaceable(picture, mRecipe.source->path + ": properties output");
    timed("write " + path.filename().string(), [&] {
        AtomicFile file(path.string());
        file.stream() << p.dump(2) << "\n";
        AtomicFile png(picture.string());
        png.stream() << directionalModulusPng(mPropertiesStiffness);
        file.commit();
        png.commit();
        return 0;
    });
    mReport["properties_picture"] = picture.string();
    mReport["outputs"].push_back(path.string());
    mReport["outputs"].push_back(picture.string());
}

void Job::writePreview(const std::filesystem::path& path, const MeshOptions& options)
{
    const TriangleMesh& m = mesh(options);
    timed("preview", [&] {
        AtomicFile file(path.string());
        file.stream() << renderMeshPreview(m);
        file.commit();
        return 0;
    });
    mReport["preview"] = path.string();
}

void Job::writeSlices(const SliceSettings& settings, const std::filesystem::path& path, bool pageLayers)
{
    // Where the archive and its preview go, checked before any work (the preview is a relative
    // name beside the archive: checked when the recipe loads, resolved here).
    if (settings.preview != "off") {
        const std::string preview =
            settings.preview.empty() ? path.filename().string() + ".preview.png" : settings.preview;
        outputPathIn(path.parent_path().empty() ? std::filesystem::path(".") : path.parent_path(), preview,
                     settings.where + ": preview");
    }
    warnStaleTemporaries({path});
    std::optional<OutputTransaction> own;
    if (!OutputTransaction::current()) own.emplace(writeInterrupter());
    const PrinterProfile printer = loadPrinterProfile(settings.printer, settings.printerWhere);
    solveLevels();  // a `density:` level is solved on the recipe's voxel grid first
    // The part is the recipe's domain box as written (not snapped to voxels): slices need no
    // voxels. Without one, the result's own bounding box, the one a mesh's domain is grown from
    // (the part then stands on the build plate, with no empty layers under it).
    const std::optional<Box3> support = mResult->support();
    Box3 part = mRecipe.domainBox ? *mRecipe.domainBox : support ? *support : mDomain.box;
    if (!mRecipe.domainBox)
        part.min.z() = timed("find the part's floor",
                             [&] { return lowestSolidZ(*mResult, part, 0.5 * mDomain.voxel, *mContext); });
    const std::string where = mRecipe.domainBox ? mRecipe.node("domain").where() : mRecipe.source->path;
    SliceResult result = timed("slice " + path.filename().string(), [&] {
        return sliceToFile(*mResult, part, printer, settings, path, where, mContext, pageLayers);
    });
    nlohmann::json entry = result.report;
    entry["part_box"] = {{"from", mRecipe.domainBox ? "recipe domain"
                                  : support         ? "result's bounding box"
                                                    : "job domain"},
                         {"min", vec(part.min)},
                         {"max", vec(part.max)}};
    mReport["slices"].push_back(entry);
    if (pageLayers) mPageLayers = std::move(result.thumbnails);
    // The first slice job's findings also at the top (`printability.islands`, ...), where users look.
    if (result.report.contains("printability") && !mReport.contains("printability"))
        mReport["printability"] = result.report["printability"];
    if (own) {
        mContext->checkCancelled();
        own->commit();
    }
    mReport["outputs"].push_back(path.string());
}

nlohmann::json Job::report() const
{
    nlohmann::json r = mReport;
    auto describe = [](const MeshVariant& v) {
        if (!v.measures) v.measures = v.mesh->measure();
        nlohmann::json entry = v.report;
        entry["volume_mm3"] = v.measures->volume;
        entry["area_mm2"] = v.measures->area;
        return entry;
    };
    if (!mMeshes.empty()) {
        r["mesh"] = describe(*mMeshes.front());
        // The volume a user gets is the mesh's: the voxel count differs from it by the surface's
        // sub-voxel placement (and by projection or decimation), so it is kept apart, named.
        if (!mMeshes.front()->files.empty() && r.contains("result") && r["result"].contains("volume_mm3")) {
            r["result"]["voxel_count_volume_mm3"] = r["result"]["volume_mm3"];
            r["result"]["volume_mm3"] = r["mesh"]["volume_mm3"];
            r["result"]["volume_from"] = "the mesh " + mMeshes.front()->files.front();
        }
    }
    if (mMeshes.size() > 1) {
        r["meshes"] = nlohmann::json::array();
        for (const auto& v : mMeshes) {
            nlohmann::json entry = describe(*v);
            entry["files"] = v->files;
            r["meshes"].push_back(entry);
        }
    }
    for (const auto& [name, found] : mDensityFromMesh.items())
        if (r.contains("fields") && r["fields"].contains(name)) r["fields"][name].update(found);
    for (const auto& reporter : mBuilder.reporters()) reporter(r);
    const std::vector<Warning> warnings = mContext->warnings();
    if (!warnings.empty()) {
        r["warnings"] = nlohmann::json::array();
        for (const Warning& w : warnings) {
            nlohmann::json entry = w.details;
            entry["code"] = w.code;
            entry["message"] = w.message;
            r["warnings"].push_back(entry);
        }
    }
    r["timings_s"] = mTimings;
    r["peak_memory_mb"] = double(peakMemoryBytes()) / (1024.0 * 1024.0);
    r["threads"] = tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
    return r;
}

void Job::writeReport(const std::filesystem::path& path)
{
    AtomicFile file(path.string());
    file.stream() << report().dump(2) << "\n";
    file.commit();
}

}  // namespace voxlat
