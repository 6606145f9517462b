#include "fields/frames/OrientField.h"

#include "fields/core/Scratch.h"

#include <algorithm>
#include <cmath>

namespace voxlat {

namespace {

/// The largest distance from @a o to a point of @a box (at one of its corners).
double farthest(const Box3& box, const Vec3d& o)
{
    double d2 = 0.0;
    for (int a = 0; a < 3; ++a) d2 += sqr(std::max(std::abs(box.min[a] - o[a]), std::abs(box.max[a] - o[a])));
    return std::sqrt(d2);
}

}  // namespace

OrientField::OrientField(FieldPtr child, std::shared_ptr<const FrameField> frame, const Vec3d& origin)
    : mChild(std::move(child)), mFrame(std::move(frame)), mOrigin(origin)
{
}

void OrientField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
        ScratchLease scratch(12 * n);
        Mat3d* r = scratch.as<Mat3d>();
        Vec3d* q = reinterpret_cast<Vec3d*>(scratch.data() + 9 * n);
        mFrame->frames(points.subspan(b, n), std::span<Mat3d>(r, n));
        for (std::size_t i = 0; i < n; ++i) q[i] = toLocal(points[b + i], r[i]);
        mChild->values(std::span<const Vec3d>(q, n), out.subspan(b, n));
    });
}

void OrientField::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
        ScratchLease scratch(39 * n);
        Mat3d* r = scratch.as<Mat3d>();
        auto* dr = reinterpret_cast<std::array<Mat3d, 3>*>(scratch.data() + 9 * n);
        Vec3d* q = reinterpret_cast<Vec3d*>(scratch.data() + 36 * n);
        mFrame->frameDerivatives(points.subspan(b, n), std::span<Mat3d>(r, n), std::span<std::array<Mat3d, 3>>(dr, n));
        for (std::size_t i = 0; i < n; ++i) q[i] = toLocal(points[b + i], r[i]);
        mChild->gradients(std::span<const Vec3d>(q, n), out.subspan(b, n), grad.subspan(b, n));
        for (std::size_t i = 0; i < n; ++i) {
            // q_j = o_j + sum_a R(a, j) (p - o)_a, so dq_j/dp_k = R(k, j) + sum_a dR_k(a, j) (p - o)_a
            // and d value/dp_k = (R g)_k + (p - o) . (dR_k g).
            const Vec3d g = grad[b + i], offset = points[b + i] - mOrigin;
            Vec3d world = r[i] * g;
            for (int k = 0; k < 3; ++k) world[k] += offset.dot(dr[i][k] * g);
            grad[b + i] = world;
        }
    });
}

void OrientField::gridValues(const GridBatch& batch, std::span<double> out) const
{
    const std::size_t n = batch.size();
    ScratchLease scratch(12 * n);
    Mat3d* r = scratch.as<Mat3d>();
    Vec3d* q = reinterpret_cast<Vec3d*>(scratch.data() + 9 * n);
    mFrame->gridFrames(batch, std::span<Mat3d>(r, n));
    std::size_t i = 0;
    for (int ix = 0; ix < batch.nx; ++ix)
        for (int iy = 0; iy < batch.ny; ++iy)
            for (int iz = 0; iz < batch.nz; ++iz, ++i) q[i] = toLocal(batch.point(ix, iy, iz), r[i]);
    mChild->values(std::span<const Vec3d>(q, n), out);
}

Interval OrientField::bound(const Box3& box) const
{
    // |q - o| = |p - o|: q lies in the ball about o through the box's farthest corner.
    const double reach = farthest(box, mOrigin);
    Box3 local{mOrigin - Vec3d(reach), mOrigin + Vec3d(reach)};
    if (const std::optional<FrameBound> f = mFrame->bound(box)) {
        // Centred form: the box rotated exactly by the frame at its centre c, grown by how far
        // each axis can turn away from it over the box times the reach.
        const Vec3d c = box.center();
        Mat3d rc;
        mFrame->frames(std::span<const Vec3d>(&c, 1), std::span<Mat3d>(&rc, 1));
        for (int j = 0; j < 3; ++j) {
            // q_j - o_j = axis_j(p) . (p - o): its deviation from axis_j(c) . (p - o) is at most
            // |axis_j(p) - axis_j(c)| |p - o|.
            double deviation2 = 0.0;
            for (int row = 0; row < 3; ++row) {
                const Interval e = (*f)[row][j];
                deviation2 += sqr(std::max(std::abs(e.lo - rc(row, j)), std::abs(e.hi - rc(row, j))));
            }
            const double grow = std::sqrt(deviation2) * reach;
            // The interval product R^T (p - o) and the centred form both enclose q_j.
            Interval product(mOrigin[j]), centred(mOrigin[j] - grow, mOrigin[j] + grow);
            for (int a = 0; a < 3; ++a) {
                const Interval offset(box.min[a] - mOrigin[a], box.max[a] - mOrigin[a]);
                product += (*f)[a][j] * offset;
                centred += rc(a, j) * offset;
            }
            for (const Interval& qj : {product, centred}) {
                // Each encloses q; an empty meet can only come from rounding, then keep the other.
                if (qj.hi < local.min[j] || qj.lo > local.max[j]) continue;
                local.min[j] = std::max(local.min[j], qj.lo);
                local.max[j] = std::min(local.max[j], qj.hi);
            }
        }
    }
    return mChild->bound(local);
}

std::optional<Box3> OrientField::support() const
{
    const std::optional<Box3> s = mChild->support();
    if (!s) return std::nullopt;
    const double reach = farthest(*s, mOrigin);
    return Box3{mOrigin - Vec3d(reach), mOrigin + Vec3d(reach)};
}

}  // namespace voxlat
