/// @file SinCos.h
/// @brief Sines and cosines of many angles at once (SLEEF's vector functions, 3.5 ulp).
///
/// Point queries of TPMS fields (projection, decimation checks, deviation measures) spend most of
/// their time in sin and cos of the scaled coordinates; four at a time that cost falls about four
/// times. The results are within 3.5 ulp of the exact values (SLEEF's u35 functions: twice as fast
/// as its 1-ulp ones, and 1e-15 relative is far below any tolerance a mesh or grid is held to),
/// the same for any thread count (each
/// angle's result depends on that angle alone), chosen once per run by what the CPU has.
#pragma once

#include <cstddef>

namespace voxlat {

/// Sets @a s[i] = sin(@a x[i]) and @a c[i] = cos(@a x[i]) for i < @a n (3.5 ulp; @a s and @a c may
/// not overlap @a x).
void sinCosBatch(const double* x, double* s, double* c, std::size_t n);

/// The four-lane AVX2 version (SinCosAvx2.cpp); false from hasAvx2SinCos() where it is not built
/// or the CPU lacks AVX2 and FMA.
void sinCosBatchAvx2(const double* x, double* s, double* c, std::size_t n);
bool hasAvx2SinCos();

}  // namespace voxlat
