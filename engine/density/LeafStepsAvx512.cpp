/// @file LeafStepsAvx512.cpp
/// LeafSteps.h's loops in AVX-512F lanes, sixteen voxels (two rows of a leaf) at a time: the same
/// IEEE operations in the same order as the loops (float differences, double squares summed in x,
/// y, z order, no contraction), so the same floats. Run only where hasAvx512Rows(); a build for
/// another processor has none (avx512LeafSteps() is null).
#include "engine/density/LeafSteps.h"

#include <bit>
#include <initializer_list>

#if defined(__AVX512F__)
// GCC 12's casts between widths start from a vector it calls uninitialised (its own headers).
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"
#include <immintrin.h>
#endif

namespace voxlat::coverage {

#if defined(__AVX512F__)

namespace {

/// Rows @a a and @a b (eight floats each) in one vector, a in the low half.
__m512 twoRows(const float* a, const float* b)
{
    const __m512d low = _mm512_castps_pd(_mm512_castps256_ps512(_mm256_loadu_ps(a)));
    return _mm512_castpd_ps(_mm512_insertf64x4(low, _mm256_castps_pd(_mm256_loadu_ps(b)), 1));
}

/// The low (@a high false) or high eight floats of @a v as doubles.
__m512d half(__m512 v, bool high)
{
    const __m256 part =
        high ? _mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(v), 1)) : _mm512_castps512_ps256(v);
    return _mm512_cvtps_pd(part);
}

/// Sixteen voxels' differences along one axis, and which neighbours are there (below 1e30).
struct AxisDifferences {
    __m512 both, up, down;  // up - down, up - value, value - down (floats)
    __mmask16 hasUp, hasDown;
};

AxisDifferences differences(__m512 value, __m512 up, __m512 down)
{
    const __m512 absent = _mm512_set1_ps(1e30f);
    return AxisDifferences{_mm512_sub_ps(up, down), _mm512_sub_ps(up, value), _mm512_sub_ps(value, down),
                           _mm512_cmp_ps_mask(up, absent, _CMP_LT_OQ), _mm512_cmp_ps_mask(down, absent, _CMP_LT_OQ)};
}

/// laneChange() for the low (@a high false) or high eight of the sixteen voxels.
__m512d change(const AxisDifferences& d, bool high)
{
    const int shift = high ? 8 : 0;
    const auto hasUp = __mmask8(d.hasUp >> shift), hasDown = __mmask8(d.hasDown >> shift);
    const __m512d both = _mm512_mul_pd(_mm512_set1_pd(0.5), half(d.both, high));
    const __m512d oneDown = _mm512_maskz_mov_pd(hasDown, half(d.down, high));
    const __m512d one = _mm512_mask_mov_pd(oneDown, hasUp, half(d.up, high));
    return _mm512_mask_mov_pd(one, __mmask8(hasUp & hasDown), both);
}

void stepsInLanes(const LeafWithNeighbours& leaf, float* steps, float lo, float hi)
{
    const float* data = leaf.data;
    const __m512 low = _mm512_set1_ps(lo), high = _mm512_set1_ps(hi);
    // Lane j of zUp takes lane j + 1, the last of each row the next leaf's (extra lane 0 or 1);
    // zDown lane j - 1, the first of each row the leaf below's (extra lane 2 or 3).
    const __m512i upIndex = _mm512_setr_epi32(1, 2, 3, 4, 5, 6, 7, 16, 9, 10, 11, 12, 13, 14, 15, 17);
    const __m512i downIndex = _mm512_setr_epi32(18, 0, 1, 2, 3, 4, 5, 6, 19, 8, 9, 10, 11, 12, 13, 14);
    for (int x = 0; x < 8; ++x) {
        const float *xUp = xPlane(leaf, x, true), *xDown = xPlane(leaf, x, false);
        for (int y = 0; y < 8; y += 2) {
            const int r = x * 64 + y * 8;
            const float* row = data + r;
            const __m512 v = _mm512_loadu_ps(row);
            if ((_mm512_cmp_ps_mask(v, low, _CMP_NLT_UQ) & _mm512_cmp_ps_mask(v, high, _CMP_NGT_UQ)) == 0) {
                _mm512_storeu_ps(steps + r, _mm512_setzero_ps());  // no voxel of the two rows in the band
                continue;
            }
            const __m512 xu = _mm512_loadu_ps(xUp + y * 8), xd = _mm512_loadu_ps(xDown + y * 8);
            const __m512 yu = y < 6 ? _mm512_loadu_ps(row + 8) : twoRows(row + 8, leaf.next[1][1] + x * 64);
            const __m512 yd = y > 0 ? _mm512_loadu_ps(row - 8) : twoRows(leaf.next[1][0] + x * 64 + 56, row);
            const __m512 extra = _mm512_setr_ps(leaf.next[2][1][r], leaf.next[2][1][r + 8], leaf.next[2][0][r + 7],
                                                leaf.next[2][0][r + 15], 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0);
            const __m512 zu = _mm512_permutex2var_ps(v, upIndex, extra);
            const __m512 zd = _mm512_permutex2var_ps(v, downIndex, extra);
            const AxisDifferences dx = differences(v, xu, xd), dy = differences(v, yu, yd), dz = differences(v, zu, zd);
            for (const bool high : {false, true}) {
                const __m512d cx = change(dx, high), cy = change(dy, high), cz = change(dz, high);
                const __m512d sum =
                    _mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(cx, cx), _mm512_mul_pd(cy, cy)), _mm512_mul_pd(cz, cz));
                _mm256_storeu_ps(steps + r + (high ? 8 : 0), _mm512_cvtpd_ps(_mm512_sqrt_pd(sum)));
            }
        }
    }
}

