/// @file Unary.h
/// @brief Pointwise unary maps of a field: negation, absolute value, offset.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/core/PlaneBands.h"

namespace voxlat {

enum class UnaryOp { Negate, Abs, Offset };

/// op(child(p)); Offset adds a constant (a positive offset shrinks the solid).
class UnaryField final : public FieldNode, public PlaneBands {
public:
    UnaryField(FieldPtr child, UnaryOp op, double offset = 0.0);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;
    /// The child's planeValues with the band moved back through the map (an offset, a negation;
    /// an absolute value takes gridValues, every tile 0).
    void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                     std::span<signed char> side, std::span<const TileNeed> need) const override;
    bool planeCheap() const override { return planeCheapOf(*mChild); }
    double period(int axis) const override { return mChild->period(axis); }
    AxisRepeat axisRepeat(int axis) const override { return mChild->axisRepeat(axis); }
    /// A positive offset only shrinks the solid: the child's box. Other maps: unbounded.
    std::optional<Box3> support() const override;

private:
    double apply(double v, double& slope) const;

    FieldPtr mChild;
    UnaryOp mOp;
    double mOffset;
};

}  // namespace voxlat
