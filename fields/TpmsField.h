/// @file TpmsField.h
/// @brief The raw TPMS function f(x, y, z) with a cell size per axis.
#pragma once

#include "fields/FieldNode.h"
#include "fields/TpmsEquations.h"

namespace voxlat {

/// f of a TPMS, periodic with the given cell size per axis. Not a solid on its own: wrap it in a
/// LevelSolid (network: f <= c, sheet: |f| <= t).
class TpmsField final : public FieldNode {
public:
    TpmsField(TpmsType type, const Vec3d& cellSize);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    /// Separable fast path: the trigonometric terms are computed once per axis coordinate.
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    /// Separable gradients: the dual-number trigonometric terms are computed once per axis.
    void gridGradients(const GridBatch& batch, std::span<double> out, std::span<Vec3d> grad) const override;
    /// Shifted values from the per-axis terms: sin(X +- S) = sin X cos S +- cos X sin S, with
    /// sin S and cos S of the small shift angle shared by both signs.
    void gridValuesShifted(const GridBatch& batch, std::span<const Vec3d> shift, std::span<double> plus,
                           std::span<double> minus) const override;
    Interval bound(const Box3& box) const override;
    /// One cell: every equation repeats every 2 pi in each of its angles.
    double period(int axis) const override { return mCell[axis]; }

    TpmsType type() const { return mType; }
    const Vec3d& cellSize() const { return mCell; }

private:
    TpmsType mType;
    Vec3d mCell;
    Vec3d mWave;  ///< 2*pi / cell per axis
};

}  // namespace voxlat
