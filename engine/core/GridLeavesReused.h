/// @file GridLeavesReused.h
/// @brief A field whose batches that are leaves of a grid evaluated from it are read from that
/// grid: a second sparse pass over a wider band evaluates only the leaves the first did not.
#pragma once

#include "engine/core/Domain.h"

#include <openvdb/openvdb.h>

#include <tbb/parallel_for.h>

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace voxlat {

/// The voxel of @a domain whose centre is @a points' origin, bit for bit (domain.worldOf()), into
/// @a ijk; false when it is none or the spacing is not the voxel.
inline bool gridPointIndex(const Domain& domain, const GridBatch& points, openvdb::Coord& ijk)
{
    if (points.spacing != Vec3d(domain.voxel)) return false;
    for (int a = 0; a < 3; ++a) ijk[a] = int(std::lround((points.origin[a] - domain.box.min[a]) / domain.voxel - 0.5));
    return domain.worldOf(ijk) == points.origin;
}

/// The index of the first leaf of @a batch as evaluateSparse() on @a domain makes it (8 x 8 x 8m
/// points: a leaf, or a stack of m leaves along z; spacing the voxel; origin domain.worldOf() of
/// a leaf's origin bit for bit) into @a ijk; false when it is no leaf's or stack's batch.
inline bool gridLeafOrigin(const Domain& domain, const GridBatch& batch, openvdb::Coord& ijk)
{
    constexpr int n = int(openvdb::FloatGrid::TreeType::LeafNodeType::DIM);
    if (batch.nx != n || batch.ny != n || batch.nz % n != 0) return false;
    return gridPointIndex(domain, batch, ijk) && ((ijk.x() | ijk.y() | ijk.z()) & (n - 1)) == 0;
}

/// Replaces each leaf of @a grid for which @a drop(leaf) is true (decided in parallel) by a
/// leaf-sized inactive tile of the background value, freeing it.
template <class Drop>
void tileLeavesWhere(openvdb::FloatGrid& grid, Drop drop)
{
    std::vector<const openvdb::FloatGrid::TreeType::LeafNodeType*> leaves;
    grid.tree().getNodes(leaves);
    std::vector<std::uint8_t> dropped(leaves.size(), 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size()), [&](const auto& range) {
        for (std::size_t n = range.begin(); n != range.end(); ++n) dropped[n] = drop(*leaves[n]);
    });
    for (std::size_t n = 0; n < leaves.size(); ++n)
        if (dropped[n]) grid.tree().addTile(1, leaves[n]->origin(), grid.background(), false);
}

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
            openvdb::Coord first;
            bool all = gridLeafOrigin(mDomain, batch, first);
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
