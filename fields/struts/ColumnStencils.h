/// @file ColumnStencils.h
/// @brief A plane's columns between exact ones taken by eight-point Lagrange interpolation
/// along x, where a proven bound on the error stays below a tolerance: a strut lattice's plane
/// (a slicer's layer) then evaluates one column in two or three, the rest from their
/// neighbours.
///
/// The bound. Strut j's field F_j = int w(s) exp(-|p - c(s)|^2 / 2 sigma^2) ds (unit speed c)
/// has an eighth derivative along x of at most
///     |d^8 F_j / dx^8| <= C8 peak_j / sigma^8 exp(-d_j^2 / 4 sigma^2),
///     C8 = sqrt(2) max_t |He8(t)| exp(-t^2 / 4) = sqrt(2) x 144.32 <= 204.2,
/// (d^8/dx^8 exp(-x^2 / 2 sigma^2) = sigma^-8 He8(x / sigma) exp(-x^2 / 2 sigma^2); split the
/// exponent in halves, bound the first with He8, integrate the second along the strut:
/// 2 sqrt(pi) sigma = sqrt(2) peak / wMax), d_j the strut's distance to the stencil's span. The
/// eight-point interpolant at x then misses by at most |prod_l (x - x_l)| / 8! max |F^(8)|:
///     |error| <= K sum_j peak_j exp(-d_j^2 / 4 sigma_j^2),
///     K = |prod_l (x - x_l) / dx^8| (dx / sigma)^8 C8 / 8!,
/// K (per column; sigma the least of the struts') below the tolerance for every interpolated
/// column, else the column is exact. A strut's cut-off (its contribution dropped beyond r_c, at
/// most eps of its peak) is a step the interpolant does not see: near one, the interpolated
/// value may miss the cut field by up to (1 + sum_l |L_l|) eps peak_j, against the uncut field's
/// eps peak_j that every path drops: columns whose stencil has sum_l |L_l| above 2.5 (one-sided
/// ones near the plane's ends) stay exact.
///
/// A strut's direction tightens C8 (segmentEighthDerivativeBound). Split x = b u + a n (b = |u.x|,
/// a = sqrt(1 - b^2), n normal to the strut): D_x^8 = sum_k C(8, k) a^(8-k) b^k D_n^(8-k) D_u^k,
/// and along the strut D_u^k integrates to the ends' terms, so the derivatives' signs cancel
/// where the first bound took their absolute values. A ray (from A along u, weight w) has
///     |D_x^8 F| <= R(b) w sigma sqrt(2 pi) / sigma^8 exp(-d^2 / 4 sigma^2),
/// R(b) the sup of the nine Hermite terms' sum times exp(d^2 / 4) (rayEighthDerivativeBound:
/// tabled per 1/64 of b, tests/scripts/directional_eighth_bound.py; 145.8 across x, 38.9 for a
/// cube's diagonal, 21.1 along x). A segment is ray(A) - ray(B); at a point whose projection is
/// nearer A, ray(A)'s distance is the segment's and ray(B)'s at least sqrt(d^2 + L^2 / 4), so
/// a unit weight gives R(b) (1 + exp(-L^2 / 16 sigma^2)). A linear weight w_min + (wMax - w_min)
/// s / L adds the ramp, the mean over t of the unit segments [t, L]: R(b) (1 + min(1, 2 sqrt(pi)
/// sigma / L)). Per unit of the peak wMax sigma sqrt(2 pi):
///     C8_j = R(b) (1 + (w_min exp(-L^2 / 16 sigma^2) + (wMax - w_min) min(1, 2 sqrt(pi) sigma / L)) / wMax),
/// and the least of it and C8 holds (at 19 um and sigma 0.2, a cube's diagonals take nodes every
/// fourth column where C8 allows every third).
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "fields/struts/GaussianSegment.h"

namespace voxlat {

/// C8 above: sqrt(2) times the largest |He8(t)| exp(-t^2 / 4) (144.32 at t = 2.27), rounded up.
inline constexpr double kEighthDerivativeBound = 204.2;

/// R(b) above: a ray's eighth derivative along x per unit of its peak and of exp(-d^2 / 4 sigma^2)
/// sigma^-8, for |u.x| = @a b (the table's largest over b's 1/64 step, 1 % up).
double rayEighthDerivativeBound(double b);

/// C8_j above for one strut along @a axis (0, 1, 2: x, y, z; weights > 0): at most
/// kEighthDerivativeBound.
double segmentEighthDerivativeBound(const GaussianSegment& segment, int axis = 0);

/// Which columns of a plane of @a nx columns are exact and how the others are interpolated.
struct ColumnStencils {
    int stride = 1;  ///< nodes every stride columns (1: every column exact)
    /// Per column: -1 where it is exact, else its stencil's first node (columns first,
    /// first + stride, .. first + 7 stride).
    std::vector<int> first;
    std::vector<std::array<double, 8>> weights;  ///< per column: the Lagrange weights (interpolated ones)
    double worst = 0.0;                          ///< the largest K over the interpolated columns
    std::size_t exactCount() const;
};

/// The stencils of a plane of @a nx columns @a spacing apart for struts of least kernel width
/// @a sigma: nodes every m columns (m = 2, 3 or 4, the one that leaves the fewest exact), each
/// other column interpolated from the eight nodes nearest it (shifted to stay inside the plane)
/// where its K is at most @a tolerance and its weights' absolute sum at most 2.5, else exact (the
/// columns past the last node, and those whose one-sided stencil near the plane's ends bounds
/// too loosely), K taken with @a eighthBound for C8 (the largest of the struts'
/// segmentEighthDerivativeBound). A deterministic function of its arguments.
ColumnStencils columnStencils(int nx, double spacing, double sigma, double tolerance,
                              double eighthBound = kEighthDerivativeBound);

/// @a values (a plane's, column i at values[i * ny]) at each interpolated column's points: of
/// runs of tiles whose bits @a columnTiles[i] holds (points b0 tile .. (b1 + 1) tile + 1, as
/// PlaneBands' halo), from its nodes' values at the same points, summed in node order.
void interpolateColumns(const ColumnStencils& stencils, int ny, const std::uint64_t* columnTiles, int tile,
                        double* values);

}  // namespace voxlat
