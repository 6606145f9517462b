#include "engine/density/Coverage.h"

#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <memory>

namespace voxlat::coverage {

namespace {

/// Offset strides and shifts of the x, y, z coordinates in an 8^3 leaf's buffer.
constexpr int kLeafStride[3] = {64, 8, 1};
constexpr int kLeafShift[3] = {6, 3, 0};

}  // namespace

namespace {

using Leaf = openvdb::FloatTree::LeafNodeType;

/// Calls emit(value, change) for each band voxel of @a leaf (values in [@a lo, @a hi] inside
/// @a region), in offset order, with its per-voxel change along each axis. Neighbours that were
/// not evaluated (tiles, background, outside @a around) fall back to one-sided differences.
template <class Emit>
void leafBand(const Leaf& leaf, openvdb::FloatGrid::ConstAccessor& acc, float lo, float hi,
              const openvdb::CoordBBox& region, const openvdb::CoordBBox& around, Emit&& emit)
{
    const float* data = leaf.buffer().data();
    for (int i = 0; i < 512; ++i) {
        if (data[i] < lo || data[i] > hi) continue;
        const openvdb::Coord c = leaf.offsetToGlobalCoord(i);
        if (!region.isInside(c)) continue;
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
                if (local < 7)
                    upValue = data[i + kLeafStride[a]];
                else if (acc.probeConstLeaf(up))
                    upValue = acc.getValue(up);
                else
                    hasUp = false;
                hasUp = hasUp && upValue < 1e30f;
            }
            if (hasDown) {
                if (local > 0)
                    downValue = data[i - kLeafStride[a]];
                else if (acc.probeConstLeaf(down))
                    downValue = acc.getValue(down);
                else
                    hasDown = false;
                hasDown = hasDown && downValue < 1e30f;
            }
            change[a] = axisChange(data[i], upValue, hasUp, downValue, hasDown);
        }
        emit(data[i], change);
    }
}

/// Band voxels with their per-voxel change along each axis (make(value, d) builds a sample), for
/// the sub-voxel coverage estimates, in leaf order (leafBand()).
template <class Make>
auto bandSamples(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, float lo, float hi,
                 const openvdb::CoordBBox& around, Make make, const std::function<void()>& interrupt)
{
    using Sample = decltype(make(0.0f, std::array<double, 3>{}));
    std::vector<const Leaf*> leaves;
    grid.tree().getNodes(leaves);
    // Two passes: each leaf's count of band voxels, then the samples written in place at the
    // leaf's offset (leaf order, as before). Per-leaf vectors joined afterwards held the band
    // twice at once: a plate's solve peaked there.
    std::vector<std::size_t> offset(leaves.size() + 1, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size()), [&](const auto& range) {
        for (std::size_t n = range.begin(); n != range.end(); ++n) {
            if (interrupt && n % 64 == 0) interrupt();
            const float* data = leaves[n]->buffer().data();
            std::size_t count = 0;
            for (int i = 0; i < 512; ++i)
                count += !(data[i] < lo || data[i] > hi) && region.isInside(leaves[n]->offsetToGlobalCoord(i));
            offset[n + 1] = count;
        }
    });
    for (std::size_t n = 0; n < leaves.size(); ++n) offset[n + 1] += offset[n];
    std::vector<Sample> all(offset.back());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size()), [&](const auto& range) {
        auto acc = grid.getConstAccessor();
        for (std::size_t n = range.begin(); n != range.end(); ++n) {
            // Per 64 leaves: a range of the partitioner can hold half the band.
            if (interrupt && n % 64 == 0) interrupt();
            std::size_t at = offset[n];
            leafBand(*leaves[n], acc, lo, hi, region, around,
                     [&](float v, const std::array<double, 3>& change) { all[at++] = make(v, change); });
        }
    });
    return all;
}

/// A coverage sample's step: the length of its per-voxel change.
CoverageSample coverageSample(float v, const std::array<double, 3>& d)
{
    return CoverageSample{v, float(std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]))};
}

/// The share of sample @a s below @a level (coveredVoxels()' term).
double sampleCoverage(const CoverageSample& s, double level)
{
    return s.step > 0.0f ? std::clamp(0.5 + (level - s.value) / s.step, 0.0, 1.0) : double(s.value < level);
}

}  // namespace

