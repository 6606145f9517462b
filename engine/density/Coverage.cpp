#include "engine/density/Coverage.h"

#include "engine/density/LeafSteps.h"

#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
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
/// An accessor that caches the leaves' parents, not the leaves: caching a leaf asks its buffer for
/// its data (a call that locks where the buffer may be unloaded), which the coverage passes' six
/// neighbours a leaf paid in a tenth of their time.
using NodeAccessor = openvdb::tree::ValueAccessor1<const openvdb::FloatTree, false, 1>;

/// The leaf with its six neighbours' buffers (leafNoNeighbours() where no leaf is), when every
/// voxel of it is in @a region and every neighbour in @a around: the common case, whose steps
/// leafSteps() takes for the whole leaf at once.
bool withNeighbours(const Leaf& leaf, NodeAccessor& acc, const openvdb::CoordBBox& region,
                    const openvdb::CoordBBox& around, LeafWithNeighbours& out)
{
    const openvdb::CoordBBox box(leaf.origin(), leaf.origin() + openvdb::Coord(7));
    const openvdb::CoordBBox grown(box.min() - openvdb::Coord(1), box.max() + openvdb::Coord(1));
    if (!region.isInside(box) || !around.isInside(grown)) return false;
    out.data = leaf.buffer().data();
    // A neighbour past the leaf's face is read from the neighbouring leaf's buffer, found once
    // per face (the same value the accessor gives).
    for (int a = 0; a < 3; ++a) {
        openvdb::Coord down = box.min(), up = box.min();
        down[a] -= 1;
        up[a] += 8;
        const Leaf* below = acc.probeConstLeaf(down);
        const Leaf* above = acc.probeConstLeaf(up);
        out.next[a][0] = below ? below->buffer().data() : leafNoNeighbours();
        out.next[a][1] = above ? above->buffer().data() : leafNoNeighbours();
    }
    return true;
}

/// Calls emit(value, step) for each band voxel of @a leaf (values in [@a lo, @a hi] inside
/// @a region), in offset order, with the length of its per-voxel change (a CoverageSample's
/// step). Neighbours that were not evaluated (tiles, background, outside @a around) fall back to
/// one-sided differences.
template <class Emit>
void leafBand(const Leaf& leaf, NodeAccessor& acc, float lo, float hi, const openvdb::CoordBBox& region,
              const openvdb::CoordBBox& around, Emit&& emit)
{
    const float* data = leaf.buffer().data();
    LeafWithNeighbours withNext{};
    if (withNeighbours(leaf, acc, region, around, withNext)) {
        // The common case: the whole leaf's steps at once, where any voxel is in the band.
        if (!leafMeets(data, lo, hi)) return;
        alignas(64) float steps[512];
        leafSteps(withNext, steps, lo, hi);
        for (int i = 0; i < 512; ++i)
            if (!(data[i] < lo || data[i] > hi)) emit(data[i], steps[i]);
        return;
    }
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
        emit(data[i], float(std::sqrt(change[0] * change[0] + change[1] * change[1] + change[2] * change[2])));
    }
}

