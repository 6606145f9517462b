/// @file ParametricSurface.h
/// @brief A surface given by three equations in u, v in [0, 1] (IntraLattice's conformal
/// frames map cells between two of them).
#pragma once

#include "fields/expr/Expression.h"

#include <array>
#include <memory>

namespace voxlat {

/// S(u, v) = (x(u, v), y(u, v), z(u, v)): three compiled equations whose inputs 0 and 1 are u and
/// v. It is a node of the recipe graph so it can be named in `fields:`, but not a scalar field:
/// the recipe builder refuses it wherever a field is expected, and values() and bound() throw.
class ParametricSurface final : public FieldNode {
public:
    /// @a coordinates: x, y and z, each a program with at most two inputs (u, v).
    explicit ParametricSurface(std::array<std::shared_ptr<const ExprProgram>, 3> coordinates);

    /// The point at (@a u, @a v).
    Vec3d point(double u, double v) const;

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    Interval bound(const Box3& box) const override;

private:
    std::array<std::shared_ptr<const ExprProgram>, 3> mCoordinates;
};

}  // namespace voxlat
