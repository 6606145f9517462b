/// @file CellSample.h
/// @brief The voxel model of one periodic cell of a field: a voxel is solid when the field is
/// negative at its centre, exactly what the density solve counts.
#pragma once

#include "engine/properties/Homogenization.h"
#include "fields/core/FieldNode.h"

#include <array>
#include <functional>
#include <vector>

namespace voxlat {

/// Samples @a field at the voxel centres of the box [@a origin, @a origin + @a size) cut into
/// @a counts voxels per axis, in parallel (the same cell for any thread count). @a progress gets
/// the fraction done and returns false to cancel (then Cancelled is thrown).
VoxelCell sampleCell(const FieldNode& field, const Vec3d& origin, const Vec3d& size, const std::array<int, 3>& counts,
                     const std::function<bool(double)>& progress = {});

/// The field's values at the same voxel centres as sampleCell() (x fastest, then y, then z),
/// for a caller that chooses the level itself (cellLevelShift()).
std::vector<double> sampleCellValues(const FieldNode& field, const Vec3d& origin, const Vec3d& size,
                                     const std::array<int, 3>& counts,
                                     const std::function<bool(double)>& progress = {});

/// The shift s for which exactly round(@a density * n) of the n @a values lie below s (each
/// value is a field value minus its level, so s moves the level): the level at which the voxel
/// model holds the density asked, halfway between the two values that bracket it. @a density is
/// in (0, 1); needs at least two values.
double cellLevelShift(std::vector<double> values, double density);

/// The voxel model of @a values at @a shift: a voxel is solid when its value is below it.
VoxelCell cellAtShift(const std::vector<double>& values, const Vec3d& size, const std::array<int, 3>& counts,
                      double shift);

}  // namespace voxlat
