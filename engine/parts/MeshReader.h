/// @file MeshReader.h
/// @brief Reads a part's triangle mesh: STL (binary and ASCII), OBJ, PLY, 3MF.
#pragma once

#include "mesher/extract/TriangleMesh.h"

#include <filesystem>
#include <optional>
#include <string>

namespace voxlat {

/// A mesh as read from a file, vertices welded (equal coordinates are one vertex).
struct PartMesh {
    TriangleMesh mesh;
    std::string format;                ///< "binary STL", "ASCII STL", "OBJ", "PLY", "3MF"
    std::optional<double> fileUnitMm;  ///< millimetres per file unit, where the file says (3MF)
};

/// Reads @a path by its extension (.stl, .obj, .ply, .3mf). Throws InputError with a message
/// that starts with @a shown (the path as the user wrote it) for a missing, unreadable,
/// truncated or otherwise corrupted file, or one with no triangles.
PartMesh readPartMesh(const std::filesystem::path& path, const std::string& shown);

/// Merges vertices with identical coordinates (STL stores every triangle's corners apart) and
/// renumbers the triangles; the first occurrence keeps its place, so the order is fixed.
void weldVertices(TriangleMesh& mesh);

}  // namespace voxlat
