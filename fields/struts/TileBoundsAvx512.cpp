/// @file TileBoundsAvx512.cpp
/// TileBounds.h's eight-lane form. This file alone is compiled for AVX-512F without
/// contraction: each lane makes the scalar loop's IEEE operations in its order (the same doubles;
/// tests/test_struts.cpp compares the planes' bounds bit for bit).

#include "fields/struts/TileBounds.h"

#include <cmath>
#include <cstddef>
#include <cstdlib>

#ifdef VOXLAT_AVX512_ROWS
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include <immintrin.h>
#endif

namespace voxlat {

#ifdef VOXLAT_AVX512_ROWS

void addTileBoundsAvx512(const TileColumnStrut& s, int a0, int a1, int b0, int b1, int tilesY,
                         const ExpUpperNodes& table, double* upper, double* peaks, TileColumnReach* reachOf)
{
    const __m512d lane = _mm512_setr_pd(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
    const __m512d zero = _mm512_setzero_pd();
    const __m512d cy0 = _mm512_set1_pd(s.cy0), stepY = _mm512_set1_pd(s.stepY), ay = _mm512_set1_pd(s.ay),
                  ux = _mm512_set1_pd(s.ux), uy = _mm512_set1_pd(s.uy), uz = _mm512_set1_pd(s.uz),
                  length = _mm512_set1_pd(s.length), ez = _mm512_set1_pd(s.ez);
    const __m512d ezuz = _mm512_mul_pd(ez, uz);
    const __m512d halfX = _mm512_set1_pd(s.halfX), halfY = _mm512_set1_pd(s.halfY),
                  halfDiagonal = _mm512_set1_pd(s.halfDiagonal), margin = _mm512_set1_pd(s.margin);
    const __m512d peak = _mm512_set1_pd(s.peak), inv2s2 = _mm512_set1_pd(s.inv2s2), steps = _mm512_set1_pd(table.steps),
                  last = _mm512_set1_pd(double(table.size - 1));
    const __m512d farHaloSqr = _mm512_set1_pd(s.farHaloSqr), farSqr = _mm512_set1_pd(s.farSqr),
                  innerSqr = _mm512_set1_pd(s.innerSqr);
    // The lanes' ey (the same for every column).
    constexpr int kGroups = 8;
    __m512d eyOf[kGroups], eyuyOf[kGroups];
    for (int g = 0; g * 8 <= b1 - b0 && g < kGroups; ++g) {
        eyOf[g] = _mm512_sub_pd(
            _mm512_add_pd(cy0, _mm512_mul_pd(_mm512_add_pd(_mm512_set1_pd(double(b0 + 8 * g)), lane), stepY)), ay);
        eyuyOf[g] = _mm512_mul_pd(eyOf[g], uy);
    }
    for (int a = a0; a <= a1; ++a) {
        TileColumnReach reach;
        double* upperA = upper + std::size_t(a) * tilesY;
        double* peaksA = peaks + std::size_t(a) * tilesY;
        const double exs = s.cx0 + a * s.stepX - s.ax;
        const __m512d ex = _mm512_set1_pd(exs), exux = _mm512_set1_pd(exs * s.ux);
        for (int b = b0, g = 0; b <= b1; b += 8, ++g) {
            const __mmask8 live = __mmask8(b1 - b >= 7 ? 0xff : (1u << (b1 - b + 1)) - 1);
            // ey = cy0 + b stepY - ay; h = ex ux + ey uy + ez uz clamped to [0, L].
            const __m512d ey = eyOf[g];
            const __m512d hRaw = _mm512_add_pd(_mm512_add_pd(exux, eyuyOf[g]), ezuz);
            const __m512d low = _mm512_mask_blend_pd(_mm512_cmp_pd_mask(hRaw, zero, _CMP_LT_OQ), hRaw, zero);
            const __m512d h = _mm512_mask_blend_pd(_mm512_cmp_pd_mask(length, hRaw, _CMP_LT_OQ), low, length);
            const __m512d rx = _mm512_sub_pd(ex, _mm512_mul_pd(h, ux)), ry = _mm512_sub_pd(ey, _mm512_mul_pd(h, uy)),
                          rz = _mm512_sub_pd(ez, _mm512_mul_pd(h, uz));
            const __m512d dSqr =
                _mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(rx, rx), _mm512_mul_pd(ry, ry)), _mm512_mul_pd(rz, rz));
            const __mmask8 halo = _mm512_mask_cmp_pd_mask(live, dSqr, farHaloSqr, _CMP_LT_OQ);
            const __mmask8 within = _mm512_mask_cmp_pd_mask(live, dSqr, farSqr, _CMP_LT_OQ);
            const __mmask8 inner = _mm512_mask_cmp_pd_mask(within, dSqr, innerSqr, _CMP_LT_OQ);
            reach.halo |= std::uint64_t(halo) << b;
            reach.inner |= std::uint64_t(inner) << b;
            if (!within) continue;
            const __m512d d = _mm512_sqrt_pd(dSqr);
            const __m512d spread = _mm512_div_pd(
                _mm512_add_pd(_mm512_mul_pd(halfX, _mm512_abs_pd(rx)), _mm512_mul_pd(halfY, _mm512_abs_pd(ry))), d);
            const __m512d spreadMin =
                _mm512_mask_blend_pd(_mm512_cmp_pd_mask(spread, halfDiagonal, _CMP_LT_OQ), halfDiagonal, spread);
            const __m512d root = _mm512_sub_pd(_mm512_sub_pd(d, spreadMin), margin);
            const __m512d near = _mm512_mask_blend_pd(_mm512_cmp_pd_mask(zero, root, _CMP_LT_OQ), zero, root);
            const __m512d x = _mm512_mul_pd(_mm512_mul_pd(near, near), inv2s2);
            const __m512d at = _mm512_mul_pd(x, steps);
            const __mmask8 tabled = _mm512_mask_cmp_pd_mask(within, at, last, _CMP_LT_OQ);
            // Truncation: the node at or below x (at >= 0).
            const __m256i index = _mm512_cvttpd_epi32(_mm512_mask_blend_pd(tabled, zero, at));
            __m512d kernel = _mm512_mask_i32gather_pd(zero, tabled, index, table.value, 8);
            if (tabled != within) {
                alignas(64) double xs[8], ks[8];
                _mm512_store_pd(xs, x);
                _mm512_store_pd(ks, kernel);
                for (int l = 0; l < 8; ++l)
                    if ((within >> l & 1) && !(tabled >> l & 1)) ks[l] = std::exp(-xs[l]);
                kernel = _mm512_load_pd(ks);
            }
            const __m512d add = _mm512_mul_pd(peak, kernel);
            _mm512_mask_storeu_pd(upperA + b, within, _mm512_add_pd(_mm512_maskz_loadu_pd(within, upperA + b), add));
            _mm512_mask_storeu_pd(peaksA + b, within, _mm512_add_pd(_mm512_maskz_loadu_pd(within, peaksA + b), peak));
        }
        reachOf[a - a0] = reach;
    }
}

#else

void addTileBoundsAvx512(const TileColumnStrut&, int, int, int, int, int, const ExpUpperNodes&, double*, double*,
                         TileColumnReach*)
{
    std::abort();
}

#endif

}  // namespace voxlat
