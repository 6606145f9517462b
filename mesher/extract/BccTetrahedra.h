/// @file BccTetrahedra.h
/// @brief Marching tetrahedra on a body-centred-cubic lattice: the grid's voxels plus the centres
/// of its cubes, the other mesher of `outputs: {mesh: {extractor: bcc}}`.
///
/// The lattice (Aether's, the Voronoi cells of which are truncated octahedra) has two kinds of
/// nodes: the grid's samples (the corners of marching cubes' cubes, read from the grid) and the
/// centre of every cube (the field evaluated there). Its standard tetrahedralisation has one
/// tetrahedron per (cube face, face edge): the centres of the two cubes sharing the face and the
/// edge's two ends. The tetrahedra are congruent (edges 1, 1 and four of sqrt(3)/2 voxels), fill
/// space (12 per cube, each h^3 / 12) and meet face to face, so marching tetrahedra on them gives
/// a closed, manifold, oriented surface with no ambiguous case.
///
/// Same contract as marchingCubes(): every sign change lies in leaf nodes; tiles and the
/// background have one sign over their box grown by one voxel (as evaluateSparse() makes them),
/// which the centres of their cubes then share.
#pragma once

#include "fields/core/FieldNode.h"
#include "mesher/extract/MarchingCubes.h"
#include "mesher/extract/TriangleMesh.h"

#include <openvdb/openvdb.h>

#include <cstddef>

namespace voxlat {

/// What a BCC run did, for diagnostics and tests.
struct BccStats {
    /// Leaf nodes of the grid; each owns the cubes whose minimum corner it contains.
    std::size_t leafBlocks = 0;
    /// Cube centres evaluated through the field (512 per leaf, in one grid batch each).
    std::size_t centreValues = 0;
    /// Centres of cubes in tiles evaluated one by one because a centre-to-centre edge from them
    /// into a leaf crosses the level (the vertex needs the true value, not the tile's).
    std::size_t tileCentreValues = 0;
    /// Tetrahedra with a sign change.
    std::size_t crossingTetrahedra = 0;
    /// Tetrahedra left out because an edge they cross belongs to no leaf (the mesh then has
    /// holes). Always 0 for grids that honour the contract.
    std::size_t droppedTetrahedra = 0;
};

/// Extract the level set of @a field at @a isoValue on the BCC lattice of @a grid, as an
/// indexed triangle mesh in world space, outward oriented (counter-clockwise seen from outside).
///
/// @param grid      sparse grid of @a field (negative inside): its voxels are the lattice's corner
///                  nodes, read as marching cubes reads them
/// @param field     the field the grid samples; evaluated at the cube centres (index space
///                  ijk + 1/2) of every leaf, through gridValues() one leaf at a time
/// @param isoValue  threshold; a node exactly at the threshold counts as outside
/// @param progress  optional progress callback (see ProgressFn)
/// @param stats     optional out-parameter receiving diagnostics
///
/// Vertices lie on the crossing lattice edges, by linear interpolation of the two node values
/// (kept 1/1000 of the edge off its ends, as marching cubes does); each quadrilateral is split
/// along its shorter diagonal. Work is parallel over leaves and the output byte-identical for
/// any number of threads (vertices numbered leaf by leaf in the tree's leaf order).
TriangleMesh bccTetrahedra(const openvdb::FloatGrid& grid, const FieldNode& field, float isoValue = 0.0f,
                           ProgressFn progress = {}, BccStats* stats = nullptr);

}  // namespace voxlat
