/// @file GridLeavesReused.h
/// @brief A field whose batches that are leaves of a grid evaluated from it are read from that
/// grid: a second sparse pass over a wider band evaluates only the leaves the first did not.
#pragma once

#include "engine/core/Domain.h"

#include <openvdb/openvdb.h>

#include <cmath>
#include <cstddef>
#include <span>

namespace voxlat {

/// @a field, except that a batch which is one of @a grid's leaves, as evaluateSparse() on
/// @a domain makes its batches (8^3 points, spacing the voxel, origin domain.worldOf(leaf origin)
/// bit for bit), takes that leaf's floats. When @a grid is evaluateSparse(@a field, @a domain, o)
/// for options o without clipToDomain, those floats are what the evaluator would store again (a
/// float widened to a double and narrowed back is the same float): another evaluateSparse()
/// over this field on @a domain gives the grid a fresh evaluation of @a field gives. Everything
/// else goes to @a field. @a field, @a grid and @a domain must outlive it.
class GridLeavesReused final : public FieldNode {
public:
    GridLeavesReused(const FieldNode& field, const openvdb::FloatGrid& grid, const Domain& domain)
        : mField(field), mGrid(grid), mDomain(domain)
    {
    }

    void values(std::span<const Vec3d> points, std::span<double> out) const override { mField.values(points, out); }
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override
    {
        mField.gradients(points, out, grad);
    }
    void gridValues(const GridBatch& batch, std::span<double> out) const override
    {
        if (const LeafT* leaf = leafOf(batch)) {
            const float* data = leaf->buffer().data();
            for (std::size_t i = 0; i < LeafT::SIZE; ++i) out[i] = double(data[i]);
            return;
        }
        mField.gridValues(batch, out);
    }
    Interval bound(const Box3& box) const override { return mField.bound(box); }

private:
    using LeafT = openvdb::FloatGrid::TreeType::LeafNodeType;

    /// The grid's leaf that @a batch is, or null.
    const LeafT* leafOf(const GridBatch& batch) const
    {
        constexpr int n = int(LeafT::DIM);
        if (batch.nx != n || batch.ny != n || batch.nz != n || batch.spacing != Vec3d(mDomain.voxel)) return nullptr;
        openvdb::Coord ijk;
        for (int a = 0; a < 3; ++a)
            ijk[a] = int(std::lround((batch.origin[a] - mDomain.box.min[a]) / mDomain.voxel - 0.5));
        if (((ijk.x() | ijk.y() | ijk.z()) & (n - 1)) != 0 || mDomain.worldOf(ijk) != batch.origin) return nullptr;
        const LeafT* leaf = mGrid.tree().probeConstLeaf(ijk);
        return leaf && leaf->buffer().data() ? leaf : nullptr;
    }

    const FieldNode& mField;
    const openvdb::FloatGrid& mGrid;
    const Domain& mDomain;
};

}  // namespace voxlat
