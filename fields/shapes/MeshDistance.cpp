#include "fields/shapes/MeshDistance.h"

#include "fields/core/Scratch.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace voxlat {

namespace {
constexpr int kBlock = 8;
int blockOf(int i)
{
    return i >= 0 ? i / kBlock : -((-i + kBlock - 1) / kBlock);
}
}  // namespace

MeshDistance::MeshDistance(openvdb::FloatGrid::ConstPtr grid, std::optional<Box3> support)
    : mGrid(std::move(grid)), mSupport(support)
{
    static std::atomic<std::uint64_t> made{0};
    mId = ++made;
    const auto& xform = mGrid->transform();
    if (!xform.isLinear() || !xform.hasUniformScale())
        throw std::invalid_argument("MeshDistance needs a grid with a uniform linear transform");
    mVoxel = xform.voxelSize()[0];
    mOrigin = xform.indexToWorld(openvdb::Vec3d(0.0));
    mBackground = mGrid->background();

    // Min / max of every 8^3 block of samples over the grid's leaves (and the tiles between
    // them), one block of background around.
    openvdb::CoordBBox leafBox;
    if (!mGrid->tree().evalLeafBoundingBox(leafBox) || leafBox.empty()) return;
    mBlockMin = openvdb::Coord(blockOf(leafBox.min().x()), blockOf(leafBox.min().y()), blockOf(leafBox.min().z())) -
                openvdb::Coord(1);
    const openvdb::Coord blockMax =
        openvdb::Coord(blockOf(leafBox.max().x()), blockOf(leafBox.max().y()), blockOf(leafBox.max().z())) +
        openvdb::Coord(1);
    mBlockDims = blockMax - mBlockMin + openvdb::Coord(1);
    const std::size_t count = std::size_t(mBlockDims.x()) * mBlockDims.y() * mBlockDims.z();
    mBlockLo.assign(count, mBackground);
    mBlockHi.assign(count, mBackground);
    tbb::parallel_for(tbb::blocked_range<int>(0, mBlockDims.x()), [&](const tbb::blocked_range<int>& range) {
        auto acc = mGrid->getConstAccessor();
        for (int bx = range.begin(); bx != range.end(); ++bx)
            for (int by = 0; by < mBlockDims.y(); ++by)
                for (int bz = 0; bz < mBlockDims.z(); ++bz) {
                    const openvdb::Coord block = mBlockMin + openvdb::Coord(bx, by, bz);
                    const openvdb::Coord origin(block.x() * kBlock, block.y() * kBlock, block.z() * kBlock);
                    const std::size_t n = (std::size_t(bx) * mBlockDims.y() + by) * mBlockDims.z() + bz;
                    if (const auto* leaf = acc.probeConstLeaf(origin)) {
                        const float* data = leaf->buffer().data();
                        const auto [lo, hi] = std::minmax_element(data, data + 512);
                        mBlockLo[n] = *lo;
                        mBlockHi[n] = *hi;
                    } else {
                        mBlockLo[n] = mBlockHi[n] = acc.getValue(origin);  // a tile or the background
                    }
                }
    });
}

template <typename Accessor>
double MeshDistance::sample(Accessor& acc, const Vec3d& p, Vec3d* grad) const
{
    const Vec3d x = (p - mOrigin) / mVoxel;
    const openvdb::Coord i0(int(std::floor(x[0])), int(std::floor(x[1])), int(std::floor(x[2])));
    const double fx = x[0] - i0.x(), fy = x[1] - i0.y(), fz = x[2] - i0.z();
    double v[2][2][2];
    for (int a = 0; a < 2; ++a)
        for (int b = 0; b < 2; ++b)
            for (int c = 0; c < 2; ++c) v[a][b][c] = acc.getValue(i0.offsetBy(a, b, c));
    // Along z, then y, then x.
    double e[2][2], de[2][2];
    for (int a = 0; a < 2; ++a)
        for (int b = 0; b < 2; ++b) {
            e[a][b] = v[a][b][0] + fz * (v[a][b][1] - v[a][b][0]);
            de[a][b] = v[a][b][1] - v[a][b][0];
        }
    const double f0 = e[0][0] + fy * (e[0][1] - e[0][0]), f1 = e[1][0] + fy * (e[1][1] - e[1][0]);
    if (grad) {
        const double dz0 = de[0][0] + fy * (de[0][1] - de[0][0]), dz1 = de[1][0] + fy * (de[1][1] - de[1][0]);
        const double dy0 = e[0][1] - e[0][0], dy1 = e[1][1] - e[1][0];
        *grad = Vec3d(f1 - f0, dy0 + fx * (dy1 - dy0), dz0 + fx * (dz1 - dz0)) / mVoxel;
    }
    return f0 + fx * (f1 - f0);
}

