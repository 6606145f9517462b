/// @file IsoRadiusSingle.h
/// @brief IsoRadius's map in single precision, for planes whose values are approximate already
/// (StrutConvolution::planeValues' interpolated columns, planeTolerance() > 0): a slicer's open
/// tiles, where the double map (a logarithm, a division and a square root per value) was 8 % of
/// slicing a strut plate.
///
/// rho = sigma sqrt(2 |u|) sign(u), u = ln P - ln F, with ln F in single precision from F's
/// exponent and a polynomial of its mantissa (Cephes' logf: about 1 ulp). u misses ln(P / F) by
/// at most 2.9e-7 (1 + |u|) (measured over F from the cap to 20 P: the test), a relative error
/// of F as much: near the surface (u about 1) rho by about 4e-7 of sigma (8e-8 mm at sigma 0.2,
/// four millionths of a 19 um pixel), against the interpolation's 2.5e-5 of the peaks. One loop
/// of IEEE operations without contraction or reassociation, built both for the target's baseline
/// for AVX-512F (isoRadiiSingleAvx512) and for AVX2 (isoRadiiSingleAvx2): the same doubles any
/// way, on any CPU.
#pragma once

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>

namespace voxlat {

/// The map's constants (IsoRadius's, ln P and sigma rounded to single precision).
struct SingleRadii {
    float lnPeak, sigma;
    double fMin, rhoMax;
};

// The loops are static: each build of them (the baseline's, AVX-512F's) keeps its own copy,
// where an inline function's copies would be merged into one at link time, whichever's flags.
/// rho of @a n values in place; values at or below fMin take rhoMax, the others at most rhoMax.
static inline void isoRadiiSingleLoop(double* values, std::size_t n, const SingleRadii& m)
{
    // Locals: the stores below may alias @a m's fields, which would be reloaded in the loop.
    const float lnPeak = m.lnPeak, sigma = m.sigma;
    const double fMin = m.fMin, rhoMax = m.rhoMax;
    for (std::size_t k = 0; k < n; ++k) {
        const double f = values[k];
        // Values at or below fMin (at least 1e-30: IsoRadius::planeSingle) take rhoMax below
        // whatever this gives them (zero, a subnormal: finite), and sums of struts' peaks stay far
        // within single range.
        const float x = float(f);
        const std::uint32_t bits = std::bit_cast<std::uint32_t>(x);
        // x = mantissa 2^e, mantissa in [sqrt(1/2), sqrt(2)).
        const std::uint32_t half = (bits & 0x007fffffu) | 0x3f000000u;  // [0.5, 1)
        const float mantissa = std::bit_cast<float>(half);
        const bool low = mantissa < 0.707106781186547524f;
        const int e = int(bits >> 23) - 126 - int(low);
        const float t = mantissa * (low ? 2.0f : 1.0f) - 1.0f;
        const float z = t * t;
        float y = 7.0376836292e-2f;
        y = y * t - 1.1514610310e-1f;
        y = y * t + 1.1676998740e-1f;
        y = y * t - 1.2420140846e-1f;
        y = y * t + 1.4249322787e-1f;
        y = y * t - 1.6668057665e-1f;
        y = y * t + 2.0000714765e-1f;
        y = y * t - 2.4999993993e-1f;
        y = y * t + 3.3333331174e-1f;
        y = y * t * z;
        const float fe = float(e);
        y = y + -2.12194440e-4f * fe;
        y = y - 0.5f * z;
        const float logX = (t + y) + 0.693359375f * fe;
        const float u = lnPeak - logX;
        const double rho = double(std::copysign(sigma * std::sqrt(2.0f * std::abs(u)), u));
        const double capped = rho < rhoMax ? rho : rhoMax;
        values[k] = f <= fMin ? rhoMax : capped;
    }
}

/// isoRadiiSingleLoop built for AVX-512F (sixteen lanes; the same doubles). Runs only where
/// hasAvx512Rows().
void isoRadiiSingleAvx512(double* values, std::size_t n, const SingleRadii& m);

/// isoRadiiSingleLoop built for AVX2 (eight lanes; the same doubles), for CPUs without AVX-512F.
/// Runs only where hasAvx2Rows().
void isoRadiiSingleAvx2(double* values, std::size_t n, const SingleRadii& m);

}  // namespace voxlat
