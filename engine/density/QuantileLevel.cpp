#include "engine/density/DensitySolver.h"

#include "engine/core/Errors.h"
#include "engine/core/GridLeavesReused.h"
#include "engine/core/GridMeasure.h"
#include "engine/core/SparseEvaluator.h"
#include "engine/core/SystemInfo.h"
#include "engine/density/Coverage.h"
#include "fields/core/BlockLattice.h"
#include "fields/core/Scratch.h"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <deque>
#include <functional>
#include <limits>
#include <optional>
#include <sstream>
#include <unordered_map>
#include <vector>

// The quantile solve over a domain: a count of voxel centres, with sub-voxel coverage when value
// ties defeat the count (engine/density/Coverage.h).

namespace voxlat {

using namespace coverage;

namespace {

/// A leaf's values of g (as floats: a GridValueMemo's) where the mask cut it.
struct CutLeaf {
    openvdb::Coord origin;
    std::array<float, 512> values;
};

/// g where mask < 0, kOutsideMask elsewhere: a level below kOutsideMask then selects only voxels
/// inside the mask, so the unmasked quantile machinery measures density relative to the mask.
class MaskedIndicator final : public FieldNode {
public:
    MaskedIndicator(const FieldNode& g, const FieldNode& mask) : mG(g), mMask(mask) {}

    /// From now on, keeps g's values of each leaf of @a domain's grid that a batch evaluates and
    /// the mask cuts (some voxels inside, some not; a leaf the caller does not read, never), so
    /// that restoreCutLeaves() can put them back in place of the mask's.
    void keepCutLeaves(const Domain& domain) { mCutDomain = domain; }

    /// Puts g's values back into each leaf of @a grid holding kOutsideMask whose values were kept
    /// (keepCutLeaves()); returns how many. The kept values are then freed.
    std::size_t restoreCutLeaves(openvdb::FloatGrid& grid)
    {
        std::unordered_map<openvdb::Coord, const CutLeaf*, CoordHash> kept;
        for (const std::deque<CutLeaf>& leaves : mCut)
            for (const CutLeaf& leaf : leaves) kept.emplace(leaf.origin, &leaf);
        std::vector<openvdb::FloatGrid::TreeType::LeafNodeType*> leaves;
        grid.tree().getNodes(leaves);
        std::atomic<std::size_t> restored{0};
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size()), [&](const auto& range) {
            for (std::size_t n = range.begin(); n != range.end(); ++n) {
                float* data = leaves[n]->buffer().data();
                if (!data || std::none_of(data, data + 512, [](float v) { return v == float(kOutsideMask); })) continue;
                const auto found = kept.find(leaves[n]->origin());
                if (found == kept.end()) continue;
                std::copy(found->second->values.begin(), found->second->values.end(), data);
                ++restored;
            }
        });
        mCut.clear();
        return restored.load();
    }

    void values(std::span<const Vec3d> points, std::span<double> out) const override
    {
        mG.values(points, out);
        std::array<double, kBatchSize> m;
        forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
            mMask.values(points.subspan(b, n), std::span<double>(m.data(), n));
            for (std::size_t i = 0; i < n; ++i) out[b + i] = apply(out[b + i], m[i]);
        });
    }
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override
    {
        mG.gradients(points, out, grad);
        std::array<double, kBatchSize> m;
        forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
            mMask.values(points.subspan(b, n), std::span<double>(m.data(), n));
            for (std::size_t i = 0; i < n; ++i) out[b + i] = apply(out[b + i], m[i]);
        });
    }
    void gridValues(const GridBatch& batch, std::span<double> out) const override
    {
        // The mask's bound first: a batch wholly inside it is g's alone (the mask cuts none of its
        // leaves), one wholly outside needs no g; a float test on the bound holds for every value
        // within it (rounding to float keeps order).
        const Interval bound = mMask.bound(batch.bounds());
        if (float(bound.hi) < 0.0f) {
            mG.gridValues(batch, out);
            return;
        }
        if (!(float(bound.lo) < 0.0f)) {
            std::fill(out.begin(), out.begin() + batch.size(), kOutsideMask);
            return;
        }
        // Then its values. (A stack of leaves, more than kBatchSize points, takes them in this
        // thread's scratch: a vector of its own per stack was zeroed and faulted in every time.)
        std::array<double, kBatchSize> small;
        const ScratchLease large(batch.size() > kBatchSize ? batch.size() : 0);
        const std::span<double> m(batch.size() > kBatchSize ? large.data() : small.data(), batch.size());
        mMask.gridValues(batch, m);
        if (std::none_of(m.begin(), m.end(), [](double v) { return float(v) < 0.0f; })) {
            std::fill(out.begin(), out.begin() + batch.size(), kOutsideMask);
            return;
        }
        mG.gridValues(batch, out);
        if (mCutDomain) keepCut(batch, out, m);
        for (std::size_t i = 0; i < batch.size(); ++i) out[i] = apply(out[i], m[i]);
    }
    Interval bound(const Box3& box) const override
    {
        const Interval m = mMask.bound(box);
        if (!(float(m.lo) < 0.0f)) return Interval(kOutsideMask);
        const Interval g = mG.bound(box);
        return float(m.hi) < 0.0f ? g : hull(g, Interval(kOutsideMask));
    }

