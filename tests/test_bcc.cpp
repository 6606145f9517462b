// The BCC extractor (issue 16, Aether's mesher as an option): marching tetrahedra on the grid's
// voxels plus the cube centres. Distances are measured with the test's own formulas (a sphere's
// exact distance, the gyroid's equation and gradient written out), not with the code under test.

#include "FieldChecks.h"
#include "MeshChecks.h"
#include "TestUtil.h"
#include "engine/core/SparseEvaluator.h"
#include "engine/jobs/Job.h"
#include "fields/levels/LevelSolid.h"
#include "fields/shapes/Boolean.h"
#include "fields/shapes/BoxField.h"
#include "fields/shapes/Sphere.h"
#include "fields/tpms/TpmsField.h"
#include "mesher/checks/MeshCheck.h"
#include "mesher/extract/BccTetrahedra.h"
#include "mesher/extract/MarchingCubes.h"
#include "mesher/tolerance/SurfaceProjection.h"
#include "mesher/writers/MeshWriters.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <functional>
#include <numbers>
#include <set>

namespace {

using namespace voxlat;

/// The test's own gyroid network G < c: its first-order signed distance (G - c) / |grad G|.
double gyroidDistance(const Vec3d& p, double cell, double c)
{
    const double k = 2.0 * std::numbers::pi / cell;
    const double sx = std::sin(k * p.x()), cx = std::cos(k * p.x()), sy = std::sin(k * p.y()), cy = std::cos(k * p.y()),
                 sz = std::sin(k * p.z()), cz = std::cos(k * p.z());
    const double g = sx * cy + sy * cz + sz * cx;
    const Vec3d grad(k * (cx * cy - sz * sx), k * (cy * cz - sx * sy), k * (cz * cx - sy * sz));
    return (g - c) / grad.length();
}

using test::boxDistance;
using test::clipped;

/// The grid the Job evaluates (clipped to the domain) and the BCC mesh of it.
struct Meshed {
    openvdb::FloatGrid::Ptr grid;
    TriangleMesh mesh;
    BccStats stats;
};

Meshed bccOf(const FieldNode& f, const Domain& d)
{
    SparseOptions options;
    options.clipToDomain = true;
    Meshed m;
    m.grid = evaluateSparse(f, d, options);
    m.mesh = bccTetrahedra(*m.grid, f, 0.0f, {}, &m.stats);
    return m;
}

using test::at;

double maxOverVertices(const TriangleMesh& m, const std::function<double(const Vec3d&)>& distance)
{
    double worst = 0.0;
    for (unsigned v = 0; v < m.points.size(); ++v) worst = std::max(worst, std::abs(distance(at(m, v))));
    return worst;
}

/// Closed and manifold, and a closed surface (even Euler characteristic).
void expectClosedSurface(const TriangleMesh& m)
{
    test::expectClosedManifold(m);
    const MeshTopology t = checkTopology(m);
    EXPECT_TRUE(t.closedManifold());
    EXPECT_EQ(t.eulerCharacteristic % 2, 0);
}

/// Every vertex is used by some triangle: no stray points from miscounted offsets.
std::size_t unusedPoints(const TriangleMesh& m)
{
    std::vector<bool> used(m.points.size(), false);
    for (const auto& t : m.triangles)
        for (int k = 0; k < 3; ++k)
            if (t[k] < used.size()) used[t[k]] = true;
    return std::size_t(std::count(used.begin(), used.end(), false));
}

/// Triangles whose normal points against @a outward (the direction away from the solid).
std::size_t inwardTriangles(const TriangleMesh& m, const std::function<Vec3d(const Vec3d&)>& outward)
{
    std::size_t count = 0;
    for (const openvdb::Vec3I& t : m.triangles) {
        const Vec3d a = at(m, t[0]), b = at(m, t[1]), c = at(m, t[2]);
        count += (b - a).cross(c - a).dot(outward((a + b + c) / 3.0)) <= 0.0;
    }
    return count;
}

struct GyroidCase {
    double cell = 5.0, level = 0.3, voxel = 0.1;
    Box3 box{Vec3d(0.0), Vec3d(6.0, 5.5, 5.0)};
    FieldPtr lattice() const
    {
        return std::make_shared<LevelSolid>(std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(cell)),
                                            SolidSide::Below, level);
    }
    FieldPtr field() const { return clipped(lattice(), box); }
    double distance(const Vec3d& p) const { return std::max(gyroidDistance(p, cell, level), boxDistance(p, box)); }
};

