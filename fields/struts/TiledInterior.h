/// @file TiledInterior.h
/// @brief A strut field read from a cheaper equal field away from the struts where the two differ:
/// a frame trimmed `within:` a solid is, deeper inside the solid than the kernel's reach, the
/// untrimmed box frame its cells come from, which a PeriodicTiling tables one period deep.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/core/PlaneBands.h"

#include <array>
#include <cstdint>
#include <vector>

namespace voxlat {

/// value(p) = exact(p), with gridValues() taken from @a same in the leaves that lie farther than
/// @a reach from every segment of @a differing. The caller guarantees
///   exact(p) = same(p)   (up to rounding)
/// wherever no segment of @a differing lies within @a reach of p: both sum the same struts there
/// (a trimmed frame and its untrimmed one: @a differing holds the struts the trim removed or
/// cut, and the trimmed frame's cut pieces; @a reach the kernel's cut-off radius).
///
/// Where it applies: a batch of 8 x 8 x 8m points (a stack of leaves) is decided leaf by leaf,
/// any other batch whole; a leaf is far when every cell of a coarse grid (marked once, with
/// segmentBoxDistance, exact up to rounding) its points' box meets is. Runs of far leaves are
/// read from @a same, the rest from @a exact, in sub-batches of the stack; which leaves are far
/// depends only on the batch, so the values do not depend on threads. Batches one sample
/// thick (slices; planeValues) are @a exact's, as are values(), gradients() and support();
/// bound() is @a same's on far boxes (its tables' cache), @a exact's elsewhere.
class TiledInterior final : public FieldNode, public PlaneBands {
public:
    /// @param differing segments as (a, b) pairs; @param reach how far a segment is seen (mm).
    TiledInterior(FieldPtr exact, FieldPtr same, const std::vector<std::array<Vec3d, 2>>& differing, double reach);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;
    void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                     std::span<signed char> side, std::span<const TileNeed> need) const override;
    bool planeCheap() const override { return planeCheapOf(*mExact); }
    std::optional<Box3> support() const override { return mExact->support(); }

    /// Whether every point of @a box lies farther than the reach from every differing segment.
    bool far(const Box3& box) const;

private:
    FieldPtr mExact, mSame;
    double mReach;
    /// Coarse cells (x fastest) over the differing segments' reach: 1 where a segment is within
    /// the reach of the cell's box; beyond the grid every point is far.
    Vec3d mOrigin{0.0};
    double mCell = 1.0;
    std::array<long, 3> mDims{0, 0, 0};
    std::vector<std::uint8_t> mNear;
};

}  // namespace voxlat
