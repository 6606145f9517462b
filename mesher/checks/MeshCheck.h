/// @file MeshCheck.h
/// @brief Topological validation of triangle meshes: watertightness, manifoldness, orientation.
#pragma once

#include "mesher/extract/ExtractProgress.h"
#include "mesher/extract/TriangleMesh.h"

#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace voxlat {

/// Topological defects of a triangle mesh. Edges are undirected vertex-index pairs.
struct MeshTopology {
    /// Edges used by exactly one triangle (holes).
    std::size_t boundaryEdges = 0;
    /// Edges used by more than two triangles.
    std::size_t nonManifoldEdges = 0;
    /// Vertices whose incident triangles do not form a single fan, i.e. whose link (the edges
    /// opposite the vertex) is not one simple path or cycle. Includes the ends of non-manifold edges.
    std::size_t nonManifoldVertices = 0;
    /// Edges shared by two triangles that traverse it in the same direction.
    std::size_t inconsistentlyOrientedEdges = 0;
    /// Triangles with a repeated (or out-of-range) vertex index or zero area in double precision.
    std::size_t degenerateTriangles = 0;
    /// V - E + F over the vertices and edges used by triangles with three distinct valid indices
    /// (2 for each sphere-like closed component, 2 - 2g for genus g).
    int eulerCharacteristic = 0;
    /// Connected pieces: triangles joined through shared vertices.
    std::size_t pieces = 0;
    /// Pieces without boundary or non-manifold edges (closed surfaces).
    std::size_t closedPieces = 0;
    /// The sum over the closed pieces of their genus g = 1 - chi/2 (chi: each piece's own
    /// V - E + F); 0 for a set of balls, 1 for a torus, 3 for a gyroid network's unit cell.
    int genus = 0;

    /// True for a watertight, manifold, consistently oriented mesh without degenerate triangles.
    bool closedManifold() const
    {
        return boundaryEdges == 0 && nonManifoldEdges == 0 && nonManifoldVertices == 0 &&
               inconsistentlyOrientedEdges == 0 && degenerateTriangles == 0;
    }
};

/// Analyse the topology of @a mesh (parallel; O(triangles); the same result for any thread count).
/// With @a fansApart, also per vertex whether its fan is shown to lie apart (the crossing check's
/// certificate, see countSelfIntersections(); all 0 where a triangle repeats a corner): the rows
/// it walks anyway, so the crossing check after it need not build them again. @a progress
/// (optional) runs from 0 to 1, is called from any thread and may throw to cancel.
MeshTopology checkTopology(const TriangleMesh& mesh, std::vector<std::uint8_t>* fansApart = nullptr,
                           const ProgressFn& progress = {});

/// Pairs of triangles of @a mesh that cross each other: an edge of one passes through the
/// interior of the other. Pairs that share an edge are not tested; pairs that share one vertex
/// are tested with the edges away from it, unless the fan around that vertex is shown to lie
/// apart (one projection in which its triangles tile the plane around the vertex once: then they
/// meet only there; W9 skips 7.0 M of 9.3 M pair tests so). Coplanar overlaps are not counted. Triangles are
/// binned in a uniform grid (cells about twice the mean edge) and only pairs sharing a cell are
/// tested, each pair once (in the lowest cell both boxes cover); parallel over fixed cell
/// blocks, integer counts, so the same result for any thread count. @a progress (optional) runs
/// from 0 to 1 and may throw to cancel.
/// Vertices of @a mesh that lie at the same position (the same float bits) as another vertex,
/// counting every vertex of such a group but the first. Read by position (an STL has no
/// indices), the edges at such a point are shared by more than two triangles: a mesh closed and
/// manifold by index is not so by position.
std::size_t countCoincidentVertices(const TriangleMesh& mesh);

std::size_t countSelfIntersections(const TriangleMesh& mesh, const ProgressFn& progress = {});
/// The same with the fans' certificate from checkTopology() (for this mesh as it is).
std::size_t countSelfIntersections(const TriangleMesh& mesh, const std::vector<std::uint8_t>& fansApart,
                                   const ProgressFn& progress = {});

/// The crossing pairs countSelfIntersections() counts, as triangle indices (lower first), in a
/// fixed order.
std::vector<std::pair<std::uint32_t, std::uint32_t>> selfIntersections(const TriangleMesh& mesh);
/// The same, only for pairs with at least one triangle flagged in @a tested (one flag per
/// triangle; empty: all pairs): a local check of changed triangles among fixed ones.
std::vector<std::pair<std::uint32_t, std::uint32_t>> selfIntersections(const TriangleMesh& mesh,
                                                                       const std::vector<std::uint8_t>& tested);
/// The same with the fans' certificate given (from checkTopology(); null: computed when all pairs
/// are tested, none used when some are flagged); @a progress (optional) runs from 0 to 1 and may
/// throw to cancel.
std::vector<std::pair<std::uint32_t, std::uint32_t>> selfIntersections(const TriangleMesh& mesh,
                                                                       const std::vector<std::uint8_t>& tested,
                                                                       const std::vector<std::uint8_t>* fansApart,
                                                                       const ProgressFn& progress = {});

}  // namespace voxlat