void MeshDistance::values(std::span<const Vec3d> points, std::span<double> out) const
{
    auto acc = mGrid->getConstAccessor();
    for (std::size_t n = 0; n < points.size(); ++n) out[n] = sample(acc, points[n], nullptr);
}

void MeshDistance::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    auto acc = mGrid->getConstAccessor();
    for (std::size_t n = 0; n < points.size(); ++n) out[n] = sample(acc, points[n], &grad[n]);
}

void MeshDistance::gridValues(const GridBatch& batch, std::span<double> out) const
{
    if (!lookUpGrid(batch, out)) interpolateGrid(batch, out, 0, nullptr);
}

bool MeshDistance::lookUpGrid(const GridBatch& batch, std::span<double> out) const
{
    const Vec3d first = (batch.origin - mOrigin) / mVoxel;
    bool onSamples = true;
    for (int a = 0; a < 3; ++a) onSamples = onSamples && std::abs(first[a] - std::round(first[a])) <= 1e-6;
    // Spacing in whole voxels (a coarse pass): every point is a sample, looked up alone (the
    // interpolation at a sample gives the sample).
    const double stride = std::round(batch.spacing[0] / mVoxel);
    bool strided = onSamples && stride >= 2.0;
    for (int a = 0; a < 3; ++a) {
        strided = strided && std::abs(batch.spacing[a] - stride * mVoxel) <= 1e-9 * mVoxel;
        onSamples = onSamples && std::abs(batch.spacing[a] - mVoxel) <= 1e-9 * mVoxel;
    }
    if (strided) {
        const int step = int(stride);
        const openvdb::Coord base(int(std::round(first[0])), int(std::round(first[1])), int(std::round(first[2])));
        auto acc = mGrid->getConstAccessor();
        std::size_t n = 0;
        for (int i = 0; i < batch.nx; ++i)
            for (int j = 0; j < batch.ny; ++j)
                for (int k = 0; k < batch.nz; ++k, ++n)
                    out[n] = acc.getValue(base.offsetBy(i * step, j * step, k * step));
        return true;
    }
    if (!onSamples) return false;
    const openvdb::Coord base(int(std::round(first[0])), int(std::round(first[1])), int(std::round(first[2])));
    const openvdb::Coord last = base.offsetBy(batch.nx - 1, batch.ny - 1, batch.nz - 1);
    auto acc = mGrid->getConstAccessor();
    // One lookup per 8^3 leaf of the grid the batch overlaps, then its values straight from the
    // leaf's buffer (a leaf's value is its buffer's, active or not; elsewhere a tile's value).
    using Leaf = openvdb::FloatTree::LeafNodeType;
    const int sj = batch.nz, si = batch.ny * batch.nz;
    const openvdb::Coord leafLo = base & ~(Leaf::DIM - 1), leafHi = last & ~(Leaf::DIM - 1);
    for (int lx = leafLo.x(); lx <= leafHi.x(); lx += Leaf::DIM)
        for (int ly = leafLo.y(); ly <= leafHi.y(); ly += Leaf::DIM)
            for (int lz = leafLo.z(); lz <= leafHi.z(); lz += Leaf::DIM) {
                const openvdb::Coord leafOrigin(lx, ly, lz);
                const openvdb::Coord lo = openvdb::Coord::maxComponent(leafOrigin, base);
                const openvdb::Coord hi = openvdb::Coord::minComponent(leafOrigin.offsetBy(Leaf::DIM - 1), last);
                if (const Leaf* leaf = acc.probeConstLeaf(leafOrigin)) {
                    const float* data = leaf->buffer().data();
                    for (int x = lo.x(); x <= hi.x(); ++x)
                        for (int y = lo.y(); y <= hi.y(); ++y) {
                            const float* row = data + Leaf::coordToOffset(openvdb::Coord(x, y, lo.z()));
                            double* dst = out.data() + (x - base.x()) * si + (y - base.y()) * sj - base.z();
                            for (int z = lo.z(); z <= hi.z(); ++z) dst[z] = row[z - lo.z()];
                        }
                } else {
                    const double value = acc.getValue(leafOrigin);
                    for (int x = lo.x(); x <= hi.x(); ++x)
                        for (int y = lo.y(); y <= hi.y(); ++y) {
                            double* dst = out.data() + (x - base.x()) * si + (y - base.y()) * sj - base.z();
                            for (int z = lo.z(); z <= hi.z(); ++z) dst[z] = value;
                        }
                }
            }
    return true;
}

