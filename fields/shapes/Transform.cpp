#include "fields/shapes/Transform.h"

#include <array>
#include <cmath>
#include <limits>
#include <numbers>
#include <stdexcept>

namespace voxlat {

TransformField::TransformField(FieldPtr child, const Mat3d& linear, const Vec3d& translation)
    : mChild(std::move(child)), mTranslation(translation)
{
    if (std::abs(linear.det()) < 1e-12) throw std::invalid_argument("transform is singular (a zero scale?)");
    mInverse = linear.inverse();
    mDiagonal = true;
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            if (r != c && mInverse(r, c) != 0.0) mDiagonal = false;
}

Mat3d TransformField::rotation(const Vec3d& axis, double degrees)
{
    if (axis.length() <= 0.0) throw std::invalid_argument("rotation axis has zero length");
    const Vec3d u = axis.unit();
    const double a = degrees * std::numbers::pi / 180.0, c = std::cos(a), s = std::sin(a), t = 1.0 - c;
    // Rodrigues' rotation matrix about the unit axis u.
    return Mat3d(t * u[0] * u[0] + c, t * u[0] * u[1] - s * u[2], t * u[0] * u[2] + s * u[1],
                 t * u[0] * u[1] + s * u[2], t * u[1] * u[1] + c, t * u[1] * u[2] - s * u[0],
                 t * u[0] * u[2] - s * u[1], t * u[1] * u[2] + s * u[0], t * u[2] * u[2] + c);
}

void TransformField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    std::array<Vec3d, kBatchSize> local;
    forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
        for (std::size_t i = 0; i < n; ++i) local[i] = toLocal(points[b + i]);
        mChild->values(std::span<const Vec3d>(local.data(), n), out.subspan(b, n));
    });
}

void TransformField::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    std::array<Vec3d, kBatchSize> local;
    const Mat3d inverseTranspose = mInverse.transpose();
    forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
        for (std::size_t i = 0; i < n; ++i) local[i] = toLocal(points[b + i]);
        mChild->gradients(std::span<const Vec3d>(local.data(), n), out.subspan(b, n), grad.subspan(b, n));
        // Chain rule: grad_world = A^-T grad_local.
        for (std::size_t i = 0; i < n; ++i) grad[b + i] = inverseTranspose * grad[b + i];
    });
}

void TransformField::gridValues(const GridBatch& batch, std::span<double> out) const
{
    if (!mDiagonal) {
        FieldNode::gridValues(batch, out);
        return;
    }
    GridBatch local = batch;
    local.origin = toLocal(batch.origin);
    for (int a = 0; a < 3; ++a) local.spacing[a] = mInverse(a, a) * batch.spacing[a];
    mChild->gridValues(local, out);
}

double TransformField::period(int axis) const
{
    // A step P along the world axis moves the child's point by P times the inverse's column:
    // a period when that column points along one child axis b (P |inverse(b, axis)| = child period).
    // Entries below 1e-12 of the column's largest are the rounding of a rotation matrix's zeros.
    const double largest =
        std::max({std::abs(mInverse(0, axis)), std::abs(mInverse(1, axis)), std::abs(mInverse(2, axis))});
    int along = -1;
    for (int b = 0; b < 3; ++b) {
        if (std::abs(mInverse(b, axis)) <= 1e-12 * largest) continue;
        if (along >= 0) return kNoPeriod;
        along = b;
    }
    if (along < 0) return kNoPeriod;
    return mChild->period(along) / std::abs(mInverse(along, axis));
}

Interval TransformField::bound(const Box3& box) const
{
    Box3 local{Vec3d(std::numeric_limits<double>::max()), Vec3d(std::numeric_limits<double>::lowest())};
    for (int corner = 0; corner < 8; ++corner) {
        const Vec3d p(corner & 1 ? box.max[0] : box.min[0], corner & 2 ? box.max[1] : box.min[1],
                      corner & 4 ? box.max[2] : box.min[2]);
        const Vec3d q = toLocal(p);
        local.min = openvdb::math::minComponent(local.min, q);
        local.max = openvdb::math::maxComponent(local.max, q);
    }
    return mChild->bound(local);
}

std::optional<Box3> TransformField::support() const
{
    const std::optional<Box3> local = mChild->support();
    if (!local) return std::nullopt;
    const Mat3d forward = mInverse.inverse();
    Box3 world{Vec3d(std::numeric_limits<double>::max()), Vec3d(std::numeric_limits<double>::lowest())};
    for (int corner = 0; corner < 8; ++corner) {
        const Vec3d p(corner & 1 ? local->max[0] : local->min[0], corner & 2 ? local->max[1] : local->min[1],
                      corner & 4 ? local->max[2] : local->min[2]);
        const Vec3d q = forward * p + mTranslation;
        world.min = openvdb::math::minComponent(world.min, q);
        world.max = openvdb::math::maxComponent(world.max, q);
    }
    return world;
}

}  // namespace voxlat
