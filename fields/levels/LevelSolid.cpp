#include "fields/levels/LevelSolid.h"

#include "fields/shapes/Unary.h"
#include "fields/tpms/TpmsField.h"

#include <cmath>
#include <stdexcept>

namespace voxlat {

LevelSolid::LevelSolid(FieldPtr raw, SolidSide side, double level) : mRaw(std::move(raw)), mSide(side), mLevel(level) {}

std::shared_ptr<LevelSolid> LevelSolid::unsolved(FieldPtr raw, SolidSide side)
{
    auto solid = std::make_shared<LevelSolid>(std::move(raw), side, 0.0);
    solid->mSolved = false;
    return solid;
}

void LevelSolid::solve(double level)
{
    if (mSolved) throw std::logic_error("LevelSolid::solve: the level is already set (a solid is solved once)");
    mLevel = level;
    mSolved = true;
}

void LevelSolid::correct(double level)
{
    if (!mSolved || mCorrections >= 3)
        throw std::logic_error("LevelSolid::correct: only a solved level is corrected, at most three times");
    mLevel = level;
    ++mCorrections;
}

void LevelSolid::throwUnsolved()
{
    throw std::logic_error(
        "LevelSolid: the level is used before the density solve gave it (build, solve, then evaluate)");
}

namespace {
/// Maps raw values in place to the solid's value and derivative factor.
inline double applySide(SolidSide side, double raw, double level, double& slope)
{
    switch (side) {
        case SolidSide::Below:
            slope = 1.0;
            return raw - level;
        case SolidSide::Band:
            slope = raw < 0 ? -1.0 : 1.0;
            return std::abs(raw) - level;
        case SolidSide::Above:
            slope = -1.0;
            return level - raw;
    }
    slope = 1.0;
    return raw;
}

/// applySide over a whole span, one loop per side so each vectorises (no switch per value).
void applySideInPlace(SolidSide side, std::span<double> out, double level)
{
    switch (side) {
        case SolidSide::Below:
            for (double& v : out) v -= level;
            return;
        case SolidSide::Band:
            for (double& v : out) v = std::abs(v) - level;
            return;
        case SolidSide::Above:
            for (double& v : out) v = level - v;
            return;
    }
}
}  // namespace

void LevelSolid::values(std::span<const Vec3d> points, std::span<double> out) const
{
    requireSolved();
    mRaw->values(points, out);
    applySideInPlace(mSide, out, mLevel);
}

void LevelSolid::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    requireSolved();
    mRaw->gradients(points, out, grad);
    for (std::size_t n = 0; n < out.size(); ++n) {
        double slope;
        out[n] = applySide(mSide, out[n], mLevel, slope);
        grad[n] *= slope;
    }
}

void LevelSolid::gridValues(const GridBatch& batch, std::span<double> out) const
{
    requireSolved();
    // A TPMS applies the level as it makes its values (the same doubles, one pass less).
    if (const auto* tpms = dynamic_cast<const TpmsField*>(mRaw.get())) {
        tpms->gridValuesAtLevel(batch, out, mSide, mLevel);
        return;
    }
    mRaw->gridValues(batch, out);
    applySideInPlace(mSide, out, mLevel);
}

void LevelSolid::planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                             std::span<signed char> side, std::span<const TileNeed> need) const
{
    requireSolved();
    // A sheet first: no cast (a cross-cast per slicer block cost a TPMS sheet's slices 5 %).
    const auto* bands = mSide == SolidSide::Band ? nullptr : dynamic_cast<const PlaneBands*>(mRaw.get());
    const std::size_t tiles = PlaneTiles::of(plane, tile).size();
    if (!bands) {
        gridValues(plane, out);
        std::fill(side.begin(), side.begin() + tiles, static_cast<signed char>(0));
        return;
    }
    // raw - level > hi where raw > hi + level (level - raw > hi where raw < level - hi), with a
    // margin for the subtraction's rounding.
    const double slack = 1e-12 * (std::abs(mLevel) + finiteScale(band) + 1.0);
    const bool below = mSide == SolidSide::Below;
    const Interval raw = below ? Interval{band.lo + mLevel - slack, band.hi + mLevel + slack}
                               : Interval{mLevel - band.hi - slack, mLevel - band.lo + slack};
    bands->planeValues(plane, tile, raw, out, side, need);
    if (!below)
        for (std::size_t t = 0; t < tiles; ++t) side[t] = static_cast<signed char>(-side[t]);
    applySideInPlace(mSide, out.first(plane.size()), mLevel);
}

bool LevelSolid::planeCheap() const
{
    return mSide == SolidSide::Band || planeCheapOf(*mRaw);
}

Interval LevelSolid::bound(const Box3& box) const
{
    requireSolved();
    return atLevel(mRaw->bound(box));
}

std::optional<Interval> LevelSolid::heldRange(const GridBatch& points) const
{
    requireSolved();
    const std::optional<Interval> r = mRaw->heldRange(points);
    return r ? std::optional(atLevel(*r)) : std::nullopt;
}

Interval LevelSolid::atLevel(const Interval& r) const
{
    switch (mSide) {
        case SolidSide::Below:
            return r - mLevel;
        case SolidSide::Band:
            return abs(r) - mLevel;
        case SolidSide::Above:
            return mLevel - r;
    }
    return r;
}

bool LevelSolid::meets(const Box3& box, const Interval& band) const
{
    requireSolved();
    switch (mSide) {
        case SolidSide::Below:  // raw - level in band: raw in band + level
            return mRaw->meets(box, Interval(band.lo + mLevel, band.hi + mLevel));
        case SolidSide::Above:  // level - raw in band: raw in level - band
            return mRaw->meets(box, Interval(mLevel - band.hi, mLevel - band.lo));
        case SolidSide::Band:
            return false;
    }
    return false;
}

FieldPtr LevelSolid::indicator() const
{
    switch (mSide) {
        case SolidSide::Below:
            return mRaw;
        case SolidSide::Band:
            return std::make_shared<UnaryField>(mRaw, UnaryOp::Abs);
        case SolidSide::Above:
            return std::make_shared<UnaryField>(mRaw, UnaryOp::Negate);
    }
    return mRaw;
}

double LevelSolid::levelFromIndicator(double indicatorLevel) const
{
    return mSide == SolidSide::Above ? -indicatorLevel : indicatorLevel;
}

}  // namespace voxlat
