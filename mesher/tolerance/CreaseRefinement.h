/// @file CreaseRefinement.h
/// @brief Error-driven refinement where a mesh meets its creases: triangles that stray from the
/// solid are bisected at a point on its surface (on the crease when their edge crosses one).
///
/// Projection and crease splitting leave every vertex on the surface, yet a triangle can still
/// cut through the solid: where a lattice meets a box face at a sharp wedge, a triangle may span
/// from a vertex on the lattice to two on the face while the crease between them runs outside
/// the triangle, so the chamfer it makes is a tenth of a voxel deep although its corners are
/// exact. Bisecting such triangles at points on the true surface (the crease, where the edge
/// crosses it) removes the chamfer; decimation then joins what it can within its tolerance.
#pragma once

#include "mesher/extract/TriangleMesh.h"
#include "mesher/tolerance/CreaseSplit.h"

#include <cstddef>

namespace voxlat {

struct RefinementOptions {
    /// The level of the surfaces' fields (each solid below it).
    double level = 0.0;
    /// A triangle with a sampled point farther than this from the solid is bisected (mm).
    double threshold = 0.005;
    /// Samples on each triangle at most this far apart (mm).
    double spacing = 0.025;
    /// A new vertex lies within this of the midpoint of the edge it splits (mm).
    double maxMove = 0.1;
    /// Newton stops once the point is within this of every surface it is put on (mm).
    double tolerance = 1e-6;
    /// Newton steps per new vertex at most.
    int maxIterations = 16;
    /// Rounds of bisection at most.
    int rounds = 10;
};

/// What refineCreases() did.
struct RefinementStats {
    /// Triangles sampled in the first round: those whose corners do not all lie on one and the
    /// same surface (crease triangles, and vertices the projection held back).
    std::size_t checked = 0;
    /// Of those, triangles above the threshold.
    std::size_t over = 0;
    /// Edges split, over all rounds.
    std::size_t split = 0;
    /// Edge splits dropped: no point on the surface near the edge, a piece would have turned
    /// over or lost its area, or crossed another triangle.
    std::size_t dropped = 0;
    /// Corners of those triangles that lay on no surface (held back by the projection) moved
    /// onto it.
    std::size_t moved = 0;
    /// Triangles still above the threshold at the end.
    std::size_t remaining = 0;
    int rounds = 0;
    /// The largest sampled distance over the checked triangles before and after (mm).
    double maxBefore = 0.0, maxAfter = 0.0;
};

/// Bisects the triangles of @a mesh that stray from the solid bounded by @a surfaces (the
/// intersection of the fields' solids and the box) by more than options.threshold, in rounds:
/// each such triangle's longest edge (the next longest once that split was dropped) is split in
/// both triangles that share it, so the mesh stays conforming; the new vertex goes onto the
/// solid's surface from the edge's midpoint by Newton steps on the surfaces it lies outside of
/// (least-norm steps on two or three at once: a point on the crease when the edge crosses one),
/// within options.maxMove. A split is dropped when a piece would face against both the surface's
/// normal at its centre and its parent triangle, lose its area, or cross a triangle around it.
/// Distances are first-order, max over the surfaces of f / |grad f|, sampled on a barycentric
/// grid. Only triangles whose corners are not all on one and the same surface are sampled (a
/// triangle on one surface is the projection's and decimation's business). The mesh stays
/// closed, manifold and oriented; new vertices are appended in the order of their edges, and
/// evaluation runs in fixed batches, so the bytes are the same for any thread count.
/// @a progress (optional) runs from 0 to 1 and may throw to cancel.
RefinementStats refineCreases(TriangleMesh& mesh, const CreaseSurfaces& surfaces, const RefinementOptions& options,
                              const ProgressFn& progress = {});

}  // namespace voxlat
