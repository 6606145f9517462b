/// @file ClusterDecimation.h
/// @brief A small picture-quality copy of a mesh: vertex clustering on a uniform grid.
///
/// No error bound (the error-bounded decimation is extract/Decimation): for previews only, where
/// a mesh of millions of triangles must become one a browser draws at once.
#pragma once

#include "mesher/extract/TriangleMesh.h"

#include <cstddef>

namespace voxlat {

/// @a mesh with its vertices merged per cell of a cubic grid (each cell's vertices replaced by
/// their mean) and the triangles that collapse dropped, the cell grown in steps of a fifth (from
/// an estimate made from the mean edge length) until at most @a maxTriangles triangles are left.
/// Orientation is kept; the result is the same for any thread count (two cells of that sequence
/// are tried at once, the first within the budget kept).
TriangleMesh clusterDecimate(const TriangleMesh& mesh, std::size_t maxTriangles);

}  // namespace voxlat
