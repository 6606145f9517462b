#include "fields/maps/PeriodicTiling.h"

#include <oneapi/tbb/blocked_range.h>
#include <oneapi/tbb/collaborative_call_once.h>
#include <oneapi/tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <mutex>
#include <stdexcept>
#include <unordered_map>

namespace voxlat {

namespace {

/// Grid positions x0 + n h along one axis and the table slot of each: the zone below the box's
/// inner margin and one period kept as they are, positions deeper inside folded onto that
/// period, the zone above kept as it is. Where the child is mirror symmetric about the box's
/// middle, positions above the middle take their images' slots (the high zone is the low zone's
/// image), and within the period each pair of images shares one slot.
struct AxisMap {
    double h = 0.0, x0 = 0.0;
    long n0 = 0, n1 = -1;         ///< covered positions (inclusive)
    std::vector<long> slotOf;     ///< per covered position n (index n - n0)
    std::vector<long> positions;  ///< per slot: the position it holds (ascending)
    long size() const { return long(positions.size()); }

    /// The table slot of position n, or -1 outside the covered range.
    long slot(long n) const { return n < n0 || n > n1 ? -1 : slotOf[std::size_t(n - n0)]; }
    /// The position a slot holds.
    long position(long t) const { return positions[std::size_t(t)]; }
};

/// Grids a tiling keeps tables for.
constexpr std::size_t kMaxTables = 4;

/// A leaf of padding beyond the box, so that leaves straddling the box's faces are covered.
constexpr long kPad = 8;

/// Values a table block's brick holds (blocks are up to 8 slots per axis).
constexpr std::size_t kBrick = 512;

AxisMap makeAxis(double h, double x0, double lo, double hi, double period, double reach, bool mirror)
{
    AxisMap m;
    m.h = h;
    m.x0 = x0;
    m.n0 = long(std::floor((lo - x0) / h)) - kPad;
    m.n1 = long(std::ceil((hi - x0) / h)) + kPad;
    // Folding: positions nA..nB lie at least `reach` (plus a voxel of safety on each side, so
    // rounding never crosses the margin) inside both faces.
    long nA = 0, nB = -1, folds = 0;
    if (period > 0.0) {
        const double steps = period / h;
        const long whole = std::lround(steps);
        if (whole >= 1 && std::abs(steps - double(whole)) <= 1e-9 * steps) {
            nA = long(std::ceil((lo + reach - x0) / h)) + 1;
            nB = long(std::floor((hi - reach - x0) / h)) - 1;
            if (nB - nA + 1 > whole) folds = whole;
        }
    }
    // Mirror: position n's image about the middle is M - n, when that is a grid position.
    const double images = (lo + hi - 2.0 * x0) / h;
    const long M = std::lround(images);
    const bool mirrored = mirror && std::abs(images - double(M)) <= 1e-6;
    auto fold = [&](long n) { return folds > 0 && n >= nA + folds && n <= nB ? nA + (n - nA) % folds : n; };
    auto canonical = [&](long n) {
        if (mirrored && M - n >= m.n0 && M - n < n) n = M - n;
        n = fold(n);
        // Within the period, the field is symmetric about the middle's images too (periodic
        // between the zones and mirror symmetric): a pair of images shares the smaller's slot.
        if (mirrored && folds > 0 && n >= nA && n < nA + folds && M - n >= nA && M - n <= nB)
            n = std::min(n, nA + (M - n - nA) % folds);
        return n;
    };
    std::vector<long> of(std::size_t(m.n1 - m.n0 + 1));
    for (long n = m.n0; n <= m.n1; ++n) {
        of[std::size_t(n - m.n0)] = canonical(n);
        if (of[std::size_t(n - m.n0)] == n) m.positions.push_back(n);
    }
    m.slotOf.resize(of.size());
    for (std::size_t i = 0; i < of.size(); ++i)
        m.slotOf[i] = long(std::lower_bound(m.positions.begin(), m.positions.end(), of[i]) - m.positions.begin());
    return m;
}

}  // namespace

struct PeriodicTiling::BoundCache {
    using Key = std::array<long long, 6>;
    struct Hash {
        std::size_t operator()(const Key& k) const
        {
            std::size_t h = 1469598103934665603ull;
            for (long long v : k) h = (h ^ std::size_t(v)) * 1099511628211ull;
            return h;
        }
    };
    static constexpr std::size_t kShards = 64;
    static constexpr std::size_t kMaxPerShard = 1 << 16;
    struct Shard {
        std::mutex mutex;
        std::unordered_map<Key, Interval, Hash> map;
    };
    std::array<Shard, kShards> shards;
};

struct PeriodicTiling::Table {
    std::array<AxisMap, 3> axis;
    bool useful = false;
    /// Block by block (x, y, z block order), each block's values in 8^3 slots (x, y, z order):
    /// a batch reads a few contiguous bricks instead of 64 rows strided across the table.
    std::vector<double> values;
    tbb::collaborative_once_flag once;
    /// Per axis, blocks of up to 8 slots whose positions are consecutive (start, length), and
    /// the block of each slot.
    std::array<std::vector<std::pair<long, int>>, 3> runs;
    std::array<std::vector<std::uint32_t>, 3> runOf;
    /// One flag per block: a block is evaluated the first time a batch needs it (only blocks
    /// near the surface are), by one gridValues() call on positions fixed by the grid, so its
    /// values do not depend on which thread comes first.
    std::unique_ptr<std::once_flag[]> blockDone;
};

PeriodicTiling::PeriodicTiling(FieldPtr child, const Box3& box, const Vec3d& period, double reach,
                               std::array<bool, 3> mirror)
    : mChild(std::move(child)),
      mBox(box),
      mPeriod(period),
      mReach(reach),
      mMirror(mirror),
      mBounds(std::make_unique<BoundCache>())
{
    for (int a = 0; a < 3; ++a)
        if (!(period[a] >= 0.0) || !(box.max[a] >= box.min[a]))
            throw std::invalid_argument("a periodic tiling needs periods >= 0 and a box");
    if (!(period[0] > 0.0 || period[1] > 0.0 || period[2] > 0.0))
        throw std::invalid_argument("a periodic tiling needs a positive period along some axis");
}

PeriodicTiling::~PeriodicTiling() = default;

void PeriodicTiling::values(std::span<const Vec3d> points, std::span<double> out) const
{
    mChild->values(points, out);
}

void PeriodicTiling::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    mChild->gradients(points, out, grad);
}

