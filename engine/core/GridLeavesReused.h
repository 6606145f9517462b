/// @file GridLeavesReused.h
/// @brief A field whose batches that are leaves of a grid evaluated from it are read from that
/// grid: a second sparse pass over a wider band evaluates only the leaves the first did not.
#pragma once

#include "engine/core/Domain.h"

#include <openvdb/openvdb.h>

#include <array>
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
/// else goes to @a field. A stack of leaves along z (SparseOptions::stackLeaves) whose every leaf
/// the grid holds is read the same way. @a field, @a grid and @a domain must outlive it.
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
        // A stack of leaves (SparseOptions::stackLeaves: 8 x 8 x 8m points) whose every leaf the
        // grid holds reads them all; a stack missing one is evaluated whole (its values are the
        // stack's alone, so the leaves read and those evaluated agree).
        constexpr int n = int(LeafT::DIM);
        const int count = batch.nz % n == 0 ? batch.nz / n : 0;
        std::array<const LeafT*, 16> leaves{};
        if (count >= 1 && count <= 16) {
            GridBatch leafBatch = batch;
            leafBatch.nz = n;
            openvdb::Coord first;
            bool all = leafIndex(leafBatch, first);
            for (int m = 0; m < count && all; ++m) {
                leaves[std::size_t(m)] = leafAt(first + openvdb::Coord(0, 0, m * n));
                all = leaves[std::size_t(m)] != nullptr;
            }
            if (all) {
                for (int m = 0; m < count; ++m) {
                    const float* data = leaves[std::size_t(m)]->buffer().data();
                    for (int ij = 0; ij < n * n; ++ij)
                        for (int k = 0; k < n; ++k)
                            out[std::size_t(ij) * batch.nz + std::size_t(m * n + k)] =
                                double(data[std::size_t(ij) * n + std::size_t(k)]);
                }
                return;
            }
        }
        mField.gridValues(batch, out);
    }
    Interval bound(const Box3& box) const override { return mField.bound(box); }

private:
    using LeafT = openvdb::FloatGrid::TreeType::LeafNodeType;

    /// The index of the leaf whose batch evaluateSparse() makes as @a batch (8^3 points, the
    /// voxel's spacing, origin domain.worldOf() of a leaf's origin bit for bit) into @a ijk;
    /// false when it is no leaf's batch.
    bool leafIndex(const GridBatch& batch, openvdb::Coord& ijk) const
    {
        constexpr int n = int(LeafT::DIM);
        if (batch.nx != n || batch.ny != n || batch.nz != n || batch.spacing != Vec3d(mDomain.voxel)) return false;
        for (int a = 0; a < 3; ++a)
            ijk[a] = int(std::lround((batch.origin[a] - mDomain.box.min[a]) / mDomain.voxel - 0.5));
        return ((ijk.x() | ijk.y() | ijk.z()) & (n - 1)) == 0 && mDomain.worldOf(ijk) == batch.origin;
    }
    /// The grid's leaf at @a ijk with values, or null.
    const LeafT* leafAt(const openvdb::Coord& ijk) const
    {
        const LeafT* leaf = mGrid.tree().probeConstLeaf(ijk);
        return leaf && leaf->buffer().data() ? leaf : nullptr;
    }

    const FieldNode& mField;
    const openvdb::FloatGrid& mGrid;
    const Domain& mDomain;
};

}  // namespace voxlat