TEST(Bcc, TablesHoldTwelveCongruentTetrahedraPerCube)
{
    // One cube of a constant field has no surface; the tables are validated when first built
    // (every tetrahedron of volume h^3 / 12, every case polygon turning outward).
    const Domain d = Domain::fromBox(Box3{Vec3d(0.0), Vec3d(1.0)}, 0.25);
    const Sphere far(Vec3d(100.0), 1.0);
    const Meshed m = bccOf(far, d);
    EXPECT_TRUE(m.mesh.empty());
    EXPECT_EQ(m.stats.crossingTetrahedra, 0u);
}

TEST(Bcc, SphereIsClosedOutwardAndAccurate)
{
    const double voxel = 0.2, radius = 3.7;
    const Vec3d centre(5.03, 4.98, 5.01);
    const Box3 box{Vec3d(0.0), Vec3d(10.0)};
    const FieldPtr field = clipped(std::make_shared<Sphere>(centre, radius), box);
    const Meshed m = bccOf(*field, Domain::fromBox(box, voxel));
    EXPECT_EQ(m.stats.droppedTetrahedra, 0u);
    EXPECT_GT(m.stats.crossingTetrahedra, 0u);
    expectClosedSurface(m.mesh);
    EXPECT_EQ(checkTopology(m.mesh).eulerCharacteristic, 2);
    EXPECT_EQ(unusedPoints(m.mesh), 0u);
    EXPECT_EQ(inwardTriangles(m.mesh, [&](const Vec3d& p) { return p - centre; }), 0u);

    // Chords of the sphere lie inside it: a little less volume than the ball's.
    const double exact = 4.0 / 3.0 * std::numbers::pi * std::pow(radius, 3);
    RecordProperty("volume_error_percent", std::to_string(100.0 * (m.mesh.volume() - exact) / exact));
    EXPECT_NEAR(m.mesh.volume(), exact, 0.005 * exact);
    EXPECT_LT(m.mesh.volume(), exact);

    auto distance = [&](const Vec3d& p) { return (p - centre).length() - radius; };
    const double raw = maxOverVertices(m.mesh, distance);
    RecordProperty("raw_max_vertex_deviation_voxels", std::to_string(raw / voxel));
    EXPECT_LT(raw, 0.03 * voxel);

    TriangleMesh projected = m.mesh;
    projectToSurface(projected, *field, {0.0, 0.5 * voxel, 1e-6, 12});
    const double after = maxOverVertices(projected, distance);
    RecordProperty("projected_max_vertex_deviation_voxels", std::to_string(after / voxel));
    EXPECT_LT(after, 0.01 * voxel);
    expectClosedSurface(projected);

    // Marching cubes on the same grid: the same solid.
    SparseOptions options;
    options.clipToDomain = true;
    const TriangleMesh cubes = marchingCubes(*m.grid, 0.0f);
    EXPECT_NEAR(m.mesh.volume(), cubes.volume(), 0.005 * exact);
}

TEST(Bcc, GyroidCutByItsBoxIsClosedOutwardAndAccurate)
{
    const GyroidCase g;
    const FieldPtr field = g.field();
    const Meshed m = bccOf(*field, Domain::fromBox(g.box, g.voxel));
    EXPECT_EQ(m.stats.droppedTetrahedra, 0u);
    ASSERT_GT(m.mesh.triangles.size(), 100000u);
    expectClosedSurface(m.mesh);
    EXPECT_EQ(unusedPoints(m.mesh), 0u);
    // Outward: along the gradient of the solid's (test-written) distance, away from the box's
    // edges where two surfaces meet and the direction is not defined.
    auto outward = [&](const Vec3d& p) {
        const double h = 1e-5;
        Vec3d grad;
        for (int a = 0; a < 3; ++a) {
            Vec3d e(0.0);
            e[a] = h;
            grad[a] = g.distance(p + e) - g.distance(p - e);
        }
        return grad;
    };
    TriangleMesh interior;
    interior.points = m.mesh.points;
    for (const openvdb::Vec3I& t : m.mesh.triangles) {
        const Vec3d c = (at(m.mesh, t[0]) + at(m.mesh, t[1]) + at(m.mesh, t[2])) / 3.0;
        if (std::abs(gyroidDistance(c, g.cell, g.level) - boxDistance(c, g.box)) > g.voxel)
            interior.triangles.push_back(t);
    }
    ASSERT_GT(interior.triangles.size(), m.mesh.triangles.size() / 2);
    EXPECT_EQ(inwardTriangles(interior, outward), 0u);

    // The volume against a fine numerical integral of the test's own indicator (midpoint rule on
    // a grid four times finer, the boundary cells counted by their share of the distance).
    const double h = g.voxel / 4.0;
    double volume = 0.0;
    for (double x = g.box.min.x() + 0.5 * h; x < g.box.max.x(); x += h)
        for (double y = g.box.min.y() + 0.5 * h; y < g.box.max.y(); y += h)
            for (double z = g.box.min.z() + 0.5 * h; z < g.box.max.z(); z += h) {
                const double s = gyroidDistance(Vec3d(x, y, z), g.cell, g.level);
                volume += std::clamp(0.5 - s / h, 0.0, 1.0);
            }
    volume *= h * h * h;
    RecordProperty("volume_error_percent", std::to_string(100.0 * (m.mesh.volume() - volume) / volume));
    EXPECT_NEAR(m.mesh.volume(), volume, 0.005 * volume);

    // Vertex deviation more than two voxels inside the box: where the lattice meets the box, the
    // grid samples max(G - c, box distance), whose straight-line interpolation misses the crease by
    // up to a quarter of a voxel for either extractor (the Job's crease steps handle it).
    auto distance = [&](const Vec3d& p) { return g.distance(p); };
    auto inside = [&](const Vec3d& p) { return boxDistance(p, g.box) < -2.0 * g.voxel ? g.distance(p) : 0.0; };
    const double raw = maxOverVertices(m.mesh, inside);
    RecordProperty("raw_max_vertex_deviation_voxels", std::to_string(raw / g.voxel));
    RecordProperty("raw_max_vertex_deviation_voxels_at_the_box",
                   std::to_string(maxOverVertices(m.mesh, distance) / g.voxel));
    EXPECT_LT(raw, 0.04 * g.voxel);
    EXPECT_GT(raw, 0.001 * g.voxel);  // not on the surface by accident: the field bends
    TriangleMesh projected = m.mesh;
    const ProjectionStats ps = projectToSurface(projected, *field, {0.0, 0.5 * g.voxel, 1e-6, 12});
    const double after = maxOverVertices(projected, inside);
    RecordProperty("projected_max_vertex_deviation_voxels", std::to_string(after / g.voxel));
    RecordProperty("projected_max_vertex_deviation_voxels_at_the_box",
                   std::to_string(maxOverVertices(projected, distance) / g.voxel));
    RecordProperty("projected_vertices_held_back", std::to_string(ps.heldBack));
    EXPECT_LT(after, 0.01 * g.voxel);
    EXPECT_LT(maxOverVertices(projected, distance), 0.05 * g.voxel);
    expectClosedSurface(projected);
}

