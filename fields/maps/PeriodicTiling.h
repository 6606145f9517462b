/// @file PeriodicTiling.h
/// @brief A field that repeats with a period inside a box, sampled once per period on a grid.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/core/PlaneBands.h"

#include <array>
#include <memory>
#include <mutex>
#include <vector>

namespace voxlat {

/// value(p) = child(p), with gridValues() taken from a table of one period when the batch's
/// spacing divides the period. The child must satisfy
///   child(p) = child(p + m * period)   (m a vector of integers)
/// whenever, along every axis where m is non-zero, both points lie at least @a reach inside
/// @a box. A box frame of identical cells with identical struts does: every strut within the
/// kernel's cut-off radius (@a reach) of such a point belongs to the infinite periodic lattice,
/// so the box's faces are out of sight. A period of 0 along an axis means the child does not
/// repeat along it (m is 0 there): a box frame whose radii are graded along that axis only.
///
/// Per axis, grid positions closer than @a reach to a face (the faces' zones, up to a leaf
/// beyond the box) are tabled as they are, and the positions between the zones map onto one
/// period, so a W x W x W domain needs (2 zones + 1 period)^3 evaluations of the child instead
/// of W^3. Along an axis where @a mirror says the child is its own mirror image about the box's
/// middle (child(p) = child(p') for p' p's image), positions above the middle read their images'
/// values, and so do the period's positions paired by the mirror (periodic and mirror symmetric,
/// the child is symmetric within the period too): about half the positions per axis. The
/// values an image reads equal the child's there up to rounding (the child evaluated at the
/// image instead). The table is built the first time a grid (spacing and phase) is seen, by all threads
/// that need it, from sample positions that depend only on the grid: results are identical for
/// any thread count. Batches the table does not cover, batches one sample thick (slices), grids
/// whose spacing does not divide the period and grids beyond the first four are evaluated by the
/// child. values() and gradients() are the child's; bound() is the
/// child's bound of the box moved into the first period (boxes deep inside repeat, so a sparse
/// evaluation bounds each distinct leaf once), snapped outwards to 1e-6 mm so the bound depends
/// only on the box and not on which thread asked first.
class PeriodicTiling final : public FieldNode, public PlaneBands {
public:
    PeriodicTiling(FieldPtr child, const Box3& box, const Vec3d& period, double reach, std::array<bool, 3> mirror = {});
    ~PeriodicTiling() override;

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;
    /// A plane is one sample thick, so gridValues takes it from the child: so do these.
    void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                     std::span<signed char> side, std::span<const TileNeed> need) const override;
    bool planeCheap() const override { return planeCheapOf(*mChild); }
    std::optional<Box3> support() const override { return mChild->support(); }
    /// Along an axis with a period: that period between the faces' zones (at least @a reach
    /// inside the box), as the constructor's contract says; else none.
    AxisRepeat axisRepeat(int axis) const override
    {
        if (!(mPeriod[axis] > 0.0)) return {};
        return {mPeriod[axis], mBox.min[axis] + mReach, mBox.max[axis] - mReach};
    }

    /// Values held in tables so far (grids whose spacing divides the period; for tests).
    std::size_t tabledValues() const;

private:
    struct Table;
    /// The table for the batch's grid, building it on first use; null when none applies.
    const Table* table(const GridBatch& batch) const;

    struct BoundCache;
    /// Evaluates one block of a table (its runs bx, by, bz).
    void fillBlock(Table& t, std::size_t bx, std::size_t by, std::size_t bz) const;

    FieldPtr mChild;
    Box3 mBox;
    Vec3d mPeriod;
    double mReach;
    std::array<bool, 3> mMirror;
    mutable std::mutex mMutex;
    mutable std::vector<std::unique_ptr<Table>> mTables;
    std::unique_ptr<BoundCache> mBounds;
};

}  // namespace voxlat
