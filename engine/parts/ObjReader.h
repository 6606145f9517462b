/// @file ObjReader.h
/// @brief A checked Wavefront OBJ reader for part meshes.
///
/// OpenMesh's OBJ reader aborts on an assertion for faces such as `f /2 3 7` (found by
/// fuzz_mesh); this one reads the few statements a part mesh needs and refuses anything it cannot
/// read with the line number, never quoting the file's text.
#pragma once

#include "mesher/extract/TriangleMesh.h"

#include <string>

namespace voxlat {

/// Reads the `v` (x, y, z; a fourth weight or colour values after them are ignored) and `f`
/// statements of an OBJ file held in @a bytes. Face corners are `i`, `i/t`, `i//n` or `i/t/n`
/// with i counted from 1, or from the end when negative; polygons are split into fans. Other
/// statements (vt, vn, o, g, s, usemtl, mtllib, l, p, ...) and comments are skipped. Throws
/// InputError starting with @a shown and the line for a coordinate that is not a finite number,
/// a face with fewer than three corners, or an index of a vertex not defined before it.
TriangleMesh readObj(const std::string& bytes, const std::string& shown);

}  // namespace voxlat
