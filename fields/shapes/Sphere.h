/// @file Sphere.h
/// @brief Exact signed distance to a sphere.
#pragma once

#include "fields/core/PointField.h"

namespace voxlat {

/// |p - centre| - radius.
class Sphere final : public PointField<Sphere> {
public:
    Sphere(const Vec3d& center, double radius) : mCenter(center), mRadius(radius) {}

    template <typename T>
    T eval(const T& x, const T& y, const T& z) const
    {
        using std::sqrt;
        return sqrt(sqr(x - mCenter[0]) + sqr(y - mCenter[1]) + sqr(z - mCenter[2])) - mRadius;
    }
    std::optional<Box3> support() const override { return Box3{mCenter - Vec3d(mRadius), mCenter + Vec3d(mRadius)}; }

private:
    Vec3d mCenter;
    double mRadius;
};

}  // namespace voxlat
