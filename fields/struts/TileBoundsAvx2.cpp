/// @file TileBoundsAvx2.cpp
/// TileBounds.h's four-lane form, for CPUs without AVX-512F. This file alone is compiled for AVX2
/// without FMA or contraction: each lane makes the scalar loop's IEEE operations in its order (the
/// same doubles; tests/test_struts.cpp compares the planes' bounds bit for bit).

#include "fields/struts/TileBounds.h"

#include <cmath>
#include <cstddef>
#include <cstdlib>

#ifdef VOXLAT_AVX2_ROWS
#include <immintrin.h>
#endif

namespace voxlat {

#ifdef VOXLAT_AVX2_ROWS

namespace {

/// Lanes of @a mask as four bits.
unsigned bits(__m256d mask)
{
    return unsigned(_mm256_movemask_pd(mask));
}

/// b where @a mask is set, else a.
__m256d select(__m256d mask, __m256d a, __m256d b)
{
    return _mm256_blendv_pd(a, b, mask);
}

}  // namespace

void addTileBoundsAvx2(const TileColumnStrut& s, int a0, int a1, int b0, int b1, int tilesY, const ExpUpperNodes& table,
                       double* upper, double* peaks, TileColumnReach* reachOf)
{
    const __m256d lane = _mm256_setr_pd(0.0, 1.0, 2.0, 3.0);
    const __m256d zero = _mm256_setzero_pd(), signBit = _mm256_set1_pd(-0.0);
    const __m256d cy0 = _mm256_set1_pd(s.cy0), stepY = _mm256_set1_pd(s.stepY), ay = _mm256_set1_pd(s.ay),
                  ux = _mm256_set1_pd(s.ux), uy = _mm256_set1_pd(s.uy), uz = _mm256_set1_pd(s.uz),
                  length = _mm256_set1_pd(s.length), ez = _mm256_set1_pd(s.ez);
    const __m256d ezuz = _mm256_mul_pd(ez, uz);
    const __m256d halfX = _mm256_set1_pd(s.halfX), halfY = _mm256_set1_pd(s.halfY),
                  halfDiagonal = _mm256_set1_pd(s.halfDiagonal), margin = _mm256_set1_pd(s.margin);
    const __m256d peak = _mm256_set1_pd(s.peak), inv2s2 = _mm256_set1_pd(s.inv2s2), steps = _mm256_set1_pd(table.steps),
                  last = _mm256_set1_pd(double(table.size - 1));
    const __m256d farHaloSqr = _mm256_set1_pd(s.farHaloSqr), farSqr = _mm256_set1_pd(s.farSqr),
                  innerSqr = _mm256_set1_pd(s.innerSqr);
    // The lanes' ey (the same for every column), and which lanes are tiles (b <= b1).
    constexpr int kGroups = 16;
    __m256d eyOf[kGroups], eyuyOf[kGroups];
    __m256d liveOf[kGroups];
    for (int g = 0; g * 4 <= b1 - b0 && g < kGroups; ++g) {
        const __m256d b = _mm256_add_pd(_mm256_set1_pd(double(b0 + 4 * g)), lane);
        eyOf[g] = _mm256_sub_pd(_mm256_add_pd(cy0, _mm256_mul_pd(b, stepY)), ay);
        eyuyOf[g] = _mm256_mul_pd(eyOf[g], uy);
        liveOf[g] = _mm256_cmp_pd(b, _mm256_set1_pd(double(b1)), _CMP_LE_OQ);
    }
    for (int a = a0; a <= a1; ++a) {
        TileColumnReach reach;
        double* upperA = upper + std::size_t(a) * tilesY;
        double* peaksA = peaks + std::size_t(a) * tilesY;
        const double exs = s.cx0 + a * s.stepX - s.ax;
        const __m256d ex = _mm256_set1_pd(exs), exux = _mm256_set1_pd(exs * s.ux);
        for (int b = b0, g = 0; b <= b1; b += 4, ++g) {
            const __m256d live = liveOf[g];
            // ey = cy0 + b stepY - ay; h = ex ux + ey uy + ez uz clamped to [0, L].
            const __m256d ey = eyOf[g];
            const __m256d hRaw = _mm256_add_pd(_mm256_add_pd(exux, eyuyOf[g]), ezuz);
            const __m256d low = select(_mm256_cmp_pd(hRaw, zero, _CMP_LT_OQ), hRaw, zero);
            const __m256d h = select(_mm256_cmp_pd(length, hRaw, _CMP_LT_OQ), low, length);
            const __m256d rx = _mm256_sub_pd(ex, _mm256_mul_pd(h, ux)), ry = _mm256_sub_pd(ey, _mm256_mul_pd(h, uy)),
                          rz = _mm256_sub_pd(ez, _mm256_mul_pd(h, uz));
            const __m256d dSqr =
                _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(rx, rx), _mm256_mul_pd(ry, ry)), _mm256_mul_pd(rz, rz));
            const __m256d withinMask = _mm256_and_pd(live, _mm256_cmp_pd(dSqr, farSqr, _CMP_LT_OQ));
            const unsigned halo = bits(_mm256_and_pd(live, _mm256_cmp_pd(dSqr, farHaloSqr, _CMP_LT_OQ)));
            const unsigned within = bits(withinMask);
            const unsigned inner = within & bits(_mm256_cmp_pd(dSqr, innerSqr, _CMP_LT_OQ));
            reach.halo |= std::uint64_t(halo) << b;
            reach.inner |= std::uint64_t(inner) << b;
            if (!within) continue;
            const __m256d d = _mm256_sqrt_pd(dSqr);
            const __m256d spread = _mm256_div_pd(_mm256_add_pd(_mm256_mul_pd(halfX, _mm256_andnot_pd(signBit, rx)),
                                                               _mm256_mul_pd(halfY, _mm256_andnot_pd(signBit, ry))),
                                                 d);
            const __m256d spreadMin = select(_mm256_cmp_pd(spread, halfDiagonal, _CMP_LT_OQ), halfDiagonal, spread);
            const __m256d root = _mm256_sub_pd(_mm256_sub_pd(d, spreadMin), margin);
            const __m256d near = select(_mm256_cmp_pd(zero, root, _CMP_LT_OQ), zero, root);
            const __m256d x = _mm256_mul_pd(_mm256_mul_pd(near, near), inv2s2);
            const __m256d at = _mm256_mul_pd(x, steps);
            const __m256d tabledMask = _mm256_and_pd(withinMask, _mm256_cmp_pd(at, last, _CMP_LT_OQ));
            const unsigned tabled = bits(tabledMask);
            // Truncation: the node at or below x (at >= 0).
            const __m128i index = _mm256_cvttpd_epi32(select(tabledMask, zero, at));
            __m256d kernel = _mm256_mask_i32gather_pd(zero, table.value, index, tabledMask, 8);
            if (tabled != within) {
                alignas(32) double xs[4], ks[4];
                _mm256_store_pd(xs, x);
                _mm256_store_pd(ks, kernel);
                for (int l = 0; l < 4; ++l)
                    if ((within >> l & 1) && !(tabled >> l & 1)) ks[l] = std::exp(-xs[l]);
                kernel = _mm256_load_pd(ks);
            }
            const __m256d add = _mm256_mul_pd(peak, kernel);
            const __m256i store = _mm256_castpd_si256(withinMask);
            _mm256_maskstore_pd(upperA + b, store, _mm256_add_pd(_mm256_maskload_pd(upperA + b, store), add));
            _mm256_maskstore_pd(peaksA + b, store, _mm256_add_pd(_mm256_maskload_pd(peaksA + b, store), peak));
        }
        reachOf[a - a0] = reach;
    }
}

#else

void addTileBoundsAvx2(const TileColumnStrut&, int, int, int, int, int, const ExpUpperNodes&, double*, double*,
                       TileColumnReach*)
{
    std::abort();
}

#endif

}  // namespace voxlat
