/// @file PlaneBands.h
/// @brief A plane batch's values only where they can matter for a threshold: nodes that prove
/// whole tiles of the plane on one side of it leave those tiles' values out (a slicer's layer of
/// a strut lattice, where most tiles lie far from the surface).
///
/// An interface of its own beside FieldNode (a node implements both; composites ask their child
/// through planeValuesOf()), so that the nodes that know how need no change of FieldNode.h.
#pragma once

#include "fields/core/FieldNode.h"

#include <algorithm>
#include <cstdint>

namespace voxlat {

/// The tiles of a plane batch (nz = 1) whose points but a one-point halo are cut in squares of
/// @a tile points: tile (a, b) holds the points 1 + a tile .. (a + 1) tile along x and likewise
/// along y; its footprint is its points' cells (half a spacing around each point).
struct PlaneTiles {
    int tile = 8;
    int nx = 0, ny = 0;  ///< tiles along x and y
    /// The tiles of @a plane, or none (nx = 0) when its points less the halo are not whole tiles.
    static PlaneTiles of(const GridBatch& plane, int tile)
    {
        PlaneTiles t;
        t.tile = tile;
        if (plane.nz != 1 || tile < 1 || plane.nx < 2 + tile || plane.ny < 2 + tile || (plane.nx - 2) % tile != 0 ||
            (plane.ny - 2) % tile != 0)
            return t;
        t.nx = (plane.nx - 2) / tile;
        t.ny = (plane.ny - 2) / tile;
        return t;
    }
    std::size_t size() const { return std::size_t(nx) * ny; }
};

/// A node that can leave out the tiles of a plane batch it proves on one side of a band.
class PlaneBands {
public:
    /// Values of the plane batch @a plane (PlaneTiles::of(plane, tile) has tiles) with the side of
    /// each tile at side[a * tiles.ny + b]: +1 when every value over the tile's footprint is proven
    /// above band.hi, -1 below band.lo, else 0. The values of the 0 tiles and of the points around
    /// them (the 3 x 3 neighbourhood of each of their points) are gridValues' own, the same doubles;
    /// the others are finite and mean nothing.
    virtual void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                             std::span<signed char> side) const = 0;

protected:
    ~PlaneBands() = default;
};

/// @a field's PlaneBands::planeValues when it has them, else its gridValues with every tile 0.
inline void planeValuesOf(const FieldNode& field, const GridBatch& plane, int tile, Interval band,
                          std::span<double> out, std::span<signed char> side)
{
    if (const auto* bands = dynamic_cast<const PlaneBands*>(&field)) {
        bands->planeValues(plane, tile, band, out, side);
        return;
    }
    field.gridValues(plane, out);
    std::fill(side.begin(), side.begin() + PlaneTiles::of(plane, tile).size(), static_cast<signed char>(0));
}

}  // namespace voxlat
