/// @file MarchingCubes.h
/// @brief Sparse, parallel, topologically safe marching cubes over an OpenVDB float grid.
///
/// The surface separates voxels with value < isoValue (inside) from voxels with value >= isoValue
/// (outside). The mesh is watertight, manifold, outward oriented, free of degenerate triangles and
/// byte-identical for any number of threads, provided every sign-changing pair of face-adjacent
/// voxels lies inside leaf nodes (tiles and background never touch the surface).
#pragma once

#include "mesher/extract/TriangleMesh.h"

#include <openvdb/Grid.h>
#include <openvdb/openvdb.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

namespace voxlat {

/// Progress callback: @a fraction grows from 0 to 1. It may be called from any thread (calls are
/// serialized and strictly increasing) and at most about 100 times per meshing run.
using ProgressFn = std::function<void(double fraction)>;

/// What a marching cubes run did, for diagnostics and tests.
struct MarchingCubesStats {
    /// Leaf nodes of the grid, each of which owns the cubes whose minimum corner it contains.
    std::size_t leafBlocks = 0;
    /// 8^3 blocks of tiles or background just below a leaf: they own the cubes whose minimum
    /// corner is a tile voxel but which reach into a leaf, so those cubes are not lost.
    std::size_t tileBlocks = 0;
    /// Triangles emitted by cubes owned by tile blocks (see @c tileBlocks).
    std::size_t tileBlockTriangles = 0;
    /// Loop centroid vertices added because no fan apex avoided a face diagonal.
    std::size_t centroidVertices = 0;
    /// Distinct sign-changing voxel edges whose lower voxel is not in a leaf, so they have no
    /// vertex. Always 0 for grids that honour the contract above.
    std::size_t skippedEdges = 0;
    /// Cubes left untriangulated because they touch a skipped edge (the mesh then has holes).
    std::size_t droppedCubes = 0;
    /// The triangles emitted up to the end of each chunk of consecutive blocks that
    /// marchingCubesStreamed() delivers at once (its chunks' ends in the mesh's triangle order).
    std::vector<std::uint64_t> chunkTriangleEnds;
};

/// Extract the isosurface of @a grid at @a isoValue as an indexed triangle mesh in world space.
///
/// Cube corners are voxel centres. Ambiguous cube faces are resolved with the asymptotic decider
/// from the four face values alone, so neighbouring cubes always agree.
///
/// @param grid      sparse level-set-like grid: negative (below @a isoValue) inside
/// @param isoValue  threshold; a voxel exactly at the threshold counts as outside
/// @param progress  optional progress callback (see ProgressFn)
/// @param stats     optional out-parameter receiving diagnostics
TriangleMesh marchingCubes(const openvdb::FloatGrid& grid, float isoValue = 0.0f, ProgressFn progress = {},
                           MarchingCubesStats* stats = nullptr);

/// One triangle as its three corners in world space, in its winding order.
using TriangleCorners = std::array<openvdb::Vec3f, 3>;

/// Where marchingCubesStreamed() delivers its triangles. The run splits the cubes into
/// consecutive chunks; each chunk's triangles go to @c format (called in parallel, for any
/// chunks at once, each with its own slot in [0, slots)), then to @c write (one call at a time,
/// chunks in order) with the same slot. A slot is reused by a later chunk only after its
/// @c write returned, so a consumer keeps one buffer per slot.
struct TriangleStream {
    std::size_t slots = 8;
    std::function<void(std::size_t chunk, std::size_t slot, std::span<const TriangleCorners> triangles)> format;
    std::function<void(std::size_t chunk, std::size_t slot)> write;
};

/// The memory a streamed run writing an STL (writeMarchingCubesStl) holds whatever the grid's
/// size: its slots' chunks in flight (each slot a chunk's triangle corners and their STL bytes)
/// and the file's direct-write buffers. Measured at 77 MB on the densest surface seen (capsule
/// struts at 0.1 mm, 180 triangles a leaf; valgrind massif); the evaluation's memory estimate
/// adds it for a job that writes a mesh (SparseOptions::bytesBeside).
inline constexpr std::uint64_t kStreamedMeshBytes = std::uint64_t(96) << 20;

/// Counts of a streamed run (the mesh marchingCubes() would return has these sizes).
struct StreamedMeshCounts {
    std::uint64_t triangles = 0;
    std::uint64_t vertices = 0;
};

/// marchingCubes() without holding the mesh: the same triangles, in the same order, with
/// corners of the same bits (each position is computed from the same two grid values wherever
/// the vertex is used), delivered chunk by chunk to @a stream in one pass over the grid; the
/// counts are known when it returns. For an output that is the mesh's only use: a binary STL
/// is written without the vertex and triangle arrays (220 MB for the acceptance gyroid), a
/// counting pass, or a second pass over the mesh.
StreamedMeshCounts marchingCubesStreamed(const openvdb::FloatGrid& grid, float isoValue, const TriangleStream& stream,
                                         ProgressFn progress = {}, MarchingCubesStats* stats = nullptr);

/// The volume marchingCubes(@a grid, @a isoValue) encloses, without the mesh: its triangles
/// streamed (marchingCubesStreamed()) and their signed tetrahedra about @a reference (a point
/// near the mesh) summed per chunk, then in chunk order: the same for any thread count, and the
/// volume a file of that mesh holds (up to the rounding of its sums).
double marchingCubesVolume(const openvdb::FloatGrid& grid, float isoValue, const openvdb::Vec3d& reference,
                           ProgressFn progress = {});

/// marchingCubesVolume() of the grid @a mesh was made from by marchingCubes(), which gave @a stats:
/// the same tetrahedra summed in the same chunks in the same order, so the same double, without
/// a second pass over the grid (a job that holds the mesh measures its share from it).
double marchingCubesVolume(const TriangleMesh& mesh, const MarchingCubesStats& stats, const openvdb::Vec3d& reference);

/// Facts about the precomputed case table, for tests and reports.
struct MarchingCubesTableInfo {
    std::size_t entries = 0;        ///< reachable (corner case, face decision) combinations
    std::size_t loops = 0;          ///< surface loops over all reachable entries
    std::size_t centroidLoops = 0;  ///< loops that needed an extra centroid vertex
    std::size_t maxTriangles = 0;   ///< most triangles any single cube emits
};

/// Builds the case table on first use (thread-safe) and describes it.
MarchingCubesTableInfo marchingCubesTableInfo();

}  // namespace voxlat
