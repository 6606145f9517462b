/// @file IsoRadiusAvx2.cpp
/// IsoRadius's map in four lanes. This file alone is built for AVX2 and FMA. Its logarithm is
/// glibc's (sysdeps/ieee754/dbl-64/e_log.c, which came from Arm's optimized-routines) as the
/// library builds it for CPUs with FMA (__log_fma, glibc 2.36; table and coefficients read
/// from its __log_data): log x = k ln2 + log c + log1p(z / c - 1) with
/// x = 2^k z, c and 1 / c from a 128-entry table indexed by z's leading mantissa bits, and the
/// same fused multiply-adds in the same order, so each lane gives the library's double. The
/// library picks that variant where the CPU has AVX2 and FMA; hasIsoRadiiAvx2() checks the
/// doubles against std::log once (another C library, or another variant, and the map keeps
/// std::log). x near 1 (glibc's second path) and special values take std::log.

#include "fields/struts/IsoRadiusAvx2.h"

#include "fields/struts/GlibcLogData.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#if defined(VOXLAT_AVX2_ROWS)
#include <immintrin.h>
#endif

namespace voxlat {

#if defined(VOXLAT_AVX2_ROWS)

namespace {

using glibc_log::kA;
using glibc_log::kLn2Hi;
using glibc_log::kLn2Lo;
using glibc_log::LogColumns;

const LogColumns& columns()
{
    static const LogColumns c;
    return c;
}

/// log of four lanes by the table path; @a regular marks the lanes it covers (x >= 2^-1022,
/// finite, outside [1 - 2^-4, 1 + 0x1.09p-4)); the others hold garbage.
inline __m256d logLanes(__m256d x, __m256d& regular)
{
    const LogColumns& t = columns();
    const __m256d near1 = _mm256_and_pd(_mm256_cmp_pd(x, _mm256_set1_pd(1.0 - 0x1p-4), _CMP_GE_OQ),
                                        _mm256_cmp_pd(x, _mm256_set1_pd(1.0 + 0x1.09p-4), _CMP_LT_OQ));
    const __m256d normal =
        _mm256_and_pd(_mm256_cmp_pd(x, _mm256_set1_pd(0x1p-1022), _CMP_GE_OQ),
                      _mm256_cmp_pd(x, _mm256_set1_pd(std::numeric_limits<double>::infinity()), _CMP_LT_OQ));
    regular = _mm256_andnot_pd(near1, normal);
    // Lanes off the path take x = 1.5 meanwhile (any regular value), so the table is read in range.
    const __m256i ix = _mm256_castpd_si256(_mm256_blendv_pd(_mm256_set1_pd(1.5), x, regular));
    const __m256i tmp = _mm256_sub_epi64(ix, _mm256_set1_epi64x(0x3fe6000000000000LL));
    const __m256i i = _mm256_and_si256(_mm256_srli_epi64(tmp, 45), _mm256_set1_epi64x(0x7f));
    // k = tmp >> 52 (arithmetic): the high halves shifted by 20, as 32-bit integers.
    const __m256i high = _mm256_permutevar8x32_epi32(tmp, _mm256_setr_epi32(1, 3, 5, 7, 0, 2, 4, 6));
    const __m256d kd = _mm256_cvtepi32_pd(_mm_srai_epi32(_mm256_castsi256_si128(high), 20));
    const __m256i iz =
        _mm256_sub_epi64(ix, _mm256_and_si256(tmp, _mm256_set1_epi64x(std::int64_t(0xfff0000000000000ULL))));
    const __m256d z = _mm256_castsi256_pd(iz);
    const __m256d invc = _mm256_i64gather_pd(t.invc, i, 8), logc = _mm256_i64gather_pd(t.logc, i, 8);
    // __log_fma's operations in its order.
    const __m256d w = _mm256_fmadd_pd(kd, _mm256_set1_pd(kLn2Hi), logc);
    const __m256d r = _mm256_fmadd_pd(z, invc, _mm256_set1_pd(-1.0));
    const __m256d a21 = _mm256_fmadd_pd(r, _mm256_set1_pd(kA[2]), _mm256_set1_pd(kA[1]));
    const __m256d hi = _mm256_add_pd(r, w);
    const __m256d r2 = _mm256_mul_pd(r, r);
    const __m256d lo = _mm256_fmadd_pd(kd, _mm256_set1_pd(kLn2Lo), _mm256_add_pd(_mm256_sub_pd(w, hi), r));
    const __m256d r3 = _mm256_mul_pd(r, r2);
    const __m256d a43 = _mm256_fmadd_pd(r, _mm256_set1_pd(kA[4]), _mm256_set1_pd(kA[3]));
    const __m256d lo2 = _mm256_fmadd_pd(r2, _mm256_set1_pd(kA[0]), lo);
    const __m256d p = _mm256_fmadd_pd(a43, r2, a21);
    return _mm256_add_pd(_mm256_fmadd_pd(r3, p, lo2), hi);
}

/// log of four values, std::log's doubles on the lanes off the table path.
inline __m256d logOf(__m256d x)
{
    __m256d regular;
    const __m256d y = logLanes(x, regular);
    if (_mm256_movemask_pd(regular) == 0xf) return y;
    alignas(32) double in[4], out[4];
    _mm256_store_pd(in, x);
    _mm256_store_pd(out, y);
    glibc_log::logOffPath<4>(in, out, unsigned(_mm256_movemask_pd(regular)));
    return _mm256_load_pd(out);
}

bool logMatchesTheLibrary()
{
    return glibc_log::logMatchesTheLibrary<4>(
        [](const double* x, double* y) { _mm256_storeu_pd(y, logOf(_mm256_loadu_pd(x))); });
}

}  // namespace

bool hasIsoRadiiAvx2()
{
    static const bool has = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") && logMatchesTheLibrary();
    return has;
}

void isoRadiiAvx2(double* f, std::size_t n, double peak, double fMin, double sigma, double rhoMax)
{
    const __m256d vPeak = _mm256_set1_pd(peak), vMin = _mm256_set1_pd(fMin), vSigma = _mm256_set1_pd(sigma),
                  vMax = _mm256_set1_pd(rhoMax), two = _mm256_set1_pd(2.0), sign = _mm256_set1_pd(-0.0);
    std::size_t k = 0;
    for (; k + 4 <= n; k += 4) {
        const __m256d v = _mm256_loadu_pd(f + k);
        const __m256d capped = _mm256_cmp_pd(v, vMin, _CMP_LE_OQ);
        // radii(): u = peak / (f <= fMin ? peak : f), log u (0 where u == 1), then the root.
        const __m256d q = _mm256_div_pd(vPeak, _mm256_blendv_pd(v, vPeak, capped));
        const __m256d u = _mm256_andnot_pd(_mm256_cmp_pd(q, _mm256_set1_pd(1.0), _CMP_EQ_OQ), logOf(q));
        const __m256d root = _mm256_mul_pd(vSigma, _mm256_sqrt_pd(_mm256_mul_pd(two, _mm256_andnot_pd(sign, u))));
        const __m256d rho = _mm256_or_pd(_mm256_andnot_pd(sign, root), _mm256_and_pd(sign, u));
        // std::min(rhoMax, rho): rho where rho < rhoMax, else rhoMax (NaN too).
        _mm256_storeu_pd(f + k, _mm256_blendv_pd(_mm256_min_pd(rho, vMax), vMax, capped));
    }
    for (; k < n; ++k) {
        const double u0 = peak / (f[k] <= fMin ? peak : f[k]);
        const double u = u0 == 1.0 ? 0.0 : std::log(u0);
        const double rho = std::min(rhoMax, std::copysign(sigma * std::sqrt(2.0 * std::abs(u)), u));
        f[k] = f[k] <= fMin ? rhoMax : rho;
    }
}

#else

bool hasIsoRadiiAvx2()
{
    return false;
}

void isoRadiiAvx2(double*, std::size_t, double, double, double, double) {}

#endif

}  // namespace voxlat
