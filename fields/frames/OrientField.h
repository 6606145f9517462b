/// @file OrientField.h
/// @brief Cells oriented by a frame field: any field evaluated in coordinates rotated point by
/// point about an origin.
#pragma once

#include "fields/frames/FrameField.h"

namespace voxlat {

/// value(p) = child(q(p)) with q(p) = o + R(p)^T (p - o): the child's x, y, z axes follow the
/// frame's axes at p. A constant frame is the rigid rotation by R about o. Where R varies, the
/// cells are rotated in place but also sheared: dq/dp = R^T + (dR^T/dp)(p - o), so they stay
/// undistorted only where |dR/dp| |p - o| is small against 1 (R varies slowly across a cell and
/// over the distance to o). Since |q - o| = |p - o|, a field that turns the z axis towards
/// p - o everywhere (a radial field about o) maps every sphere about o to one point of the child:
/// choose o in the middle of the part and fields that turn slowly.
class OrientField final : public FieldNode {
public:
    OrientField(FieldPtr child, std::shared_ptr<const FrameField> frame, const Vec3d& origin);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    /// Chain rule through q(p): grad = R g + sum_k e_k (p - o) . (dR/dp_k g), g = child's gradient at q.
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    /// The frame from the direction fields' grid fast path, then the child at the rotated points.
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    /// The child's bound over the box of q: R's entries bounded over the box (interval
    /// Gram-Schmidt) times the box's offsets from o, cut to the ball |q - o| <= max |p - o|
    /// (the whole ball where the frame cannot be bounded).
    Interval bound(const Box3& box) const override;
    /// The child's support is reached only from points as far from o as its corners.
    std::optional<Box3> support() const override;

    /// q(p) for one frame.
    Vec3d toLocal(const Vec3d& p, const Mat3d& frame) const { return mOrigin + frame.transpose() * (p - mOrigin); }
    const FrameField& frame() const { return *mFrame; }

private:
    FieldPtr mChild;
    std::shared_ptr<const FrameField> mFrame;
    Vec3d mOrigin;
};

}  // namespace voxlat