private:
    struct CoordHash {
        std::size_t operator()(const openvdb::Coord& c) const
        {
            return std::size_t(c.x()) * 73856093u ^ std::size_t(c.y()) * 19349663u ^ std::size_t(c.z()) * 83492791u;
        }
    };

    // The test is made in float, as the grid that counts the mask's voxels stores it.
    static double apply(double g, double mask) { return float(mask) < 0.0f ? g : kOutsideMask; }

    /// keepCutLeaves()'s work for one batch: g's values @a g, the mask's @a m.
    void keepCut(const GridBatch& batch, std::span<const double> g, std::span<const double> m) const
    {
        openvdb::Coord first;
        if (!gridLeafOrigin(*mCutDomain, batch, first)) return;
        const auto nz = std::size_t(batch.nz);
        for (int leaf = 0; leaf < batch.nz / 8; ++leaf) {
            if (batch.unread >> leaf & 1u) continue;
            const auto k0 = std::size_t(8 * leaf);
            int inside = 0;
            for (std::size_t ij = 0; ij < 64; ++ij)
                for (std::size_t k = 0; k < 8; ++k) inside += float(m[ij * nz + k0 + k]) < 0.0f;
            if (inside == 0 || inside == 512) continue;
            CutLeaf& kept = mCut.local().emplace_back();
            kept.origin = first + openvdb::Coord(0, 0, int(k0));
            for (std::size_t ij = 0; ij < 64; ++ij)
                for (std::size_t k = 0; k < 8; ++k) kept.values[ij * 8 + k] = float(g[ij * nz + k0 + k]);
        }
    }

    const FieldNode& mG;
    const FieldNode& mMask;
    std::optional<Domain> mCutDomain;
    mutable tbb::enumerable_thread_specific<std::deque<CutLeaf>> mCut;
};

/// A cell of the coarse lattice (a sample and its three forward neighbours): the range of its
/// values and its change per voxel.
struct CoarseCell {
    float lo, hi, step;
};