Interval PeriodicTiling::bound(const Box3& box) const
{
    constexpr double kQuantum = 1e-6;  // mm
    BoundCache::Key key;
    for (int a = 0; a < 3; ++a) {
        double lo = box.min[a], hi = box.max[a];
        const double inner = mBox.min[a] + mReach, outer = mBox.max[a] - mReach;
        if (mPeriod[a] > 0.0 && lo >= inner && hi <= outer && outer - inner >= mPeriod[a]) {
            const double shift = std::floor((lo - inner) / mPeriod[a]) * mPeriod[a];
            lo = std::max(inner, lo - shift);
            hi = std::min(outer, hi - shift);
        }
        if (!(std::abs(lo) < 1e12 && std::abs(hi) < 1e12)) return mChild->bound(box);
        // One quantum out: the snapped box holds the box. Rounded to the nearest quantum first,
        // not down: a box moved by whole periods lands within rounding of a multiple of the
        // quantum (decimal voxels and periods), where floor() would split one box into two keys.
        key[a] = std::llround(lo / kQuantum) - 1;
        key[a + 3] = std::llround(hi / kQuantum) + 1;
    }
    BoundCache::Shard& shard = mBounds->shards[BoundCache::Hash()(key) % BoundCache::kShards];
    {
        std::lock_guard<std::mutex> lock(shard.mutex);
        const auto it = shard.map.find(key);
        if (it != shard.map.end()) return it->second;
    }
    const Box3 snapped{Vec3d(double(key[0]), double(key[1]), double(key[2])) * kQuantum,
                       Vec3d(double(key[3]), double(key[4]), double(key[5])) * kQuantum};
    const Interval b = mChild->bound(snapped);
    std::lock_guard<std::mutex> lock(shard.mutex);
    if (shard.map.size() < BoundCache::kMaxPerShard) shard.map.emplace(key, b);
    return b;
}

