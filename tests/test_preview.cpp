// The mesh preview: a real picture of the part (a sphere renders as a filled disk), identical for
// any thread count.
#include "engine/core/Domain.h"
#include "engine/core/SparseEvaluator.h"
#include "fields/Sphere.h"
#include "mesher/extract/MarchingCubes.h"
#include "mesher/writers/MeshPreview.h"
#include "mesher/writers/SliceWriters.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <numbers>

using namespace voxlat;

TEST(Preview, SphereRendersAsAFilledDiskForAnyThreadCount)
{
    const Domain d = Domain::fromBox(Box3{Vec3d(-6), Vec3d(6)}, 0.1);
    const TriangleMesh mesh = marchingCubes(*evaluateSparse(Sphere(Vec3d(0), 5.0), d, SparseOptions{}), 0.0f);
    std::string one, many;
    {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
        one = renderMeshPreview(mesh, 400);
    }
    {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 4);
        many = renderMeshPreview(mesh, 400);
    }
    EXPECT_EQ(one, many);

    int w = 0, h = 0, channels = 0;
    const auto pixels = decodePng(one, w, h, channels);
    ASSERT_EQ(w, 400);
    ASSERT_EQ(channels, 4);
    int lit = 0, minX = w, maxX = -1;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::uint8_t* p = &pixels[(std::size_t(y) * w + x) * 4];
            if (p[0] == 255 && p[1] == 255 && p[2] == 255) continue;  // background
            ++lit;
            minX = std::min(minX, x);
            maxX = std::max(maxX, x);
        }
    // The silhouette of a sphere is a disk: its area matches its measured width, so no holes.
    const double radius = 0.5 * (maxX - minX + 1);
    EXPECT_GT(radius, 50.0);
    EXPECT_NEAR(lit, std::numbers::pi * radius * radius, 0.02 * std::numbers::pi * radius * radius);
}
