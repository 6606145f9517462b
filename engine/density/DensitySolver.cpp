#include "engine/density/DensitySolver.h"

#include "engine/core/Errors.h"

#include "engine/core/GridMeasure.h"
#include "engine/core/SparseEvaluator.h"

#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <functional>
#include <limits>
#include <vector>

namespace voxlat {

namespace {

/// The indicator's value outside the mask: above every level the solve can choose.
constexpr double kOutsideMask = 1e36;

/// g where mask < 0, kOutsideMask elsewhere: a level below kOutsideMask then selects only voxels
/// inside the mask, so the unmasked quantile machinery measures density relative to the mask.
class MaskedIndicator final : public FieldNode {
public:
    MaskedIndicator(const FieldNode& g, const FieldNode& mask) : mG(g), mMask(mask) {}

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
        if (batch.size() > kBatchSize) {
            FieldNode::gridValues(batch, out);
            return;
        }
        // The mask first: a batch wholly outside it needs no g.
        std::array<double, kBatchSize> m;
        mMask.gridValues(batch, std::span<double>(m.data(), batch.size()));
        if (std::none_of(m.begin(), m.begin() + batch.size(), [](double v) { return float(v) < 0.0f; })) {
            std::fill(out.begin(), out.begin() + batch.size(), kOutsideMask);
            return;
        }
        mG.gridValues(batch, out);
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
    // The test is made in float, as the grid that counts the mask's voxels stores it.
    static double apply(double g, double mask) { return float(mask) < 0.0f ? g : kOutsideMask; }

    const FieldNode& mG;
    const FieldNode& mMask;
};

/// Samples g at every stride-th voxel centre of the domain, in parallel and in a fixed order.
/// @a maxStep, when given, receives the largest change of g per voxel seen between neighbouring
/// samples that are both below 1e30 (inside a mask): an estimate of the widest voxel step.
std::vector<float> coarseSamples(const FieldNode& g, const Domain& domain, int stride, double* maxStep = nullptr)
{
    int n[3];
    for (int a = 0; a < 3; ++a) n[a] = (domain.dims[a] + stride - 1) / stride;
    const int bx = (n[0] + 7) / 8, by = (n[1] + 7) / 8, bz = (n[2] + 7) / 8;
    std::vector<std::vector<float>> perBlock(std::size_t(bx) * by * bz);
    std::vector<double> blockStep(perBlock.size(), 0.0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, perBlock.size()), [&](const auto& range) {
        std::array<double, 512> values;
        for (std::size_t b = range.begin(); b != range.end(); ++b) {
            const int ix = int(b / (std::size_t(by) * bz)), iy = int((b / bz) % by), iz = int(b % bz);
            GridBatch batch;
            batch.nx = std::min(8, n[0] - 8 * ix);
            batch.ny = std::min(8, n[1] - 8 * iy);
            batch.nz = std::min(8, n[2] - 8 * iz);
            const int half = stride / 2;
            const openvdb::Coord first(8 * ix * stride + half, 8 * iy * stride + half, 8 * iz * stride + half);
            batch.origin = domain.worldOf(first);
            batch.spacing = Vec3d(domain.voxel * stride);
            g.gridValues(batch, std::span<double>(values.data(), batch.size()));
            if (maxStep) {
                // Forward differences within the block (x-major, z fastest, as gridValues fills).
                const int sx = batch.ny * batch.nz, sy = batch.nz;
                double step = 0.0;
                for (int i = 0; i + 1 < batch.nx; ++i)
                    for (int j = 0; j + 1 < batch.ny; ++j)
                        for (int k = 0; k + 1 < batch.nz; ++k) {
                            const int v = i * sx + j * sy + k;
                            const double c = values[v], dx = values[v + sx], dy = values[v + sy], dz = values[v + 1];
                            if (c > 1e30 || dx > 1e30 || dy > 1e30 || dz > 1e30) continue;
                            step = std::max(step, (dx - c) * (dx - c) + (dy - c) * (dy - c) + (dz - c) * (dz - c));
                        }
                blockStep[b] = std::sqrt(step) / stride;
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
        }
    });
    std::vector<float> all;
    for (const auto& block : perBlock) all.insert(all.end(), block.begin(), block.end());
    if (maxStep) *maxStep = blockStep.empty() ? 0.0 : *std::max_element(blockStep.begin(), blockStep.end());
    return all;
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

/// A bracketed voxel value and its change across one voxel (central differences of the grid).
struct CoverageSample {
    float value;
    float step;
};

/// Offset strides and shifts of the x, y, z coordinates in an 8^3 leaf's buffer.
constexpr int kLeafStride[3] = {64, 8, 1};
constexpr int kLeafShift[3] = {6, 3, 0};

/// A sample's change along one axis: the central difference, one-sided where a neighbour is
/// absent (not evaluated, or outside a density mask), 0 with neither.
double axisChange(float value, float up, bool hasUp, float down, bool hasDown)
{
    if (hasUp && hasDown) return 0.5 * (up - down);
    if (hasUp) return up - value;
    if (hasDown) return value - down;
    return 0.0;
}

/// Band voxels with their per-voxel change along each axis (make(value, d) builds a sample), for
/// the sub-voxel coverage estimates. Neighbours that were not evaluated (tiles, background,
/// outside @a around) fall back to one-sided differences.
template <class Make>
auto bandSamples(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, float lo, float hi,
                 const openvdb::CoordBBox& around, Make make)
{
    using Sample = decltype(make(0.0f, std::array<double, 3>{}));
    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    grid.tree().getNodes(leaves);
    std::vector<std::vector<Sample>> perLeaf(leaves.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size()), [&](const auto& range) {
        auto acc = grid.getConstAccessor();
        for (std::size_t n = range.begin(); n != range.end(); ++n) {
            const float* data = leaves[n]->buffer().data();
            for (int i = 0; i < 512; ++i) {
                const openvdb::Coord c = leaves[n]->offsetToGlobalCoord(i);
                if (data[i] < lo || data[i] > hi || !region.isInside(c)) continue;
                std::array<double, 3> change{};
                for (int a = 0; a < 3; ++a) {
                    openvdb::Coord up = c, down = c;
                    up[a] += 1;
                    down[a] -= 1;
                    // Neighbours inside the leaf are read from its buffer; others through the
                    // accessor. Neighbours outside a density mask hold kOutsideMask: not a neighbour.
                    const int local = (i >> kLeafShift[a]) & 7;
                    float upValue = 0.0f, downValue = 0.0f;
                    bool hasUp = around.isInside(up), hasDown = around.isInside(down);
                    if (hasUp) {
                        if (local < 7) upValue = data[i + kLeafStride[a]];
                        else if (acc.probeConstLeaf(up)) upValue = acc.getValue(up);
                        else hasUp = false;
                        hasUp = hasUp && upValue < 1e30f;
                    }
                    if (hasDown) {
                        if (local > 0) downValue = data[i - kLeafStride[a]];
                        else if (acc.probeConstLeaf(down)) downValue = acc.getValue(down);
                        else hasDown = false;
                        hasDown = hasDown && downValue < 1e30f;
                    }
                    change[a] = axisChange(data[i], upValue, hasUp, downValue, hasDown);
                }
                perLeaf[n].push_back(make(data[i], change));
            }
        }
    });
    std::vector<Sample> all;
    for (const auto& v : perLeaf) all.insert(all.end(), v.begin(), v.end());
    return all;
}

/// Band voxels with the length of their per-voxel change, for the linear coverage estimate.
std::vector<CoverageSample> coverageSamples(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region,
                                            float lo, float hi)
{
    return bandSamples(grid, region, lo, hi, region, [](float v, const std::array<double, 3>& d) {
        return CoverageSample{v, float(std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]))};
    });
}

