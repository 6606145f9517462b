#include "fields/struts/TiledInterior.h"

#include "fields/struts/StrutIndex.h"

#include <oneapi/tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>

namespace voxlat {

namespace {

/// Coarse cells at most (a byte each): a finer grid than this is coarsened.
constexpr double kMaxCells = 1 << 24;

}  // namespace

TiledInterior::TiledInterior(FieldPtr exact, FieldPtr same, const std::vector<std::array<Vec3d, 2>>& differing,
                             double reach)
    : mExact(std::move(exact)), mSame(std::move(same)), mReach(reach)
{
    if (differing.empty()) return;
    Vec3d lo(std::numeric_limits<double>::infinity()), hi(-std::numeric_limits<double>::infinity());
    for (const auto& [a, b] : differing)
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min({lo[k], a[k], b[k]});
            hi[k] = std::max({hi[k], a[k], b[k]});
        }
    // Half the reach a cell: a leaf near the segments' capsules is decided to within that.
    mCell = std::max(0.5 * reach, 1e-6);
    auto count = [&](int k) { return long(std::floor((hi[k] - lo[k] + 2.0 * reach) / mCell)) + 3; };
    while (double(count(0)) * double(count(1)) * double(count(2)) > kMaxCells) mCell *= 1.25;
    for (int k = 0; k < 3; ++k) {
        mOrigin[k] = lo[k] - reach - mCell;
        mDims[k] = count(k);
    }
    mNear.assign(std::size_t(mDims[0] * mDims[1] * mDims[2]), 0);
    // Each segment marks the cells its capsule of radius `reach` meets (exact box distances; a
    // cell marked twice is marked alike, so the grid does not depend on the order).
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, differing.size(), 64), [&](const auto& r) {
        for (std::size_t s = r.begin(); s < r.end(); ++s) {
            const auto& [a, b] = differing[s];
            std::array<long, 3> c0, c1;
            for (int k = 0; k < 3; ++k) {
                c0[k] = std::max(0L, long(std::floor((std::min(a[k], b[k]) - reach - mOrigin[k]) / mCell)));
                c1[k] = std::min(mDims[k] - 1, long(std::floor((std::max(a[k], b[k]) + reach - mOrigin[k]) / mCell)));
            }
            for (long z = c0[2]; z <= c1[2]; ++z)
                for (long y = c0[1]; y <= c1[1]; ++y)
                    for (long x = c0[0]; x <= c1[0]; ++x) {
                        std::atomic_ref<std::uint8_t> cell(mNear[std::size_t((z * mDims[1] + y) * mDims[0] + x)]);
                        if (cell.load(std::memory_order_relaxed)) continue;
                        const Vec3d min = mOrigin + Vec3d(double(x), double(y), double(z)) * mCell;
                        if (segmentBoxDistance(a, b, {min, min + Vec3d(mCell)}) <= reach)
                            cell.store(1, std::memory_order_relaxed);
                    }
        }
    });
}

bool TiledInterior::far(const Box3& box) const
{
    if (mNear.empty()) return true;
    std::array<long, 3> c0, c1;
    for (int k = 0; k < 3; ++k) {
        // Cells are closed boxes: a face shared by two cells counts in both.
        c0[k] = std::max(0L, long(std::floor((box.min[k] - mOrigin[k]) / mCell)) - 1);
        c1[k] = std::min(mDims[k] - 1, long(std::floor((box.max[k] - mOrigin[k]) / mCell)) + 1);
        if (c0[k] > c1[k]) return true;  // beyond the grid: no segment within reach
    }
    for (long z = c0[2]; z <= c1[2]; ++z)
        for (long y = c0[1]; y <= c1[1]; ++y)
            for (long x = c0[0]; x <= c1[0]; ++x) {
                if (!mNear[std::size_t((z * mDims[1] + y) * mDims[0] + x)]) continue;
                // A marked cell matters only where it meets the box.
                const Vec3d min = mOrigin + Vec3d(double(x), double(y), double(z)) * mCell, max = min + Vec3d(mCell);
                bool meets = true;
                for (int k = 0; k < 3; ++k) meets = meets && min[k] <= box.max[k] && max[k] >= box.min[k];
                if (meets) return false;
            }
    return true;
}

void TiledInterior::values(std::span<const Vec3d> points, std::span<double> out) const
{
    mExact->values(points, out);
}

void TiledInterior::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    mExact->gradients(points, out, grad);
}

void TiledInterior::gridValues(const GridBatch& batch, std::span<double> out) const
{
    if (batch.nz == 1) {
        mExact->gridValues(batch, out);
        return;
    }
    // Leaves of a stack (8 x 8 x 8m), or the batch as one piece.
    const bool stack = batch.nx == 8 && batch.ny == 8 && batch.nz % 8 == 0 && batch.nz / 8 <= 32;
    const int pieces = stack ? batch.nz / 8 : 1;
    const int depth = stack ? 8 : batch.nz;
    std::uint32_t farLeaves = 0;
    for (int m = 0; m < pieces; ++m) {
        GridBatch leaf = batch;
        leaf.origin[2] += double(m * depth) * batch.spacing[2];
        leaf.nz = depth;
        if (far(leaf.bounds())) farLeaves |= 1u << m;
    }
    const std::uint32_t all = pieces == 32 ? ~0u : (1u << pieces) - 1u;
    if (farLeaves == 0 || farLeaves == all) {
        (farLeaves ? mSame : mExact)->gridValues(batch, out);
        return;
    }
    // Runs of leaves alike, each from its field as a sub-stack.
    std::vector<double> part;
    for (int m = 0; m < pieces;) {
        const bool isFar = farLeaves >> m & 1u;
        int e = m + 1;
        while (e < pieces && bool(farLeaves >> e & 1u) == isFar) ++e;
        GridBatch sub = batch;
        sub.origin[2] += double(m * depth) * batch.spacing[2];
        sub.nz = (e - m) * depth;
        sub.unread = batch.unread >> m & ((e - m) == 32 ? ~0u : (1u << (e - m)) - 1u);
        part.resize(sub.size());
        (isFar ? mSame : mExact)->gridValues(sub, part);
        for (int i = 0; i < batch.nx; ++i)
            for (int j = 0; j < batch.ny; ++j)
                std::copy_n(part.begin() + std::ptrdiff_t((i * sub.ny + j) * sub.nz), sub.nz,
                            out.begin() + std::ptrdiff_t((i * batch.ny + j) * batch.nz + m * depth));
        m = e;
    }
}

Interval TiledInterior::bound(const Box3& box) const
{
    return far(box) ? mSame->bound(box) : mExact->bound(box);
}

void TiledInterior::planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                                std::span<signed char> side, std::span<const TileNeed> need) const
{
    planeValuesOf(*mExact, plane, tile, band, out, side, need);
}

}  // namespace voxlat
