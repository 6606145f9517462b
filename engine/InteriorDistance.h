/// @file InteriorDistance.h
/// @brief Deepens the inside band of a mesh's signed distance grid with exact distances to the
/// triangles, found per block of voxels by top-down culling of the candidate triangles.
#pragma once

#include "mesher/TriangleMesh.h"

#include <openvdb/openvdb.h>

namespace voxlat {

/// Takes a narrow-band signed distance grid of @a mesh (world units, samples at voxel centres,
/// as meshToSignedDistanceField makes it, whatever its inside width) and makes its inside band
/// @a interiorVoxels voxels deep: every inside sample closer than that to the mesh gets its exact
/// (unsigned) distance to the nearest triangle, negated, and becomes active; every other inside
/// value (inactive voxels and tiles) becomes -interiorVoxels voxels. The sign is the grid's own
/// (its flood fill decides inside), so only the distances come from the triangles here.
///
/// Why: meshToVolume grows a deep band one voxel layer at a time, checking the nearest triangles
/// of each voxel's neighbours, which costs far more than the distances themselves. Here blocks of
/// 64^3 voxels down to 2^3 keep only the triangles that can be nearest to some point of the block
/// (within min distance + 2 half-diagonals of the block centre), so each voxel tests a few
/// triangles. Blocks are independent and written per leaf: the result does not depend on the
/// thread count.
void deepenInteriorBand(openvdb::FloatGrid& grid, const TriangleMesh& mesh, float interiorVoxels);

}  // namespace voxlat