/// A voxel cut by the plane of its value and per-axis changes, counted `weight` times.
struct PlaneSample {
    float value;
    float change[3];  ///< |per-voxel change| along x, y, z
    float weight;
};

/// Share of the unit cube with m . u < alpha (m >= 0 sorted ascending, m0 + m1 + m2 = 1,
/// 0 <= alpha <= 1/2), the analytic relation of Scardovelli & Zaleski (2000), written so that
/// no case divides by a component that may vanish without a bounded numerator.
double cubeShareBelowPlane(const double m[3], double alpha)
{
    const double m0 = m[0], m1 = m[1], m2 = m[2], m01 = m0 + m1;
    if (alpha < m0) return alpha * alpha * alpha / (6.0 * m0 * m1 * m2);
    const double corner = (3.0 * alpha * alpha - 3.0 * alpha * m0 + m0 * m0) / (6.0 * m1 * m2);
    if (alpha < m1) return corner;
    if (alpha < m01 && alpha < m2) return corner - std::pow(alpha - m1, 3) / (6.0 * m0 * m1 * m2);
    if (alpha < m01)  // m2 <= alpha: the plane has passed three corners
        return corner - (std::pow(alpha - m1, 3) + std::pow(alpha - m2, 3)) / (6.0 * m0 * m1 * m2);
    return (2.0 * alpha - m01) / (2.0 * m2);  // m01 <= alpha (and m01 <= m2 since alpha <= 1/2)
}

