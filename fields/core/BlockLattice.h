/// @file BlockLattice.h
/// @brief A field sampled over a regular lattice of points in 8^3 blocks, in parallel: the one
/// loop behind the density solve's coarse pass and pieces, density tables and skin-frame grids.
#pragma once

#include "fields/core/FieldNode.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <array>
#include <cstddef>
#include <span>
#include <vector>

namespace voxlat {

/// The points base + (index * stride + offset) * step along each axis, index = 0 .. count - 1.
/// (The form keeps each caller's own rounding: a domain's voxel centre min + (ijk + 1/2) voxel is
/// base min, offset 1/2, step voxel.)
struct BlockLattice {
    Vec3d base{0.0};
    Vec3d step{1.0};
    Vec3d offset{0.0};
    std::array<int, 3> stride{1, 1, 1};
    std::array<int, 3> count{0, 0, 0};
    /// Points of a block along z (8 x 8 x depth): 8, or a multiple of 8 for long rows along z (a
    /// convolution lattice's rows of 8 points are mostly their set-up).
    int depth = 8;
    /// The points are a voxel lattice's centres (step the voxel, offset 1/2 plus a whole number,
    /// the same stride along every axis): batches say so (GridBatch::onLattice), their first
    /// point voxel latticeOffset + stride times its index.
    bool onLattice = false;
    Vec3d latticeMin{0.0};
    std::array<int, 3> latticeOffset{0, 0, 0};

    /// Blocks along each axis (the last one cut at the lattice's far face).
    std::array<int, 3> blocks() const
    {
        return {(count[0] + 7) / 8, (count[1] + 7) / 8, (count[2] + depth - 1) / depth};
    }
    std::size_t blockCount() const
    {
        const auto b = blocks();
        return std::size_t(b[0]) * std::size_t(b[1]) * std::size_t(b[2]);
    }
    /// The lattice index of block @a b's first point (blocks numbered x-major, z fastest).
    std::array<int, 3> firstIndex(std::size_t b) const
    {
        const auto n = blocks();
        return {int(b / (std::size_t(n[1]) * n[2])) * 8, int((b / n[2]) % n[1]) * 8, int(b % n[2]) * depth};
    }
    /// Block @a b as a batch for FieldNode::gridValues().
    GridBatch batch(std::size_t b) const
    {
        const auto first = firstIndex(b);
        GridBatch g;
        for (int a = 0; a < 3; ++a) {
            g.origin[a] = base[a] + (double(first[a]) * stride[a] + offset[a]) * step[a];
            g.spacing[a] = step[a] * stride[a];
        }
        g.nx = std::min(8, count[0] - first[0]);
        g.ny = std::min(8, count[1] - first[1]);
        g.nz = std::min(depth, count[2] - first[2]);
        if (onLattice) {
            g.onLattice = true;
            g.latticeMin = latticeMin;
            g.latticeStride = stride[0];
            g.latticeVoxel = step[0];
            for (int a = 0; a < 3; ++a)
                g.latticeIndex[std::size_t(a)] = latticeOffset[std::size_t(a)] + first[a] * stride[0];
        }
        return g;
    }
};

/// Evaluates @a field on every block of @a lattice in parallel and calls
/// `fn(b, batch, first, values)` per block: `first` its first lattice index, `values` in
/// gridValues() order (x-major, z fastest). Blocks are independent, so whatever fn writes per block
/// is the same for any thread count; fn runs concurrently for different blocks.
template <typename Fn>
void sampleBlocks(const FieldNode& field, const BlockLattice& lattice, Fn&& fn)
{
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, lattice.blockCount()), [&](const auto& range) {
        std::vector<double> values(std::size_t(64) * std::size_t(lattice.depth));
        for (std::size_t b = range.begin(); b != range.end(); ++b) {
            const GridBatch batch = lattice.batch(b);
            const std::span<double> out(values.data(), batch.size());
            field.gridValues(batch, out);
            fn(b, batch, lattice.firstIndex(b), std::span<const double>(out));
        }
    });
}

}  // namespace voxlat
