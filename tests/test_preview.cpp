// The mesh preview: a real picture of the part (a sphere renders as a filled disk), identical for
// any thread count.
#include "engine/core/Domain.h"
#include "engine/core/SparseEvaluator.h"
#include "engine/jobs/ReportPage.h"
#include "fields/shapes/Sphere.h"
#include "mesher/extract/MarchingCubes.h"
#include "mesher/tolerance/ClusterDecimation.h"
#include "mesher/writers/MeshPreview.h"
#include "mesher/writers/SliceWriters.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <numbers>
#include <regex>
#include <vector>

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

TEST(Preview, ClusteredSphereStaysWithinItsTriangleBudgetAndShape)
{
    const Domain d = Domain::fromBox(Box3{Vec3d(-6), Vec3d(6)}, 0.05);
    const TriangleMesh mesh = marchingCubes(*evaluateSparse(Sphere(Vec3d(0), 5.0), d, SparseOptions{}), 0.0f);
    ASSERT_GT(mesh.triangles.size(), 100000u);
    const TriangleMesh small = clusterDecimate(mesh, 5000);
    EXPECT_LE(small.triangles.size(), 5000u);
    EXPECT_GT(small.triangles.size(), 1000u) << "far coarser than the budget asks";
    // Still the ball: its volume within 3 % (clustering keeps the orientation) and every used
    // vertex near the sphere.
    const double ball = 4.0 / 3.0 * std::numbers::pi * 125.0;
    EXPECT_NEAR(small.volume(), ball, 0.03 * ball);
    for (const openvdb::Vec3I& t : small.triangles)
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(small.points[t[c]].length(), 5.0, 0.3);
    EXPECT_EQ(clusterDecimate(small, 5000).triangles.size(), small.triangles.size()) << "within budget: kept";
}

TEST(Preview, ClusteringIsTheSameForAnyThreadCountWhicheverTryStops)
{
    // The cells are tried two at a time, the first of the sequence within the budget kept
    // (report.html's mesh in bench/reference/byte_identity.json is the one-at-a-time loop's):
    // budgets from a tenth of the mesh to a hundredth stop at different tries, and each gives
    // the same mesh on one thread as on two, within its budget.
    const Domain d = Domain::fromBox(Box3{Vec3d(-6), Vec3d(6)}, 0.1);
    const TriangleMesh mesh = marchingCubes(*evaluateSparse(Sphere(Vec3d(0), 5.0), d, SparseOptions{}), 0.0f);
    std::vector<std::size_t> sizes;
    for (std::size_t budget : {20000u, 9000u, 6000u, 4000u, 3000u, 2000u}) {
        TriangleMesh one, two;
        {
            tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
            one = clusterDecimate(mesh, budget);
        }
        {
            tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 2);
            two = clusterDecimate(mesh, budget);
        }
        EXPECT_EQ(one.points, two.points) << budget;
        EXPECT_EQ(one.triangles, two.triangles) << budget;
        EXPECT_LE(one.triangles.size(), budget);
        EXPECT_GT(one.triangles.size(), budget / 3) << "far coarser than the budget asks";
        sizes.push_back(one.triangles.size());
    }
    EXPECT_TRUE(std::is_sorted(sizes.rbegin(), sizes.rend()));
}

TEST(Preview, ReportPageInlinesTheReportMeshAndScripts)
{
    TriangleMesh mesh;
    mesh.points = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    mesh.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
    const nlohmann::json report = {{"recipe", "a</script><b>.yaml"}, {"peak_memory_mb", 12.5}};
    const std::string page = reportPage(report, mesh, {"var a = '</script>';", "var b = 2;"});
    // Exactly one closing tag per script element: nothing inlined can end one early.
    const std::regex closing("</script>");
    const auto tags = std::distance(std::sregex_iterator(page.begin(), page.end(), closing), std::sregex_iterator());
    EXPECT_EQ(tags, 4);
    EXPECT_EQ(page.find("<script src"), std::string::npos);
    // The report comes back from its element as the same JSON (`<\/` reads as `</`).
    const std::string open = "<script type=\"application/json\" id=\"voxlat-report\">";
    const std::size_t from = page.find(open) + open.size();
    const nlohmann::json back = nlohmann::json::parse(page.substr(from, page.find("</script>", from) - from));
    EXPECT_EQ(back, report);
    // The mesh as base64 of its float and index arrays: 4 points = 48 bytes = 64 digits.
    const std::string meshOpen = "<script type=\"application/json\" id=\"voxlat-mesh\">";
    const std::size_t m = page.find(meshOpen) + meshOpen.size();
    const nlohmann::json meshBack = nlohmann::json::parse(page.substr(m, page.find("</script>", m) - m));
    EXPECT_EQ(meshBack["vertices"], 4);
    EXPECT_EQ(meshBack["triangles"], 4);
    const std::string digits = meshBack["points"].get<std::string>();
    ASSERT_EQ(digits.size(), 64u);
    // Decoded by hand, the digits are the points' floats in order.
    const std::string alphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    std::vector<unsigned char> bytes;
    for (std::size_t i = 0; i < digits.size(); i += 4) {
        std::uint32_t word = 0;
        for (int k = 0; k < 4; ++k) word = (word << 6) | std::uint32_t(alphabet.find(digits[i + std::size_t(k)]));
        for (int k = 2; k >= 0; --k) bytes.push_back(static_cast<unsigned char>((word >> (8 * k)) & 0xFF));
    }
    ASSERT_EQ(bytes.size(), 48u);
    for (std::size_t v = 0; v < 4; ++v)
        for (int c = 0; c < 3; ++c) {
            float f;
            std::memcpy(&f, bytes.data() + 12 * v + 4 * std::size_t(c), sizeof f);
            EXPECT_EQ(f, mesh.points[v][c]) << "point " << v << " coordinate " << c;
        }
    EXPECT_NE(page.find("<title>voxlat report: a&lt;/script&gt;&lt;b&gt;.yaml</title>"), std::string::npos)
        << "the title is escaped";
}

TEST(Preview, TheReportPagesCoarseGridDividesARepeatingResultsPeriods)
{
    // 500^3 voxels: 7.8125 of them a coarse voxel keeps the page's grid within 2^18 voxels.
    EXPECT_DOUBLE_EQ(pageGridFactor(125000000, {}), 7.8125);
    // A lattice repeating every 50 voxels along x and y: 10, the first whole number from 7.8125
    // that divides 50, so the coarse grid folds into the lattice's one-period table.
    EXPECT_DOUBLE_EQ(pageGridFactor(125000000, {50.0, 50.0}), 10.0);
    EXPECT_DOUBLE_EQ(pageGridFactor(125000000, {48.0}), 8.0);
    // No divisor up to twice the factor (a prime period), or periods that disagree: as before.
    EXPECT_DOUBLE_EQ(pageGridFactor(125000000, {47.0}), 7.8125);
    EXPECT_DOUBLE_EQ(pageGridFactor(125000000, {50.0, 9.0}), 7.8125);
    // A small domain is meshed at its own voxel.
    EXPECT_DOUBLE_EQ(pageGridFactor(1000, {50.0}), 1.0);
    // A factor from the budget's up keeps the coarse grid within its 2^18 voxels.
    for (const double f : {pageGridFactor(125000000, {50.0}), pageGridFactor(125000000, {48.0})})
        EXPECT_LE(125000000.0 / (f * f * f), double(1 << 18));
}