/// The share of a voxel below @a level, the voxel's field taken as the plane through its value
/// with its per-axis changes (exact for planes at any orientation).
double planeCoverage(const PlaneSample& s, double level)
{
    double m[3] = {s.change[0], s.change[1], s.change[2]};
    const double sum = m[0] + m[1] + m[2];
    if (!(sum > 0.0)) return s.value < level ? 1.0 : 0.0;
    const double alpha = (level - double(s.value)) / sum + 0.5;
    if (alpha <= 0.0) return 0.0;
    if (alpha >= 1.0) return 1.0;
    for (double& v : m) v /= sum;
    std::sort(m, m + 3);
    return alpha <= 0.5 ? cubeShareBelowPlane(m, alpha) : 1.0 - cubeShareBelowPlane(m, 1.0 - alpha);
}

/// Weighted voxels below @a level by planeCoverage().
double planeCovered(const std::vector<PlaneSample>& samples, double level)
{
    double covered = 0.0;
    for (const PlaneSample& s : samples) covered += s.weight * planeCoverage(s, level);
    return covered;
}

/// Weighted coverage of @a samples at @a level (planeCovered()), summed in parallel over fixed
/// blocks combined in a fixed tree, so the sum is the same for any thread count.
double planeCoveredParallel(const std::vector<PlaneSample>& samples, double level)
{
    return tbb::parallel_deterministic_reduce(
        tbb::blocked_range<std::size_t>(0, samples.size(), 1 << 13), 0.0,
        [&](const tbb::blocked_range<std::size_t>& r, double sum) {
            for (std::size_t i = r.begin(); i != r.end(); ++i)
                sum += samples[i].weight * planeCoverage(samples[i], level);
            return sum;
        },
        std::plus<>());
}

/// The level in [a, b] at which @a settled + planeCovered() reaches @a wanted, given that it is
/// at most @a wanted at a and at least at b. The covered volume is continuous and increasing
/// in the level (piecewise smooth), so regula falsi with the Illinois modification converges
/// superlinearly: about ten passes instead of sixty halvings. Samples whose coverage no longer
/// changes over what is left of the bracket are set aside as it narrows. @a covered, when
/// given, receives the covered weight at the level returned.
double solvePlaneCoverage(std::vector<PlaneSample> active, double settled, double wanted, double a, double b,
                          double* covered = nullptr)
{
    auto half = [](const PlaneSample& s) { return 0.5 * (double(s.change[0]) + s.change[1] + s.change[2]); };
    auto excess = [&](double level) { return settled + planeCoveredParallel(active, level) - wanted; };
    double fa = std::min(0.0, excess(a)), fb = std::max(0.0, excess(b));
    double level = 0.5 * (a + b);
    int lastSide = 0;
    for (int iteration = 0; iteration < 200; ++iteration) {
        // The secant through the bracket's ends; the midpoint where that makes no progress.
        level = fb - fa > 0.0 ? a + (b - a) * (-fa / (fb - fa)) : 0.5 * (a + b);
        if (!(level > a && level < b)) level = 0.5 * (a + b);
        if (!(level > a && level < b)) break;  // a and b are neighbouring doubles
        const double f = excess(level);
        if (f == 0.0) break;
        if (f < 0.0) {
            a = level;
            fa = f;
            if (lastSide == -1) fb *= 0.5;  // Illinois: the end that stays has its value halved
            lastSide = -1;
        } else {
            b = level;
            fb = f;
            if (lastSide == 1) fa *= 0.5;
            lastSide = 1;
        }
        // The covered volume to 1e-13 of the target or the level to 1e-13 of its size: far
        // below what the sampling resolves.
        if (b - a <= 1e-13 * std::max(1.0, std::abs(a) + std::abs(b)) || std::abs(f) <= 1e-13 * wanted) break;
        std::size_t kept = 0;
        for (const PlaneSample& s : active) {
            const double h = half(s);
            if (a >= s.value + h) settled += s.weight;
            else if (b > s.value - h) active[kept++] = s;
        }
        active.resize(kept);
    }
    if (covered) *covered = settled + planeCoveredParallel(active, level);
    return level;
}

/// Voxels below @a level counted with sub-voxel coverage: a voxel whose value is within half a
/// step of the level is partly inside, linearly in the distance (a plane cutting the voxel).
double coveredVoxels(const std::vector<CoverageSample>& samples, double level)
{
    double covered = 0.0;
    for (const CoverageSample& s : samples) {
        if (s.step > 0.0f) covered += std::clamp(0.5 + (level - s.value) / s.step, 0.0, 1.0);
        else covered += s.value < level;
    }
    return covered;
}

