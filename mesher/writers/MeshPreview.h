/// @file MeshPreview.h
/// @brief A shaded picture of a mesh, so a person can see what they made before printing it.
#pragma once

#include "mesher/extract/TriangleMesh.h"

#include <string>

namespace voxlat {

/// Renders @a mesh seen from the front-right-top (orthographic, flat Lambert shading, two lights)
/// into a @a size x @a size RGBA PNG and returns its bytes. Rasterised in parallel with per-thread
/// depth buffers merged by (depth, triangle index), so the picture is the same for any thread count.
std::string renderMeshPreview(const TriangleMesh& mesh, int size = 800);

}  // namespace voxlat
