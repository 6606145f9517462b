/// @file StrutIndex.h
/// @brief A uniform bin grid over segments, each with a reach (a capsule around it), answering
/// "which segments may reach this box" in ascending index order.
#pragma once

#include "fields/core/FieldNode.h"

#include <cstdint>
#include <vector>

namespace voxlat {

/// Squared distance from point @a p to the segment [a, b].
double pointSegmentDistanceSqr(const Vec3d& p, const Vec3d& a, const Vec3d& b);

/// A lower bound of the distance between the segment [a, b] and @a box, exact up to rounding
/// (the squared distance is a convex quadratic between the points where the segment crosses
/// the box's slab faces: the minimum is among their ends and stationary points).
double segmentBoxDistance(const Vec3d& a, const Vec3d& b, const Box3& box);

/// Largest distance from a point of @a box to the segment [a, b] (upper bound: centre distance
/// plus the box's half diagonal).
double segmentBoxMaxDistance(const Vec3d& a, const Vec3d& b, const Box3& box);

/// Segments binned by the bounding boxes of their reach capsules. Immutable and thread-safe.
class StrutIndex {
public:
    StrutIndex() = default;
    StrutIndex(const std::vector<Vec3d>& a, const std::vector<Vec3d>& b, const std::vector<double>& reach);

    /// Replaces @a out with the segments whose reach capsule meets @a box, ascending. With
    /// @a boxDistance, also replaces it with segmentBoxDistance() of each segment kept to @a box
    /// (the same doubles; the test's own where it took one, so none is taken twice).
    void gather(const Box3& box, std::vector<std::uint32_t>& out, std::vector<double>* boxDistance = nullptr) const;
    /// Replaces @a out with the segments whose bins overlap @a box, ascending (a superset of
    /// gather(); no distance test).
    void candidates(const Box3& box, std::vector<std::uint32_t>& out) const;

    std::size_t size() const { return mA.size(); }
    /// The box holding every reach capsule.
    const Box3& bounds() const { return mBounds; }

private:
    std::vector<Vec3d> mA, mB;
    std::vector<double> mReach;
    Box3 mBounds;
    double mBin = 1.0;
    int mDims[3] = {0, 0, 0};
    std::vector<std::uint32_t> mStart;  ///< per bin, into mItems (size bins + 1)
    std::vector<std::uint32_t> mItems;
};

}  // namespace voxlat