/// Samples g at every stride-th voxel centre of the domain, in parallel and in a fixed order.
/// @a cells, when given, receives every cell of neighbouring samples that are all below 1e30
/// (inside a mask) with its change of g per voxel: stepNear() picks the widest voxel step about a
/// bracket from them. @a interrupt is called per block and throws to stop. Blocks are 8 x 8 x
/// @a depth samples (BlockLattice::depth).
std::vector<float> coarseSamples(const FieldNode& g, const Domain& domain, int stride,
                                 const std::function<void()>& interrupt, std::vector<CoarseCell>* cells = nullptr,
                                 int depth = 8, KnownSamples* known = nullptr, int margin = 0)
{
    // Every stride-th voxel centre, from voxel `phase` of the first stride: min + (i stride +
    // phase + 1/2) voxel. The phase is even, near the stride's middle (solveDensity's strides
    // are 1 or even): with the lattice's offset even too, every sample is a voxel of even index.
    const int phase = stride == 1 ? 0 : 2 * (stride / 4);
    BlockLattice lattice;
    lattice.base = domain.box.min;
    lattice.step = Vec3d(domain.voxel);
    lattice.offset = Vec3d(phase + 0.5);
    lattice.stride = {stride, stride, stride};
    lattice.depth = depth;
    for (int a = 0; a < 3; ++a) lattice.count[a] = (domain.dims[a] + stride - 1) / stride;
    // The samples lie on the domain's voxel lattice, and their batches say so: at stride 1 they
    // are the domain's grid batches (a GridValueMemo keeps them for the grid, which must get the
    // values its own batches would); at an even stride, on a lattice whose offset is even (the
    // domain's own, or one grown by an even margin), every sample is a voxel of even index: a node of a
    // convolution lattice's coarse nodes (StrutConvolution), which the grids of the band read as
    // well, so the pass costs no strut sums of its own.
    lattice.onLattice = true;
    lattice.latticeMin = domain.latticeMin();
    lattice.latticeOffset = {domain.latticeOffset.x() + phase, domain.latticeOffset.y() + phase,
                             domain.latticeOffset.z() + phase};
    std::vector<std::vector<float>> perBlock(lattice.blockCount());
    // Every sample, those past the domain too (values of the field all the same), at its place:
    // the sparse cull's proofs (KnownSamples), in the indices of the domain @a margin voxels
    // inside this one.
    if (known) {
        known->origin = openvdb::Coord(phase - margin);
        known->stride = stride;
        known->count = openvdb::Coord(lattice.count[0], lattice.count[1], lattice.count[2]);
        known->values.assign(std::size_t(lattice.count[0]) * lattice.count[1] * lattice.count[2], 0.0f);
        known->error = 0.0;
    }
    std::vector<std::vector<CoarseCell>> blockCells(cells ? perBlock.size() : 0);
    sampleBlocks(g, lattice, [&](std::size_t b, const GridBatch& batch, auto index, std::span<const double> values) {
        // A plate's coarse pass takes seconds of strut sums: the cancel is checked per block.
        interrupt();
        const openvdb::Coord first(index[0] * stride + phase, index[1] * stride + phase, index[2] * stride + phase);
        if (cells) {
            // Forward differences within the block (x-major, z fastest, as gridValues fills).
            const int sx = batch.ny * batch.nz, sy = batch.nz;
            for (int i = 0; i + 1 < batch.nx; ++i)
                for (int j = 0; j + 1 < batch.ny; ++j)
                    for (int k = 0; k + 1 < batch.nz; ++k) {
                        const int v = i * sx + j * sy + k;
                        const double c = values[v], dx = values[v + sx], dy = values[v + sy], dz = values[v + 1];
                        if (c > 1e30 || dx > 1e30 || dy > 1e30 || dz > 1e30) continue;
                        const double step =
                            std::sqrt((dx - c) * (dx - c) + (dy - c) * (dy - c) + (dz - c) * (dz - c)) / stride;
                        blockCells[b].push_back(
                            {float(std::min({c, dx, dy, dz})), float(std::max({c, dx, dy, dz})), float(step)});
                    }
        }
        if (known) {
            std::size_t v = 0;
            for (int i = 0; i < batch.nx; ++i)
                for (int j = 0; j < batch.ny; ++j) {
                    float* row = known->values.data() +
                                 (std::size_t(index[0] + i) * lattice.count[1] + std::size_t(index[1] + j)) *
                                     std::size_t(lattice.count[2]) +
                                 std::size_t(index[2]);
                    for (int k = 0; k < batch.nz; ++k, ++v) row[k] = float(values[v]);
                }
        }
        // Drop samples past the domain (the last stride may overhang).
        auto& out = perBlock[b];
        std::size_t v = 0;
        for (int i = 0; i < batch.nx; ++i)
            for (int j = 0; j < batch.ny; ++j)
                for (int k = 0; k < batch.nz; ++k, ++v) {
                    const openvdb::Coord c = first + openvdb::Coord(i * stride, j * stride, k * stride);
                    if (c.x() < domain.dims.x() && c.y() < domain.dims.y() && c.z() < domain.dims.z())
                        out.push_back(float(values[v]));
                }
    });
    std::vector<float> all;
    for (const auto& block : perBlock) all.insert(all.end(), block.begin(), block.end());
    if (cells)
        for (std::vector<CoarseCell>& block : blockCells) {
            cells->insert(cells->end(), block.begin(), block.end());
            std::vector<CoarseCell>().swap(block);
        }
    return all;
}

/// The widest change per voxel among the coarse cells whose values meet [lo, hi]: an estimate of
/// the widest voxel step about a level in that bracket (the coverage pass's band). Cells far
/// from the bracket (a strut lattice's capped iso-radius, joints) do not widen it; an estimate
/// too narrow costs a second evaluation, never a different result.
double stepNear(const std::vector<CoarseCell>& cells, double lo, double hi)
{
    float widest = 0.0f;
    for (const CoarseCell& c : cells)
        if (!(double(c.hi) < lo) && !(double(c.lo) > hi)) widest = std::max(widest, c.step);
    return widest;
}

/// How far beyond the bracket a masked solve evaluates, in coarse estimates of the voxel step:
/// the coverage pass needs the widest step either side of the level.
constexpr double kStepReserve = 1.25;

