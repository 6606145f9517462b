/// @file LevelSolid.h
/// @brief A solid cut from a raw field at a level: the node the density solve adjusts.
#pragma once

#include "fields/FieldNode.h"

namespace voxlat {

/// Which side of the level is solid.
enum class SolidSide {
    Below,  ///< raw <= level (a TPMS network; value raw - level)
    Band,   ///< |raw| <= level (a TPMS sheet; value |raw| - level)
    Above,  ///< raw >= level (a convolution lattice; value level - raw)
};

/// value = indicator(raw) - level, negative inside. The density solve works on indicator(raw)
/// (see indicator()), so one quantile serves all three sides.
class LevelSolid final : public FieldNode {
public:
    LevelSolid(FieldPtr raw, SolidSide side, double level);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;
    double period(int axis) const override { return mRaw->period(axis); }

    /// The level in the node's own units (c for a network, t for a sheet or a convolution).
    double level() const { return mLevel; }
    /// Sets the level; only the engine does this, before any evaluation.
    void setLevel(double level) { mLevel = level; }
    SolidSide side() const { return mSide; }
    const FieldPtr& raw() const { return mRaw; }

    /// The field whose sub-level set {g <= indicatorLevel(level)} is the solid: raw, |raw| or -raw.
    FieldPtr indicator() const;
    /// Converts a level of indicator() back into this node's level.
    double levelFromIndicator(double indicatorLevel) const;

private:
    FieldPtr mRaw;
    SolidSide mSide;
    double mLevel;
};

}  // namespace voxlat
