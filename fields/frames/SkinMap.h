/// @file SkinMap.h
/// @brief A lattice laid out in the cells of a skin frame (SkinCells): the child is evaluated at
/// each point's local cell coordinates, and the region the cells fill as a field of its own.
#pragma once

#include "fields/frames/SkinCells.h"

#include <memory>

namespace voxlat {

/// value(p) = child(q), q = (u cx, v cy, w cz) with (u, v, w) the local coordinates of p in the
/// skin cell holding it (inverse trilinear map) and c the child's cell: one period of a TPMS per
/// hexahedral cell, its z running inward. Outside every cell the value is @a outside (above any
/// level the child takes, so the lattice stops at the cells).
///
/// Continuity: within a cell and across the faces between layers (same orientation, and the
/// child periodic with period c) the field is continuous. Across a face between two cells of a
/// layer it is continuous where both cells' (u, v) axes line up (SkinFrame turns each quad so
/// they do wherever a consistent choice exists); where they are turned by 90 degrees against
/// each other (seams, round irregular vertices of the quad mesh) it is continuous only for a child
/// with a 4-fold symmetry about its z axis (Schwarz P, for instance; a gyroid has a seam there).
///
/// Gradients by the chain rule: grad_p = J^-T (c * grad_q child), J the map's Jacobian; zero
/// outside. Bounds: the child's bound over one cell's q range (with the outer extension), joined
/// with @a outside where the box may leave the cells, and exactly @a outside where no cell comes
/// near the box.
class SkinMapField final : public FieldNode {
public:
    SkinMapField(FieldPtr child, std::shared_ptr<const SkinCells> cells, const Vec3d& cellSize, double outside);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    Interval bound(const Box3& box) const override;
    /// The cells' box: outside every cell the value is positive.
    std::optional<Box3> support() const override
    {
        return mOutside > 0.0 ? std::optional(mCells->bounds()) : std::nullopt;
    }

    const std::shared_ptr<const SkinCells>& cells() const { return mCells; }
    /// The child's coordinates of @a p, or false outside the cells.
    bool toCell(const Vec3d& p, Vec3d& q) const;

private:
    FieldPtr mChild;
    std::shared_ptr<const SkinCells> mCells;
    Vec3d mCell;
    double mOutside;
    Interval mInside;  ///< the child's bound over one cell (and the extension)
};

/// -1 inside the cells of a skin frame (their extension clipped as in SkinCells), +1 outside: the
/// region whose share a skin lattice's density is measured in.
class SkinRegionField final : public FieldNode {
public:
    explicit SkinRegionField(std::shared_ptr<const SkinCells> cells) : mCells(std::move(cells)) {}

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    Interval bound(const Box3& box) const override;
    std::optional<Box3> support() const override { return mCells->bounds(); }

private:
    std::shared_ptr<const SkinCells> mCells;
};

}  // namespace voxlat