/// The level in [a, b] at which fullyBelow + coveredVoxels(samples, level) reaches @a wanted, by
/// 60 bisection steps. Samples whose coverage is constant (0 or 1) over what is left of the
/// bracket are set aside as it narrows, so later steps visit only the voxels the level still
/// cuts; each kept sample contributes exactly what coveredVoxels() would give it.
double bisectCoverage(const std::vector<CoverageSample>& samples, double fullyBelow, double wanted, double a, double b)
{
    auto coverage = [](const CoverageSample& s, double level) {
        return s.step > 0.0f ? std::clamp(0.5 + (level - s.value) / s.step, 0.0, 1.0) : double(s.value < level);
    };
    // Each sample's coverage at both ends of the bracket, carried along: the end that moves takes
    // the coverage at the midpoint just summed, so each step computes one coverage per sample.
    struct Active {
        CoverageSample s;
        double atA, atB;
    };
    std::vector<Active> active;
    active.reserve(samples.size());
    for (const CoverageSample& s : samples) active.push_back({s, coverage(s, a), coverage(s, b)});
    std::vector<double> atMid(active.size());
    double settled = fullyBelow;  // whole voxels below every level left in the bracket
    // Once every sample left is partly covered across the whole bracket, the coverage is linear
    // there: settled + constant + level * slope, and the remaining steps cost nothing.
    bool linear = false;
    double constant = 0.0, slope = 0.0;
    for (int iteration = 0; iteration < 60; ++iteration) {
        const double mid = 0.5 * (a + b);
        double covered = settled;
        if (linear) covered += constant + mid * slope;
        else
            for (std::size_t i = 0; i < active.size(); ++i) covered += atMid[i] = coverage(active[i].s, mid);
        const bool raiseA = covered < wanted;
        (raiseA ? a : b) = mid;
        if (linear) continue;
        // Coverage is monotone in the level: full at a means full on [a, b], empty at b empty.
        std::size_t kept = 0;
        bool ramps = true;
        for (std::size_t i = 0; i < active.size(); ++i) {
            Active t = active[i];
            (raiseA ? t.atA : t.atB) = atMid[i];
            if (t.atA >= 1.0) settled += 1.0;
            else if (t.atB > 0.0) {
                active[kept++] = t;
                ramps = ramps && t.s.step > 0.0f && t.atA > 0.0 && t.atB < 1.0;
            }
        }
        active.resize(kept);
        if (ramps) {
            linear = true;
            for (const Active& t : active) {
                constant += 0.5 - double(t.s.value) / t.s.step;
                slope += 1.0 / t.s.step;
            }
        }
    }
    return 0.5 * (a + b);
}

}  // namespace

