/// @file CreaseSplit.h
/// @brief Sharp creases where several surfaces bound a solid (the operands of an intersection or
/// difference, the faces of the domain box): edges that run from one surface to another are
/// split at the point on both.
#pragma once

#include "fields/core/FieldNode.h"
#include "mesher/extract/TriangleMesh.h"
#include "mesher/tolerance/SurfaceProjection.h"

#include <cstddef>
#include <optional>
#include <vector>

namespace voxlat {

/// The surfaces whose intersection bounds a solid: fields (each solid below options.level) and,
/// optionally, a box whose six faces count as six surfaces (so the box's own edges and corners
/// are creases too).
struct CreaseSurfaces {
    std::vector<const FieldNode*> fields;
    std::optional<Box3> box;
};

/// What splitCreaseEdges() did.
struct CreaseSplitStats {
    /// Edges from a vertex on one surface to a vertex on another (neither on both).
    std::size_t creaseEdges = 0;
    /// Of those, edges split at a point on both surfaces (three at a corner).
    std::size_t split = 0;
    /// Crease edges left as they were: Newton found no point on both surfaces near the edge,
    /// or a new triangle would have turned over.
    std::size_t leftFlat = 0;
    /// Of those, edges whose split point (as stored, in single precision) is the position of a
    /// vertex or of another edge's split point: left flat so that no two vertices coincide.
    std::size_t coincident = 0;
};

/// Splits every crease edge of @a mesh at a point on all the surfaces its two ends lie on (two,
/// or three at a corner): Newton from the edge's midpoint with least-norm steps on those
/// surfaces' equations, kept only when it converges within options.maxMove of the midpoint.
/// The triangles around a split edge are divided (one, two or three split edges per triangle);
/// when a new triangle would turn over against its parent, that parent's splits are dropped, in
/// rounds. No split point is stored at the position of a vertex or of another split point (that
/// edge is left flat). The result stays closed, manifold and oriented, by index and by position. A vertex is on a
/// surface when its first-order distance is within a hundredth of options.maxMove. New vertices are appended in the
/// order of their edges (sorted vertex pairs); evaluation is in fixed batches, so the same bytes for any thread count.
/// @a progress (optional) runs from 0 to 1, is called from any thread and may throw to cancel.
CreaseSplitStats splitCreaseEdges(TriangleMesh& mesh, const CreaseSurfaces& surfaces, const ProjectionOptions& options,
                                  const ProgressFn& progress = {});

}  // namespace voxlat