void MeshDistance::gatherSamples(const openvdb::Coord& lo, const openvdb::Coord& hi, double* dst) const
{
    // Layout [x][y][z] over the index box [lo, hi]; a leaf's values from its buffer (active or
    // not, as getValue), elsewhere a tile's or the background's value.
    using Leaf = openvdb::FloatTree::LeafNodeType;
    const int sz = hi.z() - lo.z() + 1, sy = hi.y() - lo.y() + 1;
    auto acc = mGrid->getConstAccessor();
    const openvdb::Coord leafLo = lo & ~(Leaf::DIM - 1), leafHi = hi & ~(Leaf::DIM - 1);
    for (int lx = leafLo.x(); lx <= leafHi.x(); lx += Leaf::DIM)
        for (int ly = leafLo.y(); ly <= leafHi.y(); ly += Leaf::DIM)
            for (int lz = leafLo.z(); lz <= leafHi.z(); lz += Leaf::DIM) {
                const openvdb::Coord leafOrigin(lx, ly, lz);
                const openvdb::Coord a = openvdb::Coord::maxComponent(leafOrigin, lo);
                const openvdb::Coord b = openvdb::Coord::minComponent(leafOrigin.offsetBy(Leaf::DIM - 1), hi);
                const Leaf* leaf = acc.probeConstLeaf(leafOrigin);
                const double value = leaf ? 0.0 : double(acc.getValue(leafOrigin));
                for (int x = a.x(); x <= b.x(); ++x)
                    for (int y = a.y(); y <= b.y(); ++y) {
                        double* row = dst + (std::size_t(x - lo.x()) * sy + (y - lo.y())) * sz - lo.z();
                        if (leaf) {
                            const float* src = leaf->buffer().data() + Leaf::coordToOffset(openvdb::Coord(x, y, a.z()));
                            for (int z = a.z(); z <= b.z(); ++z) row[z] = double(src[z - a.z()]);
                        } else {
                            for (int z = a.z(); z <= b.z(); ++z) row[z] = value;
                        }
                    }
            }
}

