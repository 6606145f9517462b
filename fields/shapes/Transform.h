/// @file Transform.h
/// @brief An affine placement of a field: translate, rotate, scale.
#pragma once

#include "fields/core/FieldNode.h"

#include <openvdb/math/Mat3.h>

namespace voxlat {

using Mat3d = openvdb::math::Mat3<double>;

/// value(p) = child(A^-1 (p - t)), i.e. the child moved by p -> A p + t. Values are not rescaled,
/// so a scaled TPMS keeps its level-to-density relation and a scaled distance field keeps its
/// zero set (its values then measure distance in the child's units).
class TransformField final : public FieldNode {
public:
    TransformField(FieldPtr child, const Mat3d& linear, const Vec3d& translation);

    static Mat3d rotation(const Vec3d& axis, double degrees);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    /// Translations and axis-aligned scales keep a grid batch regular, so the child's fast path
    /// still applies; rotations fall back to points.
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;
    std::optional<Box3> support() const override;
    /// The child's period along the axis when the placement keeps the axis's direction
    /// (translations, axis-aligned scales, rotations about the axis), scaled; otherwise none.
    double period(int axis) const override;

private:
    Vec3d toLocal(const Vec3d& p) const { return mInverse * (p - mTranslation); }

    FieldPtr mChild;
    Mat3d mInverse;
    Vec3d mTranslation;
    bool mDiagonal;
};

}  // namespace voxlat
