#include "engine/DensitySolver.h"

#include "engine/GridMeasure.h"
#include "engine/Progress.h"
#include "engine/SparseEvaluator.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <vector>

namespace voxlat {

namespace {

/// Samples g at every stride-th voxel centre of the domain, in parallel and in a fixed order.
std::vector<float> coarseSamples(const FieldNode& g, const Domain& domain, int stride)
{
    int n[3];
    for (int a = 0; a < 3; ++a) n[a] = (domain.dims[a] + stride - 1) / stride;
    const int bx = (n[0] + 7) / 8, by = (n[1] + 7) / 8, bz = (n[2] + 7) / 8;
    std::vector<std::vector<float>> perBlock(std::size_t(bx) * by * bz);
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
    return all;
}

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

/// Band voxels with their per-voxel change, for the sub-voxel coverage estimate. Neighbours that
/// were not evaluated (tiles, background, outside the domain) fall back to one-sided differences.
std::vector<CoverageSample> coverageSamples(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region,
                                            float lo, float hi)
{
    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    grid.tree().getNodes(leaves);
    std::vector<std::vector<CoverageSample>> perLeaf(leaves.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size()), [&](const auto& range) {
        auto acc = grid.getConstAccessor();
        for (std::size_t n = range.begin(); n != range.end(); ++n) {
            const float* data = leaves[n]->buffer().data();
            for (int i = 0; i < 512; ++i) {
                const openvdb::Coord c = leaves[n]->offsetToGlobalCoord(i);
                if (data[i] < lo || data[i] > hi || !region.isInside(c)) continue;
                double sum = 0.0;
                for (int a = 0; a < 3; ++a) {
                    openvdb::Coord up = c, down = c;
                    up[a] += 1;
                    down[a] -= 1;
                    const bool hasUp = region.isInside(up) && acc.probeConstLeaf(up);
                    const bool hasDown = region.isInside(down) && acc.probeConstLeaf(down);
                    double d = 0.0;
                    if (hasUp && hasDown) d = 0.5 * (acc.getValue(up) - acc.getValue(down));
                    else if (hasUp) d = acc.getValue(up) - data[i];
                    else if (hasDown) d = data[i] - acc.getValue(down);
                    sum += d * d;
                }
                perLeaf[n].push_back({data[i], float(std::sqrt(sum))});
            }
        }
    });
    std::vector<CoverageSample> all;
    for (const auto& v : perLeaf) all.insert(all.end(), v.begin(), v.end());
    return all;
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

}  // namespace

DensitySolution solveDensity(const FieldNode& indicator, const Domain& domain, double target, bool subVoxel)
{
    DensitySolution sol;
    sol.domainVoxels = domain.voxelCount();
    const auto wanted = std::uint64_t(std::llround(target * double(sol.domainVoxels)));

    const int stride = std::max(1, int(std::ceil(std::cbrt(double(sol.domainVoxels) / 2.0e6))));
    std::vector<float> samples = coarseSamples(indicator, domain, stride);

    // Widen the bracket until the exact quantile falls inside it (usually the first round).
    for (const double margin : {0.01, 0.05, 1.0}) {
        ++sol.rounds;
        const double lo = quantile(samples, target - margin), hi = quantile(samples, target + margin);
        SparseOptions options;
        options.band = Interval(std::max(lo, -1e30), std::min(hi, 1e30));
        options.margin = 0;
        options.insideValue = -std::numeric_limits<float>::max();
        options.outsideValue = std::numeric_limits<float>::max();
        options.stage = "solving density";
        const auto grid = evaluateSparse(indicator, domain, options);
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
        if (subVoxel || std::abs(double(sol.insideVoxels) - double(wanted)) > 1e-3 * double(wanted)) {
            const auto samples = coverageSamples(*grid, domain.indexBox(), float(options.band.lo), float(options.band.hi));
            double a = options.band.lo, b = std::min(options.band.hi, 1e30);
            // An open bracket (a target within 1 % of 0 or 1): bisect over the values present.
            for (const CoverageSample& c : samples) {
                if (options.band.lo <= -1e30) a = std::min(a == options.band.lo ? 1e300 : a, double(c.value) - c.step);
                if (options.band.hi >= 1e30) b = std::max(b == 1e30 ? -1e300 : b, double(c.value) + c.step);
            }
            for (int iteration = 0; iteration < 60; ++iteration) {
                const double mid = 0.5 * (a + b);
                (double(below) + coveredVoxels(samples, mid) < double(wanted) ? a : b) = mid;
            }
            sol.level = 0.5 * (a + b);
            sol.coverage = true;
            sol.achieved = (double(below) + coveredVoxels(samples, sol.level)) / double(sol.domainVoxels);
        }
        return sol;
    }
    return sol;  // unreachable: the last round brackets everything
}

}  // namespace voxlat