/// The sample quantile at share q (a selection, no full sort); -inf / +inf outside (0, 1).
double quantile(std::vector<float>& samples, double q)
{
    if (q <= 0.0) return -std::numeric_limits<double>::infinity();
    if (q >= 1.0) return std::numeric_limits<double>::infinity();
    const std::size_t i = std::min(samples.size() - 1, std::size_t(q * double(samples.size())));
    std::nth_element(samples.begin(), samples.begin() + i, samples.end());
    return samples[i];
}

/// d share / d level about the m-th smallest of @a band (whose values are already split at m by
/// nth_element): the secant between the values @a k ranks either side (clamped to the band),
/// over @a total voxels; 0 when they tie.
double countSlope(DefaultInitVector<float>& band, std::size_t m, std::size_t k, double total)
{
    if (band.size() < 2) return 0.0;
    const std::size_t lo = m > k ? m - k : 0, hi = std::min(band.size() - 1, m + k);
    if (lo < m) std::nth_element(band.begin(), band.begin() + lo, band.begin() + m);
    if (hi > m) std::nth_element(band.begin() + m + 1, band.begin() + hi, band.end());
    const double width = double(band[hi]) - double(band[lo]);
    return width > 0.0 ? double(hi - lo) / total / width : 0.0;
}

/// splitByBand of the grid evaluateSparse(@a g, @a domain, @a options) would give, measured on
/// each leaf as it is evaluated instead of on a grid. The count and the band's values (a multiset:
/// the level taken from it does not depend on their order) are those of splitByBand.
BandSplit streamedSplit(const FieldNode& g, const Domain& domain, const openvdb::CoordBBox& region,
                        const SparseOptions& options, std::uint64_t& evaluatedLeaves)
{
    const float lo = float(options.band.lo), hi = float(options.band.hi);
    struct Local {
        std::uint64_t below = 0;
        std::vector<float> band;
    };
    tbb::enumerable_thread_specific<Local> locals;
    SparseOptions streamed = options;
    streamed.leafVisitor = [&](const openvdb::Coord& origin, const float* v) {
        Local& local = locals.local();
        const openvdb::CoordBBox box(origin, origin + openvdb::Coord(7));
        const bool whole = region.isInside(box);
        for (int i = 0; i < 512; ++i) {
            if (!whole && !region.isInside(origin + openvdb::Coord(i >> 6, (i >> 3) & 7, i & 7))) continue;
            if (v[i] < lo)
                ++local.below;
            else if (v[i] <= hi)
                local.band.push_back(v[i]);
        }
    };
    SparseStats stats;
    const auto tiles = evaluateSparse(g, domain, streamed, &stats);
    evaluatedLeaves = stats.leaves;
    BandSplit split;
    split.below = countBelow(*tiles, region, lo);  // the tiles: the grid holds no leaf
    std::size_t total = 0;
    for (const Local& l : locals) total += l.band.size();
    split.band.reserve(total);
    for (Local& l : locals) {
        split.below += l.below;
        split.band.insert(split.band.end(), l.band.begin(), l.band.end());
        std::vector<float>().swap(l.band);
    }
    return split;
}

}  // namespace

/// What a coverage solve measured over its bracket first (solveDensity's coverBracket()).
struct BracketCoverage {
    float widest = 0.0f;   ///< the widest voxel step of the bracket's voxels
    bool stepped = false;  ///< widest is a step (positive, finite)
    /// The evaluated band holds the bracket grown by widest either side: the samples were taken.
    bool measured = false;
    StraddlingSamples straddling;
    std::uint64_t bracketBelow = 0;  ///< voxels covered whole at every level of the bracket
    /// splitByBand()'s count over the bracket: the voxels below it and within it.
    std::uint64_t countBelow = 0, countInBracket = 0;
    bool bracketed = false;  ///< the bracket's ends' coverage holds the target between them
    double slope = 0.0;      ///< covered voxels per unit of level across the bracket
};

