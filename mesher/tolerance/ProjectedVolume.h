/// @file ProjectedVolume.h
/// @brief The volume the solid's true surface encloses within a box, estimated from a
/// marching-cubes mesh whose vertices (a sample of them) are projected onto the surface, without
/// holding the mesh: what a projected, box-cut mesh of the field will hold before it is made.
#pragma once

#include "fields/core/FieldNode.h"
#include "mesher/extract/MarchingCubes.h"
#include "mesher/tolerance/SurfaceProjection.h"

#include <openvdb/openvdb.h>

#include <cstdint>

namespace voxlat {

/// What projectedVolumeInBox() measured.
struct ProjectedVolume {
    /// The estimated volume of the solid within the box, bounded by the projected surface and
    /// the box's faces (mm³).
    double volume = 0.0;
    /// The volume within the box of the solid the true surface bounds: @c volume plus what lies
    /// between each projected triangle and the surface, taken as 3/4 of the distance at its
    /// centre (a quadratic through its corners) times its area (what a mesh refined to a small
    /// tolerance holds).
    double surface = 0.0;
    /// The volume within the box of the solid the marching-cubes mesh bounds, vertices where the
    /// grid put them (exact for that polyhedron), the estimate's baseline.
    double unprojected = 0.0;
    /// That solid's cross-section on the box's face of largest x (mm²).
    double capArea = 0.0;
    /// Triangles of the mesh that meet the box; of them, those the box cuts (all projected) and
    /// those inside it that were projected as a sample.
    std::uint64_t triangles = 0, cut = 0, sampled = 0;
};

/// The volume of the solid f < @a options.level of @a field within @a box, as a mesh of its
/// surface with every vertex on it, cut by the box's faces exactly, holds it. @a grid samples f
/// beyond the box on every side (unclipped: the surface runs on past the faces by a voxel or
/// more); its marching-cubes mesh is streamed once, never held.
///
/// The baseline is exact for the polyhedron the mesh bounds, intersected with the box: by the
/// divergence theorem with (x - x_min, 0, 0), the integral of (x - x_min) n_x over the triangles
/// clipped to the box, plus (x_max - x_min) times the section on the face x = x_max; that area by
/// Green's theorem from the clipped triangles' edges on the face, plus (y_max - y_min) times the
/// solid's length along the box's edge x = x_max, y = y_max, from where those edges meet it and
/// whether the corner (x_max, y_max, z_max) is inside. The projection onto the surface then adds
/// the volume each triangle's part within the box sweeps as its corners move (projectToSurface()
/// with @a options, each triangle's own corners; ((N + N') / 2) . (mean move), second order):
/// every triangle the box cuts, and every @a sampleEvery-th of the others in each chunk, scaled
/// by their count over the sampled ones. The box's creases are exact (no chamfer of max(f, box));
/// creases inside the field (a Boolean) are as marching cubes and projection leave them. Sums
/// per chunk, then in chunk order: the same for any thread count. @a progress runs from 0 to 1
/// and may throw to cancel.
ProjectedVolume projectedVolumeInBox(const openvdb::FloatGrid& grid, const FieldNode& field, const Box3& box,
                                     const ProjectionOptions& options, std::uint64_t sampleEvery,
                                     ProgressFn progress = {});

}  // namespace voxlat
