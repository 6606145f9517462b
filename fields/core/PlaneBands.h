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
#include <bit>
#include <cmath>
#include <cstdint>
#include <span>

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
    /// Tile (a, b)'s footprint in @a plane: its points' cells, half a spacing around each.
    Box3 footprint(const GridBatch& plane, int a, int b) const
    {
        const Vec3d lo = plane.point(1 + a * tile, 1 + b * tile, 0),
                    hi = plane.point((a + 1) * tile, (b + 1) * tile, 0);
        const Vec3d half(0.5 * plane.spacing.x(), 0.5 * plane.spacing.y(), 0.0);
        return {lo - half, hi + half};
    }
};

/// What a caller needs of one tile of a plane batch (planeValues' @a need).
enum class TileNeed : std::uint8_t {
    Decide,  ///< its side when the node proves one (values left out), else its values
    Exact,   ///< its values (and its halo's), side 0, even where a side could be proven
    Skip,    ///< nothing: neither values nor side (another operand decided it)
};

/// Calls @a f(b0, b1) for each run of set bits b0..b1 of @a bits, in increasing order (a column's
/// runs of tiles).
template <class F>
void forEachTileRun(std::uint64_t bits, F&& f)
{
    while (bits != 0) {
        const int b0 = std::countr_zero(bits);
        const std::uint64_t from = bits >> b0;
        const int b1 = b0 + (from == ~std::uint64_t(0) ? 64 : std::countr_zero(~from)) - 1;
        bits = b1 >= 63 ? 0 : bits & ~((std::uint64_t(2) << b1) - 1);
        f(b0, b1);
    }
}

/// @a need's entry for tile @a t (an empty @a need: every tile Decide).
inline TileNeed needOf(std::span<const TileNeed> need, std::size_t t)
{
    return need.empty() ? TileNeed::Decide : need[t];
}

/// |band.lo| + |band.hi| over the finite ends: the scale of a band's rounding slack.
inline double finiteScale(Interval band)
{
    return (std::isfinite(band.lo) ? std::abs(band.lo) : 0.0) + (std::isfinite(band.hi) ? std::abs(band.hi) : 0.0);
}

/// A node that can leave out the tiles of a plane batch it proves on one side of a band.
class PlaneBands {
public:
    /// Values of the plane batch @a plane (PlaneTiles::of(plane, tile) has tiles) with the side of
    /// each tile at side[a * tiles.ny + b]: +1 when every value over the tile's footprint is proven
    /// above band.hi, -1 below band.lo, else 0 (band ends may be infinite: no side there). @a need
    /// (empty: every tile Decide) says per tile what the caller needs: a Skip tile's side is 0 and
    /// means nothing, an Exact tile's side is 0. The values of the tiles with side 0 that are not
    /// skipped, and of the points around them (the 3 x 3 neighbourhood of each of their points),
    /// are gridValues' own, the same doubles (unless planeTolerance() says otherwise); the others
    /// are finite and mean nothing.
    virtual void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                             std::span<signed char> side, std::span<const TileNeed> need) const = 0;
    /// Whether deciding a plane's tiles costs little next to a strut lattice's sums (a distance
    /// grid, a primitive): a boolean asks such operands first, so the costly ones skip the tiles
    /// the cheap ones decide.
    virtual bool planeCheap() const { return false; }
    /// How far planeValues' values of the open tiles may be from gridValues', per unit of the
    /// node's own scale (StrutConvolution: of the struts' peaks near; its interpolated columns):
    /// 0, the same doubles. A node mapping such values may then map them more cheaply as well
    /// (IsoRadius: in single precision).
    virtual double planeTolerance() const { return 0.0; }

protected:
    ~PlaneBands() = default;
};

/// @a field's PlaneBands::planeValues when it has them, else its gridValues with every tile 0.
inline void planeValuesOf(const FieldNode& field, const GridBatch& plane, int tile, Interval band,
                          std::span<double> out, std::span<signed char> side, std::span<const TileNeed> need = {})
{
    if (const auto* bands = dynamic_cast<const PlaneBands*>(&field)) {
        bands->planeValues(plane, tile, band, out, side, need);
        return;
    }
    field.gridValues(plane, out);
    std::fill(side.begin(), side.begin() + PlaneTiles::of(plane, tile).size(), static_cast<signed char>(0));
}

/// Whether a plane's tiles are cheap to decide for @a field (PlaneBands::planeCheap; a node
/// without PlaneBands decides nothing, so its place in a boolean's order does not matter).
inline bool planeCheapOf(const FieldNode& field)
{
    const auto* bands = dynamic_cast<const PlaneBands*>(&field);
    return !bands || bands->planeCheap();
}

/// Copies tile (a, b)'s points and their one-point halo from @a from to @a to (plane layout).
inline void copyTileWithHalo(const GridBatch& plane, int tile, int a, int b, const double* from, double* to)
{
    const int j0 = b * tile, j1 = std::min(plane.ny - 1, (b + 1) * tile + 1);
    for (int i = a * tile; i <= std::min(plane.nx - 1, (a + 1) * tile + 1); ++i) {
        const std::size_t row = std::size_t(i) * plane.ny;
        std::copy(from + row + j0, from + row + j1 + 1, to + row + j0);
    }
}

}  // namespace voxlat
