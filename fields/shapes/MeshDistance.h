/// @file MeshDistance.h
/// @brief A signed distance grid (a part's narrow band) sampled trilinearly as a field.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/core/PlaneBands.h"

#include <openvdb/openvdb.h>

#include <cstdint>
#include <optional>
#include <vector>

namespace voxlat {

/// Trilinear interpolation of a narrow-band signed distance grid (negative inside, world units).
///
/// The grid's samples sit at its voxel centres (index space = world through a linear transform).
/// Outside the narrow band the grid holds its flood-filled constants (+exterior width outside,
/// -interior width inside), so the field is the signed distance clamped to the band: exact
/// inside the band, and of the right sign everywhere. Gradients are those of the trilinear
/// interpolant (exact derivatives of what values() returns).
///
/// Bounds come from the grid itself, not from a Lipschitz constant (which would cull nothing
/// past the band): per 8^3 block of samples the minimum and maximum are stored once, and a box's
/// bound is the hull over the blocks its interpolation stencils touch; trilinear interpolation
/// never leaves the range of its eight samples, so the bound is conservative.
class MeshDistance final : public FieldNode, public PlaneBands {
public:
    /// @a grid: a level set with a linear, uniform transform; @a support: a box outside which the
    /// field is positive (the mesh's bounds grown by a voxel), or none.
    MeshDistance(openvdb::FloatGrid::ConstPtr grid, std::optional<Box3> support);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    /// Blocks whose points are the grid's own sample points (also every n-th one, for coarse
    /// passes) are looked up, not interpolated.
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;
    /// gridValues with each tile's side from the samples its footprint's cells interpolate; the
    /// thread's last plane is kept (a part read several times per plane).
    void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                     std::span<signed char> side, std::span<const TileNeed> need) const override;
    bool planeCheap() const override { return true; }
    std::optional<Box3> support() const override { return mSupport; }

    const openvdb::FloatGrid& grid() const { return *mGrid; }
    double voxel() const { return mVoxel; }

private:
    /// Value (and gradient when @a grad is set) at @a p.
    template <typename Accessor>
    double sample(Accessor& acc, const Vec3d& p, Vec3d* grad) const;
    /// The samples of the index box [lo, hi] as doubles, [x][y][z] order.
    void gatherSamples(const openvdb::Coord& lo, const openvdb::Coord& hi, double* dst) const;
    /// gridValues' paths for blocks on the grid's samples (every sample, or every n-th): false
    /// when the points fall between samples (nothing written).
    bool lookUpGrid(const GridBatch& batch, std::span<double> out) const;
    /// gridValues between the samples: sample()'s interpolation, separated by axis; with
    /// @a tileRange a plane's tiles' (of @a tile points) ranges of the samples their footprints
    /// interpolate. False when the points are too sparse for it (the point path gave the values;
    /// no range is set).
    bool interpolateGrid(const GridBatch& batch, std::span<double> out, int tile, Interval* tileRange) const;

    openvdb::FloatGrid::ConstPtr mGrid;
    std::uint64_t mId = 0;  ///< this grid's number among all made (planeValues' per-thread memo)
    std::optional<Box3> mSupport;
    double mVoxel = 1.0;
    Vec3d mOrigin{0.0};  ///< world position of index (0, 0, 0)
    float mBackground = 0.0f;
    openvdb::Coord mBlockMin{0};  ///< first block (in units of 8 voxels)
    openvdb::Coord mBlockDims{0};
    std::vector<float> mBlockLo, mBlockHi;
};

}  // namespace voxlat
