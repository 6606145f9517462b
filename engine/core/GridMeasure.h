/// @file GridMeasure.h
/// @brief Counting voxels of a sparse grid inside a region, tiles included.
#pragma once

#include "engine/core/DefaultInitVector.h"

#include <openvdb/openvdb.h>

#include <cstdint>
#include <functional>
#include <vector>

namespace voxlat {

/// The voxels of a region split by a band [lo, hi]: those below are counted, those inside are
/// collected (in leaf order), those above are dropped. Tiles never meet the surface, so an
/// active tile below lo counts whole.
struct BandSplit {
    std::uint64_t below = 0;
    DefaultInitVector<float> band;  ///< sized up front and filled in parallel, not zeroed first
};
/// @a interrupt, when set, is called every 64 leaves and throws to stop.
BandSplit splitByBand(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, float lo, float hi,
                      const std::function<void()>& interrupt = {});

/// The voxels of @a region inside a distance field's zero set, each sample's cell counted by how
/// much of it lies inside: 1/2 - value/@a voxel clamped to [0, 1] (exact for a face parallel to
/// the cells, where a count of samples below zero is half a voxel off), tiles below zero whole.
/// Summed per leaf, then in leaf order: the same for any thread count.
double distanceCoverage(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, double voxel);

/// Number of voxels in @a region whose value is below @a threshold (tiles included).
std::uint64_t countBelow(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, float threshold);

/// countBelow() of the active tiles alone (no leaf voxel visited).
std::uint64_t countTilesBelow(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, float threshold);

}  // namespace voxlat
