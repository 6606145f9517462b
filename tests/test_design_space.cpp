// Design spaces from meshes (issue 6): signed distances against analytic ones, part volume,
// closed-mesh checks and repair, orientation, bad files, shells and infill measured on the
// result, density relative to the space inside the skin, conformal frames, automatic domains.
#include "TestUtil.h"
#include "engine/density/DensitySolver.h"
#include "engine/jobs/Job.h"
#include "engine/parts/MeshDesignSpace.h"
#include "engine/parts/MeshSdf.h"
#include "fields/frames/CoordinateMap.h"
#include "fields/levels/LevelSolid.h"
#include "fields/shapes/BoxField.h"
#include "fields/shapes/Sphere.h"
#include "fields/tpms/TpmsField.h"
#include "mesher/writers/MeshWriters.h"

#include <gtest/gtest.h>

#include <openvdb/math/Proximity.h>
#include <openvdb/tools/Interpolation.h>
#include <tbb/global_control.h>
#include <algorithm>
#include <cstring>
#include <nlohmann/json.hpp>

#include <cmath>
#include <numbers>
#include <random>

using namespace voxlat;
using namespace voxlat::test;

namespace {

/// An icosphere of @a radius, @a levels times subdivided, outward.
TriangleMesh sphereMesh(double radius, int levels)
{
    const double t = (1.0 + std::sqrt(5.0)) / 2.0;
    std::vector<Vec3d> p{{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                         {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
    std::vector<std::array<int, 3>> f{{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                      {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                      {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                      {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
    for (int l = 0; l < levels; ++l) {
        std::map<std::pair<int, int>, int> mid;
        auto middle = [&](int a, int b) {
            const auto key = std::minmax(a, b);
            if (auto it = mid.find(key); it != mid.end()) return it->second;
            p.push_back(0.5 * (p[a] + p[b]));
            return mid[key] = int(p.size()) - 1;
        };
        std::vector<std::array<int, 3>> next;
        for (const auto& tri : f) {
            const int a = middle(tri[0], tri[1]), b = middle(tri[1], tri[2]), c = middle(tri[2], tri[0]);
            next.insert(next.end(), {{tri[0], a, c}, {tri[1], b, a}, {tri[2], c, b}, {a, b, c}});
        }
        f = std::move(next);
    }
    TriangleMesh m;
    for (const Vec3d& q : p) {
        const Vec3d s = q.unit() * radius;
        m.points.emplace_back(float(s[0]), float(s[1]), float(s[2]));
    }
    for (const auto& tri : f) m.triangles.emplace_back(tri[0], tri[1], tri[2]);
    return m;
}

PartMesh asPart(TriangleMesh m)
{
    weldVertices(m);
    return PartMesh{std::move(m), "test", std::nullopt};
}

/// Largest |field - reference| over random points within @a band of the surface (by the reference).
double maxErrorNearSurface(const FieldNode& field, const FieldNode& reference, const Box3& box, double band)
{
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    double worst = 0.0;
    int tested = 0;
    while (tested < 20000) {
        const Vec3d p = box.min + Vec3d(u(rng), u(rng), u(rng)) * box.extent();
        const double r = reference.value(p);
        if (std::abs(r) > band) continue;
        worst = std::max(worst, std::abs(field.value(p) - r));
        ++tested;
    }
    return worst;
}

std::filesystem::path bracket()
{
    return sourceDir() / "data/meshes/bracket.stl";
}

}  // namespace

TEST(MeshDistance, SphereMatchesAnalyticDistanceWithinHalfAVoxel)
{
    const double voxel = 0.2;
    MeshSpaceOptions o;
    o.voxel = voxel;
    MeshDesignSpace space(asPart(sphereMesh(5.0, 5)), "sphere", o);
    space.requireInteriorBand(1.0);
    const auto d = space.distance();
    const Sphere exact(Vec3d(0.0), 5.0);
    const Box3 box{Vec3d(-7), Vec3d(7)};
    // Inside the band (3 voxels out, 1 mm + 2 voxels in): the distance itself.
    EXPECT_LT(maxErrorNearSurface(*d, exact, box, 0.55), 0.5 * voxel);
    // Everywhere: the right sign, and bounds that contain the values.
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> u(-8.0, 8.0);
    for (int n = 0; n < 5000; ++n) {
        const Vec3d p(u(rng), u(rng), u(rng));
        const double e = exact.value(p), v = d->value(p);
        if (std::abs(e) > voxel) {
            EXPECT_EQ(e < 0, v < 0) << p;
        }
        const Box3 b{p - Vec3d(0.3), p + Vec3d(0.45)};
        const Interval bound = d->bound(b);
        EXPECT_TRUE(bound.contains(v)) << p;
        EXPECT_TRUE(bound.contains(d->value(b.max)));
    }
    // Far boxes are culled (the bound is not merely Lipschitz).
    EXPECT_GT(d->bound(Box3{Vec3d(20), Vec3d(30)}).lo, 0.0);
    EXPECT_LT(d->bound(Box3{Vec3d(-1), Vec3d(1)}).hi, 0.0);
    // Gradients: unit length, radial, near the surface.
    const auto [v, g] = d->valueAndGradient(Vec3d(3.1, 2.2, 2.9));
    EXPECT_NEAR(g.length(), 1.0, 0.05);
    EXPECT_GT(g.dot(Vec3d(3.1, 2.2, 2.9).unit()), 0.99);
    EXPECT_NEAR(space.gridVolume(), space.meshVolume(), 0.01 * space.meshVolume());
}

TEST(MeshDistance, CubeMatchesAnalyticDistanceWithinHalfAVoxel)
{
    const double voxel = 0.25;
    MeshSpaceOptions o;
    o.voxel = voxel;
    o.sampleOrigin = Vec3d(0.0371, 0.11, -0.05);  // samples off the faces
    MeshDesignSpace space(asPart(cubeMesh(-4, 4)), "cube", o);
    space.requireInteriorBand(1.5);
    const BoxField exact(Box3{Vec3d(-4), Vec3d(4)});
    EXPECT_LT(maxErrorNearSurface(*space.distance(), exact, Box3{Vec3d(-5), Vec3d(5)}, 0.7), 0.5 * voxel);
    EXPECT_NEAR(space.gridVolume(), 512.0, 0.01 * 512.0);
    EXPECT_NEAR(space.meshVolume(), 512.0, 1e-9);
    ASSERT_TRUE(PartField(std::make_shared<MeshDesignSpace>(asPart(cubeMesh(-4, 4)), "c", o)).support());
}

TEST(MeshDistance, GridValuesBetweenSamplesAreThePointPathsDoubles)
{
    // Blocks whose points fall between the grid's samples (a slicer's plane at the printer's
    // pitch, a pixel's sub-samples, a leaf off the samples, a coarse pass) interpolate by axis:
    // every value must be the point path's own double.
    const double voxel = 0.2;
    MeshSpaceOptions o;
    o.voxel = voxel;
    MeshDesignSpace space(asPart(sphereMesh(3.0, 3)), "sphere", o);
    space.requireInteriorBand(1.0);
    const auto d = space.distance();
    std::vector<GridBatch> batches;
    auto add = [&](Vec3d origin, Vec3d spacing, int nx, int ny, int nz) {
        GridBatch g;
        g.origin = origin;
        g.spacing = spacing;
        g.nx = nx;
        g.ny = ny;
        g.nz = nz;
        batches.push_back(g);
    };
    add(Vec3d(-3.7, -2.93, 0.4371), Vec3d(0.019, 0.024, 1.0), 66, 66, 1);        // a slicer's block, across the surface
    add(Vec3d(2.91, -0.013, -1.02), Vec3d(0.019 / 8, 0.024 / 8, 1.0), 8, 8, 1);  // one pixel's sub-samples
    add(Vec3d(-1.03, 2.117, 1.5), Vec3d(0.07, 0.07, 0.07), 8, 8, 8);             // a leaf off the samples
    add(Vec3d(-4.1, -4.1, -4.1), Vec3d(1.05, 0.93, 1.1), 8, 9, 7);               // sparse: the point path itself
    add(Vec3d(-9.5, 7.25, -0.3), Vec3d(0.05, 0.05, 0.05), 5, 6, 3);              // beyond the band (background)
    for (const GridBatch& g : batches) {
        std::vector<double> grid(g.size()), points(g.size());
        std::vector<Vec3d> p;
        for (int i = 0; i < g.nx; ++i)
            for (int j = 0; j < g.ny; ++j)
                for (int k = 0; k < g.nz; ++k) p.push_back(g.point(i, j, k));
        d->gridValues(g, grid);
        d->values(p, points);
        for (std::size_t n = 0; n < p.size(); ++n) ASSERT_EQ(grid[n], points[n]) << p[n];
    }
}

TEST(MeshDesignSpace, BracketVolumeFromGridMatchesMesh)
{
    MeshSpaceOptions o;
    o.voxel = 0.1;
    MeshDesignSpace space(readPartMesh(bracket(), "bracket.stl"), "bracket.stl", o);
    space.build();
    EXPECT_EQ(space.mesh().triangles.size(), 1292u);
    EXPECT_GT(space.meshVolume(), 6000.0);
    EXPECT_NEAR(space.gridVolume(), space.meshVolume(), 0.01 * space.meshVolume());
    EXPECT_TRUE(space.warnings().empty());
    // The L profile: 30 mm long, 24 x 24, 5 mm plates.
    EXPECT_NEAR(space.bounds().extent()[0], 30.0, 1e-6);
    EXPECT_LT(space.distance()->value(Vec3d(15, 12, 2.5)), 0.0);   // inside the base
    EXPECT_GT(space.distance()->value(Vec3d(7.5, 16, 2.5)), 0.0);  // in a hole
    EXPECT_GT(space.distance()->value(Vec3d(15, 15, 15)), 0.0);    // in the crook of the L
}

TEST(MeshDesignSpace, OpenMeshIsRefusedWithItsBoundaryEdgesOrRepaired)
{
    const TriangleMesh closed = sphereMesh(5.0, 3);
    TriangleMesh open = closed;
    open.triangles.pop_back();  // a hole of three boundary edges
    MeshSpaceOptions o;
    o.voxel = 0.1;
    const std::string message = errorOf([&] { MeshDesignSpace(asPart(open), "holey.stl", o); });
    EXPECT_NE(message.find("holey.stl"), std::string::npos) << message;
    EXPECT_NE(message.find("open: 3 boundary edges"), std::string::npos) << message;
    EXPECT_NE(message.find("1 hole"), std::string::npos) << message;
    EXPECT_NE(message.find("repair: true"), std::string::npos) << message;
    o.repair = true;
    MeshDesignSpace repaired(asPart(open), "holey.stl", o);
    EXPECT_NEAR(repaired.meshVolume(), closed.volume(), 0.001 * closed.volume());
    repaired.build();
    EXPECT_NEAR(repaired.gridVolume(), closed.volume(), 0.01 * closed.volume());
    EXPECT_EQ(repaired.report()["holes_filled"], 1);
    // A hole as large as half a face of a cube is not "small": refused, with the fix.
    TriangleMesh cube = cubeMesh(0, 10);
    cube.triangles.pop_back();
    EXPECT_NE(errorOf([&] { MeshDesignSpace(asPart(cube), "cube.stl", o); }).find("too large for `repair: true`"),
              std::string::npos);
}

TEST(MeshDesignSpace, InvertedNormalsAreTurnedWhenUnambiguous)
{
    MeshSpaceOptions o;
    o.voxel = 0.25;
    // All inverted: one shell inside out.
    TriangleMesh inverted = cubeMesh(0, 10);
    for (auto& t : inverted.triangles) std::swap(t[1], t[2]);
    MeshDesignSpace a(asPart(inverted), "inverted.stl", o);
    a.build();
    EXPECT_NEAR(a.meshVolume(), 1000.0, 1e-6);
    EXPECT_EQ(a.report()["shells_turned"], 1);
    // Two triangles flipped among consistent neighbours.
    TriangleMesh mixed = cubeMesh(0, 10);
    std::swap(mixed.triangles[3][1], mixed.triangles[3][2]);
    std::swap(mixed.triangles[8][1], mixed.triangles[8][2]);
    MeshDesignSpace b(asPart(mixed), "mixed.stl", o);
    b.build();
    EXPECT_NEAR(b.meshVolume(), 1000.0, 1e-6);
    EXPECT_EQ(b.report()["triangles_reoriented"].get<int>() % 10, 2);  // 2 (or 10: the other 10 turned)
    // A surface folded onto itself (non-manifold edge) is reported, not guessed.
    TriangleMesh folded = cubeMesh(0, 10);
    folded.triangles.emplace_back(0, 1, 3);
    const std::string message = errorOf([&] { MeshDesignSpace(asPart(folded), "folded.stl", o); });
    EXPECT_NE(message.find("folded.stl: 3 edges are shared by more than two triangles"), std::string::npos) << message;
}

TEST(MeshDesignSpace, UnitsAndSizeChecks)
{
    MeshSpaceOptions o;
    o.voxel = 0.05;
    MeshDesignSpace inches(asPart(cubeMesh(0, 1.2)), "part.stl", o);
    ASSERT_EQ(inches.warnings().size(), 1u);
    EXPECT_NE(inches.warnings()[0].find("units: in"), std::string::npos) << inches.warnings()[0];
    o.unitMm = 25.4;
    MeshDesignSpace scaled(asPart(cubeMesh(0, 1.2)), "part.stl", o);
    EXPECT_TRUE(scaled.warnings().empty());
    EXPECT_NEAR(scaled.bounds().extent()[0], 30.48, 1e-4);
    o.unitMm.reset();
    o.voxel = 0.1;
    o.domain = Box3{Vec3d(0), Vec3d(20)};
    const std::string message = errorOf([&] { MeshDesignSpace(asPart(cubeMesh(0, 5000)), "huge.stl", o); });
    EXPECT_NE(message.find("huge.stl: the mesh (5000 x 5000 x 5000 mm) is far larger than the domain"),
              std::string::npos)
        << message;
}

TEST(MeshReader, PlyInAnyEncodingAndHostileHeadersRefused)
{
    TempDir dir;
    const TriangleMesh cube = cubeMesh(0, 10);
    // The same cube in ASCII, binary little- and big-endian PLY (quads in the ASCII one, split
    // into fans), with an extra element and properties to skip.
    std::string ascii =
        "ply\nformat ascii 1.0\ncomment a cube\nelement vertex 8\nproperty float x\n"
        "property float y\nproperty float z\nproperty uchar red\nelement face 6\n"
        "property list uchar int vertex_indices\nelement edge 1\nproperty int a\nproperty int b\n"
        "end_header\n";
    // A 10 mm cube in outward quads (split into fans by the reader).
    const int corners[8][3] = {{0, 0, 0},  {10, 0, 0},  {10, 10, 0},  {0, 10, 0},
                               {0, 0, 10}, {10, 0, 10}, {10, 10, 10}, {0, 10, 10}};
    for (const auto& c : corners)
        ascii += std::to_string(c[0]) + " " + std::to_string(c[1]) + " " + std::to_string(c[2]) + " 7\n";
    ascii += "4 0 3 2 1\n4 4 5 6 7\n4 0 1 5 4\n4 2 3 7 6\n4 0 4 7 3\n4 1 2 6 5\n";
    ascii += "0 1\n";
    dir.write("ascii.ply", ascii);
    auto binary = [&](bool big) {
        std::string b = std::string("ply\nformat ") + (big ? "binary_big_endian" : "binary_little_endian") +
                        " 1.0\nelement vertex 8\nproperty double x\nproperty double y\nproperty double z\n"
                        "element face 12\nproperty list uchar uint vertex_indices\nend_header\n";
        auto put = [&](const auto value) {
            char bytes[sizeof value];
            std::memcpy(bytes, &value, sizeof value);
            if (big) std::reverse(bytes, bytes + sizeof value);
            b.append(bytes, sizeof value);
        };
        for (const auto& p : cube.points)
            for (int a = 0; a < 3; ++a) put(double(p[a]));
        for (const auto& t : cube.triangles) {
            b.push_back(char(3));
            for (int c = 0; c < 3; ++c) put(std::uint32_t(t[c]));
        }
        return b;
    };
    dir.write("little.ply", binary(false));
    dir.write("big.ply", binary(true));
    for (const char* name : {"ascii.ply", "little.ply", "big.ply"}) {
        const PartMesh p = readPartMesh(dir.path / name, name);
        EXPECT_EQ(p.format, "PLY");
        EXPECT_EQ(p.mesh.triangles.size(), 12u) << name;
        EXPECT_EQ(p.mesh.points.size(), 8u) << name;
        EXPECT_NEAR(p.mesh.volume(), 1000.0, 1e-3) << name;
    }
    // Hostile files: each refused with its reason, never a crash or a hang (OpenMesh crashed on
    // the first and looped forever on the second).
    const std::vector<std::pair<std::string, std::string>> hostile = {
        {"ply\nformat ascii 1.0\nelement vertex 3\n", "no `end_header`"},
        {"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n" + std::string(1000, 'a'),
         "no `end_header`"},
        {"ply\nformat ascii 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float "
         "z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n",
         "announces elements"},
        {"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement "
         "face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n",
         "names vertex 7 of 3"},
        {"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement "
         "face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 nan\n1 0 0\n0 1 0\n3 0 1 2\n",
         "not a number"},
        {"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
         "0 0 0\n1 0 0\n0 1 0\n",
         "no `face` element"},
        {"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty "
         "float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n" +
             std::string(36, '\0') + "\xff",
         "list longer than the file"},
        {"solid\nnot a ply\n", "does not start with the line `ply`"},
        {"ply\nformat utf8 1.0\nend_header\n", "unknown format"},
    };
    for (std::size_t i = 0; i < hostile.size(); ++i) {
        const std::string name = "hostile" + std::to_string(i) + ".ply";
        dir.write(name, hostile[i].first);
        const std::string error = errorOf([&] { readPartMesh(dir.path / name, name); });
        EXPECT_NE(error.find(name + ": corrupted PLY"), std::string::npos) << error;
        EXPECT_NE(error.find(hostile[i].second), std::string::npos) << i << ": " << error;
    }
}

TEST(MeshReader, ObjFilesAreReadByACheckedParser)
{
    TempDir dir;
    // A unit cube written as quads, with texture/normal corners, negative (relative) indices,
    // comments and statements that do not change the solid.
    const std::string cube =
        "# cube\nmtllib x.mtl\no cube\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
        "v 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1 1.0\nvt 0 0\nvn 0 0 1\ns off\n"
        "f 1/1 4/1 3/1 2/1\nf 5//1 6//1 7//1 8//1\nf 1/1/1 2/1/1 6/1/1 5/1/1\n"
        "f -6 -5 -1 -2\nf 2 3 7 6\nf 4 1 5 8 # last\n";
    dir.write("cube.obj", cube);
    const PartMesh p = readPartMesh(dir.path / "cube.obj", "cube.obj");
    EXPECT_EQ(p.mesh.triangles.size(), 12u);
    EXPECT_NEAR(std::abs(p.mesh.volume()), 1.0, 1e-6);
    // Hostile files: refused with the line and the reason, never a crash. The first is what
    // fuzz_mesh found making OpenMesh's reader abort on an assertion.
    const std::vector<std::pair<std::string, std::string>> hostile = {
        {"v 1 0 0\nv 0 1 0\nv 0 0 0\nf 1 3 2\nf /2 3 7\n", "5: corrupted OBJ: a face corner must start"},
        {"v 1 0 0\nv 0 1 0\nf 1 2 3\n", "3: corrupted OBJ: a face refers to vertex 3, but 2"},
        {"v 1 0 0\nv 0 1 0\nv 0 0 0\nf 1 2 0\n", "4: corrupted OBJ: a face refers to vertex 0"},
        {"v 1 0 0\nv 0 1 0\nv 0 0 0\nf 1 2 -4\n", "4: corrupted OBJ: a face refers to vertex -4"},
        {"v 1 0\n", "1: corrupted OBJ: a vertex (`v`) needs three numbers x y z; coordinate z is missing"},
        {"v 1 0 nan\n", "1: corrupted OBJ: vertex coordinate z is not a finite number"},
        {"v 1 0 1e300\n", "1: corrupted OBJ: vertex coordinate z is not a finite number"},
        {"v 1 0 0\nv 0 1 0\nf 1 2\n", "3: corrupted OBJ: a face (`f`) needs at least three corners, got 2"},
        {std::string("v 1 0 0\n\0\x02", 10), "corrupted OBJ: OBJ is text"},
        {"# nothing\nvt 0 0\n", "the file holds no triangles"},
    };
    for (std::size_t i = 0; i < hostile.size(); ++i) {
        const std::string name = "hostile" + std::to_string(i) + ".obj";
        dir.write(name, hostile[i].first);
        const std::string error = errorOf([&] { readPartMesh(dir.path / name, name); });
        EXPECT_NE(error.find(name + ":" + (hostile[i].second[0] == 'c' || hostile[i].second[0] == 't' ? " " : "") +
                             hostile[i].second),
                  std::string::npos)
            << i << ": " << error;
    }
}

TEST(MeshReader, CorruptedAndMissingFilesNameTheFile)
{
    TempDir dir;
    writeMesh(cubeMesh(0, 10), (dir.path / "cube.stl").string());
    writeMesh(cubeMesh(0, 10), (dir.path / "cube.obj").string());
    writeMesh(cubeMesh(0, 10), (dir.path / "cube.ply").string());
    for (const char* name : {"cube.stl", "cube.obj", "cube.ply"}) {
        const PartMesh p = readPartMesh(dir.path / name, name);
        EXPECT_EQ(p.mesh.triangles.size(), 12u) << name;
        EXPECT_EQ(p.mesh.points.size(), 8u) << name;
        EXPECT_NEAR(p.mesh.volume(), 1000.0, 1e-6) << name;
    }
    // ASCII STL
    std::string ascii = "solid c\n";
    const TriangleMesh cube = cubeMesh(0, 10);
    for (const auto& t : cube.triangles) {
        ascii += "facet normal 0 0 0\nouter loop\n";
        for (int c = 0; c < 3; ++c) {
            const auto& q = cube.points[t[c]];
            ascii += "vertex " + std::to_string(q[0]) + " " + std::to_string(q[1]) + " " + std::to_string(q[2]) + "\n";
        }
        ascii += "endloop\nendfacet\n";
    }
    dir.write("ascii.stl", ascii + "endsolid c\n");
    EXPECT_EQ(readPartMesh(dir.path / "ascii.stl", "ascii.stl").format, "ASCII STL");
    dir.write("bad-ascii.stl", "solid c\nfacet normal 0 0 0\nouter loop\nvertex 1 2\n");
    EXPECT_NE(errorOf([&] { readPartMesh(dir.path / "bad-ascii.stl", "bad-ascii.stl"); }).find("bad-ascii.stl:4:"),
              std::string::npos);
    // A binary STL cut short.
    const std::string bytes = readFile(dir.path / "cube.stl");
    dir.write("cut.stl", bytes.substr(0, bytes.size() - 30));
    const std::string cut = errorOf([&] { readPartMesh(dir.path / "cut.stl", "cut.stl"); });
    EXPECT_NE(cut.find("cut.stl: corrupted binary STL: the header says 12 triangles"), std::string::npos) << cut;
    EXPECT_NE(errorOf([&] { readPartMesh(dir.path / "none.stl", "none.stl"); }).find("none.stl: no such file"),
              std::string::npos);
    dir.write("junk.3mf", "not a zip");
    EXPECT_NE(errorOf([&] { readPartMesh(dir.path / "junk.3mf", "junk.3mf"); }).find("junk.3mf: corrupted 3MF"),
              std::string::npos);
    dir.write("junk.ply", "ply\nformat nonsense\n");
    EXPECT_NE(errorOf([&] { readPartMesh(dir.path / "junk.ply", "junk.ply"); }).find("junk.ply: corrupted PLY"),
              std::string::npos);
}

TEST(Density, MaskedSolveCountsOnlyInsideTheMask)
{
    const Domain d = Domain::fromBox(Box3{Vec3d(0), Vec3d(20, 16, 12)}, 0.2);
    const auto solid =
        std::make_shared<LevelSolid>(std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(5.3)), SolidSide::Below, 0.0);
    const Sphere mask(Vec3d(9, 8, 6), 5.5);
    const DensitySolution s = solveDensity(*solid->indicator(), d, 0.3, &mask);
    // Brute force over every voxel centre: the same denominator, the same share.
    std::uint64_t den = 0, num = 0;
    for (int i = 0; i < d.dims.x(); ++i)
        for (int j = 0; j < d.dims.y(); ++j)
            for (int k = 0; k < d.dims.z(); ++k) {
                const Vec3d p = d.worldOf(openvdb::Coord(i, j, k));
                if (!(float(mask.value(p)) < 0.0f)) continue;
                ++den;
                num += float(solid->indicator()->value(p)) < s.level;
            }
    EXPECT_EQ(s.domainVoxels, den);
    EXPECT_NEAR(double(num) / double(den), 0.3, 0.001);
    if (!s.coverage) {
        EXPECT_EQ(s.insideVoxels, num);
    }
}

TEST(Infill, AcceptanceRecipeDensityMeasuredIndependently)
{
    // The acceptance recipe as shipped, at a coarser voxel to keep the test short.
    Job job(loadRecipe((sourceDir() / "data/recipes/bracket-infill.yaml").string(), {"voxel=0.2"}));
    job.solveLevels();
    const auto report = job.report();
    EXPECT_EQ(report["domain"]["from"], "result's bounding box plus a margin");
    const double achieved = report["fields"]["gyroid"]["achieved_density"].get<double>();
    EXPECT_NEAR(achieved, 0.25, 0.0025);
    // Independent: quasi-random points of the domain inside the skin; share inside the lattice.
    const FieldPtr part = job.field("part"), lattice = job.field("gyroid");
    const Domain& d = job.domain();
    std::uint64_t space = 0, inside = 0;
    const double phi[3] = {0.8191725134, 0.6710436067, 0.5497004779};  // R3 sequence
    for (int n = 0; n < 1500000; ++n) {
        Vec3d p;
        for (int a = 0; a < 3; ++a) p[a] = d.box.min[a] + std::fmod(0.5 + n * phi[a], 1.0) * d.box.extent()[a];
        if (part->value(p) + 1.0 >= 0.0) continue;
        ++space;
        inside += lattice->value(p) < 0.0;
    }
    ASSERT_GT(space, 100000u);
    EXPECT_NEAR(double(inside) / double(space), 0.25, 0.0025) << "relative error beyond 1 %";
    // The report: part volume, the lattice's density, the solid's volume.
    const auto grid = job.grid();
    (void)grid;
    const auto r = job.report()["infill"]["lattice"];
    EXPECT_NEAR(r["part_volume_mm3"].get<double>(), 6119.4, 1.0);
    EXPECT_NEAR(r["part_volume_grid_mm3"].get<double>(), r["part_volume_mm3"].get<double>(), 61.0);
    EXPECT_EQ(r["lattice_density"].get<double>(), achieved);
}

TEST(Infill, SkinThicknessMeasuredOnTheResult)
{
    TempDir dir;
    writeMesh(cubeMesh(0, 20), (dir.path / "block.stl").string());
    const auto recipe = dir.write("skin.yaml", R"(voxel: 0.1
fields:
  part: {mesh: block.stl}
  g: {tpms: gyroid, cell: 5, solid: sheet}
  lattice: {infill: {part: part, lattice: g, skin: 0.8, density: 0.2, blend: 0.3}}
  wall: {shell: {part: part, thickness: 1.2}}
result: lattice
)");
    for (const auto& [result, thickness] : {std::pair<std::string, double>{"lattice", 0.8}, {"wall", 1.2}}) {
        Job job(loadRecipe(recipe.string(), {"result=" + result}));
        const openvdb::FloatGrid& grid = job.grid();
        openvdb::tools::GridSampler<openvdb::FloatGrid, openvdb::tools::BoxSampler> sampler(grid);
        // Rays down from the top face: the first solid run, its end found by bisection on the grid.
        std::vector<double> runs;
        for (double x = 3.05; x < 17; x += 0.37)
            for (double y = 3.1; y < 17; y += 0.41) {
                auto value = [&](double z) { return sampler.wsSample(openvdb::Vec3d(x, y, z)); };
                double z = 19.9;
                ASSERT_LT(value(z), 0.0);
                while (value(z) < 0.0 && z > 10.0) z -= 0.02;
                double a = z, b = z + 0.02;  // value(a) >= 0 > value(b)
                for (int i = 0; i < 40; ++i) (value(0.5 * (a + b)) >= 0.0 ? a : b) = 0.5 * (a + b);
                // The top face from the same grid.
                double top0 = 19.5, top1 = 20.5;  // value(top0) < 0 <= value(top1)
                for (int i = 0; i < 40; ++i) (value(0.5 * (top0 + top1)) < 0.0 ? top0 : top1) = 0.5 * (top0 + top1);
                runs.push_back(top0 - a);
            }
        std::sort(runs.begin(), runs.end());
        // The skin is never thinner than asked; where no lattice meets it, it is that thick.
        EXPECT_NEAR(runs.front(), thickness, 0.05) << result;
        if (result == "wall")
            EXPECT_NEAR(runs.back(), thickness, 0.05);
        else
            EXPECT_GT(runs.back(), thickness + 0.5);  // lattice joined to the skin somewhere
    }
}

TEST(ConformalFrame, CylinderCellCountsAndPeriods)
{
    const Vec3d cell(2.0, 3.0, 4.0);
    const int around = 12;
    const auto gyroid = std::make_shared<TpmsField>(TpmsType::Gyroid, cell);
    const CoordinateMapField f(gyroid, FrameKind::Cylinder, Vec3d(1, 2, 3), Vec3d(0, 0, 1),
                               Vec3d(1.0, around * cell[1] / (2 * std::numbers::pi), 1.0));
    auto upCrossings = [](const std::function<double(double)>& g, double a, double b, int steps) {
        int count = 0;
        double prev = g(a);
        for (int i = 1; i <= steps; ++i) {
            const double v = g(a + (b - a) * i / steps);
            count += prev < 0 && v >= 0;
            prev = v;
        }
        return count;
    };
    // Around at radius 10 in the plane z = 3 (Z = 0): f = sin X cos Y + sin Y, one period per cell.
    auto around_ = [&](double th) { return f.value(Vec3d(1 + 10 * std::cos(th), 2 + 10 * std::sin(th), 3)); };
    EXPECT_EQ(upCrossings(around_, -std::numbers::pi + 0.013, std::numbers::pi + 0.013, 20000), around);
    // Continuous across the seam at angle pi.
    EXPECT_NEAR(around_(std::numbers::pi - 1e-9), around_(-std::numbers::pi + 1e-9), 1e-6);
    // Radially along angle 0 (Y = 0, Z = 0): f = sin X, a period every cell[0].
    auto radial = [&](double r) { return f.value(Vec3d(1 + r, 2, 3)); };
    EXPECT_EQ(upCrossings(radial, 0.3, 0.3 + 5 * cell[0], 20000), 5);
    // Axially at radius 10 = 5 radial cells (cos X = 1), angle 0: f = sin Z.
    auto axial = [&](double z) { return f.value(Vec3d(11, 2, 3 + z)); };
    EXPECT_EQ(upCrossings(axial, 0.1, 0.1 + 6 * cell[2], 20000), 6);
    // Gradients match finite differences.
    const Vec3d p(4.2, -3.1, 7.7);
    const auto [v, g] = f.valueAndGradient(p);
    for (int a = 0; a < 3; ++a) {
        Vec3d h(0.0);
        h[a] = 1e-6;
        EXPECT_NEAR(g[a], (f.value(p + h) - f.value(p - h)) / 2e-6, 1e-5);
    }
    // Bounds hold on random boxes.
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> u(-15, 15);
    for (int n = 0; n < 300; ++n) {
        const Vec3d c(u(rng), u(rng), u(rng));
        const Box3 box{c, c + Vec3d(0.8)};
        const Interval b = f.bound(box);
        for (int k = 0; k < 8; ++k) {
            const Vec3d q = box.min + Vec3d(k & 1, (k >> 1) & 1, (k >> 2) & 1) * 0.8;
            EXPECT_TRUE(b.contains(f.value(q)));
        }
    }
}

TEST(ConformalFrame, SphereCellsAroundTheEquator)
{
    const Vec3d cell(2.0, 3.0, 4.0);
    const auto gyroid = std::make_shared<TpmsField>(TpmsType::Gyroid, cell);
    const int around = 10, poles = 6;  // even: the equator is at Z = 2 pi * 3 (sin Z = 0)
    const CoordinateMapField f(
        gyroid, FrameKind::Sphere, Vec3d(0.0), Vec3d(0, 0, 1),
        Vec3d(1.0, around * cell[1] / (2 * std::numbers::pi), poles * cell[2] / std::numbers::pi));
    int count = 0;
    double prev = f.value(Vec3d(8.3, 0, 0));
    for (int i = 1; i <= 20000; ++i) {
        const double th = 2 * std::numbers::pi * i / 20000;
        const double v = f.value(Vec3d(8.3 * std::cos(th), 8.3 * std::sin(th), 0));
        count += prev < 0 && v >= 0;
        prev = v;
    }
    EXPECT_EQ(count, around);
}

TEST(Recipe, DomainFromTheResultsBoundsOrAClearError)
{
    TempDir dir;
    const auto ok = dir.write("ball.yaml", R"(voxel: 0.5
fields:
  ball: {sphere: {center: [10, 0, 0], radius: 3}}
  g: {tpms: gyroid, cell: 4, solid: network, density: 0.4, frame: {cylinder: {around: 8}}}
  both: {intersection: [ball, g]}
result: both
)");
    Job job(loadRecipe(ok.string()));
    EXPECT_NEAR(job.domain().box.min[0], 7.0 - 1.5, 1e-9);  // the ball's box less 3 voxels
    EXPECT_NEAR(job.domain().box.max[1], 3.0 + 1.5, 1e-9);
    job.solveLevels();
    EXPECT_NEAR(job.report()["fields"]["g"]["achieved_density"].get<double>(), 0.4, 0.004);
    const auto bare = dir.write("bare.yaml", "voxel: 0.5\nfields:\n  g: {tpms: gyroid, cell: 4}\nresult: g\n");
    const std::string message = errorOf([&] { Job(loadRecipe(bare.string())); });
    EXPECT_NE(message.find("bare.yaml: no `domain:` given and the result `g` is unbounded"), std::string::npos)
        << message;
}

TEST(Cli, BadPartMeshesExitNonZeroAndWriteNothing)
{
    TempDir dir;
    TriangleMesh open = cubeMesh(0, 10);
    open.triangles.pop_back();
    writeMesh(open, (dir.path / "open.stl").string());
    writeMesh(cubeMesh(0, 10), (dir.path / "cube.stl").string());
    const std::string bytes = readFile(dir.path / "cube.stl");
    dir.write("cut.stl", bytes.substr(0, 200));
    const std::string recipe = R"(voxel: 0.25
fields:
  part: {mesh: FILE}
  g: {tpms: gyroid, cell: 4, solid: sheet}
  lattice: {infill: {part: part, lattice: g, skin: 1.0, density: 0.3}}
result: lattice
outputs: {mesh: out.stl}
)";
    for (const auto& [file, expected] :
         {std::pair<std::string, std::string>{"open.stl", "the mesh is open: 3 boundary edges"},
          {"cut.stl", "corrupted binary STL"},
          {"missing.stl", "missing.stl: no such file"}}) {
        std::string text = recipe;
        text.replace(text.find("FILE"), 4, file);
        const auto path = dir.write("r-" + file + ".yaml", text);
        std::string out;
        EXPECT_EQ(
            runCommand(voxlatBinary() + " -q run " + path.string() + " --out " + (dir.path / ("o-" + file)).string(),
                       &out),
            2)
            << out;
        EXPECT_NE(out.find("r-" + file + ".yaml:3:"), std::string::npos) << out;  // recipe line of the mesh node
        EXPECT_NE(out.find(file + ": "), std::string::npos) << out;
        EXPECT_NE(out.find(expected), std::string::npos) << out;
        EXPECT_FALSE(std::filesystem::exists(dir.path / ("o-" + file)));
    }
}

TEST(MeshSdf, BracketDistancesMatchBruteForceAndThreadCount)
{
    // Every active sample against the brute-force nearest triangle, the sign against the part's
    // known geometry, and the same bytes with one thread or many.
    MeshSpaceOptions o;
    o.voxel = 0.25;
    MeshDesignSpace space(readPartMesh(bracket(), "bracket.stl"), "bracket.stl", o);
    const TriangleMesh& mesh = space.mesh();
    auto xform = openvdb::math::Transform::createLinearTransform(0.25);
    xform->postTranslate(Vec3d(0.125));
    const auto grid = meshToSdf(mesh, *xform, 3.0f, 9.0f);
    openvdb::FloatGrid::Ptr single;
    {
        tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        single = meshToSdf(mesh, *xform, 3.0f, 9.0f);
    }
    std::size_t active = 0, checked = 0;
    for (auto it = grid->tree().cbeginValueOn(); it; ++it, ++active) {
        EXPECT_EQ(*it, single->tree().getValue(it.getCoord()));
        if (active % 7 != 0) continue;
        const Vec3d p = xform->indexToWorld(it.getCoord());
        double best = std::numeric_limits<double>::infinity();
        for (const auto& t : mesh.triangles) {
            const Vec3d a = mesh.points[t[0]], b = mesh.points[t[1]], c = mesh.points[t[2]];
            Vec3d uvw;
            best = std::min(best, (openvdb::math::closestPointOnTriangleToPoint(a, b, c, p, uvw) - p).length());
        }
        EXPECT_NEAR(std::abs(*it), best, 1e-5) << p;
        EXPECT_LT(best, (*it < 0 ? 9.0 : 3.0) * 0.25);
        ++checked;
    }
    EXPECT_EQ(single->activeVoxelCount(), grid->activeVoxelCount());
    EXPECT_GT(checked, 5000u);
    // Signs: base plate (z in [0, 5]), upright plate, the crook of the L and a hole.
    auto at = [&](double x, double y, double z) {
        return grid->tree().getValue(xform->worldToIndexCellCentered(Vec3d(x, y, z)));
    };
    EXPECT_LT(at(15, 12, 2.5), 0.0f);
    EXPECT_GT(at(15, 15, 15), 0.0f);
    EXPECT_GT(at(7.5, 16, 2.5), 0.0f);
    EXPECT_FLOAT_EQ(at(15, 12.1, 2.4), -9.0f * 0.25f);  // deeper than the band (2.5 mm from the faces)
}
