/// @file KeptGridLeaves.h
/// @brief A density solve's grid of a GridValueMemo's values, kept as that memo's leaves.
#pragma once

#include "engine/core/Domain.h"
#include "engine/core/GridLeavesReused.h"
#include "fields/core/GridValueMemo.h"

#include <openvdb/openvdb.h>

#include <algorithm>
#include <functional>
#include <memory>
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
                    mGrid->tree().probeConstLeaf(first + openvdb::Coord(0, 0, int(LeafT::DIM) * int(m))))
                values[m] = leaf->buffer().data();
    }

    void dropIf(const std::function<bool(const GridBatch&, const float*)>& unread) override
    {
        // A leaf-sized tile in place of each dropped leaf: not a leaf, so never served.
        tileLeavesWhere(*mGrid, [&](const LeafT& leaf) {
            const float* data = leaf.buffer().data();
            if (!data) return false;
            GridBatch batch;
            batch.origin = mDomain.worldOf(leaf.origin());
            batch.spacing = Vec3d(mDomain.voxel);
            return unread(batch, data);
        });
    }

private:
    using LeafT = openvdb::FloatGrid::TreeType::LeafNodeType;

    openvdb::FloatGrid::Ptr mGrid;
    Domain mDomain;
};

}  // namespace voxlat