TEST(Bcc, SameBytesForAnyThreadCount)
{
    const GyroidCase g;
    const FieldPtr field = g.field();
    const Domain d = Domain::fromBox(g.box, 0.15);
    SparseOptions options;
    options.clipToDomain = true;
    const auto grid = evaluateSparse(*field, d, options);
    auto mesh = [&](int threads) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
        tbb::task_arena arena(threads);
        TriangleMesh m;
        arena.execute([&] { m = bccTetrahedra(*grid, *field, 0.0f); });
        return m;
    };
    const TriangleMesh one = mesh(1), two = mesh(2);
    ASSERT_GT(one.triangles.size(), 10000u);
    EXPECT_TRUE(one.points == two.points);
    EXPECT_TRUE(one.triangles == two.triangles);
    test::TempDir dir;
    writeStl(one, (dir.path / "one.stl").string());
    writeStl(two, (dir.path / "two.stl").string());
    EXPECT_EQ(test::readFile(dir.path / "one.stl"), test::readFile(dir.path / "two.stl"));
}

TEST(Bcc, TileCubesNextToLeavesAreMeshed)
{
    // A small sphere in a coarse grid: inside tiles touch the surface leaves, so tetrahedra reach
    // from tile cubes' centres into leaves. The mesh must still close, with nothing dropped.
    const double voxel = 0.05, radius = 2.0;
    const Vec3d centre(2.51, 2.47, 2.53);
    const Box3 box{Vec3d(0.0), Vec3d(5.0)};
    const FieldPtr field = clipped(std::make_shared<Sphere>(centre, radius), box);
    SparseOptions options;
    options.clipToDomain = true;
    SparseStats sparse;
    const Domain d = Domain::fromBox(box, voxel);
    const auto grid = evaluateSparse(*field, d, options, &sparse);
    ASSERT_GT(sparse.insideTiles, 0u);
    BccStats stats;
    const TriangleMesh m = bccTetrahedra(*grid, *field, 0.0f, {}, &stats);
    RecordProperty("tile_centre_values", std::to_string(stats.tileCentreValues));
    EXPECT_EQ(stats.droppedTetrahedra, 0u);
    expectClosedSurface(m);
    EXPECT_EQ(checkTopology(m).eulerCharacteristic, 2);
    const double exact = 4.0 / 3.0 * std::numbers::pi * std::pow(radius, 3);
    EXPECT_NEAR(m.volume(), exact, 0.002 * exact);
}

constexpr const char* kSmallGyroid = R"(voxel: 0.2
domain: {box: [[0, 0, 0], [6, 6, 6]]}
fields:
  lattice: {tpms: gyroid, cell: 5, solid: network, density: 0.3}
