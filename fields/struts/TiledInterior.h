/// @file TiledInterior.h
/// @brief A strut field read from a cheaper equal field away from the struts where the two differ:
/// a frame trimmed `within:` a solid is, deeper inside the solid than the kernel's reach, the
/// untrimmed box frame its cells come from, which a PeriodicTiling tables one period deep.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/core/PlaneBands.h"

#include <oneapi/tbb/collaborative_call_once.h>

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

namespace voxlat {

/// value(p) = exact(p), with gridValues() taken from a field @a same in the leaves that lie
/// farther than @a reach from every segment of @a differing. The caller guarantees
///   exact(p) = same(p)   (up to rounding)
/// wherever no segment of @a differing lies within @a reach of p: both sum the same struts there
/// (a trimmed frame and its untrimmed one: @a differing holds the struts the trim removed or
/// cut, and the trimmed frame's cut pieces; @a reach the kernel's cut-off radius).
///
/// The parts (Parts) are made the first time a batch more than one sample thick is asked for,
/// by all threads that need them: slices and point queries never pay for them. A batch of
/// 8 x 8 x 8m points (a stack of leaves) is decided leaf by leaf, any other batch whole; a leaf
/// is far when every cell of a coarse grid (marked once, with segmentBoxDistance, exact up to
/// rounding) its points' box meets is. Runs of far leaves are read from @a same, the rest from
/// @a exact, in sub-batches of the stack; which leaves are far depends only on the batch, so the
/// values do not depend on threads. Batches one sample thick (slices; planeValues) are
/// @a exact's, as are values(), gradients(), bound() and support().
class TiledInterior final : public FieldNode, public PlaneBands {
public:
    struct Parts {
        FieldPtr same;  ///< null: nothing is read from it (every batch is @a exact's)
        std::vector<std::array<Vec3d, 2>> differing;
        double reach = 0.0;  ///< how far a segment is seen (mm)
    };
    /// @param make gives the parts on first use (it may throw: a cancel).
    TiledInterior(FieldPtr exact, std::function<Parts()> make);
    ~TiledInterior() override;

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override { return mExact->bound(box); }
    void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                     std::span<signed char> side, std::span<const TileNeed> need) const override;
    bool planeCheap() const override { return planeCheapOf(*mExact); }
    std::optional<Box3> support() const override { return mExact->support(); }

    /// Whether every point of @a box lies farther than the reach from every differing segment
    /// (false when there is no @a same to read). Makes the parts when not made yet.
    bool far(const Box3& box) const;

private:
    struct Interior;
    const Interior& interior() const;

    FieldPtr mExact;
    std::function<Parts()> mMake;
    mutable tbb::collaborative_once_flag mOnce;
    mutable std::unique_ptr<Interior> mInterior;
};

}  // namespace voxlat
