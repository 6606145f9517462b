/// @file CellSample.h
/// @brief The voxel model of one periodic cell of a field: a voxel is solid when the field is
/// negative at its centre, exactly what the density solve counts.
#pragma once

#include "engine/properties/Homogenization.h"
#include "fields/FieldNode.h"

#include <array>
#include <functional>

namespace voxlat {

/// Samples @a field at the voxel centres of the box [@a origin, @a origin + @a size) cut into
/// @a counts voxels per axis, in parallel (the same cell for any thread count). @a progress gets
/// the fraction done and returns false to cancel (then Cancelled is thrown).
VoxelCell sampleCell(const FieldNode& field, const Vec3d& origin, const Vec3d& size, const std::array<int, 3>& counts,
                     const std::function<bool(double)>& progress = {});

}  // namespace voxlat
