/// @file Supported.h
/// @brief A field with a support its own node cannot state: a finite strut frame's solid is
/// outside its frame's box grown by the struts' reach, which the lattice nodes do not know.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/core/PlaneBands.h"

#include <functional>

namespace voxlat {

/// The child's values, gradients, bounds and period as they are; support() is @a box. The caller
/// guarantees the child is positive outside @a box, and that its solid repeats inside @a zone
/// when one is given (a frame of identical cells: repeatZone()).
class SupportedField final : public FieldNode, public PlaneBands {
public:
    /// @a zone is asked when repeatZone() is (a solved level may set how far the solid reaches).
    SupportedField(FieldPtr child, const Box3& box, std::function<std::optional<RepeatZone>()> zone = {})
        : mChild(std::move(child)), mBox(box), mZone(std::move(zone))
    {
    }

    void values(std::span<const Vec3d> points, std::span<double> out) const override { mChild->values(points, out); }
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override
    {
        mChild->gradients(points, out, grad);
    }
    void gridValues(const GridBatch& batch, std::span<double> out) const override { mChild->gridValues(batch, out); }
    void gridGradients(const GridBatch& batch, std::span<double> out, std::span<Vec3d> grad) const override
    {
        mChild->gridGradients(batch, out, grad);
    }
    void gridValuesShifted(const GridBatch& batch, std::span<const Vec3d> shift, std::span<double> plus,
                           std::span<double> minus) const override
    {
        mChild->gridValuesShifted(batch, shift, plus, minus);
    }
    Interval bound(const Box3& box) const override { return mChild->bound(box); }
    bool meets(const Box3& box, const Interval& band) const override { return mChild->meets(box, band); }
    std::optional<Interval> heldRange(const GridBatch& points) const override { return mChild->heldRange(points); }
    void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                     std::span<signed char> side, std::span<const TileNeed> need) const override
    {
        planeValuesOf(*mChild, plane, tile, band, out, side, need);
    }
    bool planeCheap() const override { return planeCheapOf(*mChild); }
    std::optional<Box3> support() const override { return mBox; }
    double period(int axis) const override { return mChild->period(axis); }
    AxisRepeat axisRepeat(int axis) const override { return mChild->axisRepeat(axis); }
    std::optional<RepeatZone> repeatZone() const override { return mZone ? mZone() : mChild->repeatZone(); }

    const FieldPtr& child() const { return mChild; }

private:
    FieldPtr mChild;
    Box3 mBox;
    std::function<std::optional<RepeatZone>()> mZone;
};

}  // namespace voxlat