DensitySolution solveDensity(const FieldNode& rawIndicator, const Domain& domain, double target, const FieldNode* mask,
                             bool subVoxel, const JobContext* context)
{
    DensitySolution sol;
    sol.domainVoxels = domain.voxelCount();
    std::unique_ptr<MaskedIndicator> masked;
    if (mask) {
        masked = std::make_unique<MaskedIndicator>(rawIndicator, *mask);
        SparseOptions options;
        options.context = context;
        options.margin = 0;
        options.stage = "measuring the density's space";
        sol.domainVoxels = countBelow(*evaluateSparse(*mask, domain, options), domain.indexBox(), 0.0f);
        if (sol.domainVoxels == 0)
            throw JobError("the space the density is measured in has no voxel inside the domain: check the "
                           "part, the skin thickness and the domain");
    }
    const FieldNode& indicator = masked ? *masked : rawIndicator;
    const auto wanted = std::uint64_t(std::llround(target * double(sol.domainVoxels)));

    const int stride = std::max(1, int(std::ceil(std::cbrt(double(domain.voxelCount()) / 2.0e6))));
    double coarseStep = 0.0;
    std::vector<float> samples = coarseSamples(indicator, domain, stride, masked ? &coarseStep : nullptr);
    // Share of the samples inside the mask: the quantiles of the target sit within that share.
    const double share =
        masked ? double(std::count_if(samples.begin(), samples.end(), [](float v) { return v < 1e30f; })) /
                     double(std::max<std::size_t>(1, samples.size()))
               : 1.0;

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
        options.margin = 0;
        options.insideValue = -std::numeric_limits<float>::max();
        options.outsideValue = std::numeric_limits<float>::max();
        options.stage = "solving density";
        // A masked solve measures coverage in a band of the widest voxel step about the level
        // (below). Evaluating the bracket grown by an estimate of that step up front lets the
        // same grid serve both passes; splitting by the bracket ignores the extra values.
        SparseOptions evaluated = options;
        if (masked && margin < 1.0)
            evaluated.band =
                Interval(options.band.lo - kStepReserve * coarseStep, options.band.hi + kStepReserve * coarseStep);
        const auto grid = evaluateSparse(indicator, domain, evaluated);
        sol.evaluatedLeaves = grid->tree().leafCount();

        BandSplit split = splitByBand(*grid, domain.indexBox(), float(options.band.lo), float(options.band.hi));
        const std::uint64_t below = split.below;
        std::vector<float>& band = split.band;
        if (wanted < below || wanted > below + band.size()) continue;

        // A level with exactly `wanted` values below it: between the m-th and (m+1)-th smallest
        // bracketed values (all values below the bracket are below it, all above are above).
        const std::size_t m = wanted - below;
        if (m == 0) {
            sol.level = options.band.lo;
        } else if (m == band.size()) {
            sol.level = std::nextafter(float(options.band.hi), std::numeric_limits<float>::max());
        } else {
            std::nth_element(band.begin(), band.begin() + m, band.end());
            const double upper = band[m];
            const double lower = *std::max_element(band.begin(), band.begin() + m);
            sol.level = 0.5 * (lower + upper);
        }
        // Ties (symmetric fields sampled on a regular grid repeat values exactly) can make the
        // count differ from `wanted`: count what the level really leaves below it.
        sol.insideVoxels = below + std::uint64_t(std::count_if(band.begin(), band.end(),
                                                               [&](float v) { return v < sol.level; }));
        sol.achieved = double(sol.insideVoxels) / double(sol.domainVoxels);

        // Coarse or symmetric grids repeat values in large groups, so no level may leave exactly
        // `wanted` voxels below it. Then measure with sub-voxel coverage, which is continuous in
        // the level, and bisect on it.
        if (subVoxel || std::abs(double(sol.insideVoxels) - double(wanted)) > 5e-4 * double(wanted)) {
            // Every evaluated band voxel once (a voxel's step does not depend on the band); the
            // bracket's and the wide band's samples are picked from them, in the same order.
            const float evaluatedLo = float(evaluated.band.lo), evaluatedHi = float(evaluated.band.hi);
            const std::vector<CoverageSample> evaluatedSamples =
                coverageSamples(*grid, domain.indexBox(), evaluatedLo, evaluatedHi);
            auto within = [&](float lo, float hi) {
                std::vector<CoverageSample> picked;
                for (const CoverageSample& c : evaluatedSamples)
                    if (!(c.value < lo || c.value > hi)) picked.push_back(c);
                return picked;
            };
            auto samples = within(float(options.band.lo), float(options.band.hi));
            double a = options.band.lo, b = std::min(options.band.hi, 1e30);
            std::uint64_t fullyBelow = below;
            // Within a mask the bracket (a share of the mask's voxels) can be far narrower than a
            // voxel's change, and the coverage of the voxels just outside it then never reaches
            // the target. A voxel is partly inside while the level is within half its step of
            // its value: widen the band to the largest step either side and measure again.
            // (Unmasked solves keep the bracket, whose coverage tracks the meshed volume.)
            float widest = 0.0f;
            for (const CoverageSample& c : samples)
                if (c.step < 1e29f) widest = std::max(widest, c.step);
            if (masked && widest > 0.0f && widest < 1e29f) {
                SparseOptions wide = options;
                wide.band = Interval(sol.level - widest, sol.level + widest);
                // Every voxel valued within the wide band lies in an evaluated leaf of a grid
                // whose band contains it: reuse the first grid when it does.
                const bool covered = evaluated.band.lo <= wide.band.lo && wide.band.hi <= evaluated.band.hi;
                const float wideLo = float(wide.band.lo), wideHi = float(wide.band.hi);
                if (covered && evaluatedLo <= wideLo && wideHi <= evaluatedHi) {
                    // Below the wide band: those below the bracket, moved by the voxels between the
                    // two low ends, which the evaluated band holds.
                    const float bracketLo = float(options.band.lo);
                    std::uint64_t belowWide = 0, belowBracket = 0;
                    for (const CoverageSample& c : evaluatedSamples) {
                        belowWide += c.value < wideLo;
                        belowBracket += c.value < bracketLo;
                    }
                    fullyBelow = below + belowWide - belowBracket;
                    samples = within(wideLo, wideHi);
                } else {
                    const auto wideGrid = covered ? grid : evaluateSparse(indicator, domain, wide);
                    if (!covered) sol.evaluatedLeaves = wideGrid->tree().leafCount();
                    fullyBelow = splitByBand(*wideGrid, domain.indexBox(), wideLo, wideHi).below;
                    samples = coverageSamples(*wideGrid, domain.indexBox(), wideLo, wideHi);
                }
                a = wide.band.lo;
                b = wide.band.hi;
            }
            // An open bracket (a target within 1 % of 0 or 1): bisect over the values present.
            for (const CoverageSample& c : samples) {
                if (options.band.lo <= -1e30) a = std::min(a == options.band.lo ? 1e300 : a, double(c.value) - c.step);
                if (options.band.hi >= 1e30) b = std::max(b == 1e30 ? -1e300 : b, double(c.value) + c.step);
            }
            sol.level = bisectCoverage(samples, double(fullyBelow), double(wanted), a, b);
            sol.coverage = true;
            sol.achieved = (double(fullyBelow) + coveredVoxels(samples, sol.level)) / double(sol.domainVoxels);
        }
        return sol;
    }
    return sol;  // unreachable: the last round brackets everything
}

