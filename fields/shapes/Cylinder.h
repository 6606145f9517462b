/// @file Cylinder.h
/// @brief Exact signed distance to a capped cylinder of any axis.
#pragma once

#include "fields/core/FieldNode.h"

namespace voxlat {

/// A solid cylinder of @a radius and total @a height, centred at @a center along @a axis.
class Cylinder final : public FieldNode {
public:
    Cylinder(const Vec3d& center, const Vec3d& axis, double radius, double height);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    /// Distance fields are 1-Lipschitz: value(centre) +- box radius.
    Interval bound(const Box3& box) const override;
    std::optional<Box3> support() const override;

private:
    double distance(const Vec3d& p, Vec3d* gradient) const;

    Vec3d mCenter, mAxis;
    double mRadius, mHalfHeight;
};

}  // namespace voxlat
