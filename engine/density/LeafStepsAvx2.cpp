/// @file LeafStepsAvx2.cpp
/// LeafSteps.h's loops in AVX2 lanes, for CPUs without AVX-512F: a leaf's row (eight floats) at a
/// time, its doubles four at a time. The same IEEE operations in the same order as the loops (float
/// differences, double squares summed in x, y, z order, no contraction, no FMA), so the same
/// floats. Run only where hasAvx2Rows(); a build for another processor has none (avx2LeafSteps() is null).
#include "engine/density/LeafSteps.h"

#include <bit>
#include <initializer_list>

#if defined(__AVX2__)
#include <immintrin.h>
#endif

namespace voxlat::coverage {

#if defined(__AVX2__)

namespace {

/// Which of eight floats lie within [lo, hi] (NaN does: !(v < lo || v > hi)), as a float mask.
__m256 withinBand(__m256 v, __m256 lo, __m256 hi)
{
    return _mm256_and_ps(_mm256_cmp_ps(v, lo, _CMP_NLT_UQ), _mm256_cmp_ps(v, hi, _CMP_NGT_UQ));
}

/// The low (@a high false) or high four floats of @a v as doubles.
__m256d half(__m256 v, bool high)
{
    return _mm256_cvtps_pd(high ? _mm256_extractf128_ps(v, 1) : _mm256_castps256_ps128(v));
}

/// The low or high four lanes of a float mask as a double mask (each 32-bit lane sign-extended).
__m256d halfMask(__m256 mask, bool high)
{
    const __m128 part = high ? _mm256_extractf128_ps(mask, 1) : _mm256_castps256_ps128(mask);
    return _mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm_castps_si128(part)));
}

/// A row's differences along one axis, and which neighbours are there (below 1e30).
struct AxisDifferences {
    __m256 both, up, down;  // up - down, up - value, value - down (floats)
    __m256 hasUp, hasDown;  // masks
};

AxisDifferences differences(__m256 value, __m256 up, __m256 down)
{
    const __m256 absent = _mm256_set1_ps(1e30f);
    return AxisDifferences{_mm256_sub_ps(up, down), _mm256_sub_ps(up, value), _mm256_sub_ps(value, down),
                           _mm256_cmp_ps(up, absent, _CMP_LT_OQ), _mm256_cmp_ps(down, absent, _CMP_LT_OQ)};
}

/// laneChange() for the low (@a high false) or high four of the row's eight voxels.
__m256d change(const AxisDifferences& d, bool high)
{
    const __m256d hasUp = halfMask(d.hasUp, high), hasDown = halfMask(d.hasDown, high);
    const __m256d both = _mm256_mul_pd(_mm256_set1_pd(0.5), half(d.both, high));
    const __m256d oneDown = _mm256_and_pd(hasDown, half(d.down, high));
    const __m256d one = _mm256_blendv_pd(oneDown, half(d.up, high), hasUp);
    return _mm256_blendv_pd(one, both, _mm256_and_pd(hasUp, hasDown));
}

void stepsInLanes(const LeafWithNeighbours& leaf, float* steps, float lo, float hi)
{
    const float* data = leaf.data;
    const __m256 low = _mm256_set1_ps(lo), high = _mm256_set1_ps(hi);
    // Lane k of zUp takes lane k + 1 (the last the next leaf's), zDown lane k - 1 (the first the
    // leaf below's).
    const __m256i upIndex = _mm256_setr_epi32(1, 2, 3, 4, 5, 6, 7, 7);
    const __m256i downIndex = _mm256_setr_epi32(0, 0, 1, 2, 3, 4, 5, 6);
    for (int x = 0; x < 8; ++x) {
        const float *xUp = xPlane(leaf, x, true), *xDown = xPlane(leaf, x, false);
        for (int y = 0; y < 8; ++y) {
            const int r = x * 64 + y * 8;
            const float* row = data + r;
            const __m256 v = _mm256_loadu_ps(row);
            if (_mm256_movemask_ps(withinBand(v, low, high)) == 0) {
                _mm256_storeu_ps(steps + r, _mm256_setzero_ps());  // no voxel of the row in the band
                continue;
            }
            const __m256 xu = _mm256_loadu_ps(xUp + y * 8), xd = _mm256_loadu_ps(xDown + y * 8);
            const __m256 yu = _mm256_loadu_ps(y < 7 ? row + 8 : leaf.next[1][1] + x * 64);
            const __m256 yd = _mm256_loadu_ps(y > 0 ? row - 8 : leaf.next[1][0] + x * 64 + 56);
            const __m256 zu =
                _mm256_blend_ps(_mm256_permutevar8x32_ps(v, upIndex), _mm256_set1_ps(leaf.next[2][1][r]), 0x80);
            const __m256 zd =
                _mm256_blend_ps(_mm256_permutevar8x32_ps(v, downIndex), _mm256_set1_ps(leaf.next[2][0][r + 7]), 0x01);
            const AxisDifferences dx = differences(v, xu, xd), dy = differences(v, yu, yd), dz = differences(v, zu, zd);
            for (const bool upper : {false, true}) {
                const __m256d cx = change(dx, upper), cy = change(dy, upper), cz = change(dz, upper);
                const __m256d sum =
                    _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(cx, cx), _mm256_mul_pd(cy, cy)), _mm256_mul_pd(cz, cz));
                _mm_storeu_ps(steps + r + (upper ? 4 : 0), _mm256_cvtpd_ps(_mm256_sqrt_pd(sum)));
            }
        }
    }
}

