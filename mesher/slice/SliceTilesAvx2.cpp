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

/// Eight lanes: one AVX register per row of a tile.
struct OctLanes : LanesBase<Oct, OctMask> {
    static unsigned bits(M m) { return unsigned(_mm256_movemask_ps(__m256(m))); }
    static V sqrt(V v) { return V(_mm256_sqrt_ps(__m256(v))); }
};

}  // namespace

int decideFullTileAvx2(const float* values, int stride, const float* cells, float linearTolerance, bool greyEdges,
                       std::uint8_t* pixels, std::size_t rowStride, std::uint16_t* slowList, int& slowCount)
{
    return decideFullTile<OctLanes>(values, stride, cells, linearTolerance, greyEdges, pixels, rowStride, slowList,
                                    slowCount);
}

}  // namespace voxlat

#endif
