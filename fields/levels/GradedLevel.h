/// @file GradedLevel.h
/// @brief A lattice whose level follows a target-density field point by point.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/maps/DensityTable.h"

#include <memory>

namespace voxlat {

/// value(x) = g(x) - level(rho(x)), negative inside, where g is the lattice's indicator (f for
/// a network, |f| for a sheet), rho the target density field and level() the node's own
/// DensityTable (computed once, when the node is built, over one unit cell of g). Where rho
/// varies slowly against the cell, the local relative density follows rho. Densities outside
/// what the table resolves are clamped to it (the recipe builder rejects them beforehand).
class GradedLevel final : public FieldNode {
public:
    GradedLevel(FieldPtr indicator, FieldPtr density, const Box3& cell, int samplesPerAxis = 96);
    /// With a table computed elsewhere: for a field that is periodic only away from its edges (a
    /// strut frame), the table comes from an interior cell of a small frame of the same cells.
    GradedLevel(FieldPtr indicator, FieldPtr density, std::shared_ptr<const DensityTable> table);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;
    /// A period the field and the target density share.
    double period(int axis) const override;

    const DensityTable& table() const { return *mTable; }
    const FieldPtr& density() const { return mDensity; }
    const FieldPtr& indicator() const { return mIndicator; }

private:
    double clampDensity(double rho) const;

    FieldPtr mIndicator;
    FieldPtr mDensity;
    std::shared_ptr<const DensityTable> mTable;
};

}  // namespace voxlat
