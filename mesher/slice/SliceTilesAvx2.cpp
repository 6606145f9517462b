// The slicer's whole-tile pass with eight lanes. CMake compiles this file alone with -mavx2 and
// -ffp-contract=off (and defines VOXLAT_AVX2_TILES); Slicer.cpp calls it only when the CPU
// reports AVX2. Nothing else lives here, so no other code can pick up AVX2 instructions.
#include "mesher/slice/SliceTilesAvx2.h"

#if defined(__AVX2__)
#include <immintrin.h>

#include "mesher/slice/SliceTiles.h"

namespace voxlat {

namespace {

using Oct = float __attribute__((vector_size(32)));
using OctMask = int __attribute__((vector_size(32)));

/// Per 8-bit mask, the numbers of its set lanes in order, 3 bits each (for OctLanes::compress).
struct LaneLists {
    std::uint32_t lanes[256] = {};
    constexpr LaneLists()
    {
        for (unsigned m = 0; m < 256; ++m) {
            int n = 0;
            for (unsigned k = 0; k < 8; ++k)
                if ((m >> k) & 1u) lanes[m] |= k << (3 * n++);
        }
    }
};

/// Eight lanes: one AVX register per row of a tile.
struct OctLanes : LanesBase<Oct, OctMask> {
    static unsigned bits(M m) { return unsigned(_mm256_movemask_ps(__m256(m))); }
    /// Writes the lanes of @a v whose bit is set in @a mask to @a out, in order: one permute by
    /// the mask's lane list (a table of 256 entries of eight 3-bit lane numbers).
    static void compress(V v, unsigned mask, float* out)
    {
        static constexpr LaneLists kTable{};
        const __m256i shifts = _mm256_setr_epi32(0, 3, 6, 9, 12, 15, 18, 21);
        const __m256i index =
            _mm256_srlv_epi32(_mm256_set1_epi32(int(kTable.lanes[mask & 0xFF])), shifts);  // low 3 bits used
        _mm256_storeu_ps(out, _mm256_permutevar8x32_ps(__m256(v), index));
    }
    static V sqrt(V v) { return V(_mm256_sqrt_ps(__m256(v))); }
};

}  // namespace

int decideFullTileAvx2(const float* values, int stride, const float* cells, float blockCell, float linearTolerance,
                       bool greyEdges, std::uint8_t* pixels, std::size_t rowStride, std::uint16_t* slowList,
                       int& slowCount)
{
    return decideFullTile<OctLanes>(values, stride, cells, blockCell, linearTolerance, greyEdges, pixels, rowStride,
                                    slowList, slowCount);
}

bool prepareBlockAvx2(const double* values, int nx, int ny, float* single, float* cells, float& cellMax)
{
    return prepareTileBlock<OctLanes>(values, nx, ny, single, cells, cellMax);
}

}  // namespace voxlat

#endif