std::size_t PeriodicTiling::tabledValues() const
{
    std::lock_guard<std::mutex> lock(mMutex);
    std::size_t n = 0;
    for (const auto& t : mTables)
        if (!t->values.empty()) n += std::size_t(t->axis[0].size() * t->axis[1].size() * t->axis[2].size());
    return n;
}

const PeriodicTiling::Table* PeriodicTiling::table(const GridBatch& batch) const
{
    Table* found = nullptr;
    {
        std::lock_guard<std::mutex> lock(mMutex);
        for (const auto& t : mTables) {
            bool same = true;
            for (int a = 0; a < 3 && same; ++a) {
                const double h = t->axis[a].h;
                const double f = (batch.origin[a] - t->axis[a].x0) / h;
                same = std::abs(batch.spacing[a] - h) <= 1e-12 * h && std::abs(f - std::round(f)) <= 1e-6;
            }
            if (same) {
                found = t.get();
                break;
            }
        }
        // A job uses one or two grids (the result, a density lattice); more means grids that
        // change from batch to batch, where tables would only pile up.
        if (!found && mTables.size() >= kMaxTables) return nullptr;
        if (!found) {
            auto t = std::make_unique<Table>();
            double total = 1.0, folded = 1.0;
            for (int a = 0; a < 3; ++a) {
                const double h = batch.spacing[a];
                // The grid's phase, reduced next to the box and rounded to 2^-20 of a voxel: every
                // batch of the grid gives the same x0, whichever thread comes first.
                const double lo = mBox.min[a];
                double q = (batch.origin[a] - lo) / h;
                q -= std::floor(q);
                q = std::round(q * 1048576.0) / 1048576.0;
                t->axis[a] = makeAxis(h, lo + q * h, lo, mBox.max[a], mPeriod[a], mReach, mMirror[a]);
                total *= double(t->axis[a].n1 - t->axis[a].n0 + 1);
                folded *= double(t->axis[a].size());
            }
            // Worth a table only when folding saves most of the work.
            t->useful = folded < 0.25 * total;
            found = t.get();
            mTables.push_back(std::move(t));
        }
    }
    if (!found->useful) return nullptr;
    tbb::collaborative_call_once(found->once, [&] {
        Table& t = *found;
        for (int a = 0; a < 3; ++a) {
            const AxisMap& m = t.axis[a];
            t.runOf[a].resize(std::size_t(m.size()));
            for (long s = 0; s < m.size();) {
                int len = 1;
                while (len < 8 && s + len < m.size() && m.position(s + len) == m.position(s) + len) ++len;
                for (int i = 0; i < len; ++i) t.runOf[a][std::size_t(s + i)] = std::uint32_t(t.runs[a].size());
                t.runs[a].push_back({s, len});
                s += len;
            }
        }
        const std::size_t blocks = t.runs[0].size() * t.runs[1].size() * t.runs[2].size();
        t.values.assign(blocks * kBrick, 0.0);
        t.blockDone = std::make_unique<std::once_flag[]>(blocks);
    });
    return found;
}

void PeriodicTiling::fillBlock(Table& t, std::size_t bx, std::size_t by, std::size_t bz) const
{
    const auto [s0, l0] = t.runs[0][bx];
    const auto [s1, l1] = t.runs[1][by];
    const auto [s2, l2] = t.runs[2][bz];
    GridBatch g;
    g.spacing = Vec3d(t.axis[0].h, t.axis[1].h, t.axis[2].h);
    g.origin = Vec3d(t.axis[0].x0 + double(t.axis[0].position(s0)) * t.axis[0].h,
                     t.axis[1].x0 + double(t.axis[1].position(s1)) * t.axis[1].h,
                     t.axis[2].x0 + double(t.axis[2].position(s2)) * t.axis[2].h);
    g.nx = l0;
    g.ny = l1;
    g.nz = l2;
    std::array<double, 512> block;
    mChild->gridValues(g, block);
    double* brick = t.values.data() + ((bx * t.runs[1].size() + by) * t.runs[2].size() + bz) * kBrick;
    std::size_t n = 0;
    for (int i = 0; i < l0; ++i)
        for (int j = 0; j < l1; ++j)
            for (int k = 0; k < l2; ++k) brick[(i * 8 + j) * 8 + k] = block[n++];
}

