#include "fields/frames/SkinMap.h"

#include <array>
#include <cmath>

namespace voxlat {

namespace {
}  // namespace

SkinMapField::SkinMapField(FieldPtr child, std::shared_ptr<const SkinCells> cells, const Vec3d& cellSize,
                           double outside)
    : mChild(std::move(child)), mCells(std::move(cells)), mCell(cellSize), mOutside(outside)
{
    const double e = mCells->extension();
    mInside = mChild->bound(Box3{Vec3d(-1e-6 * mCell[0], -1e-6 * mCell[1], -(e + 1e-6) * mCell[2]),
                                 Vec3d((1 + 1e-6) * mCell[0], (1 + 1e-6) * mCell[1], (1 + 1e-6) * mCell[2])});
}

bool SkinMapField::toCell(const Vec3d& p, Vec3d& q) const
{
    Vec3d t;
    if (mCells->locate(p, t) < 0) return false;
    q = Vec3d(t[0] * mCell[0], t[1] * mCell[1], t[2] * mCell[2]);
    return true;
}

void SkinMapField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    std::array<Vec3d, kBatchSize> q;
    std::array<std::uint32_t, kBatchSize> at;
    std::array<double, kBatchSize> v;
    forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
        std::size_t m = 0;
        for (std::size_t i = 0; i < n; ++i) {
            if (toCell(points[b + i], q[m]))
                at[m++] = std::uint32_t(i);
            else
                out[b + i] = mOutside;
        }
        if (m == 0) return;
        mChild->values(std::span<const Vec3d>(q.data(), m), std::span<double>(v.data(), m));
        for (std::size_t j = 0; j < m; ++j) out[b + at[j]] = v[j];
    });
}

void SkinMapField::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    std::array<Vec3d, kBatchSize> q, g;
    std::array<std::array<Vec3d, 3>, kBatchSize> jac;
    std::array<std::uint32_t, kBatchSize> at;
    std::array<double, kBatchSize> v;
    forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
        std::size_t m = 0;
        for (std::size_t i = 0; i < n; ++i) {
            Vec3d t;
            const int h = mCells->locate(points[b + i], t);
            if (h < 0) {
                out[b + i] = mOutside;
                grad[b + i] = Vec3d(0.0);
                continue;
            }
            mCells->map(std::size_t(h), t, &jac[m]);
            q[m] = Vec3d(t[0] * mCell[0], t[1] * mCell[1], t[2] * mCell[2]);
            at[m++] = std::uint32_t(i);
        }
        if (m == 0) return;
        mChild->gradients(std::span<const Vec3d>(q.data(), m), std::span<double>(v.data(), m),
                          std::span<Vec3d>(g.data(), m));
        for (std::size_t j = 0; j < m; ++j) {
            // d value / d t = c * grad_q; grad_p solves J^T grad_p = d value / d t.
            const Vec3d dt(g[j][0] * mCell[0], g[j][1] * mCell[1], g[j][2] * mCell[2]);
            const auto& J = jac[j];
            // Rows of J^-T are the cross products of J's columns over det J.
            const double det = triple(J[0], J[1], J[2]);
            const Vec3d gp = (dt[0] * J[1].cross(J[2]) + dt[1] * J[2].cross(J[0]) + dt[2] * J[0].cross(J[1])) / det;
            out[b + at[j]] = v[j];
            grad[b + at[j]] = gp;
        }
    });
}

Interval SkinMapField::bound(const Box3& box) const
{
    if (!mCells->touches(box)) return Interval(mOutside);
    return hull(mInside, Interval(mOutside));
}

void SkinRegionField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    for (std::size_t i = 0; i < points.size(); ++i) {
        Vec3d t;
        out[i] = mCells->locate(points[i], t) >= 0 ? -1.0 : 1.0;
    }
}

void SkinRegionField::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    values(points, out);
    for (auto& g : grad.first(points.size())) g = Vec3d(0.0);
}

Interval SkinRegionField::bound(const Box3& box) const
{
    return mCells->touches(box) ? Interval(-1.0, 1.0) : Interval(1.0);
}

}  // namespace voxlat
