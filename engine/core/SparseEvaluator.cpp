#include "engine/core/SparseEvaluator.h"

#include "fields/core/Scratch.h"

#include "engine/core/Errors.h"
#include "engine/core/SystemInfo.h"
#include "fields/shapes/BoxField.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace voxlat {

namespace {

using openvdb::Coord;
using openvdb::CoordBBox;
using LeafT = openvdb::FloatTree::LeafNodeType;

constexpr int kLeafDim = 8;
constexpr int kBlockDim = 128;  // children of a level-1 internal node: a level-2 tile

enum class Side { Inside, Outside, Straddle };

/// A leaf's 512 values as floats into @a data; returns whether any value is not finite and, with
/// @a countBelow, adds the floats below zero to @a below. Branch-free integer tests (an exponent
/// of all ones: infinity or NaN), so the loops vectorise; built for AVX2 too and picked at load
/// time (conversions and comparisons: the same floats and counts either way).
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
__attribute__((target_clones("avx2", "default")))
#endif
bool leafFloats(const double* __restrict values, float* __restrict data, bool countBelow, std::uint32_t& below)
{
    constexpr std::uint64_t kExponent = 0x7FF0000000000000ull;
    std::uint64_t nonFiniteSeen = 0;
    for (int i = 0; i < 512; ++i) {
        std::uint64_t bits;
        std::memcpy(&bits, &values[i], sizeof bits);
        nonFiniteSeen |= std::uint64_t((bits & kExponent) == kExponent);
        data[i] = float(values[i]);
    }
    if (countBelow) {
        std::uint32_t count = 0;
        for (int i = 0; i < 512; ++i) count += data[i] < 0.0f;
        below += count;
    }
    return nonFiniteSeen != 0;
}

/// World box of the voxel centres in [lo, lo + size) grown by one voxel on every side.
Box3 grownBox(const Domain& d, const Coord& lo, int size)
{
    return {d.worldOf(lo - Coord(1)), d.worldOf(lo + Coord(size))};
}

Side classify(const FieldNode& f, const BoxField* clip, const Domain& d, const Coord& lo, int size,
              const Interval& band, const KnownSamples* known)
{
    // A band that takes every value needs no bound (they cost more than some evaluations).
    if (band.lo <= -1e30 && band.hi >= 1e30) return Side::Straddle;
    const Box3 box = grownBox(d, lo, size);
    // Values known inside the box that meet the band: its bound would meet it too. The samples
    // of the voxels one past the leaf count: their centres lie on the grown box the bound is
    // taken over (a leaf of 8 voxels holds one or two samples of stride 5 along an axis, its
    // grown box always two). With the clip,
    // max(field, clip): a value at least band.lo stays so, and one at most band.hi stays so
    // where the clip's bound is at most band.hi.
    const std::optional<Interval> clipBound = clip ? std::optional(clip->bound(box)) : std::nullopt;
    if ((!clipBound || clipBound->hi <= band.hi) && known &&
        known->meets(CoordBBox(lo - Coord(1), lo + Coord(size)), band))
        return Side::Straddle;
    // Values held at every voxel the box's leaf reads (its own and one past it: the corners of
    // every cube the mesher takes from it) decide it as they are: a leaf whose voxels all lie on
    // one side is a tile to every reader of the grid, whatever its bound between them. (W2g's
    // 50 mm wireframe: its grid at the solved level took a tenth of its CPU in bounds of leaves
    // the solve's grid held, nearly none of them crossed.) A block's (128^3 voxels) are not
    // walked: a bound decides it for less.
    std::optional<Interval> held;
    if (size == kLeafDim) {
        GridBatch points;
        points.origin = d.worldOf(lo - Coord(1));
        points.spacing = Vec3d(d.voxel);
        points.nx = points.ny = points.nz = size + 2;
        held = f.heldRange(points);
    }
    if (!held && (!clipBound || clipBound->hi <= band.hi) && f.meets(box, band)) return Side::Straddle;
    Interval b = held ? *held : f.bound(box);
    if (clipBound) b = max(b, *clipBound);
    if (b.hi < band.lo) return Side::Inside;
    if (b.lo > band.hi) return Side::Outside;
    return Side::Straddle;
}

int floorTo(int v, int step)
{
    return int(std::floor(double(v) / step)) * step;
}

struct BlockResult {
    bool insideTile = false;
    std::vector<Coord> leaves;
    std::vector<Coord> insideLeafTiles;
    std::uint64_t culled = 0;
};

}  // namespace