bool MeshDistance::interpolateGrid(const GridBatch& batch, std::span<double> out, int tile, Interval* tileRange) const
{
    // sample() per point, separated by axis: the points' index coordinates per axis (the same
    // expressions as batch.point() and sample(), so the same doubles), the samples of the index
    // box the stencils cover gathered once, interpolated along z per (x, y) sample, then along y
    // per (x sample, row), then along x per point. Each value is sample()'s own arithmetic in its
    // own order: the same doubles as the point path.
    const int n[3] = {batch.nx, batch.ny, batch.nz};
    // Per axis and point: its cell's first sample (a whole number) and its fraction.
    ScratchLease axes(2 * std::size_t(n[0] + n[1] + n[2]));
    double* frac[3];
    double* cell[3];
    int lo[3], hi[3];
    {
        double* f = axes.data();
        for (int a = 0; a < 3; ++a) {
            frac[a] = f;
            cell[a] = f + n[a];
            f += 2 * n[a];
            lo[a] = std::numeric_limits<int>::max();
            hi[a] = std::numeric_limits<int>::lowest();
            for (int m = 0; m < n[a]; ++m) {
                const double x = (batch.origin[a] + m * batch.spacing[a] - mOrigin[a]) / mVoxel;
                const int i0 = int(std::floor(x));
                frac[a][m] = x - i0;
                cell[a][m] = i0;
                lo[a] = std::min(lo[a], i0);
                hi[a] = std::max(hi[a], i0 + 1);
            }
        }
    }
    const std::size_t dx = std::size_t(hi[0] - lo[0]) + 1, dy = std::size_t(hi[1] - lo[1]) + 1,
                      dz = std::size_t(hi[2] - lo[2]) + 1;
    // Sparse points (a coarse pass between the grid's samples): point by point.
    if (dx * dy * dz > 4 * batch.size() + 64) {
        FieldNode::gridValues(batch, out);
        return false;
    }
    ScratchLease samples(dx * dy * dz + dx * dy + dx * std::size_t(n[1]));
    double* v = samples.data();
    double* e = v + dx * dy * dz;  // along z: [x][y]
    double* f = e + dx * dy;       // then along y: [x][row]
    gatherSamples(openvdb::Coord(lo[0], lo[1], lo[2]), openvdb::Coord(hi[0], hi[1], hi[2]), v);
    if (tileRange) {
        // A plane's tiles: the interpolant over a footprint stays within the samples of the cells
        // it covers.
        const PlaneTiles tiles = PlaneTiles::of(batch, tile);
        auto span = [&](int a, double from, double to, int& i0, int& i1) {
            i0 = std::clamp(int(std::floor((from - mOrigin[a]) / mVoxel)), lo[a], hi[a]);
            i1 = std::clamp(int(std::floor((to - mOrigin[a]) / mVoxel)) + 1, lo[a], hi[a]);
        };
        const int z0 = int(cell[2][0]) - lo[2];
        for (int a = 0; a < tiles.nx; ++a)
            for (int b = 0; b < tiles.ny; ++b) {
                const Box3 foot = tiles.footprint(batch, a, b);
                int x0, x1, y0, y1;
                span(0, foot.min.x(), foot.max.x(), x0, x1);
                span(1, foot.min.y(), foot.max.y(), y0, y1);
                double vlo = std::numeric_limits<double>::infinity(), vhi = -vlo;
                for (int x = x0; x <= x1; ++x)
                    for (int y = y0; y <= y1; ++y)
                        for (int z = z0; z <= z0 + 1; ++z) {
                            const double w = v[(std::size_t(x - lo[0]) * dy + (y - lo[1])) * dz + z];
                            vlo = std::min(vlo, w);
                            vhi = std::max(vhi, w);
                        }
                tileRange[std::size_t(a) * tiles.ny + b] = Interval{vlo, vhi};
            }
    }
    for (int k = 0; k < n[2]; ++k) {
        const int z = int(cell[2][k]) - lo[2];
        const double fz = frac[2][k];
        for (std::size_t xy = 0; xy < dx * dy; ++xy) {
            const double* s = v + xy * dz + z;
            e[xy] = s[0] + fz * (s[1] - s[0]);
        }
        for (std::size_t x = 0; x < dx; ++x)
            for (int j = 0; j < n[1]; ++j) {
                const double* s = e + x * dy + (int(cell[1][j]) - lo[1]);
                f[x * n[1] + j] = s[0] + frac[1][j] * (s[1] - s[0]);
            }
        for (int i = 0; i < n[0]; ++i) {
            const double* f0 = f + std::size_t(int(cell[0][i]) - lo[0]) * n[1];
            const double* f1 = f0 + n[1];
            const double fx = frac[0][i];
            double* dst = out.data() + std::size_t(i) * n[1] * n[2] + k;
            for (int j = 0; j < n[1]; ++j) dst[std::size_t(j) * n[2]] = f0[j] + fx * (f1[j] - f0[j]);
        }
    }
    return true;
}

