/// @file NodeStencils.h
/// @brief CoarseNodes' interpolation of a batch from the nodes it reads: eight-point midpoint
/// stencils along x, then y, then z. One loop of IEEE operations in a fixed order (each value
/// summed from 0 over the stencil's eight points, first to last; no contraction), built for the
/// target's baseline, for AVX-512F (NodeStencilsAvx512.cpp) and for AVX2 (NodeStencilsAvx2.cpp):
/// the same doubles any way.
/// The passes run over whole lines of values (x and y) and over a row's odd voxels at once (z),
/// the form the compiler puts in lanes.
#pragma once

#include <array>
#include <cstddef>
#include <cstring>

namespace voxlat::node_stencils {

/// The eight-point Lagrange weights at the midpoint of nodes 3 and 4 of 0..7.
constexpr std::array<double, 8> kMidpoint{-5.0 / 2048,   49.0 / 2048,   -245.0 / 2048, 1225.0 / 2048,
                                          1225.0 / 2048, -245.0 / 2048, 49.0 / 2048,   -5.0 / 2048};
/// A midpoint between nodes m and m + 1 reads m - 3 .. m + 4.
constexpr int kHalfStencil = 4;

// The loops are static: each build of them (the baseline's, AVX-512F's) keeps its own copy,
// where an inline function's copies would be merged into one at link time, whichever's flags.
static inline int floorDiv(int a, int b)
{
    return a >= 0 ? a / b : -((b - 1 - a) / b);
}

/// A batch's interpolation: the nodes it reads (count[0] x count[1] x count[2], z fastest, node
/// m of an axis its lattice voxel 2 (lo + m)), its first voxel's lattice index and its size.
struct NodePasses {
    const double* nodes;
    std::array<int, 3> lo, count;
    std::array<int, 3> first, n;
    double* alongX;   ///< n[0] x count[1] x count[2] values of scratch
    double* alongXY;  ///< n[0] x n[1] x count[2] values of scratch
    double* out;      ///< n[0] x n[1] x n[2] values, z fastest
};

/// Line @a v of an axis whose first voxel has lattice index @a first (lattice voxel first + v):
/// node m = floor((first + v) / 2) where that index is even, else the stencil over nodes m - 3 ..
/// m + 4: @a to gets @a count values of lines @a stride apart from @a from (line 0 the axis's
/// node lo0).
static inline void combineLines(int first, int lo0, int v, const double* from, std::size_t stride, std::size_t count,
                                double* to)
{
    const int voxelIndex = first + v;
    const int m = floorDiv(voxelIndex, 2) - lo0;
    if ((voxelIndex & 1) == 0) {
        std::memcpy(to, from + std::size_t(m) * stride, count * sizeof(double));
        return;
    }
    for (std::size_t q = 0; q < count; ++q) to[q] = 0.0;
    for (int l = 0; l < 8; ++l) {
        const double w = kMidpoint[std::size_t(l)];
        const double* line = from + std::size_t(m - (kHalfStencil - 1) + l) * stride;
        for (std::size_t q = 0; q < count; ++q) to[q] += w * line[q];
    }
}

/// The three passes (x, then y, over the nodes' planes and rows: the fewest values, the nodes
/// along z until the last; then z to the batch's voxels).
static inline void nodePassesLoop(const NodePasses& p)
{
    const std::size_t cy = std::size_t(p.count[1]), cz = std::size_t(p.count[2]);
    const std::size_t nx = std::size_t(p.n[0]), ny = std::size_t(p.n[1]), nz = std::size_t(p.n[2]);
    for (std::size_t i = 0; i < nx; ++i)
        combineLines(p.first[0], p.lo[0], int(i), p.nodes, cy * cz, cy * cz, p.alongX + i * cy * cz);
    for (std::size_t i = 0; i < nx; ++i)
        for (std::size_t j = 0; j < ny; ++j)
            combineLines(p.first[1], p.lo[1], int(j), p.alongX + i * cy * cz, cz, cz, p.alongXY + (i * ny + j) * cz);
    // Along z: voxel k takes node m_k = floor((first + k) / 2) - lo where its index is even; the
    // odd ones, every second voxel from firstOdd, take stencils starting one node apart.
    const int fz = p.first[2];
    const std::size_t firstOdd = (fz & 1) != 0 ? 0 : 1;
    const std::size_t odds = nz > firstOdd ? (nz - firstOdd + 1) / 2 : 0;
    const int oddNode = floorDiv(fz + int(firstOdd), 2) - p.lo[2] - (kHalfStencil - 1);
    const std::size_t firstEven = 1 - firstOdd;
    const std::size_t evens = nz > firstEven ? (nz - firstEven + 1) / 2 : 0;
    const int evenNode = floorDiv(fz + int(firstEven), 2) - p.lo[2];
    double odd[64];
    for (std::size_t r = 0; r < nx * ny; ++r) {
        const double* line = p.alongXY + r * cz;
        double* to = p.out + r * nz;
        for (std::size_t j = 0; j < evens; ++j) to[firstEven + 2 * j] = line[std::size_t(evenNode) + j];
        for (std::size_t start = 0; start < odds; start += 64) {
            const std::size_t chunk = odds - start < 64 ? odds - start : 64;
            const double* from = line + std::size_t(oddNode) + start;
            for (std::size_t j = 0; j < chunk; ++j) odd[j] = 0.0;
            for (int l = 0; l < 8; ++l) {
                const double w = kMidpoint[std::size_t(l)];
                for (std::size_t j = 0; j < chunk; ++j) odd[j] += w * from[j + std::size_t(l)];
            }
            for (std::size_t j = 0; j < chunk; ++j) to[firstOdd + 2 * (start + j)] = odd[j];
        }
    }
}

/// nodePassesLoop built for AVX-512F (NodeStencilsAvx512.cpp; the same doubles). Runs only where
/// hasAvx512Rows().
void nodePassesAvx512(const NodePasses& p);

/// nodePassesLoop built for AVX2 (NodeStencilsAvx2.cpp; the same doubles), for CPUs without
/// AVX-512F. Runs only where hasAvx2Rows().
void nodePassesAvx2(const NodePasses& p);

}  // namespace voxlat::node_stencils
