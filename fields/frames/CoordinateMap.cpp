#include "fields/frames/CoordinateMap.h"

#include <array>
#include <cmath>
#include <numbers>
#include <stdexcept>

namespace voxlat {

namespace {
constexpr double kPi = std::numbers::pi;
}

CoordinateMapField::CoordinateMapField(FieldPtr child, FrameKind kind, const Vec3d& center, const Vec3d& axis,
                                       const Vec3d& angularScale)
    : mChild(std::move(child)), mKind(kind), mCenter(center), mAxis(axis), mScale(angularScale)
{
    if (axis.length() <= 0.0) throw std::invalid_argument("frame axis has zero length");
    mAxis.normalize();
    // Any unit vector across the axis starts the angle; v completes a right-handed frame.
    const Vec3d helper = std::abs(mAxis[0]) < 0.9 ? Vec3d(1, 0, 0) : Vec3d(0, 1, 0);
    mU = (helper - helper.dot(mAxis) * mAxis).unit();
    mV = mAxis.cross(mU);
}

Vec3d CoordinateMapField::toFrame(const Vec3d& p, Vec3d* jacobian) const
{
    const Vec3d d = p - mCenter;
    const double x = d.dot(mU), y = d.dot(mV), z = d.dot(mAxis);
    const double rho2 = x * x + y * y, rho = std::sqrt(rho2);
    const double azimuth = std::atan2(y, x);
    if (mKind == FrameKind::Cylinder) {
        if (jacobian) {
            jacobian[0] = rho > 0 ? (x * mU + y * mV) / rho : Vec3d(0.0);
            jacobian[1] = rho2 > 0 ? mScale[1] * (x * mV - y * mU) / rho2 : Vec3d(0.0);
            jacobian[2] = mAxis;
        }
        return {rho, mScale[1] * azimuth, z};
    }
    const double r2 = rho2 + z * z, r = std::sqrt(r2);
    const double polar = std::atan2(rho, z);  // 0 at the +axis pole, pi at the other
    if (jacobian) {
        jacobian[0] = r > 0 ? d / r : Vec3d(0.0);
        jacobian[1] = rho2 > 0 ? mScale[1] * (x * mV - y * mU) / rho2 : Vec3d(0.0);
        const Vec3d dRho = rho > 0 ? (x * mU + y * mV) / rho : Vec3d(0.0);
        jacobian[2] = r2 > 0 ? mScale[2] * (z * dRho - rho * mAxis) / r2 : Vec3d(0.0);
    }
    return {r, mScale[1] * azimuth, mScale[2] * polar};
}

void CoordinateMapField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    std::array<Vec3d, kBatchSize> local;
    forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
        for (std::size_t i = 0; i < n; ++i) local[i] = toFrame(points[b + i], nullptr);
        mChild->values(std::span<const Vec3d>(local.data(), n), out.subspan(b, n));
    });
}

void CoordinateMapField::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    std::array<Vec3d, kBatchSize> local;
    std::array<std::array<Vec3d, 3>, kBatchSize> jac;
    forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
        for (std::size_t i = 0; i < n; ++i) local[i] = toFrame(points[b + i], jac[i].data());
        mChild->gradients(std::span<const Vec3d>(local.data(), n), out.subspan(b, n), grad.subspan(b, n));
        // Chain rule: grad_p = sum_i (d child / d q_i) * grad_p q_i.
        for (std::size_t i = 0; i < n; ++i) {
            const Vec3d g = grad[b + i];
            grad[b + i] = g[0] * jac[i][0] + g[1] * jac[i][1] + g[2] * jac[i][2];
        }
    });
}

Interval CoordinateMapField::bound(const Box3& box) const
{
    // The box lies in the ball of its half-diagonal R around its centre.
    const double R = box.radius();
    const Vec3d d = box.center() - mCenter;
    const double x = d.dot(mU), y = d.dot(mV), z = d.dot(mAxis);
    const double rho = std::sqrt(x * x + y * y);
    Interval azimuth(-kPi, kPi);
    if (rho > R) {
        const double a = std::atan2(y, x), w = std::asin(R / rho);
        if (a - w > -kPi && a + w < kPi) azimuth = Interval(a - w, a + w);  // else it crosses the seam
    }
    Box3 q;
    if (mKind == FrameKind::Cylinder) {
        q.min = Vec3d(std::max(0.0, rho - R), mScale[1] * azimuth.lo, z - R);
        q.max = Vec3d(rho + R, mScale[1] * azimuth.hi, z + R);
    } else {
        const double r = d.length();
        Interval polar(0.0, kPi);
        if (r > R) {
            const double c = std::atan2(rho, z), w = std::asin(R / r);
            polar = Interval(std::max(0.0, c - w), std::min(kPi, c + w));
        }
        q.min = Vec3d(std::max(0.0, r - R), mScale[1] * azimuth.lo, mScale[2] * polar.lo);
        q.max = Vec3d(r + R, mScale[1] * azimuth.hi, mScale[2] * polar.hi);
    }
    return mChild->bound(q);
}

}  // namespace voxlat