LeafStraddle straddleInLanes(const float* data, const float* steps, const StraddleBounds& s)
{
    LeafStraddle out;
    const __m512 lo = _mm512_set1_ps(s.lo), hi = _mm512_set1_ps(s.hi);
    const __m512 countLo = _mm512_set1_ps(s.countLo), countHi = _mm512_set1_ps(s.countHi);
    const __m512d a = _mm512_set1_pd(s.a), b = _mm512_set1_pd(s.b), halfOf = _mm512_set1_pd(0.5);
    const __m512d zero = _mm512_setzero_pd();
    for (int i = 0; i < 512; i += 16) {
        const __m512 v = _mm512_loadu_ps(data + i), step = _mm512_loadu_ps(steps + i);
        const __mmask16 inBand = _mm512_cmp_ps_mask(v, lo, _CMP_NLT_UQ) & _mm512_cmp_ps_mask(v, hi, _CMP_NGT_UQ);
        const __mmask16 belowLo = _mm512_cmp_ps_mask(v, lo, _CMP_LT_OQ);
        const __mmask16 countBelow = _mm512_cmp_ps_mask(v, countLo, _CMP_LT_OQ);
        const __mmask16 countWithin =
            _mm512_cmp_ps_mask(v, countLo, _CMP_NLT_UQ) & _mm512_cmp_ps_mask(v, countHi, _CMP_LE_OQ);
        unsigned full = 0, empty = 0;
        for (const bool high : {false, true}) {
            const __m512d value = half(v, high), halfStep = _mm512_mul_pd(halfOf, half(step, high));
            const __mmask8 stepped = _mm512_cmp_pd_mask(halfStep, zero, _CMP_GT_OQ);
            const __mmask8 fullStepped = _mm512_cmp_pd_mask(_mm512_add_pd(value, halfStep), a, _CMP_LE_OQ);
            const __mmask8 fullFlat = _mm512_cmp_pd_mask(value, a, _CMP_LT_OQ);
            const __mmask8 emptyStepped = _mm512_cmp_pd_mask(_mm512_sub_pd(value, halfStep), b, _CMP_GE_OQ);
            const __mmask8 emptyFlat = _mm512_cmp_pd_mask(value, b, _CMP_NLT_UQ);
            // overBracket(): by the ramp where the step is positive, else by the value.
            const unsigned f = unsigned((stepped & fullStepped) | (~stepped & fullFlat)) & 0xffu;
            const unsigned e = unsigned((stepped & emptyStepped) | (~stepped & emptyFlat)) & 0xffu;
            full |= f << (high ? 8 : 0);
            empty |= e << (high ? 8 : 0);
        }
        out.below += std::uint32_t(std::popcount(unsigned(belowLo)) + std::popcount(unsigned(inBand) & full));
        out.countBelow += std::uint32_t(std::popcount(unsigned(countBelow)));
        out.countWithin += std::uint32_t(std::popcount(unsigned(countWithin)));
        const std::uint64_t changing = unsigned(inBand) & ~full & ~empty & 0xffffu;
        out.changing[i / 64] |= changing << (i % 64);
    }
    return out;
}

float widestInLanes(const float* data, const float* steps, float lo, float hi)
{
    const __m512 low = _mm512_set1_ps(lo), high = _mm512_set1_ps(hi), cap = _mm512_set1_ps(1e29f);
    __m512 widest = _mm512_setzero_ps();
    for (int i = 0; i < 512; i += 16) {
        const __m512 v = _mm512_loadu_ps(data + i), step = _mm512_loadu_ps(steps + i);
        const __mmask16 counted = _mm512_cmp_ps_mask(v, low, _CMP_NLT_UQ) & _mm512_cmp_ps_mask(v, high, _CMP_NGT_UQ) &
                                  _mm512_cmp_ps_mask(step, cap, _CMP_LT_OQ);
        widest = _mm512_mask_max_ps(widest, counted, step, widest);
    }
    return _mm512_reduce_max_ps(widest);  // a maximum: the same in any order
}

bool meetsInLanes(const float* data, float lo, float hi)
{
    const __m512 low = _mm512_set1_ps(lo), high = _mm512_set1_ps(hi);
    for (int i = 0; i < 512; i += 64) {
        __mmask16 meets = 0;
        for (int j = i; j < i + 64; j += 16) {
            const __m512 v = _mm512_loadu_ps(data + j);
            meets |= _mm512_cmp_ps_mask(v, low, _CMP_NLT_UQ) & _mm512_cmp_ps_mask(v, high, _CMP_NGT_UQ);
        }
        if (meets) return true;
    }
    return false;
}

}  // namespace

const LeafStepForms* avx512LeafSteps()
{
    static const LeafStepForms forms{stepsInLanes, straddleInLanes, widestInLanes, meetsInLanes};
    return &forms;
}

#else

const LeafStepForms* avx512LeafSteps()
{
    return nullptr;
}

#endif

}  // namespace voxlat::coverage
