#include "engine/density/DensitySolver.h"

#include "engine/core/Errors.h"
#include "engine/core/GridMeasure.h"
#include "engine/core/SparseEvaluator.h"
#include "engine/density/Coverage.h"
#include "fields/core/BlockLattice.h"

#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <functional>
#include <limits>
#include <vector>

// A box of identical cells measured on one period of its interior plus its face zones, each
// piece weighted, by the plane coverage of engine/density/Coverage.h.

namespace voxlat {

using namespace coverage;

std::vector<DensityPiece> periodicPieces(const Box3& box, const Vec3d& period, double reach, double voxel,
                                         std::array<bool, 3> mirror, bool swapXY)
{
    // Axes of period 0 do not fold (one piece spans them); the others share one period.
    const double p = std::max({period[0], period[1], period[2]});
    if (!(voxel > 0.0) || !(p > 0.0)) return {};
    for (int a = 0; a < 3; ++a)
        if (period[a] != 0.0 && std::abs(period[a] - p) > 1e-12 * p) return {};
    const long perPeriod = std::max(1L, long(std::ceil(p / voxel - 1e-9)));
    const double step = p / double(perPeriod);
    struct Segment {
        long start;  ///< in lattice steps from box.min
        long voxels;
        double weight;
        bool operator==(const Segment&) const = default;
    };
    std::array<std::vector<Segment>, 3> segments;
    for (int a = 0; a < 3; ++a) {
        const double cells = box.extent()[a] / p;
        const long whole = std::lround(cells);
        if (whole < 1 || std::abs(cells - double(whole)) > 1e-9 * cells) return {};
        if (period[a] == 0.0) {
            segments[a].push_back({0, whole * perPeriod, 1.0});
            continue;
        }
        const long zone = long(std::ceil(reach / step - 1e-9)) + 1;  // a step of safety
        const long total = whole * perPeriod;
        const long folds = (total - 2 * zone) / perPeriod;
        if (folds < 2) return {};
        // Samples between the zones past the last whole period: they repeat the period's first
        // `extra` samples (all lie at least a zone inside the box).
        const long extra = total - 2 * zone - folds * perPeriod;
        segments[a].push_back({0, zone, mirror[a] ? 2.0 : 1.0});
        std::vector<Segment> period;
        if (extra > 0) period.push_back({zone, extra, double(folds + 1)});
        period.push_back({zone + extra, perPeriod - extra, double(folds)});
        for (const Segment& s : period) {
            if (!mirror[a]) {
                segments[a].push_back(s);
                continue;
            }
            // Mirror symmetric about the box's middle and periodic between the zones, the field
            // is symmetric about box.min within a period too: sample m (centre at m + 1/2 steps)
            // has sample -m - 1 (mod the period) for its image, and each segment above is its
            // own image. Half of it counts twice (an odd segment's middle sample, once).
            const auto image = [&](long m) {
                const long r = ((-m - 1 - zone) % perPeriod + perPeriod) % perPeriod;
                return zone + r;
            };
            const long half = s.voxels / 2;
            if (image(s.start) != s.start + s.voxels - 1) {
                segments[a].push_back(s);  // not its own image (cannot happen; kept whole then)
                continue;
            }
            if (half > 0) segments[a].push_back({s.start, half, 2.0 * s.weight});
            if (s.voxels % 2 == 1) segments[a].push_back({s.start + half, 1, s.weight});
        }
        if (!mirror[a]) segments[a].push_back({total - zone, zone, 1.0});
    }
    // The field its own image under swapping x and y (about the box's corner) and both axes cut
    // alike: the piece (x, y) is the transpose of (y, x), so one of each pair counts twice.
    const bool transposed = swapXY && segments[0] == segments[1];
    std::vector<DensityPiece> pieces;
    for (std::size_t i = 0; i < segments[0].size(); ++i)
        for (std::size_t j = transposed ? i : 0; j < segments[1].size(); ++j)
            for (const Segment& z : segments[2]) {
                const Segment& x = segments[0][i];
                const Segment& y = segments[1][j];
                DensityPiece piece;
                piece.domain.voxel = step;
                piece.domain.box.min = box.min + step * Vec3d(double(x.start), double(y.start), double(z.start));
                piece.domain.dims = openvdb::Coord(int(x.voxels), int(y.voxels), int(z.voxels));
                piece.domain.box.max =
                    piece.domain.box.min + step * Vec3d(double(x.voxels), double(y.voxels), double(z.voxels));
                piece.weight = x.weight * y.weight * z.weight * (transposed && j > i ? 2.0 : 1.0);
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
    BlockLattice lattice;       ///< the samples of `around`
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
    std::size_t blocks = 0;
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
        // The voxel centres of `around`: min + (ijk + 1/2) voxel.
        d.lattice.base = pieces[p].domain.box.min;
        d.lattice.step = Vec3d(pieces[p].domain.voxel);
        for (int a = 0; a < 3; ++a) {
            d.lattice.offset[a] = d.around.min()[a] + 0.5;
            d.lattice.count[a] = d.around.dim()[a];
        }
        blocks += d.lattice.blockCount();
        total += pieces[p].weight * double(pieces[p].domain.voxelCount());
    }
    if (total <= 0.0) throw std::invalid_argument("no voxel to measure a density on");
    std::atomic<bool> nonFinite{false};
    {
        StageProgress progress(context, "solving density", blocks);
        for (DensePiece& d : dense)
            sampleBlocks(indicator, d.lattice, [&](std::size_t, const GridBatch& batch, auto first, auto values) {
                const openvdb::Coord lo = d.around.min() + openvdb::Coord(first[0], first[1], first[2]);
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
                progress.add();
            });
    }
    if (nonFinite)
        throw JobError(
            "the field is not finite (NaN or infinity) where the density is measured: check divisions, "
            "logarithms and square roots in the recipe's fields");
    sol.evaluatedLeaves = blocks;

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
    // The slope over the bracket (the cut samples' coverage at its ends; the settled weight is the same at both).
    if (b > a) sol.slope = (planeCovered(samples, b) - planeCovered(samples, a)) / (b - a) / total;
    sol.level = solvePlaneCoverage(std::move(samples), settled, wanted, a, b, &settled);
    sol.domainVoxels = std::uint64_t(std::llround(total));
    sol.insideVoxels = std::uint64_t(std::llround(settled));
    sol.achieved = settled / total;
    sol.coverage = true;
    sol.rounds = 1;
    return sol;
}

}  // namespace voxlat