/// Band voxels with the length of their per-voxel change (make(value, step) builds a sample), for
/// the sub-voxel coverage estimates, in leaf order (leafBand()).
template <class Make>
auto bandSamples(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, float lo, float hi,
                 const openvdb::CoordBBox& around, Make make, const std::function<void()>& interrupt,
                 std::uint64_t* leavesBelow = nullptr, const std::function<void(std::size_t)>& beforeHolding = {})
{
    using Sample = decltype(make(0.0f, 0.0f));
    std::vector<const Leaf*> leaves;
    grid.tree().getNodes(leaves);
    // Two passes: each leaf's count of band voxels, then the samples written in place at the
    // leaf's offset (leaf order, as before). Per-leaf vectors joined afterwards held the band
    // twice at once: a plate's solve peaked there.
    // The same pass counts the values below the band (integers: the same total for any split).
    std::vector<std::size_t> offset(leaves.size() + 1, 0);
    std::atomic<std::uint64_t> below{0};
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size()), [&](const auto& range) {
        std::uint64_t rangeBelow = 0;
        for (std::size_t n = range.begin(); n != range.end(); ++n) {
            if (interrupt && n % 64 == 0) interrupt();
            const float* data = leaves[n]->buffer().data();
            std::size_t count = 0;
            const openvdb::Coord origin = leaves[n]->origin();
            if (region.isInside(openvdb::CoordBBox(origin, origin + openvdb::Coord(7)))) {
                for (int i = 0; i < 512; ++i) {
                    count += !(data[i] < lo || data[i] > hi);
                    rangeBelow += data[i] < lo;
                }
            } else {
                for (int i = 0; i < 512; ++i) {
                    if (!region.isInside(leaves[n]->offsetToGlobalCoord(i))) continue;
                    count += !(data[i] < lo || data[i] > hi);
                    rangeBelow += data[i] < lo;
                }
            }
            offset[n + 1] = count;
        }
        below.fetch_add(rangeBelow, std::memory_order_relaxed);
    });
    if (leavesBelow) *leavesBelow = below.load();
    for (std::size_t n = 0; n < leaves.size(); ++n) offset[n + 1] += offset[n];
    if (beforeHolding) beforeHolding(offset.back());
    DefaultInitVector<Sample> all(offset.back());  // not zeroed: each sample is written below
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size()), [&](const auto& range) {
        NodeAccessor acc(grid.tree());
        for (std::size_t n = range.begin(); n != range.end(); ++n) {
            // Per 64 leaves: a range of the partitioner can hold half the band.
            if (interrupt && n % 64 == 0) interrupt();
            std::size_t at = offset[n];
            leafBand(*leaves[n], acc, lo, hi, region, around, [&](float v, float step) { all[at++] = make(v, step); });
        }
    });
    return all;
}

/// Where a sample's coverage stands over a bracket [a, b]: full at every level of it (its ramp,
/// value -+ half its step, ends at or below a; a step of 0 valued below a), empty at every level
/// (the ramp starts at or above b; a step of 0 valued at or above b), or changing within it.
enum class OverBracket { Full, Empty, Changing };

OverBracket overBracket(double value, double half, double a, double b)
{
    if (half > 0.0)
        return value + half <= a ? OverBracket::Full : value - half >= b ? OverBracket::Empty : OverBracket::Changing;
    return value < a ? OverBracket::Full : value < b ? OverBracket::Changing : OverBracket::Empty;
}

/// The share of sample @a s below @a level (coveredVoxels()' term).
double sampleCoverage(const CoverageSample& s, double level)
{
    return s.step > 0.0f ? std::clamp(0.5 + (level - s.value) / s.step, 0.0, 1.0) : double(s.value < level);
}

}  // namespace

/// Band voxels with the length of their per-voxel change, for the linear coverage estimate.
CoverageSamples coverageSamples(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, float lo, float hi,
                                const std::function<void()>& interrupt, std::uint64_t* leavesBelow,
                                const std::function<void(std::size_t samples)>& beforeHolding)
{
    return bandSamples(
        grid, region, lo, hi, region,
        [](float v, float step) {
            return CoverageSample{v, step};
        },
        interrupt, leavesBelow, beforeHolding);
}

