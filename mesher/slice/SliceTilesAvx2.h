#pragma once
/// @file SliceTilesAvx2.h
/// The slicer's whole-tile pass (SliceTiles.h's decideFullTile) with eight AVX2 lanes, in a file
/// of its own so that only it is compiled for AVX2 (and the block pass before it). Internal to the mesher.

#include <cstddef>
#include <cstdint>

namespace voxlat {

/// decideFullTile with eight lanes; the same bytes as the four-lane pass. Defined only where
/// VOXLAT_AVX2_TILES is (x86-64 builds); call it only when the CPU has AVX2.
int decideFullTileAvx2(const float* values, int stride, const float* cells, float blockCell, float linearTolerance,
                       bool greyEdges, std::uint8_t* pixels, std::size_t rowStride, std::uint16_t* slowList,
                       int& slowCount);

/// prepareTileBlock (SliceTiles.h) built for AVX2; the same floats and cells as the four-lane
/// build. Defined and callable as decideFullTileAvx2.
bool prepareBlockAvx2(const double* values, int nx, int ny, float* single, float* cells, float& cellMax);

}  // namespace voxlat
