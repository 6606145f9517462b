#pragma once
/// @file StrutRows.h
/// @brief One strut's Gaussian convolution added along one row of a grid batch: the inner loop of
/// StrutConvolution::gridValues, with a scalar form and a four-lane AVX2 form that gives the same
/// doubles (the same IEEE operations in the same order, no FMA, no contraction).

#include "fields/struts/GaussianTable.h"

#include <algorithm>
#include <limits>

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

/// Whether the point at (dx, dy, dz) from the strut's start is within its cut-off, with @a h its
/// coordinate along the strut (GaussianSegment::distanceSqr's operations in its order: the same
/// doubles wherever it is inlined).
inline bool withinCutoff(const StrutRowConstants& s, double dx, double dy, double dz, double& h)
{
    h = dx * s.ux + dy * s.uy + dz * s.uz;
    const double lengthSqr = dx * dx + dy * dy + dz * dz;
    const double r2 = std::max(0.0, lengthSqr - h * h);
    const double beyond = h < 0.0 ? h : (h > s.length ? h - s.length : 0.0);
    return r2 + beyond * beyond < s.cutoffSqr;
}

/// The squared distance from the point at (dx, dy, dz) from the strut's start to the segment, as
/// withinCutoff computes it.
inline double cutoffDistanceSqr(const StrutRowConstants& s, double dx, double dy, double dz)
{
    const double h = dx * s.ux + dy * s.uy + dz * s.uz;
    const double lengthSqr = dx * dx + dy * dy + dz * dz;
    const double r2 = std::max(0.0, lengthSqr - h * h);
    const double beyond = h < 0.0 ? h : (h > s.length ? h - s.length : 0.0);
    return r2 + beyond * beyond;
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
    return cutoffDistanceSqr(s, dx, dy, (row.z0 + inLo * row.dz) - s.az) < limit &&
           cutoffDistanceSqr(s, dx, dy, (row.z0 + inHi * row.dz) - s.az) < limit;
}

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
/// n0 + k + 1 at tau, whose weights (w00, w10, w01, w11) are the row's constants.
struct StrutRowTable {
    const double* value;  ///< J(h_n)
    const double* slope;  ///< delta J'(h_n)
    int n0;               ///< node of the row's point 0
    double w00, w10, w01, w11;
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
        const int n = table.n0 + k;
        const double j0 = ((table.w00 * table.value[n] + table.w10 * table.slope[n]) + table.w01 * table.value[n + 1]) +
                          table.w11 * table.slope[n + 1];
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

/// addStrutRowTabledScalar with four lanes; the same doubles (the same build rules as
/// addStrutRowAvx2).
void addStrutRowTabledAvx2(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                           const double* gauss, double* out);

/// gauss[k + l] for k = 0, 4, 8, .. < count and l = 0..3: lane l starts at lanes[l] and is
/// multiplied by steps[l] after each store, steps[l] by @a q16 (four interleaved geometric
/// recurrences; writes count rounded up to four).
inline void fillGaussiansScalar(const double lanes[4], const double steps[4], double q16, int count, double* gauss)
{
    double e[4] = {lanes[0], lanes[1], lanes[2], lanes[3]}, r[4] = {steps[0], steps[1], steps[2], steps[3]};
    for (int k = 0; k < count; k += 4)
        for (int l = 0; l < 4; ++l) {
            gauss[k + l] = e[l];
            e[l] *= r[l];
            r[l] *= q16;
        }
}

/// fillGaussiansScalar with four lanes; the same doubles.
void fillGaussiansAvx2(const double lanes[4], const double steps[4], double q16, int count, double* gauss);

/// addStrutRowScalar with four lanes; the same doubles. Defined only where VOXLAT_AVX2_ROWS is
/// (x86-64 builds); call it only when hasAvx2Rows() says the CPU has AVX2.
void addStrutRowAvx2(const StrutRowConstants& s, const StrutRow& row, const double* gauss, double* out);

/// Whether addStrutRowAvx2 exists in this build and the CPU can run it.
bool hasAvx2Rows();

}  // namespace voxlat