void PeriodicTiling::planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                                 std::span<signed char> side, std::span<const TileNeed> need) const
{
    if (plane.nx < 2 || plane.ny < 2 || plane.nz < 2) {
        planeValuesOf(*mChild, plane, tile, band, out, side, need);
        return;
    }
    gridValues(plane, out);
    std::fill(side.begin(), side.begin() + PlaneTiles::of(plane, tile).size(), static_cast<signed char>(0));
}

void PeriodicTiling::gridValues(const GridBatch& batch, std::span<double> out) const
{
    // A single sample along an axis says nothing about the grid's spacing there (a slice's
    // layer): such batches would each start a table of their own.
    if (batch.nx < 2 || batch.ny < 2 || batch.nz < 2) return mChild->gridValues(batch, out);
    const Table* t = table(batch);
    if (!t) return mChild->gridValues(batch, out);
    const int counts[3] = {batch.nx, batch.ny, batch.nz};
    std::array<std::array<long, 64>, 3> slots;
    for (int a = 0; a < 3; ++a) {
        if (counts[a] > 64) return mChild->gridValues(batch, out);
        const AxisMap& m = t->axis[a];
        const long first = std::lround((batch.origin[a] - m.x0) / m.h);
        for (int i = 0; i < counts[a]; ++i) {
            slots[a][i] = m.slot(first + i);
            if (slots[a][i] < 0) return mChild->gridValues(batch, out);
        }
    }
    // Evaluate the blocks this batch reads that no batch has read before.
    Table& table = const_cast<Table&>(*t);
    const std::size_t ny = table.runs[1].size(), nz = table.runs[2].size();
    std::array<std::uint32_t, 64> rx, ry, rz;
    int cx = 0, cy = 0, cz = 0;
    for (int i = 0; i < batch.nx; ++i)
        if (cx == 0 || rx[cx - 1] != table.runOf[0][slots[0][i]]) rx[cx++] = table.runOf[0][slots[0][i]];
    for (int i = 0; i < batch.ny; ++i)
        if (cy == 0 || ry[cy - 1] != table.runOf[1][slots[1][i]]) ry[cy++] = table.runOf[1][slots[1][i]];
    for (int i = 0; i < batch.nz; ++i)
        if (cz == 0 || rz[cz - 1] != table.runOf[2][slots[2][i]]) rz[cz++] = table.runOf[2][slots[2][i]];
    for (int i = 0; i < cx; ++i)
        for (int j = 0; j < cy; ++j)
            for (int k = 0; k < cz; ++k) {
                const std::size_t b = (rx[i] * ny + ry[j]) * nz + rz[k];
                std::call_once(table.blockDone[b], [&] { fillBlock(table, rx[i], ry[j], rz[k]); });
            }
    // Each slot's part of its value's index: its block's brick and its offset in the block's run.
    const std::size_t brickStride[3] = {ny * nz * kBrick, nz * kBrick, kBrick}, offsetStride[3] = {64, 8, 1};
    std::array<std::array<std::size_t, 64>, 3> part;
    for (int a = 0; a < 3; ++a)
        for (int i = 0; i < counts[a]; ++i) {
            const std::uint32_t run = table.runOf[a][slots[a][i]];
            part[a][i] = run * brickStride[a] + std::size_t(slots[a][i] - table.runs[a][run].first) * offsetStride[a];
        }
    const double* values = t->values.data();
    std::size_t n = 0;
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j) {
            const double* row = values + part[0][i] + part[1][j];
            for (int k = 0; k < batch.nz; ++k) out[n++] = row[part[2][k]];
        }
}

}  // namespace voxlat
