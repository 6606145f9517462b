/// @file MemoryEstimate.h
/// @brief How much memory homogenizing a voxel cell takes at its peak, from what grows with it:
/// the cell's voxels and the nodes of its finite-element model (grid points touched by a solid
/// voxel), measured against the solver's peak resident size (bench/homogenize_cell.cpp's
/// peak_growth_bytes).
#pragma once

#include "engine/properties/Homogenization.h"

#include <cstdint>

namespace voxlat {

/// The nodes of @a cell's finite-element model: grid points (periodic) touched by a solid voxel.
std::int64_t cellNodes(const VoxelCell& cell);

/// The peak bytes homogenizeElasticity() (and the conductivity after it) holds above the cell it
/// is given, for a cell of @a voxels voxels whose model has @a nodes nodes: per node the load
/// cases' solutions and CG's vectors, for all six cases at once (they are solved together), the
/// preconditioner's padded single-precision vectors for six right-hand sides (large ones on 2 MB
/// pages) and its diagonal blocks, the element lists of every multigrid level (about 1450
/// bytes); per voxel the component labels and the grid-to-node map (16 bytes); and 4 MB for the
/// dense coarsest level and the threads' buffers. Measured (gyroid networks at 20, 50 and 80 %
/// solid, 32, 40, 64 and 96 voxels a side): the estimate is 1.09 to 1.33 times the measured peak.
double homogenizationBytes(double voxels, double nodes);

/// homogenizationBytes() of @a cell.
double homogenizationBytes(const VoxelCell& cell);

}  // namespace voxlat
