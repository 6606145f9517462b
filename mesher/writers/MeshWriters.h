/// @file MeshWriters.h
/// @brief Mesh file output (STL, 3MF, PLY, OBJ) through AtomicFile, and an STL reader for tests.
#pragma once

#include "mesher/extract/MarchingCubes.h"
#include "mesher/extract/TriangleMesh.h"
#include "mesher/writers/AtomicFile.h"

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

namespace voxlat {

/// Writes @a mesh as binary STL, streamed in chunks. The output is byte-deterministic: a fixed
/// header ("voxlat binary STL" padded with spaces, no timestamp), facet normals computed from the
/// vertices in double, attribute words 0. Throws std::invalid_argument for out-of-range indices
/// or more than 2^32 - 1 triangles, std::runtime_error naming @a path on I/O failure.
/// @a measures, when given, receives the mesh's volume and area, summed while the facets are
/// formatted (the terms of TriangleMesh::measure() in chunk order: the same up to rounding, the
/// same bits for any thread count).
void writeStl(const TriangleMesh& mesh, const std::string& path, TriangleMesh::Measures* measures = nullptr);

/// What writeMarchingCubesStl() made: the mesh's sizes, volume and area.
struct StreamedStl {
    StreamedMeshCounts counts;
    TriangleMesh::Measures measures;
};

/// The marching-cubes mesh of @a grid at @a isoValue written to the binary STL @a path as it is
/// made (marchingCubesStreamed() into an StlStreamWriter), never held whole: the bytes
/// writeStl(marchingCubes(grid, isoValue), path) gives. Volume terms are summed about
/// @a reference (a point near the mesh).
StreamedStl writeMarchingCubesStl(const openvdb::FloatGrid& grid, float isoValue, const std::string& path,
                                  const openvdb::Vec3d& reference, ProgressFn progress = {},
                                  MarchingCubesStats* stats = nullptr);

/// A binary STL written chunk by chunk, for a mesh that is never held whole (marching cubes
/// streamed into the file: marchingCubesStreamed()). The facets have the bytes writeStl() gives
/// the same triangles. Written under a temporary name; commit() puts it in place, and a writer
/// destroyed before that removes it (nothing half-written is left).
class StlStreamWriter {
public:
    /// Opens the file and writes the header (its count is filled in by commit()). The volume is
    /// summed about @a reference (any point near the mesh keeps the sums accurate).
    StlStreamWriter(const std::string& path, const openvdb::Vec3d& reference);
    ~StlStreamWriter();
    StlStreamWriter(const StlStreamWriter&) = delete;
    StlStreamWriter& operator=(const StlStreamWriter&) = delete;

    /// Formats @a triangles into @a bytes and returns their volume and area terms. Touches no
    /// state of the writer: call it from any thread, for any chunks at once.
    TriangleMesh::Measures format(std::span<const std::array<openvdb::Vec3f, 3>> triangles,
                                  std::vector<char>& bytes) const;
    /// Appends a formatted chunk and its terms. One call at a time, chunks in file order.
    void write(const std::vector<char>& bytes, const TriangleMesh::Measures& terms);
    /// Writes the count of @a triangles into the header and puts the file in place; returns the
    /// mesh's volume and area (as TriangleMesh::measure()).
    TriangleMesh::Measures commit(std::uint64_t triangles);

private:
    std::unique_ptr<AtomicFile> mFile;
    openvdb::Vec3d mReference;
    TriangleMesh::Measures mTerms;  ///< sums of the chunks' terms, in file order
};

/// Name and value pairs a format that has metadata records (3MF) stores with the mesh.
using MeshMetadata = std::vector<std::pair<std::string, std::string>>;

/// Writes @a mesh in the format named by the (case-insensitive) extension of @a path:
/// .stl (binary, writeStl), .3mf (lib3mf: unit millimetre, one object named after the file,
/// @a metadata as the model's metadata), .ply (binary, via OpenMesh) or .obj (ASCII, via OpenMesh).
/// Throws std::invalid_argument listing the supported extensions for any other one. The PLY and
/// OBJ paths need a manifold mesh (OpenMesh rejects other faces); they throw std::runtime_error
/// rather than silently drop a face. No partial file is ever left at @a path. For STL,
/// @a measures (when given) receives what writeStl() measures; other formats leave it alone.
void writeMesh(const TriangleMesh& mesh, const std::string& path,
               std::optional<TriangleMesh::Measures>* measures = nullptr, const MeshMetadata& metadata = {});

/// Reads a binary or ASCII STL file, welding vertices with bit-identical positions (-0 == +0) in
/// order of first appearance. Throws std::runtime_error naming @a path if it cannot be read.
TriangleMesh readStl(const std::string& path);

}  // namespace voxlat