namespace {

/// Calls @a part(data, part) for each leaf of @a grid over @a voxels (data: its values, null when
/// no leaf with values holds them), with the part of @a voxels it holds; stops when it returns true.
template <class Part>
bool forEachLeafPart(const openvdb::FloatGrid& grid, const CoordBBox& voxels, Part part)
{
    using LeafT = openvdb::FloatGrid::TreeType::LeafNodeType;
    // Leaves found through their parent, cached (a box's leaves nearly always share it); not an
    // accessor that caches leaves, which asks each leaf's buffer for its data (a call that
    // locks), nor one registered with the tree (a box is asked of it per leaf of a grid).
    openvdb::tree::ValueAccessor1<const openvdb::FloatTree, false, 1> tree(grid.tree());
    const Coord first(voxels.min().x() & ~7, voxels.min().y() & ~7, voxels.min().z() & ~7);
    for (int x = first.x(); x <= voxels.max().x(); x += 8)
        for (int y = first.y(); y <= voxels.max().y(); y += 8)
            for (int z = first.z(); z <= voxels.max().z(); z += 8) {
                const LeafT* leaf = tree.probeConstLeaf(Coord(x, y, z));
                const CoordBBox within(Coord::maxComponent(voxels.min(), Coord(x, y, z)),
                                       Coord::minComponent(voxels.max(), Coord(x + 7, y + 7, z + 7)));
                if (part(leaf && !leaf->buffer().empty() ? leaf->buffer().data() : nullptr, within)) return true;
            }
    return false;
}

}  // namespace

bool heldValuesMeet(const openvdb::FloatGrid& grid, const CoordBBox& voxels, const Interval& band)
{
    BandMet met(band);
    // Leaf by leaf over the box: each leaf's part of it, read from its buffer.
    return forEachLeafPart(grid, voxels, [&](const float* data, const CoordBBox& part) {
        if (!data) return false;
        for (int i = part.min().x(); i <= part.max().x(); ++i)
            for (int j = part.min().y(); j <= part.max().y(); ++j)
                for (int k = part.min().z(); k <= part.max().z(); ++k)
                    if (met.add(data[((i & 7) << 6) | ((j & 7) << 3) | (k & 7)])) return true;
        return false;
    });
}

std::optional<Interval> heldValuesRange(const openvdb::FloatGrid& grid, const CoordBBox& voxels)
{
    // Every leaf found first (a box not all held, most of those asked, reads no value).
    std::array<std::pair<const float*, CoordBBox>, 64> held;
    std::size_t count = 0;
    const bool missing = forEachLeafPart(grid, voxels, [&](const float* data, const CoordBBox& part) {
        if (!data || count == held.size()) return true;
        held[count++] = {data, part};
        return false;
    });
    if (missing) return std::nullopt;
    // Whole rows of eight (a whole leaf's, a face's across z) in eight lanes, one per z:
    // independent chains the compiler keeps in registers; a face across z one value at a time.
    constexpr float kInf = std::numeric_limits<float>::infinity();
    std::array<float, 8> los, his;
    los.fill(kInf);
    his.fill(-kInf);
    float lo = kInf, hi = -kInf;
    auto rows = [&](const float* data, int first, int rowCount, int stride) {
        for (int r = 0; r < rowCount; ++r) {
            const float* row = data + first + r * stride;
            for (std::size_t k = 0; k < 8; ++k) {
                los[k] = row[k] < los[k] ? row[k] : los[k];
                his[k] = row[k] > his[k] ? row[k] : his[k];
            }
        }
    };
    for (std::size_t n = 0; n < count; ++n) {
        const auto& [data, part] = held[n];
        const int k0 = part.min().z() & 7, k1 = part.max().z() & 7;
        if (k0 == 0 && k1 == 7) {
            // Rows of eight: the whole leaf (64 in turn), a face across x or y, an edge along z.
            for (int i = part.min().x(); i <= part.max().x(); ++i)
                rows(data, ((i & 7) << 6) | ((part.min().y() & 7) << 3), part.max().y() - part.min().y() + 1, 8);
            continue;
        }
        for (int i = part.min().x(); i <= part.max().x(); ++i)
            for (int j = part.min().y(); j <= part.max().y(); ++j) {
                const float* row = data + (((i & 7) << 6) | ((j & 7) << 3));
                for (int k = k0; k <= k1; ++k) {
                    lo = row[k] < lo ? row[k] : lo;
                    hi = row[k] > hi ? row[k] : hi;
                }
            }
    }
    for (std::size_t k = 0; k < 8; ++k) {
        lo = std::min(lo, los[k]);
        hi = std::max(hi, his[k]);
    }
    // A value that is no number (never held: the evaluator refuses them) leaves it unproven.
    if (!(lo <= hi)) return std::nullopt;
    return Interval(lo, hi);
}

