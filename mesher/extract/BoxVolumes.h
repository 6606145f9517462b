/// @file BoxVolumes.h
/// @brief What marching cubes encloses within boxes of a grid's cells, against the count of the
/// grid's points below the iso-value there: the mesh's offset from the voxels' count, measured on
/// a sample of boxes instead of the whole mesh.
#pragma once

#include <openvdb/openvdb.h>

#include <span>
#include <vector>

namespace voxlat {

/// One box's two volumes, in index units (a voxel is 1).
struct BoxVolumes {
    /// The volume of marchingCubes(grid, iso)'s solid within the box.
    double mesh = 0.0;
    /// The box's points below iso, each weighted by its share of the box (1 inside, 1/2 on a
    /// face, 1/4 on an edge, 1/8 at a corner): summed over boxes that tile the grid, the count of
    /// the points below iso.
    double voxels = 0.0;
};

/// Per box of @a boxes (index origins, multiples of @a side, each listed once): the box is the
/// cells whose lowest corner lies in [origin, origin + side) on each axis, read from the points
/// origin + [0, side]^3, which @a grid must hold in leaves (cells with a corner elsewhere may be
/// anything: they are not read). The mesh's volume within the box is the divergence theorem over
/// the boundary of the solid there: the triangles marchingCubes() makes in the box's cells
/// (assigned by their centroid) and the inside of the box's six faces, traced as the mesher's
/// cubes trace them (the same edge points, the same asymptotic decider on the faces). Summed
/// over boxes that tile a grid which honours marchingCubes()' contract, the two volumes are
/// marchingCubesVolume() and the count of the points below iso (up to rounding).
std::vector<BoxVolumes> marchingCubesBoxVolumes(const openvdb::FloatGrid& grid, std::span<const openvdb::Coord> boxes,
                                                int side, float iso = 0.0f);

}  // namespace voxlat
