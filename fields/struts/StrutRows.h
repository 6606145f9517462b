#pragma once
/// @file StrutRows.h
/// @brief One strut's Gaussian convolution added along one row of a grid batch: the inner loop of
/// StrutConvolution::gridValues, with a scalar form and a four-lane AVX2 form that gives the same
/// doubles (the same IEEE operations in the same order, no FMA, no contraction).

#include "fields/struts/GaussianTable.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

namespace voxlat {

/// The constants of one strut the row loop needs (see GaussianSegment).
struct StrutRowConstants {
    double ax, ay, az;  ///< start A
    double ux, uy, uz;  ///< unit direction
    double length, sigma, invSigma, s2, w0, slope;
    double cutoffSqr;  ///< the cut-off radius squared: points at or beyond it add nothing
};

/// The points of one row: (x, y, z0 + k dz) for k = kLo..kHi (each coordinate computed as
/// GridBatch::point does, so the same bits).
struct StrutRow {
    double x, y, z0, dz;
    int kLo, kHi;
    /// Points inLo..inHi lie within the strut's cut-off (proven by provenWithinCutoff): the tabled
    /// loops add them without their test (the same sums). Empty (inLo > inHi) unless proven.
    int inLo = 1, inHi = 0;
};

/// The squared distance from the point at (dx, dy, dz) from the strut's start to the segment, with
/// @a h its coordinate along the strut (GaussianSegment::distanceSqr's operations in its order: the
/// same doubles wherever it is inlined).
inline double cutoffDistanceSqr(const StrutRowConstants& s, double dx, double dy, double dz, double& h)
{
    h = dx * s.ux + dy * s.uy + dz * s.uz;
    const double lengthSqr = dx * dx + dy * dy + dz * dz;
    const double r2 = std::max(0.0, lengthSqr - h * h);
    const double beyond = h < 0.0 ? h : (h > s.length ? h - s.length : 0.0);
    return r2 + beyond * beyond;
}

/// Whether the point at (dx, dy, dz) from the strut's start is within its cut-off, with @a h its
/// coordinate along the strut.
inline bool withinCutoff(const StrutRowConstants& s, double dx, double dy, double dz, double& h)
{
    return cutoffDistanceSqr(s, dx, dy, dz, h) < s.cutoffSqr;
}

/// A bound on how far cutoffDistanceSqr's value for any point of a row lies from the exact squared
/// distance of the exact point to the segment, where every point and the segment lie within
/// @a reach of the strut's start and every coordinate (the rows' and the strut's) within @a coord
/// of zero: the coordinates' roundings (about 7 eps (coord + reach) per point) move the distance
/// squared by at most about 14 eps reach (coord + reach), the arithmetic (h, |d|^2, their
/// difference, the overhang) by about 30 eps reach^2; 64 eps (reach^2 + coord reach) holds both.
inline double cutoffRoundoff(double reach, double coord)
{
    return 64.0 * std::numeric_limits<double>::epsilon() * (reach * reach + coord * reach);
}

/// Whether every point k = inLo..inHi of @a row (inLo <= inHi) passes withinCutoff's test. Along
/// a row the exact squared distance to the segment is convex in k (the squared distance of a
/// point moving on a line to a convex set), so it is at most its larger end value in between. The
/// ends' computed distances are below (1 - 1e-7) of the cut-off squared, and @a roundoff bounds
/// how far any computed distance of this row lies from the exact one (the points' coordinates and
/// the arithmetic: the caller's bound, at most half the 1e-7 margin), so every point's computed
/// distance in between is below the cut-off squared.
inline bool provenWithinCutoff(const StrutRowConstants& s, const StrutRow& row, int inLo, int inHi, double roundoff)
{
    const double limit = s.cutoffSqr * (1.0 - 1e-7);
    if (!(2.0 * roundoff < s.cutoffSqr * 1e-7)) return false;
    const double dx = row.x - s.ax, dy = row.y - s.ay;
    double h;
    return cutoffDistanceSqr(s, dx, dy, (row.z0 + inLo * row.dz) - s.az, h) < limit &&
           cutoffDistanceSqr(s, dx, dy, (row.z0 + inHi * row.dz) - s.az, h) < limit;
}

/// The constants of capsuleRowRange for one strut (unit direction (ux, uy, uz), @a length), rows of
/// step @a dz along z and the cut-off radius squared @a rc2; cc = dz^2 - (dz u_z)^2 > 0 (rows not
/// parallel to the strut).
struct CapsuleRows {
    double ux, uy, uz, length, rc2, dz, hz, cc, invDz, halfInvCc, invHz;
    CapsuleRows(double dirX, double dirY, double dirZ, double len, double step, double radiusSqr)
        : ux(dirX),
          uy(dirY),
          uz(dirZ),
          length(len),
          rc2(radiusSqr),
          dz(step),
          hz(step * dirZ),
          cc(step * step - hz * hz),
          invDz(1.0 / step),
          halfInvCc(cc > 0.0 ? 0.5 / cc : 0.0),
          invHz(hz != 0.0 ? 1.0 / hz : 0.0)
    {
    }
};

/// A real interval [lo, hi] (empty: lo > hi) holding the k where the row (x, y, z + k dz), given
/// from the strut's start, comes within rc of the segment (the union of the cylinder's part inside
/// the slab 0 <= h <= length and the two end balls; a capsule is convex, so the union is one
/// interval). Only a filter (every point in and about it still takes the exact cut-off test), so
/// the roots come from the plain formulas with the divisions taken once per strut: their rounding
/// moves an end by far less than the step its callers widen it by (the caller's rc2 is widened by
/// 1e-9 of itself against the near-tangent rows).
inline void capsuleRowRange(const CapsuleRows& k, double x, double y, double z, double& lo, double& hi)
{
    lo = std::numeric_limits<double>::infinity();
    hi = -std::numeric_limits<double>::infinity();
    // End balls: (d.z + k dz)^2 < rc^2 - d.x^2 - d.y^2, d = D - h u.
    for (const double h : {0.0, k.length}) {
        const double dx = x - h * k.ux, dy = y - h * k.uy, dz = z - h * k.uz;
        const double w = k.rc2 - dx * dx - dy * dy;
        if (!(w > 0.0)) continue;
        const double root = std::sqrt(w);
        const double a = (-dz - root) * k.invDz, b = (-dz + root) * k.invDz;
        lo = std::min(lo, std::min(a, b));
        hi = std::max(hi, std::max(a, b));
    }
    // Cylinder: r^2(k) = |D + k e|^2 - h(k)^2 < rc^2, h(k) = D.u + k dz u_z: cc k^2 + B k + C < 0.
    const double h0 = x * k.ux + y * k.uy + z * k.uz;
    const double B = 2.0 * (z * k.dz - h0 * k.hz), C = x * x + y * y + z * z - h0 * h0 - k.rc2;
    const double disc = B * B - 4.0 * k.cc * C;
    if (!(disc > 0.0)) return;
    const double root = std::sqrt(disc);
    double a = (-B - root) * k.halfInvCc, b = (-B + root) * k.halfInvCc;
    if (k.hz != 0.0) {
        double s0 = -h0 * k.invHz, s1 = (k.length - h0) * k.invHz;
        if (s0 > s1) std::swap(s0, s1);
        a = std::max(a, s0);
        b = std::min(b, s1);
    } else if (!(h0 >= 0.0 && h0 <= k.length)) {
        return;
    }
    if (a > b) return;
    lo = std::min(lo, a);
    hi = std::max(hi, b);
}

/// capsuleRowRange of four rows (x[l], y, z), l = 0..3, in four lanes; the same doubles.
void capsuleRowRangesAvx2(const CapsuleRows& k, const double x[4], double y, double z, double lo[4], double hi[4]);

/// Adds gauss[k] * J(h_k) to out[k] for every point of @a row within the strut's cut-off, where
/// h_k is the point's coordinate along the strut and J the weighted erf integral (GaussianTable).
inline void addStrutRowScalar(const StrutRowConstants& s, const StrutRow& row, const double* gauss, double* out)
{
    const GaussianTable& table = GaussianTable::instance();
    const double dx = row.x - s.ax, dy = row.y - s.ay;
    for (int k = row.kLo; k <= row.kHi; ++k) {
        double h;
        if (!withinCutoff(s, dx, dy, (row.z0 + k * row.dz) - s.az, h)) continue;
        double j0;
        if (s.slope == 0.0) {
            j0 = s.w0 * s.sigma * (table.erfIntegral((s.length - h) * s.invSigma) + table.erfIntegral(h * s.invSigma));
        } else {
            double uL, gL, uA, gA;
            table.evaluate((s.length - h) * s.invSigma, uL, gL);
            table.evaluate(h * s.invSigma, uA, gA);
            const double i0 = s.sigma * (uL + uA);
            j0 = (s.w0 + s.slope * h) * i0 + s.slope * s.s2 * (gA - gL);
        }
        out[k] += gauss[k] * j0;
    }
}

/// addStrutRowScalar with J(h) from its cubic Taylor polynomial @a c about @a hc instead of the
/// table (a pixel's sub-samples: StrutConvolution::gridValues states the bound): the same points
/// pass the cut-off (the row's proven points inLo..inHi take no test).
inline void addStrutRowTaylorScalar(const StrutRowConstants& s, const StrutRow& row, const double c[4], double hc,
                                    const double* gauss, double* out)
{
    const double dx = row.x - s.ax, dy = row.y - s.ay;
    for (int k = row.kLo; k <= row.kHi; ++k) {
        double h;
        const double dz = (row.z0 + k * row.dz) - s.az;
        if (k >= row.inLo && k <= row.inHi)
            h = dx * s.ux + dy * s.uy + dz * s.uz;  // proven within: withinCutoff's h without its test
        else if (!withinCutoff(s, dx, dy, dz, h))
            continue;
        const double d = h - hc;
        out[k] += gauss[k] * (c[0] + d * (c[1] + d * (c[2] + d * c[3])));
    }
}

/// addStrutRowTaylorScalar with four lanes; the same doubles.
void addStrutRowTaylorAvx2(const StrutRowConstants& s, const StrutRow& row, const double c[4], double hc,
                           const double* gauss, double* out);

/// J(h) of one strut tabled along the rows of a batch: nodes h_n = h0 + n delta, delta the step of
/// h from one point of a row to the next, holding J(h_n) and delta J'(h_n); the point k of a row
/// whose h(0) lies at node n0 + tau takes the cubic Hermite polynomial between nodes n0 + k and
/// n0 + k + 1 at tau, whose weights (w00, w10, w01, w11) are the row's constants. With
/// @a nextValue and @a nextSlope set, the node after value[n] is nextValue[n] (not value[n + 1]):
/// a table of m nodes per step of h (delta the step over m) kept in m phases, each node's
/// successor in the next phase.
struct StrutRowTable {
    const double* value;  ///< J(h_n)
    const double* slope;  ///< delta J'(h_n)
    int n0;               ///< node of the row's point 0
    double w00, w10, w01, w11;
    const double* nextValue = nullptr;  ///< the nodes after value's (null: value + 1)
    const double* nextSlope = nullptr;  ///< the nodes after slope's (null: slope + 1)
    /// J at the row's point @a k: its node's and the next phase's values and slopes weighted.
    double at(int k) const
    {
        const int n = n0 + k;
        const double* v1 = nextValue ? nextValue : value + 1;
        const double* s1 = nextSlope ? nextSlope : slope + 1;
        return ((w00 * value[n] + w10 * slope[n]) + w01 * v1[n]) + w11 * s1[n];
    }
};

/// addStrutRowScalar with J(h_k) from @a table (the same points pass the same cut-off test; the
/// row's proven points inLo..inHi take none).
inline void addStrutRowTabledScalar(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                                    const double* gauss, double* out)
{
    const double dx = row.x - s.ax, dy = row.y - s.ay;
    for (int k = row.kLo; k <= row.kHi; ++k) {
        double h;
        const bool inside = k >= row.inLo && k <= row.inHi;
        if (!inside && !withinCutoff(s, dx, dy, (row.z0 + k * row.dz) - s.az, h)) continue;
        const double j0 = table.at(k);
        out[k] += gauss[k] * j0;
    }
}

/// The nodes of a StrutRowTable: for m = 0..count-1 at h = h0 + (m + first) step, value[m] = J(h)
/// (as addStrutRowScalar takes it from GaussianTable) and slope[m] = step J'(h), J' = w0 (g(h) -
/// g(L - h)) + slope (I0(h) - L g(L - h)) with g(t) = exp(-t^2 / 2 sigma^2), I0 = J's erf sum.
inline void strutRowNodesScalar(const StrutRowConstants& s, double h0, double step, int first, int count, double* value,
                                double* slope)
{
    const GaussianTable& table = GaussianTable::instance();
    for (int m = 0; m < count; ++m) {
        const double h = h0 + double(m + first) * step;
        double uL, gL, uA, gA;
        table.evaluate((s.length - h) * s.invSigma, uL, gL);
        table.evaluate(h * s.invSigma, uA, gA);
        const double i0 = s.sigma * (uL + uA);
        value[m] = (s.w0 + s.slope * h) * i0 + s.slope * s.s2 * (gA - gL);
        slope[m] = (s.w0 * (gA - gL) + s.slope * (i0 - s.length * gL)) * step;
    }
}

/// strutRowNodesScalar with four lanes; the same doubles. @a value and @a slope have room for
/// count rounded up to four.
void strutRowNodesAvx2(const StrutRowConstants& s, double h0, double step, int first, int count, double* value,
                       double* slope);

/// The nodes strutRowNodesScalar makes for m = 0..count-1 (h = h0 + (m + first) step), from the
/// even ones alone: node n even is strutRowNodes' own doubles (made at twice the step, whose
/// products are the same doubles scaled by two), node n odd the cubic Hermite interpolant of its
/// neighbours n - 1 and n + 1 at their midpoint, value (v0 + v1) / 2 + (s0 - s1) / 4 and slope
/// 3 (v1 - v0) / 4 - (s0 + s1) / 4 (slopes per @a step). Its error is at most (2 step)^4 / 384
/// max |J''''| <= 0.0128 (2 step / sigma)^4 of the strut's peak (the table's bound at twice the
/// step); the slope's error term of that order vanishes at the midpoint. A node's doubles hang on
/// its index alone, not on @a first or @a count. @a avx2: strutRowNodesAvx2 for the even nodes.
inline void planeNodesFromEven(const StrutRowConstants& s, double h0, double step, int first, int count, bool avx2,
                               double* value, double* slope)
{
    thread_local std::vector<double> evenValue, evenSlope;
    const int e0 = first & ~1;            // the even node at or below the first
    const int e1 = (first + count) & ~1;  // the even node at or above the last
    const int evens = (e1 - e0) / 2 + 1;
    evenValue.resize(std::size_t(evens) + 4);  // the four-lane form writes up to a group past
    evenSlope.resize(std::size_t(evens) + 4);
    if (avx2)
        strutRowNodesAvx2(s, h0, 2.0 * step, e0 / 2, evens, evenValue.data(), evenSlope.data());
    else
        strutRowNodesScalar(s, h0, 2.0 * step, e0 / 2, evens, evenValue.data(), evenSlope.data());
    for (int m = 0; m < count; ++m) {
        const int n = first + m, e = (n - e0) >> 1;  // n's even node at or below it, e0 + 2 e
        const double v0 = evenValue[std::size_t(e)], s0 = 0.5 * evenSlope[std::size_t(e)];
        if (((n - e0) & 1) == 0) {
            value[m] = v0;
            slope[m] = s0;
            continue;
        }
        const double v1 = evenValue[std::size_t(e) + 1], s1 = 0.5 * evenSlope[std::size_t(e) + 1];
        value[m] = 0.5 * (v0 + v1) + 0.25 * (s0 - s1);
        slope[m] = 0.75 * (v1 - v0) - 0.25 * (s0 + s1);
    }
}

/// addStrutRowTabledScalar with four lanes; the same doubles (the same build rules as
/// addStrutRowAvx2).
void addStrutRowTabledAvx2(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                           const double* gauss, double* out);

/// addStrutRowTabledScalar with eight lanes (AVX-512F, StrutRowsAvx512.cpp; no contraction); the
/// same doubles, and it reads and writes only the row's points (masked). The scalar loop where the
/// build has no AVX-512 form; call it only when hasAvx512Rows() says the CPU has AVX-512F.
void addStrutRowTabledAvx512(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                             const double* gauss, double* out);

/// Whether addStrutRowTabledAvx512's eight-lane form exists in this build and the CPU can run it
/// (false when the environment sets VOXLAT_NO_AVX512).
bool hasAvx512Rows();

/// gauss[k + l] for k = 0, 4, 8, .. < count and l = 0..3: lane l starts at lanes[l] and is
/// multiplied by steps[l] after each store, steps[l] by @a q16 (four interleaved geometric
/// recurrences; writes count rounded up to four). Groups wholly before @a from are stepped
/// through without being written: the same doubles from the first group holding @a from on.
inline void fillGaussiansScalar(const double lanes[4], const double steps[4], double q16, int count, double* gauss,
                                int from = 0)
{
    double e[4] = {lanes[0], lanes[1], lanes[2], lanes[3]}, r[4] = {steps[0], steps[1], steps[2], steps[3]};
    for (int k = 0; k < count; k += 4)
        for (int l = 0; l < 4; ++l) {
            if (k + 4 > from) gauss[k + l] = e[l];
            e[l] *= r[l];
            r[l] *= q16;
        }
}

/// fillGaussians' four recurrences between groups: e[l] is the Gaussian at point k + l, r[l] its
/// lane's step (e[l] is multiplied by r[l], r[l] by q16, from one group to the next). k only grows.
struct GaussianLanes {
    double e[4], r[4];
    double q16;
    int k;
    void step()
    {
        for (int l = 0; l < 4; ++l) {
            e[l] *= r[l];
            r[l] *= q16;
        }
        k += 4;
    }
};

/// addStrutRowTabledScalar with the row's Gaussians taken from @a lanes as they are stepped (the
/// doubles fillGaussiansScalar writes from the same lanes), not from an array: @a lanes is stepped
/// on to the group of the row's last point (row.kLo must not lie before lanes.k). The same sums.
inline void addStrutRowTabledSeededScalar(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                                          GaussianLanes& lanes, double* out)
{
    const double dx = row.x - s.ax, dy = row.y - s.ay;
    for (int k = row.kLo; k <= row.kHi; ++k) {
        while (lanes.k + 4 <= k) lanes.step();
        double h;
        const bool inside = k >= row.inLo && k <= row.inHi;
        if (!inside && !withinCutoff(s, dx, dy, (row.z0 + k * row.dz) - s.az, h)) continue;
        const double j0 = table.at(k);
        out[k] += lanes.e[k - lanes.k] * j0;
    }
}

/// addStrutRowTabledSeededScalar with four lanes; the same doubles (it may leave @a lanes a group
/// earlier: at the group of its last group of four's first point).
void addStrutRowTabledSeededAvx2(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                                 GaussianLanes& lanes, double* out);

/// addStrutRowTabledSeededScalar with eight lanes (AVX-512F, StrutRowsAvx512.cpp): the four
/// recurrences stepped as there, the rest as addStrutRowTabledAvx512; the same doubles, only the
/// row's points read and written, @a lanes left at or below the row's last point. The scalar
/// loop where the build has no AVX-512 form; call it only when hasAvx512Rows() is true.
void addStrutRowTabledSeededAvx512(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                                   GaussianLanes& lanes, double* out);

/// fillGaussiansScalar with four lanes; the same doubles.
void fillGaussiansAvx2(const double lanes[4], const double steps[4], double q16, int count, double* gauss,
                       int from = 0);

/// addStrutRowScalar with four lanes; the same doubles. Defined only where VOXLAT_AVX2_ROWS is
/// (x86-64 builds); call it only when hasAvx2Rows() says the CPU has AVX2.
void addStrutRowAvx2(const StrutRowConstants& s, const StrutRow& row, const double* gauss, double* out);

/// Whether addStrutRowAvx2 exists in this build and the CPU can run it.
bool hasAvx2Rows();

}  // namespace voxlat
