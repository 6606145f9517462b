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
    /// values() at every point of @a batch, bit for bit. A cylinder along x, y or z (a `within:`
    /// mask, an infill's part) takes its axial term per index along the axis and its radial one per
    /// column across it: a square root per column, not per point; other axes go point by point.
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    /// Distance fields are 1-Lipschitz: value(centre) +- box radius.
    Interval bound(const Box3& box) const override;
    std::optional<Box3> support() const override;

private:
    double distance(const Vec3d& p, Vec3d* gradient) const;

    Vec3d mCenter, mAxis;
    double mRadius, mHalfHeight;
};

}  // namespace voxlat
