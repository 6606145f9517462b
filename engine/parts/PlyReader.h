/// @file PlyReader.h
/// @brief A checked PLY reader (ASCII and binary, either byte order).
///
/// OpenMesh's PLY reader crashes on a three-line header and loops forever on a header without
/// `end_header`; this one validates the header and the sizes it implies against the bytes there
/// are before it reads or allocates anything, so a hostile file gets a message, never a crash.
#pragma once

#include "mesher/extract/TriangleMesh.h"

#include <string>

namespace voxlat {

/// Reads the `vertex` (x, y, z of any scalar type) and `face` (`vertex_indices` or
/// `vertex_index` list; polygons split into fans) elements of a PLY file held in @a bytes; other
/// elements and properties are skipped. Throws InputError starting with @a shown for a missing
/// or malformed header, counts the bytes cannot hold, an index out of range or a coordinate that
/// is not finite.
TriangleMesh readPly(const std::string& bytes, const std::string& shown);

}  // namespace voxlat