/// Band voxels with the length of their per-voxel change, for the linear coverage estimate.
std::vector<CoverageSample> coverageSamples(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, float lo,
                                            float hi, const std::function<void()>& interrupt)
{
    return bandSamples(grid, region, lo, hi, region, coverageSample, interrupt);
}

float widestCoverageStep(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, float lo, float hi,
                         const std::function<void()>& interrupt)
{
    std::vector<const Leaf*> leaves;
    grid.tree().getNodes(leaves);
    // A maximum: the same whatever the order the leaves are met in.
    return tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, leaves.size()), 0.0f,
        [&](const tbb::blocked_range<std::size_t>& range, float widest) {
            auto acc = grid.getConstAccessor();
            for (std::size_t n = range.begin(); n != range.end(); ++n) {
                if (interrupt && n % 64 == 0) interrupt();
                leafBand(*leaves[n], acc, lo, hi, region, region, [&](float v, const std::array<double, 3>& d) {
                    const float step = coverageSample(v, d).step;
                    if (step < 1e29f) widest = std::max(widest, step);
                });
            }
            return widest;
        },
        [](float x, float y) { return std::max(x, y); });
}

namespace {

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

}  // namespace

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

namespace {

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

}  // namespace

/// The level in [a, b] at which @a settled + planeCovered() reaches @a wanted, given that it is
/// at most @a wanted at a and at least at b. The covered volume is continuous and increasing
/// in the level (piecewise smooth), so regula falsi with the Illinois modification converges
/// superlinearly: about ten passes instead of sixty halvings. Samples whose coverage no longer
/// changes over what is left of the bracket are set aside as it narrows. @a covered, when
/// given, receives the covered weight at the level returned.
double solvePlaneCoverage(std::vector<PlaneSample> active, double settled, double wanted, double a, double b,
                          double* covered)
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
            if (a >= s.value + h)
                settled += s.weight;
            else if (b > s.value - h)
                active[kept++] = s;
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
    for (const CoverageSample& s : samples) covered += sampleCoverage(s, level);
    return covered;
}

namespace {

/// Samples per block of the bisection's parallel passes: fixed, so the blocks, and what each
/// pass finds in them, are the same for any thread count.
constexpr std::size_t kBisectBlock = std::size_t(1) << 13;
/// Blocks between two calls of the bisection's interrupt (2^20 samples).
constexpr std::size_t kInterruptBlocks = (std::size_t(1) << 20) / kBisectBlock;

/// Samples held in blocks of kBisectBlock: block k's are the first count[k] from
/// base + k * kBisectBlock. Read block after block, they are the samples in their order.
struct BlockedSamples {
    const CoverageSample* base = nullptr;
    std::vector<std::uint32_t> count;

    const CoverageSample* block(std::size_t k) const { return base + k * kBisectBlock; }
    std::size_t size() const
    {
        std::size_t n = 0;
        for (std::uint32_t c : count) n += c;
        return n;
    }
    /// Calls @a f(sample) for every sample in their order, @a interrupt every kInterruptBlocks
    /// blocks.
    template <class F>
    void inOrder(const std::function<void()>& interrupt, F&& f) const;
};

template <class F>
void BlockedSamples::inOrder(const std::function<void()>& interrupt, F&& f) const
{
    for (std::size_t k = 0; k < count.size(); ++k) {
        if (interrupt && k % kInterruptBlocks == kInterruptBlocks - 1) interrupt();
        const CoverageSample* s = block(k);
        for (std::size_t i = 0; i < count[k]; ++i) f(s[i]);
    }
}

/// @a samples as blocks, each full but the last.
BlockedSamples wholeBlocks(const CoverageSample* samples, std::size_t n)
{
    BlockedSamples blocks{samples, std::vector<std::uint32_t>((n + kBisectBlock - 1) / kBisectBlock)};
    for (std::size_t k = 0; k < blocks.count.size(); ++k)
        blocks.count[k] = std::uint32_t(std::min(kBisectBlock, n - k * kBisectBlock));
    return blocks;
}

/// Calls @a body(k) for every block in parallel, @a interrupt every kInterruptBlocks blocks.
template <class Body>
void forEachBlock(std::size_t blocks, const std::function<void()>& interrupt, Body&& body)
{
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 1), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t k = r.begin(); k != r.end(); ++k) {
            if (interrupt && k % kInterruptBlocks == kInterruptBlocks - 1) interrupt();
            body(k);
        }
    });
}

