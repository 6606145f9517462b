/// @file SurfaceDistance.h
/// @brief The first-order signed distance to the boundary of an intersection of fields,
/// max_i f_i / |grad f_i|: what a mesh's deviation is measured (and decimated) against.
#pragma once

#include "fields/core/FieldNode.h"

#include <cmath>
#include <vector>

namespace voxlat {

/// The signed first-order distance r / |grad f| from a value @a r (f minus the level) and the
/// gradient's length @a gradientLength; a flat spot off the level counts as 1e30 mm away.
inline double firstOrderSignedDistance(double r, double gradientLength)
{
    if (gradientLength > 0.0) return r / gradientLength;
    return r == 0.0 ? 0.0 : std::copysign(1e30, r);
}

/// max over the operands of f_i / |grad f_i| (each operand's solid below 0), with the unit
/// normal grad f_k / |grad f_k| of the largest as its gradient (exact on the surface, where it
/// is used). A sharp intersection's own value max_i f_i picks the operand with the largest raw
/// value, which is not the one farthest away when the operands' gradients differ in length (a
/// TPMS against the domain box), so a mesh measured with it could stray further than it says.
/// A flat spot off the level (zero gradient) counts as 1e30 mm away. Meant for measuring, not
/// for sampling a grid: its bound is unbounded.
class SurfaceDistance final : public FieldNode {
public:
    explicit SurfaceDistance(std::vector<FieldPtr> operands);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    Interval bound(const Box3& box) const override;

    const std::vector<FieldPtr>& operands() const { return mOperands; }

private:
    std::vector<FieldPtr> mOperands;
};

}  // namespace voxlat
