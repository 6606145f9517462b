#pragma once
// Checks shared by the mesh tests (marching cubes, bcc, projection, decimation).
#include "mesher/checks/MeshCheck.h"
#include "mesher/extract/TriangleMesh.h"

#include <gtest/gtest.h>

namespace voxlat::test {

/// Point @a v of @a m in double precision.
inline Vec3d at(const TriangleMesh& m, unsigned v)
{
    return {m.points[v].x(), m.points[v].y(), m.points[v].z()};
}

/// No boundary, non-manifold or inconsistently oriented edge, no non-manifold vertex, no
/// degenerate triangle.
inline void expectClosedManifold(const TriangleMesh& m)
{
    const MeshTopology t = checkTopology(m);
    EXPECT_EQ(t.boundaryEdges, 0u);
    EXPECT_EQ(t.nonManifoldEdges, 0u);
    EXPECT_EQ(t.nonManifoldVertices, 0u);
    EXPECT_EQ(t.inconsistentlyOrientedEdges, 0u);
    EXPECT_EQ(t.degenerateTriangles, 0u);
}

}  // namespace voxlat::test
