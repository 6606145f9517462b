/// @file CoarseNodes.h
/// @brief A smooth field's values on a voxel lattice from exact nodes every second voxel: the
/// nodes are evaluated once per lattice in blocks shared by every batch, and each batch's points
/// are interpolated from them by eight-point Lagrange stencils along x, then y, then z.
///
/// The bound. Along one axis, a point midway between nodes 2h apart takes the eight nodes nearest
/// it (weights {-5, 49, -245, 1225, 1225, -245, 49, -5} / 2048, their absolute sum L = 1.488); a
/// point on a node takes the node. With E_a the error of one axis's interpolation of the field
/// (ColumnStencils.h: at most K_a sum_j peak_j exp(-d_j^2 / 4 sigma_j^2), K_a = |prod_l (x - x_l)|
/// / 8! (2h / sigma)^8 C8_a, the product 43.07 in node steps at a midpoint, C8_a the struts' largest
/// eighth-derivative factor along axis a), interpolating x, then y, then z misses by at most
///     E_z + L E_y + L^2 E_x <= (K_z + L K_y + L^2 K_x) sum_j peak_j exp(-d_j^2 / 4 sigma_j^2),
/// where I_z I_y I_x f - f = (I_z f - f) + I_z (I_y f - f) + I_z I_y (I_x f - f) and each I_a
/// multiplies a function's largest value by at most L. (x first: the passes then run over the
/// fewest values, the nodes along z until the last.) coarseNodesBound() gives that factor per
/// unit of the peaks near; a field uses the nodes only where it is below its tolerance. A strut's
/// cut-off (its contribution dropped beyond r_c, at most eps of its peak) is a step the stencils
/// do not see: an interpolated value may miss the cut field by up to (1 + L^3) eps peak_j more
/// there, against the eps peak_j every path drops.
#pragma once

#include "fields/core/FieldNode.h"

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>

namespace voxlat {

/// The factor K_z + L K_y + L^2 K_x above for nodes @a nodeSpacing apart (twice the voxel), struts
/// of least kernel width @a sigma and eighth-derivative factors @a c8 (x, y, z).
double coarseNodesBound(double nodeSpacing, double sigma, const std::array<double, 3>& c8);

/// The exact nodes of the lattice a field is evaluated on, in blocks of 8 x 8 x 32 nodes (16 x 16
/// x 64 voxels), each evaluated once, by whichever thread first needs it, with the same doubles
/// whichever does. Thread-safe. A block's values hang on the lattice and the block alone, so a
/// batch's interpolated values hang on its points alone: the same for any thread count. Only the
/// last lattice asked for is kept: a batch of another drops the blocks held (a batch still reading
/// one keeps it until it is done), so a field evaluated on many grids in turn (a script's) holds
/// one grid's nodes at most.
class CoarseNodes {
public:
    /// Evaluates the exact values of a batch of nodes (spacing twice the lattice's voxel).
    using Exact = std::function<void(const GridBatch&, std::span<double>)>;

    CoarseNodes();
    ~CoarseNodes();
    CoarseNodes(const CoarseNodes&) = delete;
    CoarseNodes& operator=(const CoarseNodes&) = delete;

    /// The values at the points of @a batch (onLattice, spacing equal along the axes) from the
    /// lattice's nodes, the blocks not yet made evaluated by @a exact. A strided batch
    /// (GridBatch::latticeStride above 1) must have every point a node (an even stride from even
    /// voxel indices): its values are the nodes'.
    void interpolate(const GridBatch& batch, std::span<double> out, const Exact& exact) const;
    /// Bytes the blocks held hold.
    std::size_t bytes() const;

private:
    struct Impl;
    std::unique_ptr<Impl> mImpl;
};

}  // namespace voxlat
