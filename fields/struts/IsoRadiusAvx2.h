/// @file IsoRadiusAvx2.h
/// @brief IsoRadius::radii four values at a time (AVX2 and FMA) or eight (AVX-512F): the same
/// doubles as the scalar map, its logarithm the C library's own algorithm (glibc's log on CPUs
/// with AVX2 and FMA) in lanes.
#pragma once

#include <cstddef>

namespace voxlat {

/// Whether isoRadiiAvx2 exists in this build, the CPU has AVX2 and FMA, and its logarithm gives
/// std::log's doubles here: checked once, bit for bit, on values across every interval of the
/// algorithm's table and many exponents (a C library with another log answers false, and
/// IsoRadius keeps std::log).
bool hasIsoRadiiAvx2();

/// IsoRadius::radiusOf of @a n values in place, the same doubles as IsoRadius::radii: u = peak /
/// (f <= fMin ? peak : f), rho = min(rhoMax, copysign(sigma sqrt(2 |log u|), log u)), rhoMax where
/// f <= fMin. Lanes the table path does not cover (u near 1, zero, subnormal, infinite or NaN)
/// take std::log. Call only where hasIsoRadiiAvx2().
void isoRadiiAvx2(double* f, std::size_t n, double peak, double fMin, double sigma, double rhoMax);

/// Whether isoRadiiAvx512 exists in this build, the CPU has AVX-512F (hasAvx512Rows()) and its
/// logarithm gives std::log's doubles here (checked once, as hasIsoRadiiAvx2()).
bool hasIsoRadiiAvx512();

/// isoRadiiAvx2 in eight lanes (IsoRadiusAvx512.cpp): the same doubles. Call only where
/// hasIsoRadiiAvx512().
void isoRadiiAvx512(double* f, std::size_t n, double peak, double fMin, double sigma, double rhoMax);

}  // namespace voxlat