void MeshDistance::planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                               std::span<signed char> side, std::span<const TileNeed> need) const
{
    const std::size_t tiles = PlaneTiles::of(plane, tile).size(), n = plane.size();
    const bool decidable = tiles > 0 && plane.spacing.x() > 0.0 && plane.spacing.y() > 0.0;
    std::fill(side.begin(), side.begin() + tiles, static_cast<signed char>(0));
    if (lookUpGrid(plane, out)) return;
    if (!decidable) {
        interpolateGrid(plane, out, 0, nullptr);
        return;
    }
    // A part is read several times per plane (an infill's skin, its core, and again where a
    // boolean asks for exact values): the thread's last plane of this grid is kept, its values
    // and each tile's range of samples (which do not depend on the band).
    struct Memo {
        std::uint64_t id = 0;
        double key[6] = {};
        int nx = 0, ny = 0, tile = 0;
        bool interpolated = false;
        std::vector<double> values;
        std::vector<Interval> ranges;
    };
    thread_local Memo memo;
    const double key[6] = {plane.origin.x(),  plane.origin.y(),  plane.origin.z(),
                           plane.spacing.x(), plane.spacing.y(), plane.spacing.z()};
    if (!(memo.id == mId && std::equal(key, key + 6, memo.key) && memo.nx == plane.nx && memo.ny == plane.ny &&
          memo.tile == tile)) {
        memo.id = 0;  // not valid while it is made (an exception leaves it so)
        memo.values.resize(n);
        memo.ranges.resize(tiles);
        memo.interpolated = interpolateGrid(plane, memo.values, tile, memo.ranges.data());
        std::copy(key, key + 6, memo.key);
        memo.nx = plane.nx;
        memo.ny = plane.ny;
        memo.tile = tile;
        memo.id = mId;
    }
    std::copy(memo.values.begin(), memo.values.end(), out.begin());
    if (!memo.interpolated) return;
    for (std::size_t t = 0; t < tiles; ++t) {
        if (needOf(need, t) != TileNeed::Decide) continue;
        // By rounding the interpolant stays within 1e-12 of its samples' magnitude.
        const Interval r = memo.ranges[t];
        const double slack = 1e-12 * (std::max(std::abs(r.lo), std::abs(r.hi)) + finiteScale(band));
        side[t] = static_cast<signed char>(r.lo > band.hi + slack ? 1 : r.hi < band.lo - slack ? -1 : 0);
    }
}

Interval MeshDistance::bound(const Box3& box) const
{
    // Index range of every interpolation stencil with a point in the box.
    openvdb::Coord lo, hi;
    for (int a = 0; a < 3; ++a) {
        lo[a] = int(std::floor((box.min[a] - mOrigin[a]) / mVoxel)) - 1;
        hi[a] = int(std::floor((box.max[a] - mOrigin[a]) / mVoxel)) + 2;
    }
    float vlo = std::numeric_limits<float>::max(), vhi = std::numeric_limits<float>::lowest();
    bool outsideArray = mBlockLo.empty();
    openvdb::Coord blo, bhi;
    for (int a = 0; a < 3; ++a) {
        blo[a] = blockOf(lo[a]) - mBlockMin[a];
        bhi[a] = blockOf(hi[a]) - mBlockMin[a];
        if (blo[a] < 0 || bhi[a] >= mBlockDims[a]) outsideArray = true;
        blo[a] = std::max(blo[a], 0);
        bhi[a] = std::min(bhi[a], mBlockDims[a] - 1);
        if (blo[a] > bhi[a]) outsideArray = true;
    }
    if (outsideArray) vlo = vhi = mBackground;
    if (!mBlockLo.empty() && blo.x() <= bhi.x() && blo.y() <= bhi.y() && blo.z() <= bhi.z())
        for (int x = blo.x(); x <= bhi.x(); ++x)
            for (int y = blo.y(); y <= bhi.y(); ++y) {
                const std::size_t row = (std::size_t(x) * mBlockDims.y() + y) * mBlockDims.z();
                for (int z = blo.z(); z <= bhi.z(); ++z) {
                    vlo = std::min(vlo, mBlockLo[row + z]);
                    vhi = std::max(vhi, mBlockHi[row + z]);
                }
            }
    return {double(vlo), double(vhi)};
}

}  // namespace voxlat
