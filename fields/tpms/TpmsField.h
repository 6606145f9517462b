/// @file TpmsField.h
/// @brief The raw TPMS function f(x, y, z) with a cell size per axis.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/tpms/TpmsEquations.h"

namespace voxlat {

enum class SolidSide;  // fields/core/SolidSide.h

/// f of a TPMS, periodic with the given cell size per axis. Not a solid on its own: wrap it in a
/// LevelSolid (network: f <= c, sheet: |f| <= t).
class TpmsField final : public FieldNode {
public:
    TpmsField(TpmsType type, const Vec3d& cellSize);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    /// Separable fast path: the trigonometric terms are computed once per axis coordinate.
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    /// gridValues with a solid's level applied as each value is made (LevelSolid's value of the
    /// side @a side at @a level: v - level, |v| - level or level - v), one pass instead of two;
    /// the same doubles as gridValues followed by the level.
    void gridValuesAtLevel(const GridBatch& batch, std::span<double> out, SolidSide side, double level) const;
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
    /// gridValues with @a map applied to every value.
    template <class Map>
    void gridValuesMapped(const GridBatch& batch, std::span<double> out, const Map& map) const;

    TpmsType mType;
    Vec3d mCell;
    Vec3d mWave;  ///< 2*pi / cell per axis
};

}  // namespace voxlat
