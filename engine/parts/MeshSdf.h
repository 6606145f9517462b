/// @file MeshSdf.h
/// @brief A closed triangle mesh to a narrow-band signed distance grid: exact distances to the
/// triangles, found per block of voxels by top-down culling, and inside/outside by ray parity.
#pragma once

#include "mesher/extract/TriangleMesh.h"

#include <openvdb/openvdb.h>

namespace voxlat {

/// Converts @a mesh (closed; its orientation does not matter) to a level set on @a xform (linear,
/// uniform; samples at voxel centres): every sample closer to the mesh than @a exteriorVoxels
/// voxels outside or @a interiorVoxels voxels inside holds its exact signed distance to the
/// nearest triangle (world units, negative inside) and is active; the other samples are inactive
/// and hold +exterior or -interior width (tiles where a whole leaf or more is so), as
/// openvdb::tools::meshToSignedDistanceField makes them.
///
/// Inside is decided by the parity of the mesh's crossings along a vertical ray through each
/// column of samples (each ray nudged off the sample lattice by a tiny fixed offset, and shared
/// edges tested the same way from both of their triangles, so a crossing counts exactly once).
/// Overlapping shells or a self-intersecting mesh therefore come out as their symmetric
/// difference: the caller checks the volume and falls back to OpenVDB (a union) then.
///
/// Why not meshToVolume: it grows its band one voxel layer at a time from the voxels the
/// triangles cut, which costs far more than the distances themselves. Here cubes of 32^3 samples
/// down to 2^3 keep only the triangles that can be nearest to some point of the cube (those within
/// the nearest one's distance plus 2 half-diagonals of the centre), so each sample tests a few
/// triangles; cubes wholly past the band become tiles untouched. Lower bounds skip exact
/// distances that cannot matter: a triangle's distance from the parent cube's centre less the
/// shift between centres, and the distance to its plane (beside the nearest face on a flat side,
/// its neighbours on the same plane are never measured); a point over a face takes the plane
/// distance without the corner and edge cases. Cubes are independent: the grid
/// does not depend on the thread count.
openvdb::FloatGrid::Ptr meshToSdf(const TriangleMesh& mesh, const openvdb::math::Transform& xform, float exteriorVoxels,
                                  float interiorVoxels);

}  // namespace voxlat
