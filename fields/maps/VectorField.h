/// @file VectorField.h
/// @brief A direction field: three scalar component fields (Aether's vector fields).
#pragma once

#include "fields/core/FieldNode.h"

#include <array>

namespace voxlat {

/// A vector at every point, given by three component fields. As a scalar field (so it can be
/// sampled, bounded and named like any other) its value is the vector's length; nodes that want
/// a direction call directions(), and equations read the components as `name.x`, `name.y`, `name.z`.
class VectorField final : public FieldNode {
public:
    explicit VectorField(std::array<FieldPtr, 3> components);

    /// The vectors at @a points (not normalised; consumers normalise where they need a unit).
    void directions(std::span<const Vec3d> points, std::span<Vec3d> out) const;
    const FieldPtr& component(int axis) const { return mComponents[axis]; }

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    Interval bound(const Box3& box) const override;

private:
    std::array<FieldPtr, 3> mComponents;
};

}  // namespace voxlat