LeafStraddle straddleInLanes(const float* data, const float* steps, const StraddleBounds& s)
{
    LeafStraddle out;
    const __m256 lo = _mm256_set1_ps(s.lo), hi = _mm256_set1_ps(s.hi);
    const __m256 countLo = _mm256_set1_ps(s.countLo), countHi = _mm256_set1_ps(s.countHi);
    const __m256d a = _mm256_set1_pd(s.a), b = _mm256_set1_pd(s.b), halfOf = _mm256_set1_pd(0.5);
    const __m256d zero = _mm256_setzero_pd();
    for (int i = 0; i < 512; i += 8) {
        const __m256 v = _mm256_loadu_ps(data + i), step = _mm256_loadu_ps(steps + i);
        const auto inBand = unsigned(_mm256_movemask_ps(withinBand(v, lo, hi)));
        const auto belowLo = unsigned(_mm256_movemask_ps(_mm256_cmp_ps(v, lo, _CMP_LT_OQ)));
        const auto countBelow = unsigned(_mm256_movemask_ps(_mm256_cmp_ps(v, countLo, _CMP_LT_OQ)));
        const auto countWithin = unsigned(_mm256_movemask_ps(
            _mm256_and_ps(_mm256_cmp_ps(v, countLo, _CMP_NLT_UQ), _mm256_cmp_ps(v, countHi, _CMP_LE_OQ))));
        unsigned full = 0, empty = 0;
        for (const bool upper : {false, true}) {
            const __m256d value = half(v, upper), halfStep = _mm256_mul_pd(halfOf, half(step, upper));
            const __m256d stepped = _mm256_cmp_pd(halfStep, zero, _CMP_GT_OQ);
            const __m256d fullStepped = _mm256_cmp_pd(_mm256_add_pd(value, halfStep), a, _CMP_LE_OQ);
            const __m256d fullFlat = _mm256_cmp_pd(value, a, _CMP_LT_OQ);
            const __m256d emptyStepped = _mm256_cmp_pd(_mm256_sub_pd(value, halfStep), b, _CMP_GE_OQ);
            const __m256d emptyFlat = _mm256_cmp_pd(value, b, _CMP_NLT_UQ);
            // overBracket(): by the ramp where the step is positive, else by the value.
            const auto f = unsigned(_mm256_movemask_pd(_mm256_blendv_pd(fullFlat, fullStepped, stepped)));
            const auto e = unsigned(_mm256_movemask_pd(_mm256_blendv_pd(emptyFlat, emptyStepped, stepped)));
            full |= f << (upper ? 4 : 0);
            empty |= e << (upper ? 4 : 0);
        }
        out.below += std::uint32_t(std::popcount(belowLo) + std::popcount(inBand & full));
        out.countBelow += std::uint32_t(std::popcount(countBelow));
        out.countWithin += std::uint32_t(std::popcount(countWithin));
        const std::uint64_t changing = inBand & ~full & ~empty & 0xffu;
        out.changing[i / 64] |= changing << (i % 64);
    }
    return out;
}

float widestInLanes(const float* data, const float* steps, float lo, float hi)
{
    const __m256 low = _mm256_set1_ps(lo), high = _mm256_set1_ps(hi), cap = _mm256_set1_ps(1e29f);
    __m256 widest = _mm256_setzero_ps();
    for (int i = 0; i < 512; i += 8) {
        const __m256 v = _mm256_loadu_ps(data + i), step = _mm256_loadu_ps(steps + i);
        const __m256 counted = _mm256_and_ps(withinBand(v, low, high), _mm256_cmp_ps(step, cap, _CMP_LT_OQ));
        widest = _mm256_max_ps(_mm256_and_ps(counted, step), widest);  // step > widest ? step : widest
    }
    alignas(32) float lanes[8];
    _mm256_store_ps(lanes, widest);
    float out = 0.0f;
    for (const float lane : lanes) out = lane > out ? lane : out;  // a maximum: the same in any order
    return out;
}

bool meetsInLanes(const float* data, float lo, float hi)
{
    const __m256 low = _mm256_set1_ps(lo), high = _mm256_set1_ps(hi);
    for (int i = 0; i < 512; i += 64) {
        __m256 meets = _mm256_setzero_ps();
        for (int j = i; j < i + 64; j += 8)
            meets = _mm256_or_ps(meets, withinBand(_mm256_loadu_ps(data + j), low, high));
        if (_mm256_movemask_ps(meets) != 0) return true;
    }
    return false;
}

}  // namespace

const LeafStepForms* avx2LeafSteps()
{
    static const LeafStepForms forms{stepsInLanes, straddleInLanes, widestInLanes, meetsInLanes};
    return &forms;
}

#else

const LeafStepForms* avx2LeafSteps()
{
    return nullptr;
}

#endif

}  // namespace voxlat::coverage
