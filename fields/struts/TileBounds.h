/// @file TileBounds.h
/// @brief StrutConvolution::planeValues' upper bounds of one strut over a box of a plane's tiles:
/// two tiles at a time, four (AVX2) or eight (AVX-512F), the same doubles any way.
///
/// Per tile b of the column (centre ex, cy0 + b stepY, ez from the strut's start): h the centre's
/// projection clamped to [0, L], r the centre less its nearest point of the segment,
/// dSqr = |r|^2; where dSqr < farSqr the tile takes upper[b] += peak expUpper(near^2 / 2 sigma^2)
/// and peaks[b] += peak, near = max(0, d - min(halfDiagonal, (halfX |rx| + halfY |ry|) / d) -
/// margin). expUpper(x) is the table's node at or below x (exp(-x) past the table).
#pragma once

#include <cstdint>

namespace voxlat {

/// One strut seen from a plane's tiles (planeValues' names).
struct TileColumnStrut {
    double cx0, stepX, ax;  ///< ex(a) = cx0 + a stepX - ax
    double cy0, stepY, ay;  ///< ey(b) = cy0 + b stepY - ay
    double ux, uy, uz, length, ez;
    double farSqr, farHaloSqr, innerSqr;
    double halfX, halfY, halfDiagonal, margin;
    double peak, inv2s2;
};

/// The table expUpper reads: value[k] at x = k / steps, k < size.
struct ExpUpperNodes {
    const double* value;
    double steps;
    int size;
};

/// exp(-x) from above for x >= 0: the exponential at x rounded down to a 256th (and 1e-9 more),
/// so at most 0.4 % above it (std::exp past x = 12, beyond the cut-offs of eps >= 6e-6). A tile's
/// bound needs one per strut and tile: a call of std::exp each was most of planeValues' own time.
ExpUpperNodes expUpperNodes();

/// Which tiles of the column the strut reaches: its halo (dSqr < farHaloSqr) and its inner
/// tiles (within the cut-off and dSqr < innerSqr, where planeValues adds a lower bound), bit b
/// for tile b.
struct TileColumnReach {
    std::uint64_t halo = 0, inner = 0;
};

/// Adds the strut's bounds to @a upper and @a peaks (tile (a, b) at a * @a tilesY + b) for the
/// tiles a0..a1 x b0..b1 (b1 < 64), in increasing a and b, and gives column a's reach in
/// @a reach[a - a0]. Two tiles at a time (vector extensions), on any CPU.
void addTileBoundsScalar(const TileColumnStrut& s, int a0, int a1, int b0, int b1, int tilesY,
                         const ExpUpperNodes& table, double* upper, double* peaks, TileColumnReach* reach);

/// addTileBoundsScalar eight tiles at a time (TileBoundsAvx512.cpp, AVX-512F): the same doubles.
/// Call only where hasAvx512Rows() (StrutRows.h: the build has AVX-512 forms and the CPU runs them).
void addTileBoundsAvx512(const TileColumnStrut& s, int a0, int a1, int b0, int b1, int tilesY,
                         const ExpUpperNodes& table, double* upper, double* peaks, TileColumnReach* reach);

/// addTileBoundsScalar four tiles at a time (TileBoundsAvx2.cpp, AVX2 without FMA), for CPUs
/// without AVX-512F: the same doubles. Call only where hasAvx2Rows().
void addTileBoundsAvx2(const TileColumnStrut& s, int a0, int a1, int b0, int b1, int tilesY, const ExpUpperNodes& table,
                       double* upper, double* peaks, TileColumnReach* reach);

}  // namespace voxlat
