// Built with -mavx2 -ffp-contract=off (and VOXLAT_AVX2_PAIRS defined) where the compiler targets
// x86-64 (mesher/CMakeLists.txt); MeshCheck calls it only when the CPU has AVX2.
#include "mesher/checks/PairFilter.h"

#if defined(VOXLAT_AVX2_PAIRS)
#include <immintrin.h>

namespace voxlat {

std::size_t filterPairsAvx2(const PairRows& rows, std::size_t x, std::size_t count, const bool apartX[3],
                            std::uint32_t* candidates)
{
    const __m256i cornerX = _mm256_set1_epi32(rows.corner[x]), full = _mm256_set1_epi32(15);
    __m256 lowX[3], highX[3];
    __m256i cornerOfX[3];
    for (int a = 0; a < 3; ++a) {
        lowX[a] = _mm256_set1_ps(rows.lo[a][x]);
        highX[a] = _mm256_set1_ps(rows.hi[a][x]);
        cornerOfX[a] = _mm256_set1_epi32(rows.vertex[a][x]);
    }
    std::size_t numCandidates = 0;
    for (std::size_t y = x + 1; y < count; y += 8) {
        const __m256i both =
            _mm256_or_si256(cornerX, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(rows.corner + y)));
        __m256 keep = _mm256_castsi256_ps(_mm256_cmpeq_epi32(both, full));
        for (int a = 0; a < 3; ++a) {
            // !(high_x < lo_y) and !(hi_y < low_x): unordered (a NaN) keeps the pair, as in four lanes.
            keep = _mm256_and_ps(keep, _mm256_cmp_ps(highX[a], _mm256_loadu_ps(rows.lo[a] + y), _CMP_NLT_UQ));
            keep = _mm256_and_ps(keep, _mm256_cmp_ps(_mm256_loadu_ps(rows.hi[a] + y), lowX[a], _CMP_NLT_UQ));
        }
        // Corners shared (each match -1), and whether a shared corner's fan is apart.
        __m256i matches = _mm256_setzero_si256(), sharedApart = _mm256_setzero_si256();
        for (int k = 0; k < 3; ++k) {
            __m256i matchesK = _mm256_setzero_si256();
            for (int j = 0; j < 3; ++j)
                matchesK = _mm256_add_epi32(
                    matchesK,
                    _mm256_cmpeq_epi32(cornerOfX[k],
                                       _mm256_loadu_si256(reinterpret_cast<const __m256i*>(rows.vertex[j] + y))));
            matches = _mm256_add_epi32(matches, matchesK);
            if (apartX[k]) sharedApart = _mm256_or_si256(sharedApart, matchesK);
        }
        const __m256i none = _mm256_cmpeq_epi32(matches, _mm256_setzero_si256());
        const __m256i oneNotApart = _mm256_and_si256(_mm256_cmpeq_epi32(matches, _mm256_set1_epi32(-1)),
                                                     _mm256_cmpeq_epi32(sharedApart, _mm256_setzero_si256()));
        keep = _mm256_and_ps(keep, _mm256_castsi256_ps(_mm256_or_si256(none, oneNotApart)));
        for (unsigned bits = unsigned(_mm256_movemask_ps(keep)); bits != 0; bits &= bits - 1)
            candidates[numCandidates++] = std::uint32_t(y + unsigned(__builtin_ctz(bits)));
    }
    return numCandidates;
}

}  // namespace voxlat
#else
namespace voxlat {

// Not built for AVX2 (pairFilterAvx2Available() is false): the four-lane filter.
std::size_t filterPairsAvx2(const PairRows& rows, std::size_t x, std::size_t count, const bool apartX[3],
                            std::uint32_t* candidates)
{
    return filterPairs(rows, x, count, apartX, candidates);
}

}  // namespace voxlat
#endif
