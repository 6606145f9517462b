/// @file IsoRadiusAvx512.cpp
/// IsoRadius's map in eight lanes: IsoRadiusAvx2.cpp's, the same operations in the same order
/// (glibc's log as __log_fma computes it, GlibcLogData.h), built for AVX-512F (which has the fused
/// multiply-adds) with no other contraction: the same doubles. hasIsoRadiiAvx512() checks its
/// logarithm against std::log once, as hasIsoRadiiAvx2() does.

#include "fields/struts/IsoRadiusAvx2.h"

#include "fields/struts/GlibcLogData.h"
#include "fields/struts/StrutRows.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#if defined(VOXLAT_AVX512_ROWS)
// GCC 12's casts between widths start from a vector it calls uninitialised (its own headers).
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"
#include <immintrin.h>
#endif

namespace voxlat {

#if defined(VOXLAT_AVX512_ROWS)

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

/// log of eight lanes by the table path; @a regular marks the lanes it covers (x >= 2^-1022,
/// finite, outside [1 - 2^-4, 1 + 0x1.09p-4)); the others hold garbage.
__m512d logLanes(__m512d x, __mmask8& regular)
{
    const LogColumns& t = columns();
    const __mmask8 near1 = _mm512_cmp_pd_mask(x, _mm512_set1_pd(1.0 - 0x1p-4), _CMP_GE_OQ) &
                           _mm512_cmp_pd_mask(x, _mm512_set1_pd(1.0 + 0x1.09p-4), _CMP_LT_OQ);
    const __mmask8 normal = _mm512_cmp_pd_mask(x, _mm512_set1_pd(0x1p-1022), _CMP_GE_OQ) &
                            _mm512_cmp_pd_mask(x, _mm512_set1_pd(std::numeric_limits<double>::infinity()), _CMP_LT_OQ);
    regular = __mmask8(normal & ~near1);
    // Lanes off the path take x = 1.5 meanwhile (any regular value), so the table is read in range.
    const __m512i ix = _mm512_castpd_si512(_mm512_mask_blend_pd(regular, _mm512_set1_pd(1.5), x));
    const __m512i tmp = _mm512_sub_epi64(ix, _mm512_set1_epi64(0x3fe6000000000000LL));
    const __m512i i = _mm512_and_si512(_mm512_srli_epi64(tmp, 45), _mm512_set1_epi64(0x7f));
    // k = tmp >> 52 (arithmetic), exact in 32 bits.
    const __m512d kd = _mm512_cvtepi32_pd(_mm512_cvtepi64_epi32(_mm512_srai_epi64(tmp, 52)));
    const __m512i iz =
        _mm512_sub_epi64(ix, _mm512_and_si512(tmp, _mm512_set1_epi64(std::int64_t(0xfff0000000000000ULL))));
    const __m512d z = _mm512_castsi512_pd(iz);
    const __m512d invc = _mm512_i64gather_pd(i, t.invc, 8), logc = _mm512_i64gather_pd(i, t.logc, 8);
    // __log_fma's operations in its order.
    const __m512d w = _mm512_fmadd_pd(kd, _mm512_set1_pd(kLn2Hi), logc);
    const __m512d r = _mm512_fmadd_pd(z, invc, _mm512_set1_pd(-1.0));
    const __m512d a21 = _mm512_fmadd_pd(r, _mm512_set1_pd(kA[2]), _mm512_set1_pd(kA[1]));
    const __m512d hi = _mm512_add_pd(r, w);
    const __m512d r2 = _mm512_mul_pd(r, r);
    const __m512d lo = _mm512_fmadd_pd(kd, _mm512_set1_pd(kLn2Lo), _mm512_add_pd(_mm512_sub_pd(w, hi), r));
    const __m512d r3 = _mm512_mul_pd(r, r2);
    const __m512d a43 = _mm512_fmadd_pd(r, _mm512_set1_pd(kA[4]), _mm512_set1_pd(kA[3]));
    const __m512d lo2 = _mm512_fmadd_pd(r2, _mm512_set1_pd(kA[0]), lo);
    const __m512d p = _mm512_fmadd_pd(a43, r2, a21);
    return _mm512_add_pd(_mm512_fmadd_pd(r3, p, lo2), hi);
}

/// log of eight values, std::log's doubles on the lanes off the table path.
__m512d logOf(__m512d x)
{
    __mmask8 regular = 0;
    const __m512d y = logLanes(x, regular);
    if (regular == 0xff) return y;
    alignas(64) double in[8], out[8];
    _mm512_store_pd(in, x);
    _mm512_store_pd(out, y);
    glibc_log::logOffPath<8>(in, out, regular);
    return _mm512_load_pd(out);
}

bool logMatchesTheLibrary()
{
    return glibc_log::logMatchesTheLibrary<8>(
        [](const double* x, double* y) { _mm512_storeu_pd(y, logOf(_mm512_loadu_pd(x))); });
}

}  // namespace

bool hasIsoRadiiAvx512()
{
    static const bool has = hasAvx512Rows() && logMatchesTheLibrary();
    return has;
}

void isoRadiiAvx512(double* f, std::size_t n, double peak, double fMin, double sigma, double rhoMax)
{
    const __m512d vPeak = _mm512_set1_pd(peak), vMin = _mm512_set1_pd(fMin), vSigma = _mm512_set1_pd(sigma),
                  vMax = _mm512_set1_pd(rhoMax), two = _mm512_set1_pd(2.0);
    const __m512i sign = _mm512_set1_epi64(std::int64_t(0x8000000000000000ULL));
    // The last lanes masked: a lane past the end reads peak (its log 0) and is not stored.
    for (std::size_t k = 0; k < n; k += 8) {
        const auto lanes = __mmask8(n - k >= 8 ? 0xff : (1u << (n - k)) - 1u);
        const __m512d v = _mm512_mask_loadu_pd(vPeak, lanes, f + k);
        const __mmask8 capped = _mm512_cmp_pd_mask(v, vMin, _CMP_LE_OQ);
        // radii(): u = peak / (f <= fMin ? peak : f), log u (0 where u == 1), then the root.
        const __m512d q = _mm512_div_pd(vPeak, _mm512_mask_blend_pd(capped, v, vPeak));
        const __m512d u = _mm512_maskz_mov_pd(_mm512_cmp_pd_mask(q, _mm512_set1_pd(1.0), _CMP_NEQ_UQ), logOf(q));
        const __m512i uBits = _mm512_castpd_si512(u);
        const __m512d magnitude = _mm512_castsi512_pd(_mm512_andnot_si512(sign, uBits));
        const __m512d root = _mm512_mul_pd(vSigma, _mm512_sqrt_pd(_mm512_mul_pd(two, magnitude)));
        const __m512d rho = _mm512_castsi512_pd(
            _mm512_or_si512(_mm512_andnot_si512(sign, _mm512_castpd_si512(root)), _mm512_and_si512(sign, uBits)));
        // std::min(rhoMax, rho): rho where rho < rhoMax, else rhoMax (NaN too).
        _mm512_mask_storeu_pd(f + k, lanes, _mm512_mask_blend_pd(capped, _mm512_min_pd(rho, vMax), vMax));
    }
}

#else

bool hasIsoRadiiAvx512()
{
    return false;
}

void isoRadiiAvx512(double*, std::size_t, double, double, double, double) {}

#endif

}  // namespace voxlat
