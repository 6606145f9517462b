#include "fields/shapes/Cylinder.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace voxlat {

Cylinder::Cylinder(const Vec3d& center, const Vec3d& axis, double radius, double height)
    : mCenter(center), mAxis(axis), mRadius(radius), mHalfHeight(0.5 * height)
{
    if (axis.length() <= 0.0) throw std::invalid_argument("cylinder axis has zero length");
    mAxis.normalize();
}

double Cylinder::distance(const Vec3d& p, Vec3d* gradient) const
{
    const Vec3d d = p - mCenter;
    const double h = d.dot(mAxis);
    const Vec3d radial = d - h * mAxis;
    const double r = radial.length();
    const Vec3d radialDir = r > 0 ? radial / r : Vec3d(0.0);
    const Vec3d axialDir = h < 0 ? -mAxis : mAxis;
    const double qr = r - mRadius, qh = std::abs(h) - mHalfHeight;
    if (qr > 0 && qh > 0) {
        const double len = std::sqrt(qr * qr + qh * qh);
        if (gradient) *gradient = (qr * radialDir + qh * axialDir) / len;
        return len;
    }
    if (qr > qh) {
        if (gradient) *gradient = radialDir;
        return qr;  // outside radially, or inside and nearer the mantle than a cap
    }
    if (gradient) *gradient = axialDir;
    return qh;
}

void Cylinder::values(std::span<const Vec3d> points, std::span<double> out) const
{
    for (std::size_t n = 0; n < points.size(); ++n) out[n] = distance(points[n], nullptr);
}

void Cylinder::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    for (std::size_t n = 0; n < points.size(); ++n) out[n] = distance(points[n], &grad[n]);
}

Interval Cylinder::bound(const Box3& box) const
{
    return lipschitzBound(*this, box, 1.0);
}

std::optional<Box3> Cylinder::support() const
{
    // Per world axis: the caps' centres reach halfHeight * |a_i|, their rims radius * sin(angle).
    Vec3d half;
    for (int i = 0; i < 3; ++i)
        half[i] = mHalfHeight * std::abs(mAxis[i]) + mRadius * std::sqrt(std::max(0.0, 1.0 - mAxis[i] * mAxis[i]));
    return Box3{mCenter - half, mCenter + half};
}

}  // namespace voxlat