bool KnownSamples::meets(const CoordBBox& voxels, const Interval& band) const
{
    if (stride < 1 || values.empty()) return false;
    // The samples' index range within the box: ceil and floor of (voxel - origin) / stride.
    int first[3], last[3];
    for (int a = 0; a < 3; ++a) {
        const int lo = voxels.min()[a] - origin[a], hi = voxels.max()[a] - origin[a];
        first[a] = std::max(0, lo >= 0 ? (lo + stride - 1) / stride : -((-lo) / stride));
        last[a] = std::min(count[a] - 1, hi >= 0 ? hi / stride : -((-hi + stride - 1) / stride));
        if (first[a] > last[a]) return false;
    }
    BandMet met(band, error);
    for (int i = first[0]; i <= last[0]; ++i)
        for (int j = first[1]; j <= last[1]; ++j) {
            const float* row = values.data() + (std::size_t(i) * count[1] + j) * std::size_t(count[2]);
            for (int k = first[2]; k <= last[2]; ++k)
                if (met.add(row[k])) return true;
        }
    return false;
}

openvdb::FloatGrid::Ptr evaluateSparse(const FieldNode& field, const Domain& domain, const SparseOptions& options,
                                       SparseStats* stats)
{
    const CoordBBox region(Coord(-options.margin), domain.dims - Coord(1) + Coord(options.margin));
    const auto clip = options.clipToDomain ? std::make_unique<BoxField>(domain.box) : nullptr;
    // Leaves wholly inside this index box are at least 1.5 voxels inside the domain.
    const CoordBBox deepInside(Coord(1), domain.dims - Coord(2));

    // Level-2 blocks covering the region.
    std::vector<Coord> blocks;
    const Coord first(floorTo(region.min().x(), kBlockDim), floorTo(region.min().y(), kBlockDim),
                      floorTo(region.min().z(), kBlockDim));
    for (int x = first.x(); x <= region.max().x(); x += kBlockDim)
        for (int y = first.y(); y <= region.max().y(); y += kBlockDim)
            for (int z = first.z(); z <= region.max().z(); z += kBlockDim) blocks.emplace_back(x, y, z);
    if (blocks.size() > 4'000'000)
        throw JobError("the domain has " + std::to_string(domain.voxelCount()) +
                       " voxels, far more than this machine can evaluate: raise `voxel:` or shrink the domain");

    // Stage 1: cull by bounds, block then leaf. The leaves found are counted as the cull goes, so
    // a job whose surface cannot fit in memory is refused as soon as it is known (a 200 mm box at
    // 0.01 mm ran out of memory after four minutes), not after the whole cull.
    const std::uint64_t bytesPerLeaf = options.bytesPerLeaf ? options.bytesPerLeaf : kBytesPerLeaf;
    const std::uint64_t budget = std::uint64_t(0.7 * double(availableMemoryBytes()));
    const std::uint64_t beside = options.bytesBeside;
    const std::uint64_t maxLeaves =
        options.maxLeaves ? options.maxLeaves : (budget > beside ? budget - beside : 0) / bytesPerLeaf;
    auto tooMany = [&](std::uint64_t leaves, bool partial) {
        std::ostringstream msg;
        msg << "this job needs " << (partial ? "more than " : "about ") << ((leaves * bytesPerLeaf + beside) >> 20)
            << " MB for " << (partial ? "more than " : "") << leaves << " surface leaves"
            << (beside ? " and the mesh written beside them" : "") << ", more than the "
            << ((maxLeaves * bytesPerLeaf + beside) >> 20)
            << " MB this machine can give: raise `voxel:` (memory grows as 1/voxel^2) or shrink the domain";
        return JobError(msg.str());
    };
    std::atomic<std::uint64_t> found{0};
    std::vector<BlockResult> results(blocks.size());
    {
        StageProgress progress(options.context, options.stage + " (cull)", blocks.size());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks.size(), 1), [&](const auto& range) {
            for (std::size_t b = range.begin(); b != range.end(); ++b) {
                BlockResult& r = results[b];
                const Side side =
                    classify(field, clip.get(), domain, blocks[b], kBlockDim, options.band, options.known);
                if (side == Side::Inside) r.insideTile = true;
                if (side != Side::Straddle) {
                    r.culled += side == Side::Outside;
                    progress.add();
                    continue;
                }
                const CoordBBox leafRange(blocks[b], blocks[b] + Coord(kBlockDim - 1));
                for (int x = leafRange.min().x(); x <= leafRange.max().x(); x += kLeafDim)
                    for (int y = leafRange.min().y(); y <= leafRange.max().y(); y += kLeafDim)
                        for (int z = leafRange.min().z(); z <= leafRange.max().z(); z += kLeafDim) {
                            const Coord lo(x, y, z);
                            if (!region.hasOverlap(CoordBBox(lo, lo + Coord(kLeafDim - 1)))) continue;
                            switch (classify(field, clip.get(), domain, lo, kLeafDim, options.band, options.known)) {
                                case Side::Inside:
                                    r.insideLeafTiles.push_back(lo);
                                    break;
                                case Side::Outside:
                                    ++r.culled;
                                    break;
                                case Side::Straddle:
                                    r.leaves.push_back(lo);
                                    if (found.fetch_add(1, std::memory_order_relaxed) + 1 > maxLeaves)
                                        throw tooMany(maxLeaves, true);
                                    break;
                            }
                        }
                progress.add();
            }
        });
    }

    // Deterministic order: block order, then loop order inside a block.
    std::vector<Coord> leafOrigins;
    SparseStats s;
    for (const BlockResult& r : results) {
        leafOrigins.insert(leafOrigins.end(), r.leaves.begin(), r.leaves.end());
        s.insideTiles += r.insideTile + r.insideLeafTiles.size();
        s.culledBoxes += r.culled;
    }
    s.leaves = leafOrigins.size();
    if (s.leaves > maxLeaves) throw tooMany(s.leaves, false);

    // Stage 2: evaluate each straddling leaf as one batch, or each stack of them (stackLeaves).
    // A stack's leaves are consecutive in leafOrigins: the cull walks z innermost within a block,
    // and a stack (at most 128 voxels tall, aligned) lies within one block.
    const int stack = options.stackLeaves;
    if (stack < 1 || stack > kBlockDim / kLeafDim || (stack & (stack - 1)) != 0)
        throw std::invalid_argument("evaluateSparse: stackLeaves must be 1, 2, 4, 8 or 16");
    const int stackDim = kLeafDim * stack;
    auto stackOf = [stackDim](const Coord& lo) { return Coord(lo.x(), lo.y(), floorTo(lo.z(), stackDim)); };
    struct Run {
        std::size_t first, count;  ///< leaves [first, first + count) of leafOrigins
    };
    std::vector<Run> runs;
    runs.reserve(stack == 1 ? leafOrigins.size() : leafOrigins.size() / 2 + 1);
    for (std::size_t n = 0; n < leafOrigins.size(); ++n) {
        if (!runs.empty() && stack > 1 && stackOf(leafOrigins[runs.back().first]) == stackOf(leafOrigins[n]))
            ++runs.back().count;
        else
            runs.push_back({n, 1});
    }
    if (stack > 1) s.stackedLeaves = std::uint64_t(runs.size()) * std::uint64_t(stack);
    // Owned until the tree takes them: a cancelled or failed evaluation frees what it made.
    std::vector<std::unique_ptr<LeafT>> leaves(options.leafVisitor ? 0 : leafOrigins.size());
    // Per leaf, so the total is an integer sum in leaf order whatever the thread count.
    std::vector<std::uint32_t> belowPerLeaf(leafOrigins.size(), 0);
    const CoordBBox domainIndex = domain.indexBox();
    std::atomic<bool> nonFinite{false};
    std::mutex badMutex;
    Vec3d badPoint(0.0);
    {
        StageProgress progress(options.context, options.stage, leafOrigins.size());
        const std::size_t grain = std::size_t(std::max(1, 16 / stack));
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, runs.size(), grain), [&](const auto& range) {
            std::array<double, 512> values, clipped;
            std::array<float, 512> visited;
            // This task's own (a field that waits on work of its own may run another task here:
            // that task leases the next level), kept by the thread between tasks: 32 KB allocated
            // and freed per task went back to the system and came back as fresh pages.
            ScratchLease stackScratch(stack > 1 ? std::size_t(512) * std::size_t(stack) : 0);
            const std::span<double> stacked(stackScratch.data(), stack > 1 ? std::size_t(512) * std::size_t(stack) : 0);
            std::size_t made = 0;
            for (std::size_t r = range.begin(); r != range.end(); ++r) {
                const Run& run = runs[r];
                GridBatch stackBatch;
                if (stack > 1) {
                    // The whole stack, whichever of its leaves are needed.
                    const Coord first = stackOf(leafOrigins[run.first]);
                    stackBatch.origin = domain.worldOf(first);
                    stackBatch.spacing = Vec3d(domain.voxel);
                    stackBatch.nz = stackDim;
                    stackBatch.onLattice = true;
                    stackBatch.latticeMin = domain.latticeMin();
                    const Coord index = first + domain.latticeOffset;
                    stackBatch.latticeIndex = {index.x(), index.y(), index.z()};
                    // The stack's leaves not needed here: their values are not read.
                    std::uint32_t needed = 0;
                    for (std::size_t n = run.first; n != run.first + run.count; ++n)
                        needed |= std::uint32_t(1) << ((leafOrigins[n].z() - stackOf(leafOrigins[n]).z()) / kLeafDim);
                    stackBatch.unread = ((std::uint32_t(1) << stack) - 1u) & ~needed;
                    field.gridValues(stackBatch, stacked);
                }
                for (std::size_t n = run.first; n != run.first + run.count; ++n) {
                    const Coord& lo = leafOrigins[n];
                    GridBatch batch;
                    batch.origin = domain.worldOf(lo);
                    batch.spacing = Vec3d(domain.voxel);
                    batch.onLattice = true;
                    batch.latticeMin = domain.latticeMin();
                    const Coord index = lo + domain.latticeOffset;
                    batch.latticeIndex = {index.x(), index.y(), index.z()};
                    if (stack > 1) {
                        // Rows of the stack (x-major, z fastest): the leaf's eight points of each.
                        const int k0 = lo.z() - stackOf(lo).z();
                        for (int ij = 0; ij < 64; ++ij)
                            std::memcpy(&values[std::size_t(ij) * 8], &stacked[std::size_t(ij) * stackDim + k0],
                                        8 * sizeof(double));
                    } else {
                        field.gridValues(batch, values);
                    }
                    if (clip && !deepInside.isInside(CoordBBox(lo, lo + Coord(kLeafDim - 1)))) {
                        clip->gridValues(batch, clipped);
                        for (int i = 0; i < 512; ++i) values[i] = std::max(values[i], clipped[i]);
                    }
                    std::unique_ptr<LeafT> leaf;
                    float* data = visited.data();
                    if (!options.leafVisitor) {
                        // Allocated, not filled: every value is written just below (a fill would
                        // write the 2 KB twice).
                        leaf = std::make_unique<LeafT>(openvdb::PartialCreate(), lo, options.outsideValue, true);
                        leaf->buffer().allocate();
                        data = leaf->buffer().data();
                    }
                    // The rare non-finite leaf is searched afterwards.
                    const CoordBBox leafBox(lo, lo + Coord(kLeafDim - 1));
                    const bool wholeInDomain = domainIndex.isInside(leafBox);
                    std::uint32_t below = 0;
                    if (leafFloats(values.data(), data, wholeInDomain, below)) [[unlikely]] {
                        std::lock_guard<std::mutex> lock(badMutex);
                        for (int i = 0; i < 512; ++i)
                            if (!std::isfinite(values[i]) && !nonFinite.exchange(true))
                                badPoint = batch.point(i >> 6, (i >> 3) & 7, i & 7);
                    }
                    if (!wholeInDomain && domainIndex.hasOverlap(leafBox)) {
                        for (int i = 0; i < 512; ++i)
                            below += data[i] < 0.0f && domainIndex.isInside(lo + Coord(i >> 6, (i >> 3) & 7, i & 7));
                    }
                    belowPerLeaf[n] = below;
                    if (options.leafVisitor)
                        options.leafVisitor(lo, data);
                    else
                        leaves[n] = std::move(leaf);
                }
                made += run.count;
            }
            progress.add(made);
        });
    }
    if (nonFinite) {
        std::ostringstream msg;
        msg << "the field is not finite (NaN or infinity) at (" << badPoint[0] << ", " << badPoint[1] << ", "
            << badPoint[2] << "): check divisions, logarithms and square roots in the recipe's fields";
        throw JobError(msg.str());
    }

    auto grid = openvdb::FloatGrid::create(options.outsideValue);
    grid->setTransform(domain.transform());
    auto& tree = grid->tree();
    for (std::size_t b = 0; b < blocks.size(); ++b) {
        if (results[b].insideTile) tree.addTile(2, blocks[b], options.insideValue, true);
        for (const Coord& lo : results[b].insideLeafTiles) tree.addTile(1, lo, options.insideValue, true);
    }
    for (auto& leaf : leaves) tree.addLeaf(leaf.release());
    if (stats) {
        // Inside tiles hold insideValue: below zero when it is negative.
        auto tileVoxels = [&](const Coord& lo, int size) {
            CoordBBox box(lo, lo + Coord(size - 1));
            box.intersect(domainIndex);
            return box.empty() ? std::uint64_t(0) : std::uint64_t(box.volume());
        };
        for (std::size_t b = 0; b < blocks.size() && options.insideValue < 0.0f; ++b) {
            if (results[b].insideTile) s.domainVoxelsBelowZero += tileVoxels(blocks[b], kBlockDim);
            for (const Coord& lo : results[b].insideLeafTiles) s.domainVoxelsBelowZero += tileVoxels(lo, kLeafDim);
        }
        for (const std::uint32_t below : belowPerLeaf) s.domainVoxelsBelowZero += below;
        s.estimatedBytes = s.leaves * bytesPerLeaf + beside;
        *stats = s;
    }
    return grid;
}

int stackLeavesFor(const Domain& domain, int most)
{
    const long height = std::max(1, domain.dims.z());
    int best = 1;
    double bestCost = std::numeric_limits<double>::infinity();
    for (int s = 1; s <= std::min(most, kBlockDim / kLeafDim); s *= 2) {
        const long stack = long(kLeafDim) * s;
        const double cost = double((height + stack - 1) / stack * stack) * (1.0 + 1.0 / s);
        if (cost <= bestCost) best = s, bestCost = cost;
    }
    return best;
}

}  // namespace voxlat
