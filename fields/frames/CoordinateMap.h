/// @file CoordinateMap.h
/// @brief Conformal frames: a field evaluated in cylindrical or spherical coordinates.
#pragma once

#include "fields/core/FieldNode.h"

namespace voxlat {

enum class FrameKind {
    Cylinder,  ///< q = (radius, angle * s.y, height along the axis)
    Sphere,    ///< q = (radius, azimuth * s.y, polar angle * s.z)
};

/// value(p) = child(q(p)): the child (a lattice written in a box's x, y, z) is laid out along a
/// cylinder (x radial, y around, z along the axis) or a sphere (x radial, y around the axis, z
/// from pole to pole). Angles are scaled by @a angularScale (mm of child per radian) so that a
/// whole number of child cells fits around: s = cells * cell / (2 pi) keeps the seam at angle
/// +-pi continuous. Cells near the axis (or the poles) are squeezed, as in any such map.
class CoordinateMapField final : public FieldNode {
public:
    CoordinateMapField(FieldPtr child, FrameKind kind, const Vec3d& center, const Vec3d& axis,
                       const Vec3d& angularScale);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    /// The child's bound over the box of frame coordinates the box can reach (angles widened to
    /// the full turn when the box comes near the axis or crosses the seam).
    Interval bound(const Box3& box) const override;

    /// Frame coordinates of @a p, and the Jacobian rows dq_i/dp when @a jacobian is set.
    Vec3d toFrame(const Vec3d& p, Vec3d* jacobian) const;

private:
    FieldPtr mChild;
    FrameKind mKind;
    Vec3d mCenter, mAxis, mU, mV, mScale;
};

}  // namespace voxlat