std::vector<DensityPiece> periodicPieces(const Box3& box, const Vec3d& period, double reach, double voxel,
                                         std::array<bool, 3> mirror)
{
    if (!(voxel > 0.0) || std::abs(period[1] - period[0]) > 1e-12 * period[0] ||
        std::abs(period[2] - period[0]) > 1e-12 * period[0])
        return {};
    const double p = period[0];
    const long perPeriod = std::max(1L, long(std::ceil(p / voxel - 1e-9)));
    const double step = p / double(perPeriod);
    struct Segment {
        long start;  ///< in lattice steps from box.min
        long voxels;
        double weight;
    };
    std::array<std::vector<Segment>, 3> segments;
    for (int a = 0; a < 3; ++a) {
        const double cells = box.extent()[a] / p;
        const long whole = std::lround(cells);
        if (whole < 1 || std::abs(cells - double(whole)) > 1e-9 * cells) return {};
        const long zone = long(std::ceil(reach / step - 1e-9)) + 1;  // a step of safety
        const long total = whole * perPeriod;
        const long folds = (total - 2 * zone) / perPeriod;
        if (folds < 2) return {};
        // Samples between the zones past the last whole period: they repeat the period's first
        // `extra` samples (all lie at least a zone inside the box).
        const long extra = total - 2 * zone - folds * perPeriod;
        segments[a].push_back({0, zone, mirror[a] ? 2.0 : 1.0});
        if (extra > 0) segments[a].push_back({zone, extra, double(folds + 1)});
        segments[a].push_back({zone + extra, perPeriod - extra, double(folds)});
        if (!mirror[a]) segments[a].push_back({total - zone, zone, 1.0});
    }
    std::vector<DensityPiece> pieces;
    for (const Segment& x : segments[0])
        for (const Segment& y : segments[1])
            for (const Segment& z : segments[2]) {
                DensityPiece piece;
                piece.domain.voxel = step;
                piece.domain.box.min = box.min + step * Vec3d(double(x.start), double(y.start), double(z.start));
                piece.domain.dims = openvdb::Coord(int(x.voxels), int(y.voxels), int(z.voxels));
                piece.domain.box.max =
                    piece.domain.box.min + step * Vec3d(double(x.voxels), double(y.voxels), double(z.voxels));
                piece.weight = x.weight * y.weight * z.weight;
                piece.within = box;
                pieces.push_back(piece);
            }
    return pieces;
}

namespace {

/// One piece's samples on a dense array with a sample of margin on every side (index -1 to
/// dims along each axis); margin samples outside the piece's neighbourhood are NaN (absent).
struct DensePiece {
    const DensityPiece* piece = nullptr;
    openvdb::CoordBBox around;  ///< evaluated samples, in the piece's index space
    int n[3] = {0, 0, 0};       ///< padded dims
    std::vector<float> values;
    float at(int x, int y, int z) const { return values[(std::size_t(x + 1) * n[1] + (y + 1)) * n[2] + (z + 1)]; }
};

/// The pieces' samples in fixed chunks: one x-plane range of one piece each.
struct SampleChunk {
    std::uint32_t piece;
    int x0, x1;
};

/// Calls fn(sample) for every sample of @a chunk, in a fixed order, with the sample's value,
/// per-axis changes (central differences; one-sided where a neighbour is absent) and weight.
template <class Fn>
void forEachPlaneSample(const DensePiece& d, const SampleChunk& chunk, Fn&& fn)
{
    const openvdb::Coord dims = d.piece->domain.dims;
    const float w = float(d.piece->weight);
    // Neighbours that were not evaluated (NaN) or lie outside a mask (>= 1e30) are no neighbours.
    auto change = [](float value, float up, float down) {
        return float(std::abs(axisChange(value, up, up < 1e30f, down, down < 1e30f)));
    };
    for (int x = chunk.x0; x < chunk.x1; ++x)
        for (int y = 0; y < dims.y(); ++y)
            for (int z = 0; z < dims.z(); ++z) {
                const float v = d.at(x, y, z);
                fn(PlaneSample{
                    v,
                    {change(v, d.at(x + 1, y, z), d.at(x - 1, y, z)), change(v, d.at(x, y + 1, z), d.at(x, y - 1, z)),
                     change(v, d.at(x, y, z + 1), d.at(x, y, z - 1))},
                    w});
            }
}

/// Half a sample's total change: its coverage is 0 at levels <= value - half, 1 at >= value + half.
double halfChange(const PlaneSample& s)
{
    return 0.5 * (double(s.change[0]) + s.change[1] + s.change[2]);
}

}  // namespace