DensitySolution solveDensity(const FieldNode& rawIndicator, const Domain& domain, double target, const FieldNode* mask,
                             bool subVoxel, const JobContext* context, int marginVoxels,
                             const std::function<void(Interval)>& levelWithin, int stackLeaves,
                             const std::function<void(openvdb::FloatGrid::Ptr)>& keepGrid)
{
    DensitySolution sol;
    // The voxels measured: the domain's, and @a marginVoxels more on every side (their centres
    // domain.worldOf() of indices past the domain's, so the leaves are the domain's).
    const openvdb::CoordBBox region(openvdb::Coord(-marginVoxels), domain.dims - openvdb::Coord(1 - marginVoxels));
    sol.domainVoxels = std::uint64_t(region.volume());
    std::unique_ptr<MaskedIndicator> masked;
    if (mask) {
        masked = std::make_unique<MaskedIndicator>(rawIndicator, *mask);
        // The grid handed over (keepGrid) then holds g's values where the mask cut its leaves too.
        if (keepGrid) masked->keepCutLeaves(domain);
        SparseOptions options;
        options.context = context;
        options.margin = marginVoxels;
        options.stage = "measuring the density's space";
        const openvdb::FloatGrid::Ptr maskGrid = evaluateSparse(*mask, domain, options);
        sol.domainVoxels = countBelow(*maskGrid, region, 0.0f);
        sol.maskCoverageVoxels = distanceCoverage(*maskGrid, region, domain.voxel);
        if (sol.domainVoxels == 0)
            throw JobError(
                "the space the density is measured in has no voxel inside the domain: check the "
                "part, the skin thickness and the domain");
    }
    const FieldNode& indicator = masked ? *masked : rawIndicator;
    const auto wanted = std::uint64_t(std::llround(target * double(sol.domainVoxels)));

    // The coarse pass (a bracket and step estimates only) samples the region as a domain of its own.
    const Domain coarseDomain = domain.grown(marginVoxels);
    // About two million samples, at a stride of 1 or an even one (rounded up: at least 0.84
    // million): samples at even voxels (coarseSamples) that a convolution lattice's coarse nodes
    // serve (W2g's 50 mm frames: stride 5 -> 6; the wireframe's pass took a fifteenth of its CPU).
    int stride = std::max(1, int(std::ceil(std::cbrt(double(coarseDomain.voxelCount()) / 2.0e6))));
    if (stride > 1 && stride % 2 != 0) ++stride;
    // The coarse pass and the passes over the band after its evaluation (a split, the coverage
    // samples, the bisection) take seconds on a plate: each stops on cancel.
    const std::function<void()> interrupt = [context] {
        if (context) context->checkCancelled();
    };
    std::vector<CoarseCell> coarseCells;
    // An indicator evaluated in stacks (a convolution lattice that nothing tiles) is sampled in
    // blocks 64 samples tall: rows of 64 share a strut's row set-up that rows of 8 repeated eight
    // times (the coarse pass was a ninth of the 25 mm wireframe's run). Its samples move within
    // the rows' table bound; they only bracket the level and estimate the step near it.
    // The coarse samples, kept in place, also prove leaves straddling a band to the sparse passes
    // below, which then skip their bounds (the same leaves: a wireframe's cull took an eighth of
    // its solve in bounds for leaves nearly all of which the surface crosses). One sample within
    // the band proves its leaf: on the 50 mm frames they proved 143 of 176 thousand straddling
    // leaves (cylinder) and 241 of 262 thousand (wireframe), where samples spanning the whole
    // band proved 372 and none. The bounds they skip are not in the memo for the grid at the
    // level: there, the leaves the handed-over values do not prove take theirs then (on the
    // cylinder frame 174 thousand against the 257 thousand the solve skips).
    KnownSamples known;
    std::vector<float> samples =
        coarseSamples(indicator, coarseDomain, stride, interrupt, masked || subVoxel ? &coarseCells : nullptr,
                      stackLeaves > 1 ? 64 : 8, &known, marginVoxels);
    // Share of the samples inside the mask: the quantiles of the target sit within that share.
    const double share =
        masked ? double(std::count_if(samples.begin(), samples.end(), [](float v) { return v < 1e30f; })) /
                     double(std::max<std::size_t>(1, samples.size()))
               : 1.0;

    // The memory the solve may hold: its evaluated leaves (kBytesPerLeaf each, the cull's check)
    // and, once counted, what it keeps beside them (the bracket's values, then the band's coverage
    // samples). The largest sum held is the estimate report.json gives.
    const std::uint64_t budget = std::uint64_t(0.7 * double(availableMemoryBytes()));
    auto holding = [&](std::uint64_t leaves, std::uint64_t besideBytes, const char* what) {
        const std::uint64_t bytes = leaves * kBytesPerLeaf + besideBytes;
        sol.estimatedBytes = std::max(sol.estimatedBytes, bytes);
        if (bytes <= budget) return;
        std::ostringstream msg;
        msg << "this job's density solve needs about " << (bytes >> 20) << " MB (" << leaves << " surface leaves and "
            << (besideBytes >> 20) << " MB of " << what << "), more than the " << (budget >> 20)
            << " MB this machine can give: raise `voxel:` (memory grows as 1/voxel^2) or shrink the domain";
        throw JobError(msg.str());
    };
    // The coverage's first steps over a bracket of a coverage solve's grid (evaluated over the
    // band @a evaluatedBand). The bracket (a share of the voxels) can be far narrower than a
    // voxel's change, and the coverage of the voxels just outside it then never reaches the
    // target: a voxel is partly inside while the level is within half its step of its value.
    // (Capsule struts, a distance field, in a 30 mm box: the bracket is a tenth of a step wide,
    // and the level stopped at its end holding 0.0974 by this measure for 0.1 asked while the
    // solid held 0.103.) So the widest voxel step about the bracket is measured first.
    // The count's bracket (a percent of the density either side of the target) holds the
    // coverage's level too unless the two measures differ by more: bisect there, over the
    // voxels whose coverage changes within it alone, the others counted or left out as
    // their step is taken (a 50 mm trimmed frame: 7.1 million samples held instead of the
    // 19.3 million the band of the widest step either side of the level holds). Voxels
    // valued more than the widest step outside the bracket are taken by their value, as
    // the wide band below takes those outside it. Checked: the bracket's ends hold the
    // target between them, or the wide band below is measured instead.
    auto coverBracket = [&](const openvdb::FloatGrid& grid, const Interval& bracket, const Interval& evaluatedBand) {
        BracketCoverage c;
        c.widest = widestCoverageStep(grid, region, float(bracket.lo), float(bracket.hi), interrupt);
        c.stepped = c.widest > 0.0f && c.widest < 1e29f;
        if (!c.stepped || bracket.lo <= -1e30 || bracket.hi >= 1e30 || evaluatedBand.lo > bracket.lo - c.widest ||
            bracket.hi + c.widest > evaluatedBand.hi)
            return c;
        c.measured = true;
        c.straddling = straddlingSamples(
            grid, region, bracket.lo, bracket.hi, c.widest, interrupt,
            [&](std::size_t n) {
                // Held in parts, then joined: twice, for a moment.
                holding(sol.evaluatedLeaves, 2 * n * sizeof(CoverageSample), "coverage samples");
            },
            Interval(float(bracket.lo), float(bracket.hi)));
        c.bracketBelow = countTilesBelow(grid, region, float(bracket.lo - c.widest)) + c.straddling.fullyBelow;
        c.countBelow = countTilesBelow(grid, region, float(bracket.lo)) + c.straddling.countBelow;
        c.countInBracket = c.straddling.countWithin;
        const std::array<double, 2> ends{bracket.lo, bracket.hi};
        std::array<double, 2> coveredAt{};
        coveredVoxels(c.straddling.samples, ends, coveredAt);
        if (double(c.bracketBelow) + coveredAt[0] <= double(wanted) &&
            double(c.bracketBelow) + coveredAt[1] >= double(wanted)) {
            c.bracketed = true;
            // The secant across the whole bracket (a percent of the density either side): its
            // middle half alone, the bisection's own, is noisier where values tie.
            c.slope = (coveredAt[1] - coveredAt[0]) / (bracket.hi - bracket.lo);
        }
        return c;
    };
    // Widen the bracket until the exact quantile falls inside it (usually the first round; the
    // last round brackets every value).
    for (const double margin : {0.01, 0.05, 1.0}) {
        ++sol.rounds;
        const double inf = std::numeric_limits<double>::infinity();
        const double lo = margin >= 1.0 ? -inf : quantile(samples, (target - margin) * share);
        const double hi = margin >= 1.0 ? inf : quantile(samples, (target + margin) * share);
        SparseOptions options;
        options.context = context;
        options.band = Interval(std::max(lo, -1e30), std::min(hi, 1e30));
        options.margin = marginVoxels;
        options.insideValue = -std::numeric_limits<float>::max();
        options.outsideValue = std::numeric_limits<float>::max();
        options.stage = "solving density";
        options.stackLeaves = stackLeaves;
        options.known = &known;
        // A coverage solve (masked or sub-voxel) measures in a band of the widest voxel step about the level
        // (below). Evaluating the bracket grown by an estimate of that step up front lets the
        // same grid serve both passes; splitting by the bracket ignores the extra values.
        SparseOptions evaluated = options;
        // A coverage pass keeps, beside the grid (kBytesPerLeaf a leaf, the cull's refusal), the
        // bracket's values and then the band's coverage samples: known only once the grid is
        // evaluated, they are checked then (holding() below) against the same budget. Charged
        // up front at a whole leaf's samples (16 KB a leaf), a 50 mm wireframe was estimated at
        // 4094 MB and ran in 1025 MB.
        evaluated.maxLeaves = budget / kBytesPerLeaf;
        const double coarseStep = stepNear(coarseCells, lo, hi);
        if ((masked || subVoxel) && margin < 1.0)
            evaluated.band =
                Interval(options.band.lo - kStepReserve * coarseStep, options.band.hi + kStepReserve * coarseStep);
        // A count needs each value once: the leaves are measured as they are evaluated and never
        // kept (no grid of the bracket's leaves, no second walk). Only a coverage measure (asked
        // for, masked, or value ties below) needs the grid, and evaluates it then.
        openvdb::FloatGrid::Ptr grid;
        BandSplit split;
        // The coverage over the bracket (coverBracket() below), measured up front by a sub-voxel
        // solve: when it brackets the target, the count's split of the bracket (its values, their
        // selection) is not made; the count's test that the bracket holds the target is taken
        // from the same pass (W2g's 50 mm trimmed frame: the split and its selection were 4 % of
        // the run's CPU).
        std::optional<BracketCoverage> early;
        if (!masked && !subVoxel) {
            split = streamedSplit(indicator, domain, region, options, sol.evaluatedLeaves);
            holding(sol.evaluatedLeaves, split.band.size() * sizeof(float), "values of its bracket");
        } else {
            grid = evaluateSparse(indicator, domain, evaluated);
            sol.evaluatedLeaves = grid->tree().leafCount();
            if (subVoxel) {
                early = coverBracket(*grid, options.band, evaluated.band);
                if (early->measured &&
                    (wanted < early->countBelow || wanted > early->countBelow + early->countInBracket))
                    continue;
            }
            if (!early || !early->bracketed) {
                // Only the widest step is read past here: the samples go before the split is made.
                if (early) CoverageSamples().swap(early->straddling.samples);
                split = splitByBand(*grid, region, float(options.band.lo), float(options.band.hi), interrupt);
                holding(sol.evaluatedLeaves, split.band.size() * sizeof(float), "values of its bracket");
            }
        }
        const bool counted = !(early && early->bracketed);
        const std::uint64_t below = split.below;
        DefaultInitVector<float>& band = split.band;
        if (counted && (wanted < below || wanted > below + band.size())) continue;

        // A level with exactly `wanted` values below it: between the m-th and (m+1)-th smallest
        // bracketed values (all values below the bracket are below it, all above are above).
        const std::size_t m = counted ? wanted - below : 0;
        if (!counted) {
            // Bisected over the bracket below: the count's level is not needed.
        } else if (m == 0) {
            sol.level = options.band.lo;
        } else if (m == band.size()) {
            sol.level = std::nextafter(float(options.band.hi), std::numeric_limits<float>::max());
        } else {
            std::nth_element(band.begin(), band.begin() + m, band.end());
            const double upper = band[m];
            const double lower = *std::max_element(band.begin(), band.begin() + m);
            sol.level = 0.5 * (lower + upper);
            sol.slope = countSlope(band, m, std::max<std::size_t>(16, wanted / 100), double(sol.domainVoxels));
        }
        // Ties (symmetric fields sampled on a regular grid repeat values exactly) can make the
        // count differ from `wanted`: count what the level really leaves below it.
        sol.insideVoxels =
            below + std::uint64_t(std::count_if(band.begin(), band.end(), [&](float v) { return v < sol.level; }));
        sol.achieved = double(sol.insideVoxels) / double(sol.domainVoxels);

        // Coarse or symmetric grids repeat values in large groups, so no level may leave exactly
        // `wanted` voxels below it. Then measure with sub-voxel coverage, which is continuous in
        // the level, and bisect on it.
        if (subVoxel || std::abs(double(sol.insideVoxels) - double(wanted)) > 5e-4 * double(wanted)) {
            if (!grid) {
                grid = evaluateSparse(indicator, domain, evaluated);
                sol.evaluatedLeaves = grid->tree().leafCount();
                holding(sol.evaluatedLeaves, band.size() * sizeof(float), "values of its bracket");
            }
            // The wide band's samples below, walked from the grid: a voxel's sample does not
            // depend on the band, so they are the evaluated band's samples picked in order,
            // without those (a 50 mm frame's 0.3 GB) held beside the grid and the raw values kept
            // for it. Of the bracket's, only their widest step is needed first: not held.
            DefaultInitVector<float>().swap(band);  // the count's values: not read past here
            CoverageSamples samples;
            double a = options.band.lo, b = std::min(options.band.hi, 1e30);
            std::uint64_t fullyBelow = below;
            // Bisected over the bracket when its coverage holds the target (coverBracket()); else
            // over the band of the widest step either side of the count's level, measured again.
            BracketCoverage cover = early ? std::move(*early) : coverBracket(*grid, options.band, evaluated.band);
            const float widest = cover.widest;
            if (cover.bracketed) {
                // a, b: the bracket already.
                samples = std::move(cover.straddling.samples);
                fullyBelow = cover.bracketBelow;
                if (levelWithin) levelWithin(options.band);
            } else if (cover.stepped) {
                SparseOptions wide = options;
                wide.band = Interval(sol.level - widest, sol.level + widest);
                // Every voxel valued within the wide band lies in an evaluated leaf of a grid
                // whose band contains it: reuse the first grid when it does.
                const bool covered = evaluated.band.lo <= wide.band.lo && wide.band.hi <= evaluated.band.hi;
                // The level is bisected in the wide band below.
                if (levelWithin) levelWithin(wide.band);
                const float wideLo = float(wide.band.lo), wideHi = float(wide.band.hi);
                // Every voxel valued in the wide band is in one of the measured grid's leaves
                // (tiles hold +-FLT_MAX): below it, the region's voxels below its low end, tiles
                // included (countBelow(), its leaves counted in the samples' own pass).
                auto wideGrid =
                    covered ? grid : evaluateSparse(GridLeavesReused(indicator, *grid, domain), domain, wide);
                if (!covered) sol.evaluatedLeaves = wideGrid->tree().leafCount();
                std::uint64_t leavesBelow = 0;
                // Both grids are held while the samples are made when the wide band needed its own.
                const std::uint64_t leavesHeld =
                    covered ? sol.evaluatedLeaves : grid->tree().leafCount() + wideGrid->tree().leafCount();
                samples = coverageSamples(
                    *wideGrid, region, wideLo, wideHi, interrupt, &leavesBelow,
                    [&](std::size_t n) { holding(leavesHeld, n * sizeof(CoverageSample), "coverage samples"); });
                fullyBelow = countTilesBelow(*wideGrid, region, wideLo) + leavesBelow;
                // The grid the samples came from is the one handed over below.
                grid = std::move(wideGrid);
                a = wide.band.lo;
                b = wide.band.hi;
            } else {
                samples =
                    coverageSamples(*grid, region, float(options.band.lo), float(options.band.hi), interrupt, nullptr,
                                    [&](std::size_t n) {
                                        holding(sol.evaluatedLeaves, n * sizeof(CoverageSample), "coverage samples");
                                    });
            }
            // The bisection reads the samples alone: the grid is freed first (a plate's solve
            // peaked with the grid, the band's values and its samples held), and its leaves'
            // memory given back: the bisection's copy of the samples is one block, which the
            // leaves' small blocks freed into the heaps cannot hold (a 50 mm frame's solve peaked
            // there, the freed grid's 0.4 GB resident beside it).
            if (keepGrid) {
                // Handed over: no heap trim, which would split the huge pages of its leaves
                // (each 4 KB page then faults again on its next first read). Masked, the leaves
                // the mask cut get back the values it hid (kept as they were evaluated); any
                // other leaf holding its value is left out.
                if (masked) {
                    masked->restoreCutLeaves(*grid);
                    tileLeavesWhere(*grid, [](const auto& leaf) {
                        const float* data = leaf.buffer().data();
                        return std::any_of(data, data + 512, [](float v) { return v == float(kOutsideMask); });
                    });
                }
                keepGrid(std::move(grid));
            } else {
                grid.reset();
                releaseFreedMemory();
            }
            // An open bracket (a target within 1 % of 0 or 1): bisect over the values present.
            for (const CoverageSample& c : samples) {
                if (options.band.lo <= -1e30) a = std::min(a == options.band.lo ? 1e300 : a, double(c.value) - c.step);
                if (options.band.hi >= 1e30) b = std::max(b == 1e30 ? -1e300 : b, double(c.value) + c.step);
            }
            const coverage::CoverageLevel found =
                bisectCoverage(std::move(samples), double(fullyBelow), double(wanted), a, b, interrupt);
            sol.level = found.level;
            sol.slope = (cover.bracketed ? cover.slope : found.slope) / double(sol.domainVoxels);
            sol.coverage = true;
            sol.achieved = found.covered / double(sol.domainVoxels);
        }
        return sol;
    }
    return sol;  // unreachable: the last round brackets everything
}

}  // namespace voxlat
