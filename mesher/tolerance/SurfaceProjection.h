/// @file SurfaceProjection.h
/// @brief Moves a mesh's vertices onto a field's level set by Newton steps along the field's
/// analytic gradient, without letting any triangle flip or two triangles cross.
///
/// Marching cubes places a vertex where the straight line between two voxel centres crosses the
/// level, which is off the true surface wherever the field bends within a voxel (up to a few
/// percent of the voxel on a TPMS). The field is known exactly everywhere, so each vertex can be
/// moved onto f = level instead.
#pragma once

#include "fields/core/FieldNode.h"
#include "mesher/extract/MarchingCubes.h"
#include "mesher/extract/TriangleMesh.h"

#include <cstddef>

namespace voxlat {

struct ProjectionOptions {
    /// The level set the vertices move onto (the solid is f < level).
    double level = 0.0;
    /// Farthest a vertex may move from where it started (mm); the caller passes half a voxel,
    /// which keeps a vertex inside the cubes around its edge.
    double maxMove = 0.05;
    /// Newton stops once the first-order distance |f - level| / |grad f| is below this (mm).
    double tolerance = 1e-6;
    /// Newton steps per vertex at most.
    int maxIterations = 12;
    /// projectToSurface(): hold back the moves that make two triangles cross. It checks every
    /// moved triangle for crossings, about seven times the projection's own time (a 1.3 M
    /// triangle gyroid: 0.9 s against 0.12 s), so a caller asks for it when a mesh made without
    /// it was found crossing. Meaningless for a soup of loose triangles (they share no corner).
    bool holdBackCrossings = false;
};

/// What a projection did, for report.json and tests. Distances are first-order estimates
/// |f - level| / |grad f| at the vertices (mm).
struct ProjectionStats {
    std::size_t vertices = 0;
    /// Vertices whose position changed.
    std::size_t moved = 0;
    /// Vertices whose Newton path reached the maxMove limit.
    std::size_t limited = 0;
    /// Vertices moved only half way or not at all because a full move flipped a triangle or
    /// made two triangles cross.
    std::size_t heldBack = 0;
    /// Of those, vertices held back because two triangles crossed after the moves.
    std::size_t heldBackForCrossings = 0;
    /// Rounds of the flip check (1 when no move had to be held back).
    int flipRounds = 0;
    double maxBefore = 0.0, rmsBefore = 0.0;
    double maxAfter = 0.0, rmsAfter = 0.0;
};

/// Projects every vertex of @a mesh onto the level set of @a field: Newton steps
/// p <- p - (f(p) - level) grad f / |grad f|^2, kept within options.maxMove of the start, the
/// best iterate kept. A triangle whose normal would turn by 90 degrees or more (or vanish) holds
/// its vertices back: first to half their move, then to where they were, in rounds until no
/// triangle flips. With options.holdBackCrossings, two triangles that cross once no triangle
/// flips (MeshCheck's selfIntersections(), on the triangles whose corners moved) hold their
/// moved vertices back alike, in rounds, so the projection adds no crossing to the mesh (near a
/// sharp crease of a boolean, tiny moves of marching cubes' slivers fold them into each other).
/// Vertices are evaluated in fixed batches of kBatchSize in parallel, so the
/// result is the same for any thread count. @a progress (optional) runs from 0 to 1 and may
/// throw to cancel.
ProjectionStats projectToSurface(TriangleMesh& mesh, const FieldNode& field, const ProjectionOptions& options,
                                 const ProgressFn& progress = {});

/// What sharpenCreases() did.
struct CreaseStats {
    /// Edges that ran from a vertex on one surface to a vertex on the other (a flat chamfer).
    std::size_t creaseEdges = 0;
    /// Vertices moved onto the crease (both surfaces at once).
    std::size_t moved = 0;
    /// Crease edges left as they were: no crease point near either end, or moving one would turn
    /// a triangle over.
    std::size_t leftFlat = 0;
};

/// Makes the creases of an intersection max(a, b) sharp. Marching cubes (and projection onto
/// max(a, b)) puts every vertex on one surface or the other, so where they meet, triangles span
/// from one to the other and cut the edge flat. For each edge from a vertex on a = level (b below)
/// to one on b = level (a below), the end nearer the crease moves onto it: Newton steps on both
/// equations at once (the least-norm step), at most options.maxMove. A move that turns a triangle
/// over is undone, in rounds. Vertices are evaluated in fixed batches: the same bytes for any
/// thread count. @a b is evaluated at every vertex, @a a only near b = level (pass the cheap one
/// as @a b). @a progress (optional) runs from 0 to 1, is called from any thread and may throw to
/// cancel.
CreaseStats sharpenCreases(TriangleMesh& mesh, const FieldNode& a, const FieldNode& b, const ProjectionOptions& options,
                           const ProgressFn& progress = {});

/// |f - level| / |grad f| at @a points (mm), the first-order distance to the level set, in
/// batches (parallel, same result for any thread count). A zero gradient gives infinity unless
/// f = level.
std::vector<double> levelDistances(std::span<const openvdb::Vec3f> points, const FieldNode& field, double level);

}  // namespace voxlat