DensitySolution solveDensity(const FieldNode& indicator, std::span<const DensityPiece> pieces, double target,
                             const JobContext* context)
{
    DensitySolution sol;
    // The pieces' union: on its faces the coverage takes one-sided differences, as a solve over
    // the whole box would; elsewhere a margin of one voxel gives the neighbour the box has there.
    // (Or the region the pieces say they measure.)
    Box3 all = pieces.empty() ? Box3{} : pieces.front().within.value_or(pieces.front().domain.box);
    for (const DensityPiece& piece : pieces)
        for (const Box3& b : {piece.domain.box, piece.within.value_or(piece.domain.box)})
            for (int a = 0; a < 3; ++a) {
                all.min[a] = std::min(all.min[a], b.min[a]);
                all.max[a] = std::max(all.max[a], b.max[a]);
            }
    // Every piece on a dense array (pieces are small), evaluated in 8^3 batches from the corner of
    // its neighbourhood; each batch writes its own samples, so any thread count gives the same values.
    std::vector<DensePiece> dense(pieces.size());
    struct Batch {
        std::uint32_t piece;
        openvdb::Coord lo;
    };
    std::vector<Batch> batches;
    double total = 0.0;
    for (std::size_t p = 0; p < pieces.size(); ++p) {
        DensePiece& d = dense[p];
        d.piece = &pieces[p];
        d.around = pieces[p].domain.indexBox();
        const double tolerance = 0.25 * pieces[p].domain.voxel;
        for (int a = 0; a < 3; ++a) {
            if (pieces[p].domain.box.min[a] > all.min[a] + tolerance) d.around.min()[a] -= 1;
            if (pieces[p].domain.box.max[a] < all.max[a] - tolerance) d.around.max()[a] += 1;
            d.n[a] = pieces[p].domain.dims[a] + 2;
        }
        d.values.assign(std::size_t(d.n[0]) * d.n[1] * d.n[2], std::numeric_limits<float>::quiet_NaN());
        for (int x = d.around.min().x(); x <= d.around.max().x(); x += 8)
            for (int y = d.around.min().y(); y <= d.around.max().y(); y += 8)
                for (int z = d.around.min().z(); z <= d.around.max().z(); z += 8)
                    batches.push_back({std::uint32_t(p), openvdb::Coord(x, y, z)});
        total += pieces[p].weight * double(pieces[p].domain.voxelCount());
    }
    if (total <= 0.0) throw std::invalid_argument("no voxel to measure a density on");
    std::atomic<bool> nonFinite{false};
    {
        StageProgress progress(context, "solving density", batches.size());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, batches.size()), [&](const auto& range) {
            std::array<double, 512> values;
            for (std::size_t b = range.begin(); b != range.end(); ++b) {
                DensePiece& d = dense[batches[b].piece];
                const openvdb::Coord lo = batches[b].lo;
                GridBatch batch;
                batch.origin = d.piece->domain.worldOf(lo);
                batch.spacing = Vec3d(d.piece->domain.voxel);
                batch.nx = std::min(8, d.around.max().x() + 1 - lo.x());
                batch.ny = std::min(8, d.around.max().y() + 1 - lo.y());
                batch.nz = std::min(8, d.around.max().z() + 1 - lo.z());
                indicator.gridValues(batch, std::span<double>(values.data(), batch.size()));
                std::size_t v = 0;
                for (int i = 0; i < batch.nx; ++i)
                    for (int j = 0; j < batch.ny; ++j) {
                        float* row = &d.values[(std::size_t(lo.x() + i + 1) * d.n[1] + (lo.y() + j + 1)) * d.n[2] +
                                               (lo.z() + 1)];
                        for (int k = 0; k < batch.nz; ++k, ++v) {
                            if (!std::isfinite(values[v])) [[unlikely]]
                                nonFinite = true;
                            row[k] = float(values[v]);
                        }
                    }
            }
            progress.add(range.size());
        });
    }
    if (nonFinite)
        throw JobError(
            "the field is not finite (NaN or infinity) where the density is measured: check divisions, "
            "logarithms and square roots in the recipe's fields");
    sol.evaluatedLeaves = batches.size();

    // Samples in fixed chunks (a few x-planes of one piece), so per-chunk results combined in
    // chunk order are the same for any thread count.
    std::vector<SampleChunk> chunks;
    for (std::size_t p = 0; p < pieces.size(); ++p)
        for (int x = 0; x < pieces[p].domain.dims.x(); x += 4)
            chunks.push_back({std::uint32_t(p), x, std::min(x + 4, pieces[p].domain.dims.x())});
    auto forChunks = [&](auto&& fn) {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks.size()), [&](const auto& range) {
            for (std::size_t c = range.begin(); c != range.end(); ++c) fn(c);
        });
    };

    // The levels where coverage can change: between the lowest value - half and the highest
    // value + half.
    std::vector<double> chunkLo(chunks.size()), chunkHi(chunks.size());
    forChunks([&](std::size_t c) {
        double lo = std::numeric_limits<double>::infinity(), hi = -lo;
        forEachPlaneSample(dense[chunks[c].piece], chunks[c], [&](const PlaneSample& s) {
            const double h = halfChange(s);
            lo = std::min(lo, double(s.value) - h);
            hi = std::max(hi, double(s.value) + h);
        });
        chunkLo[c] = lo;
        chunkHi[c] = hi;
    });
    const double lowest = *std::min_element(chunkLo.begin(), chunkLo.end());
    const double highest = *std::max_element(chunkHi.begin(), chunkHi.end());
    const double wanted = target * total;

    // Bracket the level before any cube-plane volume: the weight of samples whose coverage has
    // begun (value - half < level) bounds the covered volume from above, the weight of samples
    // wholly covered (value + half <= level) from below. Histograms of both over the range give a
    // bracket [a, b] in one pass; only samples the bracket cuts take part in the bisection.
    constexpr int kBins = 1024;
    const double binWidth = (highest - lowest) / kBins;
    double a = lowest, b = highest;
    if (binWidth > 0.0) {
        std::vector<std::array<double, kBins>> begun(chunks.size()), covered(chunks.size());
        auto binOf = [&](double x) { return std::clamp(int((x - lowest) / binWidth), 0, kBins - 1); };
        forChunks([&](std::size_t c) {
            begun[c].fill(0.0);
            covered[c].fill(0.0);
            forEachPlaneSample(dense[chunks[c].piece], chunks[c], [&](const PlaneSample& s) {
                const double h = halfChange(s);
                begun[c][binOf(double(s.value) - h)] += s.weight;
                covered[c][binOf(double(s.value) + h)] += s.weight;
            });
        });
        std::array<double, kBins> begunAll{}, coveredAll{};
        for (std::size_t c = 0; c < chunks.size(); ++c)
            for (int k = 0; k < kBins; ++k) {
                begunAll[k] += begun[c][k];
                coveredAll[k] += covered[c][k];
            }
        // Edge e_k = lowest + k * binWidth. Begun(e_k) <= sum of bins below k (and a bin of slack
        // either way for the rounding of binOf); the bracket is checked exactly below.
        double begunBelow = 0.0, coveredBelow = 0.0;
        int ka = 0, kb = kBins;
        for (int k = 0; k < kBins; ++k) {
            // Samples begun below edge k + 1 (bins 0..k), so at e_{k-1} fewer than these have begun.
            begunBelow += begunAll[k];
            if (begunBelow <= wanted) ka = std::max(0, k - 1);
        }
        for (int k = 0; k < kBins; ++k) {
            coveredBelow += coveredAll[k];
            // Samples with value + half in bins 0..k-1 are wholly covered at e_{k+1}.
            if (coveredBelow - coveredAll[k] >= wanted) {
                kb = std::min(kBins, k + 1);
                break;
            }
        }
        a = lowest + ka * binWidth;
        b = kb >= kBins ? highest : lowest + kb * binWidth;
    }

    // The samples the bracket cuts, in chunk order, and the weight wholly covered below it.
    auto collect = [&](double lo, double hi, double& settled) {
        std::vector<std::vector<PlaneSample>> cut(chunks.size());
        std::vector<double> below(chunks.size(), 0.0);
        forChunks([&](std::size_t c) {
            forEachPlaneSample(dense[chunks[c].piece], chunks[c], [&](const PlaneSample& s) {
                const double h = halfChange(s);
                if (lo >= double(s.value) + h)
                    below[c] += s.weight;
                else if (hi > double(s.value) - h)
                    cut[c].push_back(s);
            });
        });
        std::vector<PlaneSample> samples;
        settled = 0.0;
        for (std::size_t c = 0; c < chunks.size(); ++c) {
            samples.insert(samples.end(), cut[c].begin(), cut[c].end());
            settled += below[c];
        }
        return samples;
    };
    double settled = 0.0;
    std::vector<PlaneSample> samples = collect(a, b, settled);
    // The histograms' bracket must hold the level; if rounding ever left it out, use the whole range.
    if (!(settled + planeCovered(samples, a) <= wanted && settled + planeCovered(samples, b) >= wanted)) {
        a = lowest;
        b = highest;
        samples = collect(a, b, settled);
    }
    if (samples.empty() && settled == 0.0) throw std::invalid_argument("no voxel to measure a density on");
    sol.level = solvePlaneCoverage(std::move(samples), settled, wanted, a, b, &settled);
    sol.domainVoxels = std::uint64_t(std::llround(total));
    sol.insideVoxels = std::uint64_t(std::llround(settled));
    sol.achieved = settled / total;
    sol.coverage = true;
    sol.rounds = 1;
    return sol;
}

}  // namespace voxlat
