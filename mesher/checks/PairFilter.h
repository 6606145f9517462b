#pragma once
/// @file PairFilter.h
/// The crossing check's pair filter (MeshCheck's selfIntersections()): of a cell's triangles side
/// by side, those after triangle x that it must be tested against. Four lanes (SSE2) here and
/// eight (AVX2) in PairFilterAvx2.cpp, a file of its own so that only it is compiled for AVX2;
/// both keep the same triangles in the same order (the tests are exact comparisons). Internal to
/// the mesher.

#include <cstddef>
#include <cstdint>

namespace voxlat {

/// A cell's triangles side by side, each array padded with seven entries whose corner bits
/// (16) pair with none, so that a row read eight at a time from any start ends in them.
struct PairRows {
    const std::int32_t* corner;  // bits 0-2: this is the triangle's lowest cell per axis; 3: tested
    const float* lo[3];          // bounds, widened by a rounding
    const float* hi[3];
    const std::int32_t* vertex[3];  // corners
};

/// Writes to @a candidates the y in (x, count) that triangle x is tested against: this is the
/// lowest cell both cover, one of them is tested, their bounds overlap (a NaN bound rejects
/// nothing), and they share no corner, or one whose fan is not apart (@a apartX: x's corners').
/// Returns how many.
std::size_t filterPairs(const PairRows& rows, std::size_t x, std::size_t count, const bool apartX[3],
                        std::uint32_t* candidates);

/// filterPairs() with eight lanes: the same candidates. Eight lanes where VOXLAT_AVX2_PAIRS is
/// (x86-64 builds; call it only when the CPU has AVX2), else filterPairs() itself.
std::size_t filterPairsAvx2(const PairRows& rows, std::size_t x, std::size_t count, const bool apartX[3],
                            std::uint32_t* candidates);

/// Whether this build has filterPairsAvx2() and the CPU running it has AVX2.
bool pairFilterAvx2Available();

}  // namespace voxlat