result: lattice
)";

TEST(Bcc, TheJobMeshesWithEitherExtractor)
{
    test::TempDir dir;
    const std::string text =
        std::string(kSmallGyroid) +
        "outputs: {mesh: [{file: b.stl, extractor: bcc}, {file: m.stl, extractor: marching-cubes}, "
        "{file: p.stl, extractor: bcc, project: on}]}\n";
    Job job(parseRecipe(text, "r.yaml", dir.path));
    job.writeOutputs(dir.path / "out", false);
    const nlohmann::json r = job.report();
    ASSERT_EQ(r["meshes"].size(), 3u);
    EXPECT_EQ(r["meshes"][0]["extractor"], "bcc");
    EXPECT_EQ(r["meshes"][1]["extractor"], "marching-cubes");
    EXPECT_EQ(r["meshes"][2]["extractor"], "bcc");
    EXPECT_TRUE(r["meshes"][2]["closed_manifold"].get<bool>());
    const TriangleMesh bcc = readStl((dir.path / "out/b.stl").string());
    const TriangleMesh cubes = readStl((dir.path / "out/m.stl").string());
    expectClosedSurface(bcc);
    expectClosedSurface(cubes);
    EXPECT_EQ(r["meshes"][0]["triangles"].get<std::size_t>(), bcc.triangles.size());
    EXPECT_GT(bcc.triangles.size(), cubes.triangles.size());
    // Same solid (both within a few tenths of a percent of it).
    EXPECT_NEAR(bcc.volume(), cubes.volume(), 0.01 * cubes.volume());
    // The projected bcc mesh went through the same projection path as marching cubes'.
    // (Each edge split at a crease with the domain box, or by the crease refinement, turns the
    // two triangles beside it into four.)
    const auto& p = r["meshes"][2];
    const std::size_t splits =
        p["creases"]["edges_split"].get<std::size_t>() + p["refinement"]["edges_split"].get<std::size_t>();
    EXPECT_GE(p["triangles"].get<std::size_t>(), bcc.triangles.size());
    EXPECT_LE(p["triangles"].get<std::size_t>(), bcc.triangles.size() + 2 * splits);
    ASSERT_TRUE(p.contains("projection"));
    // The tetrahedra's slivers fold into each other when every vertex moves (48 crossing pairs
    // here): the mesh is made again with those moves held back, so no two triangles cross and a
    // few vertices stay where the extractor put them.
    EXPECT_EQ(p["self_intersections"].get<std::size_t>(), 0u);
    const auto& projection = p["projection"];
    EXPECT_LT(projection["vertices_held_back"].get<std::size_t>(),
              projection["vertices_moved"].get<std::size_t>() / 100);
    EXPECT_LT(projection["vertex_deviation_after"]["rms_mm"].get<double>(), 0.01 * 0.2);
    EXPECT_LE(projection["vertex_deviation_after"]["max_mm"].get<double>(),
              projection["vertex_deviation_before"]["max_mm"].get<double>());

    MeshOptions a, b;
    b.extractor = MeshExtractor::Bcc;
    EXPECT_FALSE(a == b);
    EXPECT_TRUE(a.raw() && b.raw());
}

TEST(Bcc, AWrongExtractorIsRefusedWithTheLineAndTheChoices)
{
    test::TempDir dir;
    const auto path =
        dir.write("bad.yaml", std::string(kSmallGyroid) + "outputs: {mesh: {file: a.stl, extractor: bc}}\n");
    std::string out;
    EXPECT_EQ(test::runCommand(
                  test::voxlatBinary() + " -q run " + path.string() + " --out " + (dir.path / "out").string(), &out),
              2)
        << out;
    EXPECT_NE(out.find("bad.yaml:6:"), std::string::npos) << out;
    EXPECT_NE(out.find("marching-cubes, bcc"), std::string::npos) << out;
    EXPECT_NE(out.find("did you mean `bcc`"), std::string::npos) << out;
    EXPECT_FALSE(std::filesystem::exists(dir.path / "out/a.stl"));

    const auto good = dir.write("good.yaml", kSmallGyroid);
    const auto file = dir.path / "m.stl";
    EXPECT_EQ(
        test::runCommand(
            test::voxlatBinary() + " -q mesh " + good.string() + " -o " + file.string() + " --extractor tetra", &out),
        2)
        << out;
    EXPECT_NE(out.find("marching-cubes, bcc"), std::string::npos) << out;
    EXPECT_FALSE(std::filesystem::exists(file));
    ASSERT_EQ(
        test::runCommand(
            test::voxlatBinary() + " -q mesh " + good.string() + " -o " + file.string() + " --extractor bcc", &out),
        0)
        << out;
    const TriangleMesh m = readStl(file.string());
    expectClosedSurface(m);
}

}  // namespace