StraddlingSamples straddlingSamples(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, double a,
                                    double b, float reach, const std::function<void()>& interrupt,
                                    const std::function<void(std::size_t samples)>& beforeHolding,
                                    const Interval& countBand)
{
    std::vector<const Leaf*> leaves;
    grid.tree().getNodes(leaves);
    // Fixed chunks of leaves, each its own samples in leaf order: joined in chunk order.
    constexpr std::size_t kChunk = 64;
    const std::size_t chunks = (leaves.size() + kChunk - 1) / kChunk;
    std::vector<CoverageSamples> parts(chunks);
    std::vector<std::array<std::uint64_t, 3>> countsPerChunk(chunks, {0, 0, 0});  // below, count's below, within
    const float lo = float(a - double(reach)), hi = float(b + double(reach));
    const float countLo = float(countBand.lo), countHi = float(countBand.hi);
    const StraddleBounds bounds{a, b, lo, hi, countLo, countHi};
    // The steps of a leaf with no voxel in the band: read by no voxel (each out of it).
    static const std::array<float, 512> kNoSteps{};
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks, 1), [&](const auto& range) {
        NodeAccessor acc(grid.tree());
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            if (interrupt) interrupt();
            CoverageSamples& part = parts[c];
            std::uint64_t below = 0, countBelow = 0, countWithin = 0;
            const std::size_t end = std::min(leaves.size(), (c + 1) * kChunk);
            for (std::size_t n = c * kChunk; n != end; ++n) {
                const Leaf& leaf = *leaves[n];
                const float* data = leaf.buffer().data();
                LeafWithNeighbours withNext{};
                if (withNeighbours(leaf, acc, region, region, withNext)) {
                    // The common case, the whole leaf at once: its steps where any voxel is in
                    // the band (none of them read elsewhere).
                    alignas(64) float steps[512];
                    const bool meets = leafMeets(data, lo, hi);
                    if (meets) leafSteps(withNext, steps, lo, hi);
                    const LeafStraddle sorted = leafStraddle(data, meets ? steps : kNoSteps.data(), bounds);
                    below += sorted.below;
                    countBelow += sorted.countBelow;
                    countWithin += sorted.countWithin;
                    for (int w = 0; w < 8; ++w)
                        for (std::uint64_t bits = sorted.changing[w]; bits != 0; bits &= bits - 1) {
                            const int i = w * 64 + std::countr_zero(bits);
                            part.push_back(CoverageSample{data[i], steps[i]});
                        }
                    continue;
                }
                const openvdb::Coord origin = leaf.origin();
                // The voxels below the band, counted by value (as countBelow would), and the
                // count's split of countBand.
                auto count = [&](float v) {
                    below += v < lo;
                    countBelow += v < countLo;
                    countWithin += !(v < countLo) && v <= countHi;
                };
                if (region.isInside(openvdb::CoordBBox(origin, origin + openvdb::Coord(7)))) {
                    for (int i = 0; i < 512; ++i) count(data[i]);
                } else {
                    for (int i = 0; i < 512; ++i)
                        if (region.isInside(leaf.offsetToGlobalCoord(i))) count(data[i]);
                }
                leafBand(leaf, acc, lo, hi, region, region, [&](float v, float step) {
                    // As bisectCoverage's steps sort them over [a, b] (stepBlock).
                    switch (overBracket(v, 0.5 * double(step), a, b)) {
                        case OverBracket::Full:
                            ++below;
                            break;
                        case OverBracket::Changing:
                            part.push_back(CoverageSample{v, step});
                            break;
                        case OverBracket::Empty:
                            break;
                    }
                });
            }
            countsPerChunk[c] = {below, countBelow, countWithin};
        }
    });
    StraddlingSamples found;
    std::size_t total = 0;
    for (std::size_t c = 0; c < chunks; ++c) {
        total += parts[c].size();
        found.fullyBelow += countsPerChunk[c][0];
        found.countBelow += countsPerChunk[c][1];
        found.countWithin += countsPerChunk[c][2];
    }
    if (beforeHolding) beforeHolding(total);
    found.samples.reserve(total);
    for (CoverageSamples& part : parts) {
        found.samples.insert(found.samples.end(), part.begin(), part.end());
        CoverageSamples().swap(part);
    }
    return found;
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
            NodeAccessor acc(grid.tree());
            for (std::size_t n = range.begin(); n != range.end(); ++n) {
                if (interrupt && n % 64 == 0) interrupt();
                const float* data = leaves[n]->buffer().data();
                LeafWithNeighbours withNext{};
                if (withNeighbours(*leaves[n], acc, region, region, withNext)) {
                    // The whole leaf's steps at once (the common case), where any voxel is in the band.
                    if (!leafMeets(data, lo, hi)) continue;
                    alignas(64) float steps[512];
                    leafSteps(withNext, steps, lo, hi);
                    widest = std::max(widest, leafWidest(data, steps, lo, hi));
                    continue;
                }
                leafBand(*leaves[n], acc, lo, hi, region, region, [&](float, float step) {
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

namespace {

/// Samples per block of the coverage sums' parallel passes: fixed, so the blocks, what each pass
/// finds in them and the order their sums are added in are the same for any thread count.
constexpr std::size_t kBisectBlock = std::size_t(1) << 13;
/// Blocks between two calls of the interrupt (2^20 samples).
constexpr std::size_t kInterruptBlocks = (std::size_t(1) << 20) / kBisectBlock;

/// Samples held in blocks of kBisectBlock: block k's are the first count[k] from
/// base + k * kBisectBlock.
struct BlockedSamples {
    const CoverageSample* base = nullptr;
    std::vector<std::uint32_t> count;

    const CoverageSample* block(std::size_t k) const { return base + k * kBisectBlock; }
};

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

/// The coverage of @a n samples from @a s at each of @a nLevels (at most 4) @a levels, into
/// @a out: one division per sample whatever the levels (the ramp's 1 / step taken once), two
/// chains of additions per level (they overlap). The same doubles for any thread count.
void blockCoverage(const CoverageSample* s, std::size_t n, const double* levels, std::size_t nLevels, double* out)
{
    double part[4][2] = {};
    for (std::size_t i = 0; i < n; ++i) {
        const double value = s[i].value;
        if (s[i].step > 0.0f) {
            const double inverse = 1.0 / s[i].step;
            for (std::size_t l = 0; l < nLevels; ++l)
                part[l][i & 1] += std::clamp(0.5 + (levels[l] - value) * inverse, 0.0, 1.0);
        } else {
            for (std::size_t l = 0; l < nLevels; ++l) part[l][i & 1] += double(value < levels[l]);
        }
    }
    for (std::size_t l = 0; l < nLevels; ++l) out[l] = part[l][0] + part[l][1];
}

/// What one step of the bisection found in one block, against the bracket [a, b] it then held:
/// its samples whose coverage is full over the bracket (settled), those whose coverage is linear
/// across it (their constant and slope: 0.5 - value / step and 1 / step), and those with a
/// breakpoint inside it (kept, and their coverage at the step's level). Samples empty over the
/// bracket are dropped.
struct BlockStep {
    std::uint32_t kept = 0;
    std::uint32_t settled = 0;
    double constant = 0.0, slope = 0.0;
    double cut = 0.0;
};

/// Block @a k of @a from sorted over [@a a, @a b] by each sample's breakpoints (value -+ half its
/// step: where its coverage leaves 0 and reaches 1; a step of 0 jumps at its value, covered below
/// a level above it), its kept samples' coverage taken at @a mid: @a keep(j, i) is called in order
/// for the i-th sample, the j-th kept. A division only for the samples kept.
template <class Keep>
BlockStep stepBlock(const BlockedSamples& from, std::size_t k, double a, double b, double mid, Keep&& keep)
{
    BlockStep f;
    const CoverageSample* s = from.block(k);
    for (std::size_t i = 0; i < from.count[k]; ++i) {
        const double value = s[i].value, half = 0.5 * double(s[i].step);
        switch (overBracket(value, half, a, b)) {
            case OverBracket::Full:
                ++f.settled;
                break;
            case OverBracket::Empty:
                break;
            case OverBracket::Changing:
                if (half > 0.0 && value - half < a && value + half > b) {
                    const double inverse = 1.0 / s[i].step;
                    f.constant += 0.5 - value * inverse;
                    f.slope += inverse;
                } else {
                    keep(f.kept++, i);
                    f.cut += sampleCoverage(s[i], mid);
                }
                break;
        }
    }
    return f;
}

}  // namespace

double coveredVoxels(const CoverageSamples& samples, double level)
{
    double covered = 0.0;
    coveredVoxels(samples, std::span<const double>(&level, 1), std::span<double>(&covered, 1));
    return covered;
}

void coveredVoxels(const CoverageSamples& samples, std::span<const double> levels, std::span<double> out)
{
    const BlockedSamples blocks = wholeBlocks(samples.data(), samples.size());
    const std::size_t nLevels = levels.size();
    std::vector<double> sums(blocks.count.size() * nLevels);
    for (std::size_t first = 0; first < nLevels; first += 4) {
        const std::size_t count = std::min<std::size_t>(4, nLevels - first);
        forEachBlock(blocks.count.size(), {}, [&](std::size_t k) {
            double found[4];
            blockCoverage(blocks.block(k), blocks.count[k], levels.data() + first, count, found);
            for (std::size_t l = 0; l < count; ++l) sums[k * nLevels + first + l] = found[l];
        });
    }
    std::fill(out.begin(), out.begin() + nLevels, 0.0);
    for (std::size_t k = 0; k < blocks.count.size(); ++k)
        for (std::size_t l = 0; l < nLevels; ++l) out[l] += sums[k * nLevels + l];
}

/// The level in [a, b] at which fullyBelow + coveredVoxels(samples, level) reaches @a wanted, by
/// 60 bisection steps. The coverage is piecewise linear in the level, with breakpoints at each
/// sample's value -+ half its step. As the bracket narrows, each step sets aside the samples
/// without a breakpoint inside it: those full across it (counted), those empty (dropped) and
/// those linear across it (their constants and slopes summed): later steps visit only the
/// samples whose breakpoints are still inside the bracket, a share that halves with it, moved to
/// the front of their block of @a samples (owned here: no copy). Each step's pass runs in
/// parallel over fixed blocks and adds the blocks' sums in their order: the same level, bit for
/// bit, for any thread count. The first pass serves the first two steps (three levels at once)
/// and gives the slope over the bracket's middle half.
CoverageLevel bisectCoverage(CoverageSamples samples, double fullyBelow, double wanted, double a, double b,
                             const std::function<void()>& interrupt)
{
    CoverageLevel result;
    BlockedSamples left = wholeBlocks(samples.data(), samples.size());  // the samples still cut
    CoverageSample* base = samples.data();
    double settled = fullyBelow;         // whole voxels below every level left in the bracket
    double constant = 0.0, slope = 0.0;  // the samples linear across the bracket
    std::vector<BlockStep> found;
    double nextCut[2] = {0.0, 0.0}, previousMid = 0.0;  // the first pass's sums for the second step
    for (int iteration = 0; iteration < 60; ++iteration) {
        if (interrupt) interrupt();
        const double mid = 0.5 * (a + b);
        const std::size_t nBlocks = left.count.size();
        double cut = 0.0;
        if (iteration == 0) {
            // The whole band brackets the level: nearly every sample has a breakpoint inside
            // it and the next bracket's half too. One pass takes their coverage at the middle
            // and at both middles the next step may take, with nothing set aside or moved.
            const std::array<double, 3> levels{mid, 0.5 * (a + mid), 0.5 * (mid + b)};
            std::vector<double> sums(nBlocks * 3);
            forEachBlock(nBlocks, interrupt, [&](std::size_t k) {
                blockCoverage(left.block(k), left.count[k], levels.data(), 3, sums.data() + k * 3);
            });
            for (std::size_t k = 0; k < nBlocks; ++k)
                for (std::size_t l = 0; l < 3; ++l) (l == 0 ? cut : nextCut[l - 1]) += sums[k * 3 + l];
            const double width = levels[2] - levels[1];
            if (width > 0.0 && width < 1e29) result.slope = (nextCut[1] - nextCut[0]) / width;
        } else if (iteration == 1) {
            cut = nextCut[mid < previousMid ? 0 : 1];
        } else if (nBlocks > 0) {
            // Kept samples move to the front of their block.
            found.assign(nBlocks, BlockStep{});
            forEachBlock(nBlocks, interrupt, [&](std::size_t k) {
                CoverageSample* s = base + k * kBisectBlock;
                found[k] = stepBlock(left, k, a, b, mid, [&](std::uint32_t to, std::size_t i) { s[to] = s[i]; });
                left.count[k] = found[k].kept;
            });
            std::size_t nowSettled = 0;
            for (const BlockStep& f : found) {
                nowSettled += f.settled;
                constant += f.constant;
                slope += f.slope;
                cut += f.cut;
            }
            settled += double(nowSettled);
            if (std::all_of(found.begin(), found.end(), [](const BlockStep& f) { return f.kept == 0; }))
                left = BlockedSamples{};
        }
        (settled + (constant + mid * slope) + cut < wanted ? a : b) = mid;
        previousMid = mid;
    }
    result.level = 0.5 * (a + b);
    // The coverage at the level: what is set aside, and the samples still kept (few by now).
    result.covered = settled + (constant + result.level * slope);
    for (std::size_t k = 0; k < left.count.size(); ++k) {
        double at = 0.0;
        blockCoverage(left.block(k), left.count[k], &result.level, 1, &at);
        result.covered += at;
    }
    return result;
}

}  // namespace voxlat::coverage
