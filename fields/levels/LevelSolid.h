/// @file LevelSolid.h
/// @brief A solid cut from a raw field at a level: the node the density solve adjusts.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/core/PlaneBands.h"
#include "fields/core/SolidSide.h"

namespace voxlat {

/// value = indicator(raw) - level, negative inside. The density solve works on indicator(raw)
/// (see indicator()), so one quantile serves all three sides.
///
/// Like every node it is immutable once it can be evaluated. A solid whose level a density solve
/// finds is made with unsolved() and given its level once, by solve(), before anything evaluates
/// it: the order build -> solve -> evaluate is enforced (evaluating an unsolved solid, reading its
/// level or solving it twice throws std::logic_error, a bug in the caller, never a user error).
class LevelSolid final : public FieldNode, public PlaneBands {
public:
    /// A solid at a known level, immutable from the start.
    LevelSolid(FieldPtr raw, SolidSide side, double level);
    /// A solid whose level is not known yet: solve() must be called once before it is used.
    static std::shared_ptr<LevelSolid> unsolved(FieldPtr raw, SolidSide side);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;
    /// The raw field's meets() over the band moved by the level (a sheet's |raw|: nothing known).
    bool meets(const Box3& box, const Interval& band) const override;
    /// The raw field's heldRange() moved by the level as bound() moves its bound.
    std::optional<Interval> heldRange(const GridBatch& points) const override;
    /// The raw field's planeValues with the band moved by the level (a network or a level above;
    /// a sheet and raw fields without them take gridValues, every tile 0).
    void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                     std::span<signed char> side, std::span<const TileNeed> need) const override;
    bool planeCheap() const override;
    double period(int axis) const override { return mRaw->period(axis); }
    AxisRepeat axisRepeat(int axis) const override { return mRaw->axisRepeat(axis); }

    /// The level in the node's own units (c for a network, t for a sheet or a convolution).
    double level() const
    {
        requireSolved();
        return mLevel;
    }
    /// Gives an unsolved() solid its level (the density solve's result); once only.
    void solve(double level);
    /// Moves a solved level, at most three times (the job's aim at the mesh's share: to the level
    /// its prediction gives, after measuring the first grid, and its secant step after measuring
    /// the moved one). Called
    /// between evaluations, never during one: no node keeps values that depend on the level
    /// (tables and caches live below the solid).
    void correct(double level);
    bool isSolved() const { return mSolved; }
    SolidSide side() const { return mSide; }
    const FieldPtr& raw() const { return mRaw; }

    /// The field whose sub-level set {g <= indicatorLevel(level)} is the solid: raw, |raw| or -raw.
    FieldPtr indicator() const;
    /// Converts a level of indicator() back into this node's level.
    double levelFromIndicator(double indicatorLevel) const;

private:
    /// A range of the raw field's values as this node's: moved by the level on its side.
    Interval atLevel(const Interval& raw) const;
    /// Throws std::logic_error when the level is used before solve().
    void requireSolved() const
    {
        if (!mSolved) [[unlikely]]
            throwUnsolved();
    }
    [[noreturn]] static void throwUnsolved();

    FieldPtr mRaw;
    SolidSide mSide;
    double mLevel;
    bool mSolved = true;
    int mCorrections = 0;
};

}  // namespace voxlat
