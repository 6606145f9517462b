/// @file Boolean.h
/// @brief Union, intersection and difference of fields, with an optional smooth blend radius.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/core/PlaneBands.h"

#include <vector>

namespace voxlat {

enum class BooleanOp { Union, Intersection, Difference };

/// Folds the operands left to right: union = min, intersection = max, difference = max(a, -b).
/// With blend radius r > 0 the polynomial smooth minimum replaces min (smin(a, b) >= min - r/4),
/// rounding the joint with a fillet of about radius r when the operands are distance-like.
class BooleanField final : public FieldNode, public PlaneBands {
public:
    BooleanField(BooleanOp op, std::vector<FieldPtr> operands, double blendRadius = 0.0);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;
    /// Sharp operations only (no blend): one operand's held values meet the band (its meets())
    /// where every other operand's bound keeps the result there. An intersection (max) takes the
    /// operand's point valued at least band.lo as it is (the max only rises) and its point valued
    /// at most band.hi where every other operand's bound is at most band.hi; a union (min) the
    /// mirror image; a difference max(a, -b, ...) the first operand's, with each -b's bound at
    /// most band.hi. False otherwise: the cull then takes the bound, which meets the band in every
    /// case this proves (max and min of the operands' bounds, as bound() folds them).
    bool meets(const Box3& box, const Interval& band) const override;
    /// When an operand holds its values at @a points (heldRange()): the operands' held ranges,
    /// or their bounds over the points' box where they hold none, folded as bound() folds them.
    std::optional<Interval> heldRange(const GridBatch& points) const override;
    /// The operands' planeValues, the cheap ones first (planeCheap): a tile one operand proves on
    /// the side that decides (a union's below, an intersection's or a difference's above) is
    /// skipped by the operands after it; one every operand proves on the other side (by the
    /// blends' reach, (operands - 1) r / 4, more) is decided too; the operands that proved a side
    /// of a tile left open are asked its values again. The values combined as gridValues'.
    void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                     std::span<signed char> side, std::span<const TileNeed> need) const override;
    bool planeCheap() const override;
    /// Intersection: the overlap of the operands' boxes; union: their hull (grown by the blend
    /// radius, which assumes distance-like operands); difference: the first operand's box.
    std::optional<Box3> support() const override;
    /// A period every operand shares (commonPeriod()).
    double period(int axis) const override;

    BooleanOp op() const { return mOp; }
    const std::vector<FieldPtr>& operands() const { return mOperands; }
    /// The smooth blend radius (0: a sharp min / max).
    double blendRadius() const { return mBlend; }

private:
    /// The operands' ranges (@a of each) folded by the operation and the blend.
    template <class Of>
    Interval foldRanges(Of of) const;

    /// Combines accumulated value a (gradient ga) with operand b (gradient gb) in place.
    void combine(double& a, Vec3d* ga, double b, const Vec3d* gb) const;
    /// Folds operand @a o's values @a b (n of them) into @a out, as gridValues does.
    void fold(double* out, const double* b, std::size_t n) const;

    BooleanOp mOp;
    std::vector<FieldPtr> mOperands;
    double mBlend;
};

}  // namespace voxlat
