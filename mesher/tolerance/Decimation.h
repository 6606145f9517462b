/// @file Decimation.h
/// @brief Error-bounded decimation of a closed mesh against the field it came from, and the
/// deviation of a mesh from a field's level set measured on samples over every triangle.
#pragma once

#include "fields/core/FieldNode.h"
#include "mesher/checks/TriangleCheck.h"
#include "mesher/extract/MarchingCubes.h"
#include "mesher/extract/TriangleMesh.h"

#include <array>
#include <cstddef>
#include <optional>

namespace voxlat {

struct DecimationOptions {
    /// Every point of every triangle stays within this of the level set (mm).
    double tolerance = 0.01;
    /// The level set (the solid is f < level).
    double level = 0.0;
    /// The grid's voxel (mm): triangles longer than a few voxels are checked in pieces.
    double voxel = 0.1;
    /// Candidates whose quadric error exceeds this share of the squared tolerance are not tried
    /// (such collapses put the point far off a plane merged into it, and the field check refuses
    /// most of them; below 1, fewer field checks for a few more triangles).
    double quadricShare = 1.0;
    /// Meshes of at least this many triangles are decimated in parallel blocks of at least
    /// blockVoxels voxels (and 1/16 of the mesh's extent), then again on blocks shifted by half.
    std::size_t blockedFrom = 200000;
    /// Small blocks keep a block's arrays in the core's cache: on W9 (0.2 mm voxels) blocks of 16
    /// voxels took 25 % less CPU than blocks of 64 for 4 % more triangles (collapses next to the
    /// more numerous seams wait for the second pass).
    double blockVoxels = 16.0;
    /// When set, the solid is also cut by this box: the field is the distance to the rest, and
    /// the box's own signed distance is taken exactly at every point the check looks at, so the
    /// kink where the two meet (a crease) is not smoothed over by the check's quadratic.
    std::optional<Box3> box;
    /// Whether the decimated mesh is checked for crossing triangles and, around any, decimated
    /// again with the original vertices there kept (at most repairRounds times, each round's
    /// region wider).
    bool repairCrossings = true;
    int repairRounds = 3;
};

struct DecimationStats {
    std::size_t trianglesBefore = 0, trianglesAfter = 0;
    std::size_t verticesBefore = 0, verticesAfter = 0;
    std::size_t collapses = 0;
    /// Candidate collapses refused because a new triangle would stray beyond the tolerance,
    /// turn over or degenerate.
    std::size_t refused = 0;
    /// False when a block holds a triangle with a repeated corner (then it is kept as is).
    bool decimated = false;
    /// With options.repairCrossings: pairs of crossing triangles after the first decimation and
    /// after the last round, the rounds decimated again and the original vertices kept there.
    std::size_t crossingPairsFound = 0, crossingPairs = 0, verticesKeptForCrossings = 0;
    int repairRounds = 0;
};

/// Collapses edges of @a mesh (halfedge collapses, so every kept vertex stays where it was:
/// on the surface after projectToSurface) in the order of the quadric error metric (area-weighted
/// plane quadrics; candidates whose error exceeds the squared tolerance are not tried), each
/// collapse made only when the link condition holds (the mesh stays closed, manifold and oriented),
/// no new triangle turns over by 90 degrees or more or loses its area, no new edge is longer than
/// 6 voxels, and every new triangle stays within options.tolerance of the level set of @a field.
/// The last is checked on each new triangle with the signed distance (f - level) / |grad f| at
/// its corners, edge midpoints and centre: the quadratic through corners and midpoints is
/// maximised over the triangle and the centre's miss of it is added as a margin (the edge limit
/// keeps triangles within the few voxels a quadratic fits on a surface the grid resolves). A
/// refused collapse is retried once its neighbourhood changes. Large meshes go in fixed spatial
/// blocks in parallel (see DecimationOptions::blockedFrom): the same bytes for any thread count.
/// The new triangles are checked against the field, not against each other: the result is then
/// checked for crossing triangles (where two sheets of the surface come within about twice the
/// tolerance, as at a concave crease), and around any the original vertices are kept and the
/// mesh decimated again (DecimationOptions::repairCrossings); stats.crossingPairs is what is left.
/// @a progress (optional) runs from 0 to 1 over the first decimation and may throw to cancel.
DecimationStats decimateToTolerance(TriangleMesh& mesh, const FieldNode& field, const DecimationOptions& options,
                                    const ProgressFn& progress = {});

/// How far a mesh strays from a level set, sampled on every triangle.
struct MeshDeviation {
    double max = 0.0;  ///< largest |f - level| / |grad f| over the samples (mm)
    double rms = 0.0;  ///< root mean square, each triangle weighted by its area
    std::size_t samples = 0;
};

/// Samples every triangle of @a mesh in rows parallel to its longest edge, rows and samples at
/// most @a spacing apart (mm; corners, edges and interior), and measures the first-order distance |f - level| / |grad
/// f|. Parallel over fixed blocks of triangles: the same numbers for any thread count. @a progress
/// (optional) runs from 0 to 1 and may throw to cancel.
MeshDeviation measureDeviation(const TriangleMesh& mesh, const FieldNode& field, double level, double spacing,
                               const ProgressFn& progress = {});

}  // namespace voxlat
