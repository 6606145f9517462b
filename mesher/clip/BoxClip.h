/// @file BoxClip.h
/// @brief Cuts the closed mesh of a smooth solid by the six faces of a box and caps the cuts, so
/// that where the solid meets the box the crease is exact instead of a chamfer.
///
/// Marching cubes on a field clipped to the box (max of the field and the box's distance) lays a
/// chamfer wherever the solid meets a face at a sharp wedge: a triangle from a vertex on the
/// surface to two on the face cuts a tenth of a voxel into the solid, and no vertex move can
/// undo a wrong triangle. Meshing the solid unclipped (a voxel past the box) and cutting the
/// mesh by the faces' planes puts every crease vertex where an edge crosses a face, then on the
/// surface within that face; the caps are planar and triangulated between the crease vertices
/// (a constrained Delaunay triangulation of each face's polygons).
#pragma once

#include "fields/core/FieldNode.h"
#include "mesher/checks/MeshCheck.h"
#include "mesher/extract/TriangleMesh.h"
#include "mesher/tolerance/SurfaceProjection.h"

#include <cstddef>
#include <string>

namespace voxlat {

/// The crease points' Newton steps as the projection's (level, maxMove from where the straight
/// edge crosses the face, tolerance, maxIterations), and how close to a face a vertex is put onto it.
struct BoxClipOptions : ProjectionOptions {
    /// Vertices closer than this to a face are put onto it before cutting (mm).
    double snap = 1e-5;
    /// Whether the capped mesh's topology is checked (BoxClipStats::topology). False where the
    /// caller checks it after changing the mesh further (a refined mesh is checked once, after:
    /// W9's coarse mesh took 0.02 s to check).
    bool checkTopology = true;
};

/// What clipToBox() did.
struct BoxClipStats {
    /// False when the cut could not be capped into a closed, manifold mesh (without the topology
    /// check: could not be capped); @a failure says why and the mesh is left as it was.
    bool ok = false;
    std::string failure;
    /// Triangles that straddled a face and were cut.
    std::size_t cutTriangles = 0;
    /// Vertices of the result where an edge crossed a face (on a box edge where it crossed two).
    std::size_t creaseVertices = 0;
    /// Of those, the ones left where the straight edge crosses: Newton did not converge within
    /// maxMove inside the box, or a triangle around it would have turned over.
    std::size_t leftOnEdge = 0;
    /// Box corners inside the solid, added as vertices of the caps.
    std::size_t corners = 0;
    /// Triangles of the caps on the box's faces.
    std::size_t capTriangles = 0;
    /// The capped mesh's topology as checked (when ok and checked): callers need not check it again.
    MeshTopology topology;
};

/// Flips away the triangles of @a mesh from index @a first on that have lost their area in single
/// precision (three distinct corners on a line: a sliver of the cut or its cap whose corners
/// rounded onto one line when written as floats; 9 of 30.6 M triangles on a 60 mm gyroid at
/// 0.08 mm made the cut fail). The longest edge, with the triangle across it, becomes the edge
/// from the middle corner to that triangle's far corner: the two triangles cover what they
/// covered, the mesh stays closed and manifold. A flip is made only when both new triangles have
/// area and face the way the neighbour faced; up to three rounds. Returns the triangles flipped.
std::size_t flipFlatTriangles(TriangleMesh& mesh, std::size_t first = 0);

/// Drops the triangles of @a mesh with a corner more than @a margin outside @a box (and the
/// vertices only they use, the others keeping their order): what a grid evaluated past the box
/// meshes beyond it, including where its samples end, is not projected or cut for nothing.
void dropTrianglesOutside(TriangleMesh& mesh, const Box3& box, double margin);

/// Cuts @a mesh, a manifold, outward-oriented mesh of the solid f < options.level that extends
/// past @a box (closed, or open only outside the box), by the box's six faces in turn (-x, +x, -y, +y, -z, +z), keeping
/// what lies inside, and closes the cuts with planar caps on the faces. A point where an edge crosses a face moves onto
/// the level set by Newton steps within that face (within the box edge where it lies on two faces), at most
/// options.maxMove, and only when no triangle around it turns over. Each face's cap is the region its crease polygons
/// bound, with the box edge between two crease points added where the field at its middle is inside the solid (the
/// box's corners likewise). The result is checked closed and manifold; otherwise @a mesh is unchanged and the stats say
/// why. Deterministic: the same bytes for any thread count. @a progress (optional) runs from 0 to
/// 1, is called from any thread and may throw to cancel (@a mesh is then unchanged).
BoxClipStats clipToBox(TriangleMesh& mesh, const FieldNode& field, const Box3& box, const BoxClipOptions& options,
                       const ProgressFn& progress = {});

}  // namespace voxlat
