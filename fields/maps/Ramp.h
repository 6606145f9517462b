/// @file Ramp.h
/// @brief A value that changes linearly between two numbers: along an axis, or with the
/// distance from another field's surface. Used for graded densities and thicknesses.
#pragma once

#include "fields/core/FieldNode.h"

namespace voxlat {

/// value(x) = from + (to - from) * clamp((u(x) - start) / (end - start), 0, 1), where u is the
/// coordinate along an axis, or |g(x)| of a source field g (its distance from g's zero set when
/// g is a distance field). Outside [start, end] the value stays at from / to.
class RampField final : public FieldNode {
public:
    /// Along axis 0, 1 or 2 (x, y, z).
    RampField(int axis, double start, double end, double from, double to);
    /// With |source|.
    RampField(FieldPtr source, double start, double end, double from, double to);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;
    /// Along an axis: invariant across it; from a source: the source's period.
    double period(int axis) const override;

    int axis() const { return mAxis; }

private:
    double map(double u) const;
    double slope(double u) const;

    FieldPtr mSource;
    int mAxis = 2;
    double mStart, mEnd, mFrom, mTo;
};

}  // namespace voxlat