/// Whether @a settled plus the coverage at @a level of each of @a blocks' samples, added one by
/// one in their order, is below @a wanted: the serial sum's answer, for any thread count. The
/// sum is taken in parallel in another order; two sums of the same n non-negative terms differ
/// by at most 2 gamma_(n-1) times the terms' total (Higham, Accuracy and Stability of Numerical
/// Algorithms, 2nd ed., 4.2), so only a parallel sum that close to @a wanted leaves the answer
/// open, and the sum is then taken again in order.
bool coveredBelow(const BlockedSamples& blocks, double settled, double level, double wanted,
                  const std::function<void()>& interrupt)
{
    const std::size_t nBlocks = blocks.count.size();
    const double sum = tbb::parallel_deterministic_reduce(
        tbb::blocked_range<std::size_t>(0, nBlocks, 1), 0.0,
        [&](const tbb::blocked_range<std::size_t>& r, double total) {
            for (std::size_t k = r.begin(); k != r.end(); ++k) {
                if (interrupt && k % kInterruptBlocks == kInterruptBlocks - 1) interrupt();
                const CoverageSample* s = blocks.block(k);
                const std::size_t n = blocks.count[k];
                double part[4] = {0.0, 0.0, 0.0, 0.0};  // four chains: the additions overlap
                std::size_t i = 0;
                for (; i + 4 <= n; i += 4)
                    for (std::size_t j = 0; j < 4; ++j) part[j] += sampleCoverage(s[i + j], level);
                for (; i < n; ++i) part[i % 4] += sampleCoverage(s[i], level);
                total += (part[0] + part[1]) + (part[2] + part[3]);
            }
            return total;
        },
        std::plus<>());
    const double terms = double(blocks.size()) + 1.0;  // settled among them
    // Twice gamma_n (n u / (1 - n u), u = 2^-53) with room to spare, times a bound of the terms'
    // total: every coverage is at most 1.
    const double bound = 4.0 * terms * std::ldexp(1.0, -53) * (std::abs(settled) + terms);
    if (settled + sum < wanted - bound) return true;
    if (settled + sum > wanted + bound) return false;
    double covered = settled;
    blocks.inOrder(interrupt, [&](const CoverageSample& s) { covered += sampleCoverage(s, level); });
    return covered < wanted;
}

/// What the bisection's pass over one block found: its samples still cut by a level in (a, b),
/// those whose coverage is full at a, and whether every one still cut ramps across [a, b].
struct BlockFilter {
    std::uint32_t kept = 0;
    std::uint32_t settled = 0;
    bool ramps = true;
};

/// Block @a k's samples of @a from sorted over [a, b]: @a keep(i, s) is called in order for the
/// i-th sample the level still cuts.
template <class Keep>
BlockFilter filterBlock(const BlockedSamples& from, std::size_t k, double a, double b, Keep&& keep)
{
    BlockFilter f;
    const CoverageSample* s = from.block(k);
    for (std::size_t i = 0; i < from.count[k]; ++i) {
        const double atA = sampleCoverage(s[i], a), atB = sampleCoverage(s[i], b);
        if (atA >= 1.0)
            ++f.settled;
        else if (atB > 0.0) {
            keep(f.kept++, i);
            f.ramps = f.ramps && s[i].step > 0.0f && atA > 0.0 && atB < 1.0;
        }
    }
    return f;
}

}  // namespace

