/// @file KeptGridLeaves.h
/// @brief A density solve's grid of a GridValueMemo's values, kept as that memo's leaves.
#pragma once

#include "engine/core/Domain.h"
#include "engine/core/GridLeavesReused.h"
#include "engine/core/SparseEvaluator.h"
#include "fields/core/GridValueMemo.h"

#include <openvdb/openvdb.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <memory>
#include <optional>
#include <span>

namespace voxlat {

/// The leaves of @a grid, evaluated by evaluateSparse() on @a domain from a GridValueMemo (as
/// GridLeavesReused requires: no clipToDomain), as that memo's KeptLeaves: each leaf's floats
/// are the memo's values for the batch it was evaluated in, and a stack's leaves lie on the same
/// aligned stacks whatever band a grid is evaluated in.
class KeptGridLeaves final : public KeptLeaves {
public:
    KeptGridLeaves(openvdb::FloatGrid::Ptr grid, const Domain& domain) : mGrid(std::move(grid)), mDomain(domain) {}

    void leaves(const GridBatch& batch, std::span<const float*> values) const override
    {
        std::fill(values.begin(), values.end(), nullptr);
        openvdb::Coord first;
        if (!gridLeafOrigin(mDomain, batch, first)) return;
        for (std::size_t m = 0; m < values.size(); ++m)
            if (const LeafT* leaf =
                    mGrid->tree().probeConstLeaf(first + openvdb::Coord(0, 0, int(LeafT::DIM) * int(m)));
                leaf && !leaf->buffer().empty())
                values[m] = leaf->buffer().data();
    }

    void release(const GridBatch& batch, std::uint32_t leaves) override
    {
        openvdb::Coord first;
        if (!gridLeafOrigin(mDomain, batch, first)) return;
        // The tree's nodes stay as they are (other threads walk them): the buffer alone is
        // swapped for an unallocated one, and freed with it.
        for (int m = 0; m < 32; ++m)
            if (leaves >> m & 1u)
                if (LeafT* leaf = mGrid->tree().probeLeaf(first + openvdb::Coord(0, 0, int(LeafT::DIM) * m))) {
                    typename LeafT::Buffer none(openvdb::PartialCreate(), 0.0f);
                    leaf->buffer().swap(none);
                }
    }

    void dropIf(const std::function<bool(const GridBatch&, const float*)>& unread) override
    {
        // A leaf-sized tile in place of each dropped leaf: not a leaf, so never served.
        tileLeavesWhere(*mGrid, [&](const LeafT& leaf) {
            if (leaf.buffer().empty()) return false;
            const float* data = leaf.buffer().data();
            GridBatch batch;
            batch.origin = mDomain.worldOf(leaf.origin());
            batch.spacing = Vec3d(mDomain.voxel);
            return unread(batch, data);
        });
    }

    /// The held voxels whose centres lie inside @a box (KnownSamples' test on them).
    bool meets(const Box3& box, const Interval& band) const override
    {
        // Voxel centres min + (c + 1/2) voxel inside the box, a hair within it.
        openvdb::Coord lo, hi;
        for (int a = 0; a < 3; ++a) {
            const double margin = 1e-9 * (std::abs(box.min[a]) + std::abs(box.max[a]) + mDomain.voxel);
            lo[a] = int(std::ceil((box.min[a] + margin - mDomain.box.min[a]) / mDomain.voxel - 0.5));
            hi[a] = int(std::floor((box.max[a] - margin - mDomain.box.min[a]) / mDomain.voxel - 0.5));
            if (lo[a] > hi[a]) return false;
        }
        return heldValuesMeet(*mGrid, openvdb::CoordBBox(lo, hi), band);
    }

    /// The range of the held values at @a points (the grid's voxels, spacing its voxel), when
    /// leaves with values hold every one of them, widened by an eighth of its width either side:
    /// a cull then keeps fewer leaves than a bound over the points' box keeps (W2g's 50 mm
    /// frames: 247 of 261, 150 of 161 and 144 of 152 thousand), not every one whose voxels meet
    /// or nearly meet a band. Its values are read back by those that interpolate between voxels:
    /// report.html's picture evaluates the field in tiles (the wireframe's 0.29 -> 0.85 s with
    /// the range unwidened, 0.44 s widened).
    std::optional<Interval> heldRange(const GridBatch& points) const override
    {
        openvdb::Coord lo;
        if (!gridPointIndex(mDomain, points, lo)) return std::nullopt;
        const std::optional<Interval> held = heldValuesRange(
            *mGrid, openvdb::CoordBBox(lo, lo + openvdb::Coord(points.nx - 1, points.ny - 1, points.nz - 1)));
        if (!held) return std::nullopt;
        const double half = 0.125 * (held->hi - held->lo);
        return Interval(held->lo - half, held->hi + half);
    }

private:
    using LeafT = openvdb::FloatGrid::TreeType::LeafNodeType;

    openvdb::FloatGrid::Ptr mGrid;
    Domain mDomain;
};

}  // namespace voxlat
