/// @file DrainChannels.h
/// @brief A solid with straight drain channels cut through it, the channels placed after the
/// solid's own levels are known (they open the resin traps the solid encloses).
#pragma once

#include "fields/core/PlaneBands.h"
#include "fields/shapes/Cylinder.h"

#include <vector>

namespace voxlat {

/// One straight channel: a flat-ended cylinder from @a from to @a to of diameter @a diameter.
struct DrainChannel {
    Vec3d from{0.0}, to{0.0};
    double diameter = 0.0;
};

/// max(solid, -min_i channel_i): @a solid with every channel removed (a field difference, so a
/// mesh and slices of it both have the holes). Like LevelSolid it is made before its numbers are
/// known: setChannels() gives the channels once, before anything evaluates it (an empty list is
/// valid: nothing to drain). Evaluating it before then throws std::logic_error (a caller's bug).
class DrainedSolid final : public FieldNode, public PlaneBands {
public:
    explicit DrainedSolid(FieldPtr solid);

    /// Gives the channels; once only.
    void setChannels(std::vector<DrainChannel> channels);
    bool hasChannels() const { return mSet; }
    const std::vector<DrainChannel>& channels() const { return mChannels; }
    /// The solid without the channels.
    const FieldPtr& solid() const { return mSolid; }

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    /// The solid's fast block path, then the channels that reach the block.
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;
    /// The solid's planeValues, then the channels as gridValues cuts them: a tile the solid
    /// proves above stays above; one it proves below stays below where every channel's bound
    /// over the tile is too, else its values are asked again.
    void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                     std::span<signed char> side, std::span<const TileNeed> need) const override;
    bool planeCheap() const override { return planeCheapOf(*mSolid); }
    std::optional<Box3> support() const override { return mSolid->support(); }
    // No period: the channels sit where the traps are, not cell by cell.

private:
    void requireSet() const;
    /// Cuts the channels whose bound over @a box can change a value at @a points (values in @a out).
    void cut(const Box3& box, std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const;
    /// The channels cut from a block's solid values (gridValues' second half).
    void cutGrid(const GridBatch& batch, std::span<double> out) const;

    FieldPtr mSolid;
    std::vector<DrainChannel> mChannels;
    std::vector<Cylinder> mCylinders;
    bool mSet = false;
};

}  // namespace voxlat