/// The level in [a, b] at which fullyBelow + coveredVoxels(samples, level) reaches @a wanted, by
/// 60 bisection steps. Samples whose coverage is constant (0 or 1) over what is left of the
/// bracket are set aside as it narrows, so later steps visit only the voxels the level still
/// cuts; each kept sample contributes exactly what coveredVoxels() would give it. A sample's
/// coverage at the bracket's ends is computed again where it is needed, not carried along: the
/// same doubles (the same function of the same two numbers), and 8 bytes a sample instead of 32
/// (a plate's band holds 10^7-10^8 samples: the solve's peak). Each step's passes run in
/// parallel over fixed blocks of samples and give the serial bisection's steps (coveredBelow()):
/// the same level, bit for bit, for any thread count.
double bisectCoverage(const std::vector<CoverageSample>& samples, double fullyBelow, double wanted, double a, double b,
                      const std::function<void()>& interrupt)
{
    // The first step reads @a samples themselves and keeps in @a active only those the level
    // still cuts: no copy of every sample (each of its pages written, and held beside the
    // samples). Later steps move the samples kept to the front of their block.
    std::unique_ptr<CoverageSample[]> active;
    BlockedSamples left = wholeBlocks(samples.data(), samples.size());  // the samples still cut
    bool first = true;
    double settled = fullyBelow;  // whole voxels below every level left in the bracket
    // Once every sample left is partly covered across the whole bracket, the coverage is linear
    // there: settled + constant + level * slope, and the remaining steps cost nothing.
    bool linear = false;
    double constant = 0.0, slope = 0.0;
    for (int iteration = 0; iteration < 60; ++iteration) {
        if (interrupt) interrupt();
        const double mid = 0.5 * (a + b);
        const bool raiseA =
            linear ? settled + (constant + mid * slope) < wanted : coveredBelow(left, settled, mid, wanted, interrupt);
        (raiseA ? a : b) = mid;
        if (linear) continue;
        // Coverage is monotone in the level: full at a means full on [a, b], empty at b empty.
        const std::size_t nBlocks = left.count.size();
        std::vector<BlockFilter> found(nBlocks);
        if (first) {
            // Which samples are kept, then each block's written at its place in one array.
            std::vector<std::uint64_t> kept((samples.size() + 63) / 64);
            forEachBlock(nBlocks, interrupt, [&](std::size_t k) {
                std::uint64_t* bits = kept.data() + k * (kBisectBlock / 64);
                found[k] =
                    filterBlock(left, k, a, b, [&](std::uint32_t, std::size_t i) { bits[i / 64] |= 1ull << (i % 64); });
            });
            std::vector<std::size_t> at(nBlocks + 1, 0);
            for (std::size_t k = 0; k < nBlocks; ++k) at[k + 1] = at[k] + found[k].kept;
            active = std::make_unique_for_overwrite<CoverageSample[]>(at[nBlocks]);
            forEachBlock(nBlocks, interrupt, [&](std::size_t k) {
                const std::uint64_t* bits = kept.data() + k * (kBisectBlock / 64);
                const CoverageSample* s = left.block(k);
                CoverageSample* to = active.get() + at[k];
                for (std::size_t i = 0; i < left.count[k]; ++i)
                    if (bits[i / 64] >> (i % 64) & 1u) *to++ = s[i];
            });
            left = wholeBlocks(active.get(), at[nBlocks]);
            first = false;
        } else {
            CoverageSample* base = active.get();
            forEachBlock(nBlocks, interrupt, [&](std::size_t k) {
                CoverageSample* s = base + k * kBisectBlock;
                found[k] = filterBlock(left, k, a, b, [&](std::uint32_t to, std::size_t i) { s[to] = s[i]; });
                left.count[k] = found[k].kept;
            });
        }
        // Each block's whole voxels: ones added one by one, as the serial pass does (exactly a
        // count added at once while the sum is a whole number below 2^53).
        std::size_t nowSettled = 0;
        bool ramps = true;
        for (const BlockFilter& f : found) {
            nowSettled += f.settled;
            ramps = ramps && f.ramps;
        }
        if (settled == std::floor(settled) && std::abs(settled) + double(nowSettled) < 0x1p53)
            settled += double(nowSettled);
        else
            for (std::size_t i = 0; i < nowSettled; ++i) settled += 1.0;
        if (ramps) {
            linear = true;
            left.inOrder(interrupt, [&](const CoverageSample& s) {
                constant += 0.5 - double(s.value) / s.step;
                slope += 1.0 / s.step;
            });
            left = BlockedSamples{};
            active.reset();
        }
    }
    return 0.5 * (a + b);
}

}  // namespace voxlat::coverage
