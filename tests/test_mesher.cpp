// Tests of the mesher: marching cubes topology and determinism, mesh checks, writers.

#include "TestUtil.h"
#include "mesher/checks/MeshCheck.h"
#include "mesher/extract/BoxVolumes.h"
#include "mesher/extract/MarchingCubes.h"
#include "mesher/writers/AtomicFile.h"
#include "mesher/writers/DirectWrites.h"
#include "mesher/writers/MeshWriters.h"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <sys/mman.h>
#include <sys/vfs.h>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>
#include <unistd.h>
#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>

#include <algorithm>
#include <bit>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>
#include <numbers>
#include <numeric>
#include <random>
#include <string>
#include <vector>

namespace {

using namespace voxlat;
using openvdb::Coord;
using openvdb::Vec3d;
using FloatGrid = openvdb::FloatGrid;

namespace fs = std::filesystem;

using voxlat::test::TempDir;

std::string readBytes(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

/// Every voxel of the 8^3 block at @a origin set to fn(index-space voxel).
template <typename Fn>
void fillLeaf(FloatGrid& grid, const Coord& origin, Fn&& fn)
{
    auto* leaf = grid.tree().touchLeaf(origin);
    for (auto it = leaf->beginValueAll(); it; ++it) it.setValue(float(fn(it.getCoord())));
    leaf->setValuesOn();
}

struct BandGrid {
    FloatGrid::Ptr grid;
    std::size_t insideVoxels = 0;
    std::size_t tiles = 0;
};

/// A Lipschitz-1 field @a fn (index space, in voxels) sampled into leaves wherever some voxel of
/// the leaf is within @a margin voxels of zero, with inside tiles where the whole block is below
/// -margin and background where it is above. Values are stored in world units. A margin just over
/// one voxel is the thinnest band that still honours the mesher's contract, so cubes that poke
/// from a tile into a leaf occur.
template <typename Fn>
BandGrid makeBandGrid(Fn&& fn, const openvdb::CoordBBox& region, double voxelSize, double margin = 1.01)
{
    BandGrid s;
    s.grid = FloatGrid::create(float(3.0 * voxelSize));
    auto xform = openvdb::math::Transform::createLinearTransform(voxelSize);
    xform->postTranslate(Vec3d(12.3, -4.56, 0.789));  // away from the origin, off the voxel lattice
    s.grid->setTransform(xform);
    for (int x = region.min().x() & ~7; x <= region.max().x(); x += 8) {
        for (int y = region.min().y() & ~7; y <= region.max().y(); y += 8) {
            for (int z = region.min().z() & ~7; z <= region.max().z(); z += 8) {
                const Coord origin(x, y, z);
                std::vector<double> values;
                for (auto it = openvdb::CoordBBox::createCube(origin, 8).begin(); it; ++it) values.push_back(fn(*it));
                const auto [lo, hi] = std::minmax_element(values.begin(), values.end());
                if (*lo > margin) continue;
                if (*hi < -margin) {
                    s.grid->tree().addTile(1, origin, float(-3.0 * voxelSize), false);
                    s.insideVoxels += 512;
                    ++s.tiles;
                    continue;
                }
                fillLeaf(*s.grid, origin, [&](const Coord& ijk) { return fn(ijk) * voxelSize; });
            }
        }
    }
    for (auto leaf = s.grid->tree().cbeginLeaf(); leaf; ++leaf) {
        for (auto it = leaf->cbeginValueAll(); it; ++it) s.insideVoxels += *it < 0.0f;
    }
    return s;
}

/// Index-space centre of the test solids: off the lattice so no symmetry hides an error.
const Vec3d kCentre = Vec3d(0.37, -0.21, 0.13) + Vec3d(5.0);

openvdb::CoordBBox regionAround(double reach)
{
    const int r = int(std::ceil(reach)) + 10;
    return openvdb::CoordBBox(Coord(5 - r), Coord(5 + r));
}

BandGrid makeSphere(double radiusVoxels, double voxelSize)
{
    auto sphere = [radiusVoxels](const Coord& ijk) {
        return (Vec3d(ijk.x(), ijk.y(), ijk.z()) - kCentre).length() - radiusVoxels;
    };
    return makeBandGrid(sphere, regionAround(radiusVoxels), voxelSize);
}

/// A gyroid solid capped by a box: max(gyroid, box distance), dense leaves around the box.
FloatGrid::Ptr makeGyroid(int size, double voxelSize, double period)
{
    auto grid = FloatGrid::create(float(voxelSize));
    grid->setTransform(openvdb::math::Transform::createLinearTransform(voxelSize));
    const double k = 2.0 * std::numbers::pi / period;
    const double lo = 2.0 * voxelSize, hi = (size - 3) * voxelSize;  // the box, in world units
    for (int x = 0; x < size; x += 8) {
        for (int y = 0; y < size; y += 8) {
            for (int z = 0; z < size; z += 8) {
                fillLeaf(*grid, Coord(x, y, z), [&](const Coord& ijk) {
                    const Vec3d p = grid->indexToWorld(ijk);
                    const double g =
                        (std::sin(k * p.x()) * std::cos(k * p.y()) + std::sin(k * p.y()) * std::cos(k * p.z()) +
                         std::sin(k * p.z()) * std::cos(k * p.x())) /
                        k;
                    double box = -1e9;
                    for (int i = 0; i < 3; ++i) box = std::max({box, lo - p[i], p[i] - hi});
                    return std::max(g, box);
                });
            }
        }
    }
    return grid;
}

/// Random values in a block of n^3 leaves; the outermost voxel layer is outside so the surface
/// closes inside leaves. Discrete values come from a small set (many exact zeros and exact ties
/// of the face decider); continuous ones are uniform with a quarter exactly at @a iso.
FloatGrid::Ptr makeRandom(unsigned seed, int leavesPerAxis, float iso, bool continuous)
{
    static const float kValues[] = {-2.0f, -1.0f, -0.5f, 0.0f, 0.0f, 0.0f, 0.5f, 1.0f, 2.0f, -0.25f, 0.75f};
    std::mt19937 rng(seed);
    std::uniform_int_distribution<int> pick(0, int(std::size(kValues)) - 1);
    std::uniform_real_distribution<float> uniform(-1.0f, 1.0f);
    const float outside = iso + 3.0f;
    auto grid = FloatGrid::create(outside);
    const int n = 8 * leavesPerAxis;
    for (int x = 0; x < n; x += 8) {
        for (int y = 0; y < n; y += 8) {
            for (int z = 0; z < n; z += 8) grid->tree().touchLeaf(Coord(x, y, z));
        }
    }
    // Fill in a fixed order (not leaf by leaf) so the values depend only on the seed.
    auto acc = grid->getAccessor();
    for (int x = 0; x < n; ++x) {
        for (int y = 0; y < n; ++y) {
            for (int z = 0; z < n; ++z) {
                const bool border = x == 0 || y == 0 || z == 0 || x == n - 1 || y == n - 1 || z == n - 1;
                float v = 0.0f;
                if (!continuous) {
                    v = kValues[pick(rng)];
                } else {
                    v = uniform(rng);
                    v = v > 0.5f ? iso : iso + v;
                }
                acc.setValue(Coord(x, y, z), border ? outside : v);
            }
        }
    }
    return grid;
}

/// Counts the voxel faces (2x2 value squares) whose inside corners lie on one diagonal.
std::size_t countAmbiguousFaces(const FloatGrid& grid, float iso)
{
    std::size_t count = 0;
    auto acc = grid.getConstAccessor();
    const openvdb::CoordBBox box = grid.evalActiveVoxelBoundingBox();
    for (auto it = box.begin(); it; ++it) {
        const Coord p = *it;
        for (int axis = 0; axis < 3; ++axis) {
            static const Coord kU[3] = {Coord(0, 1, 0), Coord(1, 0, 0), Coord(1, 0, 0)};
            static const Coord kV[3] = {Coord(0, 0, 1), Coord(0, 0, 1), Coord(0, 1, 0)};
            const Coord u = kU[axis], v = kV[axis];
            const bool a = acc.getValue(p) < iso, b = acc.getValue(p + u) < iso;
            const bool c = acc.getValue(p + u + v) < iso, d = acc.getValue(p + v) < iso;
            count += a == c && b == d && a != b;
        }
    }
    return count;
}

void expectClosedManifold(const TriangleMesh& mesh, const char* what)
{
    const MeshTopology topo = checkTopology(mesh);
    EXPECT_EQ(topo.boundaryEdges, 0u) << what;
    EXPECT_EQ(topo.nonManifoldEdges, 0u) << what;
    EXPECT_EQ(topo.nonManifoldVertices, 0u) << what;
    EXPECT_EQ(topo.inconsistentlyOrientedEdges, 0u) << what;
    EXPECT_EQ(topo.degenerateTriangles, 0u) << what;
    EXPECT_TRUE(topo.closedManifold()) << what;
    // Closed orientable surfaces have even Euler characteristic.
    EXPECT_EQ(topo.eulerCharacteristic % 2, 0) << what;
}

/// Every vertex is used: no stray points from miscounted offsets.
void expectAllPointsUsed(const TriangleMesh& mesh)
{
    std::vector<bool> used(mesh.points.size(), false);
    for (const auto& t : mesh.triangles) {
        for (int k = 0; k < 3; ++k) {
            ASSERT_LT(t[k], mesh.points.size());
            used[t[k]] = true;
        }
    }
    EXPECT_EQ(std::count(used.begin(), used.end(), false), 0);
}

TriangleMesh meshWithThreads(const FloatGrid& grid, int threads, float iso = 0.0f)
{
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
    tbb::task_arena arena(threads);
    TriangleMesh mesh;
    arena.execute([&] { mesh = marchingCubes(grid, iso); });
    return mesh;
}

class Mesher : public ::testing::Test {
protected:
    static void SetUpTestSuite() { openvdb::initialize(); }
};

TEST_F(Mesher, TableIsConsistent)
{
    const MarchingCubesTableInfo info = marchingCubesTableInfo();  // validates every entry on build
    EXPECT_GT(info.entries, 256u);
    EXPECT_LE(info.maxTriangles, 12u);
    EXPECT_GE(info.loops, info.entries - 2);  // every entry but the two empty cases has a loop
    EXPECT_LT(info.centroidLoops, info.loops);
}

TEST_F(Mesher, SingleInsideCornerTrianglesFaceAway)
{
    auto grid = FloatGrid::create(1.0f);
    fillLeaf(*grid, Coord(0), [](const Coord& ijk) { return ijk == Coord(3, 3, 3) ? -1.0 : 1.0; });
    const TriangleMesh mesh = marchingCubes(*grid);
    // Each of the eight cubes around the voxel has exactly that one corner inside: an octahedron.
    ASSERT_EQ(mesh.triangles.size(), 8u);
    EXPECT_EQ(mesh.points.size(), 6u);
    const Vec3d corner(3.0);
    for (const auto& t : mesh.triangles) {
        const Vec3d a(mesh.points[t[0]]), b(mesh.points[t[1]]), c(mesh.points[t[2]]);
        const Vec3d normal = (b - a).cross(c - a);
        EXPECT_GT(normal.dot((a + b + c) / 3.0 - corner), 0.0);
    }
    const MeshTopology topo = checkTopology(mesh);
    EXPECT_TRUE(topo.closedManifold());
    EXPECT_EQ(topo.eulerCharacteristic, 2);
    EXPECT_GT(mesh.volume(), 0.0);
    // Vertices sit at t = 0.5 on the six edges: an octahedron of "radius" 0.5.
    EXPECT_NEAR(mesh.volume(), 4.0 / 3.0 * 0.125, 1e-6);
}

TEST_F(Mesher, EveryCornerCaseIsClosed)
{
    // Each of the 256 inside/outside patterns of one cube, embedded in outside values, with
    // magnitudes spread over several orders so every feasible combination of ambiguous-face
    // verdicts shows up (the decider compares products of diagonal magnitudes).
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> logMagnitude(-4.0, 4.0);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    auto grid = FloatGrid::create(1.0f);
    for (int cs = 0; cs < 256; ++cs) {
        // Ambiguous faces: inside corners on one diagonal of the face, outside on the other.
        int ambiguousFaces = 0;
        for (int axis = 0; axis < 3; ++axis) {
            const int u = axis == 0 ? 1 : 0, v = axis == 2 ? 1 : 2;
            for (int side = 0; side < 2; ++side) {
                const int c0 = side << axis, c1 = c0 | (1 << u), c2 = c1 | (1 << v), c3 = c0 | (1 << v);
                auto in = [cs](int c) { return (cs >> c) & 1; };
                ambiguousFaces += in(c0) == in(c2) && in(c1) == in(c3) && in(c0) != in(c1);
            }
        }
        for (int trial = 0; trial < (24 << ambiguousFaces); ++trial) {
            fillLeaf(*grid, Coord(0), [&](const Coord& ijk) {
                const Coord d = ijk - Coord(3);
                if (d.x() < 0 || d.y() < 0 || d.z() < 0 || d.x() > 1 || d.y() > 1 || d.z() > 1) return 1.0;
                const int corner = d.x() | (d.y() << 1) | (d.z() << 2);
                const double m = std::exp(logMagnitude(rng));
                if ((cs >> corner) & 1) return -m;
                return unit(rng) < 0.15 ? 0.0 : m;  // exact zeros are outside
            });
            const TriangleMesh mesh = marchingCubes(*grid);
            const MeshTopology topo = checkTopology(mesh);
            ASSERT_TRUE(topo.closedManifold()) << "case " << cs << " trial " << trial;
            ASSERT_EQ(mesh.triangles.empty(), cs == 0);
            if (cs != 0) {
                ASSERT_GT(mesh.volume(), 0.0) << "case " << cs;
            }
        }
    }
}

TEST_F(Mesher, SphereIsClosedAndAccurate)
{
    const double voxel = 0.1, radius = 20.0 * voxel;
    const BandGrid s = makeSphere(20.0, voxel);
    ASSERT_GT(s.tiles, 0u);
    MarchingCubesStats stats;
    int calls = 0;
    double last = 0.0;
    bool increasing = true;
    const TriangleMesh mesh = marchingCubes(
        *s.grid, 0.0f,
        [&](double f) {
            increasing = increasing && f > last;
            last = f;
            ++calls;
        },
        &stats);

    EXPECT_EQ(stats.skippedEdges, 0u);
    EXPECT_EQ(stats.droppedCubes, 0u);
    // The one-voxel band puts cubes with a tile corner on the surface; they must be meshed too.
    EXPECT_GT(stats.tileBlocks, 0u);
    EXPECT_LE(calls, 101);
    EXPECT_TRUE(increasing);
    EXPECT_EQ(last, 1.0);

    const MeshTopology topo = checkTopology(mesh);
    EXPECT_TRUE(topo.closedManifold());
    EXPECT_EQ(topo.boundaryEdges, 0u);
    EXPECT_EQ(topo.nonManifoldEdges, 0u);
    EXPECT_EQ(topo.nonManifoldVertices, 0u);
    EXPECT_EQ(topo.inconsistentlyOrientedEdges, 0u);
    EXPECT_EQ(topo.degenerateTriangles, 0u);
    EXPECT_EQ(topo.eulerCharacteristic, 2);
    expectAllPointsUsed(mesh);

    const double exact = 4.0 / 3.0 * std::numbers::pi * std::pow(radius, 3);
    const double voxels = double(s.insideVoxels) * std::pow(voxel, 3);
    EXPECT_GT(mesh.volume(), 0.0);
    EXPECT_NEAR(mesh.volume(), exact, 0.01 * exact);
    EXPECT_NEAR(mesh.volume(), voxels, 0.01 * voxels);
    EXPECT_NEAR(mesh.area(), 4.0 * std::numbers::pi * radius * radius, 0.01 * 4.0 * std::numbers::pi * radius * radius);

    // Centred where makeSphere put it.
    const openvdb::BBoxd box = mesh.bounds();
    const Vec3d centre = s.grid->indexToWorld(kCentre);
    for (int i = 0; i < 3; ++i) {
        EXPECT_NEAR(box.min()[i], centre[i] - radius, voxel);
        EXPECT_NEAR(box.max()[i], centre[i] + radius, voxel);
    }
}

TEST_F(Mesher, CubesWithTileCornersAreMeshed)
{
    // An octahedron's faces are normal to (1,1,1)/sqrt(3): a tile voxel 1.01..1.73 voxels inside
    // has all face neighbours inside but the far corner of its cube outside. Such a cube's minimum
    // corner is in no leaf, yet it carries surface; losing it would leave holes.
    const double voxel = 0.1, size = 40.0;  // |x| + |y| + |z| <= size, in voxels
    auto octahedron = [size](const Coord& ijk) {
        const Vec3d p = Vec3d(ijk.x(), ijk.y(), ijk.z()) - kCentre;
        return (std::abs(p.x()) + std::abs(p.y()) + std::abs(p.z()) - size) / std::sqrt(3.0);
    };
    const BandGrid s = makeBandGrid(octahedron, regionAround(size), voxel);
    ASSERT_GT(s.tiles, 0u);
    MarchingCubesStats stats;
    const TriangleMesh mesh = marchingCubes(*s.grid, 0.0f, {}, &stats);
    EXPECT_EQ(stats.skippedEdges, 0u);
    EXPECT_EQ(stats.droppedCubes, 0u);
    EXPECT_GT(stats.tileBlockTriangles, 0u);
    expectClosedManifold(mesh, "octahedron");
    EXPECT_EQ(checkTopology(mesh).eulerCharacteristic, 2);
    const double exact = 4.0 / 3.0 * std::pow(size * voxel, 3);
    EXPECT_NEAR(mesh.volume(), exact, 0.01 * exact);
    EXPECT_NEAR(mesh.volume(), double(s.insideVoxels) * std::pow(voxel, 3), 0.01 * exact);
}

TEST_F(Mesher, OpenVdbLevelSetSphereIsClosed)
{
    // OpenVDB's own narrow-band level set: inside filled by signed flood fill, not by our tiles.
    auto grid = openvdb::tools::createLevelSetSphere<FloatGrid>(1.5f, openvdb::Vec3f(0.3f, 0.2f, -0.1f), 0.05f);
    MarchingCubesStats stats;
    const TriangleMesh mesh = marchingCubes(*grid, 0.0f, {}, &stats);
    EXPECT_EQ(stats.skippedEdges, 0u);
    expectClosedManifold(mesh, "level set sphere");
    EXPECT_EQ(checkTopology(mesh).eulerCharacteristic, 2);
    const double exact = 4.0 / 3.0 * std::numbers::pi * 1.5 * 1.5 * 1.5;
    EXPECT_NEAR(mesh.volume(), exact, 0.01 * exact);
}

TEST_F(Mesher, GyroidIsClosedAndThreadCountInvariant)
{
    auto grid = makeGyroid(48, 0.1, 1.6);
    MarchingCubesStats stats;
    const TriangleMesh mesh = marchingCubes(*grid, 0.0f, {}, &stats);
    EXPECT_EQ(stats.skippedEdges, 0u);
    EXPECT_EQ(stats.droppedCubes, 0u);
    ASSERT_GT(mesh.triangles.size(), 10000u);
    expectClosedManifold(mesh, "gyroid");
    expectAllPointsUsed(mesh);
    // A solid gyroid fills about half of the box it is capped by.
    const double box = std::pow((48 - 5) * 0.1, 3);
    EXPECT_GT(mesh.volume(), 0.4 * box);
    EXPECT_LT(mesh.volume(), 0.6 * box);

    // Nonzero iso value: a thicker solid, still closed.
    const TriangleMesh thick = marchingCubes(*grid, 0.05f);
    expectClosedManifold(thick, "gyroid iso 0.05");
    EXPECT_GT(thick.volume(), mesh.volume());

    TempDir dir;
    const TriangleMesh one = meshWithThreads(*grid, 1);
    const TriangleMesh four = meshWithThreads(*grid, 4);
    writeStl(mesh, dir.file("default.stl"));
    writeStl(one, dir.file("one.stl"));
    writeStl(four, dir.file("four.stl"));
    const std::string bytes = readBytes(dir.file("default.stl"));
    EXPECT_EQ(bytes.size(), 84 + 50 * mesh.triangles.size());
    EXPECT_TRUE(bytes == readBytes(dir.file("one.stl")));
    EXPECT_TRUE(bytes == readBytes(dir.file("four.stl")));
}

TEST_F(Mesher, RandomValuesWithTiesAndZerosAreClosed)
{
    std::size_t ambiguous = 0, centroids = 0, meshes = 0;
    for (unsigned seed = 1; seed <= 40; ++seed) {
        for (const bool continuous : {false, true}) {
            for (const float iso : {0.0f, 0.5f}) {
                auto grid = makeRandom(seed, seed % 4 == 0 ? 3 : 2, iso, continuous);
                ambiguous += countAmbiguousFaces(*grid, iso);
                MarchingCubesStats stats;
                const TriangleMesh mesh = marchingCubes(*grid, iso, {}, &stats);
                const std::string what = "seed " + std::to_string(seed) + (continuous ? " continuous" : " discrete") +
                                         " iso " + std::to_string(iso);
                EXPECT_EQ(stats.skippedEdges, 0u) << what;
                EXPECT_EQ(stats.droppedCubes, 0u) << what;
                centroids += stats.centroidVertices;
                expectClosedManifold(mesh, what.c_str());
                expectAllPointsUsed(mesh);
                EXPECT_GT(mesh.volume(), 0.0) << what;
                if (seed <= 2) {
                    const TriangleMesh single = meshWithThreads(*grid, 1, iso);
                    EXPECT_TRUE(single.points == mesh.points) << what;
                    EXPECT_TRUE(single.triangles == mesh.triangles) << what;
                }
                ++meshes;
            }
        }
    }
    // The data must actually exercise the face decider and the centroid fallback.
    EXPECT_GT(ambiguous, 100 * meshes);
    EXPECT_GT(centroids, meshes);
}

TEST_F(Mesher, ContractViolationIsCountedNotFatal)
{
    // An inside tile right next to an outside leaf: the sign changes across the tile's face are
    // owned by tile voxels and have no vertex.
    auto grid = FloatGrid::create(1.0f);
    grid->tree().addTile(1, Coord(-8, 0, 0), -1.0f, true);
    fillLeaf(*grid, Coord(0), [](const Coord&) { return 1.0; });
    MarchingCubesStats stats;
    const TriangleMesh mesh = marchingCubes(*grid, 0.0f, {}, &stats);
    EXPECT_GE(stats.skippedEdges, 64u);
    EXPECT_GT(stats.droppedCubes, 0u);
    for (const auto& t : mesh.triangles) {
        for (int k = 0; k < 3; ++k) EXPECT_LT(t[k], mesh.points.size());
    }
    MarchingCubesStats again;
    const TriangleMesh second = meshWithThreads(*grid, 1);
    marchingCubes(*grid, 0.0f, {}, &again);
    EXPECT_EQ(again.skippedEdges, stats.skippedEdges);
    EXPECT_TRUE(second.triangles == mesh.triangles);
}

TEST_F(Mesher, EmptyGridGivesEmptyMesh)
{
    auto grid = FloatGrid::create(1.0f);
    const TriangleMesh mesh = marchingCubes(*grid);
    EXPECT_TRUE(mesh.empty());
    EXPECT_TRUE(mesh.points.empty());
    EXPECT_EQ(mesh.volume(), 0.0);
}

TEST_F(Mesher, CheckTopologyFindsDefects)
{
    // A tetrahedron: closed, chi = 2, then break it in several ways.
    TriangleMesh tet;
    tet.points = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    tet.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
    MeshTopology topo = checkTopology(tet);
    EXPECT_TRUE(topo.closedManifold());
    EXPECT_EQ(topo.eulerCharacteristic, 2);
    EXPECT_NEAR(tet.volume(), 1.0 / 6.0, 1e-12);

    TriangleMesh open = tet;
    open.triangles.pop_back();
    topo = checkTopology(open);
    EXPECT_EQ(topo.boundaryEdges, 3u);
    EXPECT_FALSE(topo.closedManifold());

    TriangleMesh flipped = tet;
    std::swap(flipped.triangles[3][1], flipped.triangles[3][2]);
    topo = checkTopology(flipped);
    EXPECT_EQ(topo.inconsistentlyOrientedEdges, 3u);
    EXPECT_EQ(topo.boundaryEdges, 0u);

    TriangleMesh degenerate = tet;
    degenerate.triangles.push_back({0, 0, 1});
    degenerate.points.push_back({2, 0, 0});  // collinear with 0 and 1
    degenerate.triangles.push_back({0, 1, 4});
    topo = checkTopology(degenerate);
    EXPECT_EQ(topo.degenerateTriangles, 2u);

    // Two tetrahedra sharing one vertex: every edge fine, the shared vertex is not a single fan.
    TriangleMesh bowtie = tet;
    bowtie.points.insert(bowtie.points.end(), {{-1, 0, 0}, {0, -1, 0}, {0, 0, -1}});
    for (const auto& t : tet.triangles) {
        auto map = [](unsigned i) { return i == 0 ? 0u : i + 3u; };
        bowtie.triangles.push_back({map(t[0]), map(t[2]), map(t[1])});
    }
    topo = checkTopology(bowtie);
    EXPECT_EQ(topo.boundaryEdges, 0u);
    EXPECT_EQ(topo.nonManifoldEdges, 0u);
    EXPECT_EQ(topo.nonManifoldVertices, 1u);
    EXPECT_FALSE(topo.closedManifold());

    // Three triangles on one edge.
    TriangleMesh fin = tet;
    fin.points.push_back({1, 1, 1});
    fin.triangles.push_back({1, 2, 4});
    topo = checkTopology(fin);
    EXPECT_EQ(topo.nonManifoldEdges, 1u);
    EXPECT_GE(topo.nonManifoldVertices, 2u);
}

namespace {

/// checkTopology() by definition, serially: edges in a map, each vertex's fan and link, pieces by
/// a union-find over the triangles.
MeshTopology bruteForceTopology(const TriangleMesh& mesh)
{
    MeshTopology r;
    const std::size_t n = mesh.points.size();
    std::vector<openvdb::Vec3I> valid;
    for (const openvdb::Vec3I& t : mesh.triangles) {
        if (t[0] >= n || t[1] >= n || t[2] >= n || t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) {
            ++r.degenerateTriangles;
            continue;
        }
        const Vec3d a(mesh.points[t[0]]), b(mesh.points[t[1]]), c(mesh.points[t[2]]);
        if ((b - a).cross(c - a) == Vec3d(0.0)) ++r.degenerateTriangles;
        valid.push_back(t);
    }
    // Undirected edge -> the directions its triangles run it in (true: low -> high).
    std::map<std::pair<unsigned, unsigned>, std::vector<bool>> edges;
    std::vector<std::vector<std::size_t>> around(n);
    for (std::size_t i = 0; i < valid.size(); ++i)
        for (int k = 0; k < 3; ++k) {
            const unsigned a = valid[i][k], b = valid[i][(k + 1) % 3];
            edges[std::minmax(a, b)].push_back(a < b);
            around[a].push_back(i);
        }
    std::vector<unsigned> piece(n);
    std::iota(piece.begin(), piece.end(), 0u);
    std::function<unsigned(unsigned)> find = [&](unsigned v) { return piece[v] == v ? v : piece[v] = find(piece[v]); };
    for (const auto& [e, dirs] : edges) {
        r.boundaryEdges += dirs.size() == 1;
        r.nonManifoldEdges += dirs.size() > 2;
        r.inconsistentlyOrientedEdges += dirs.size() == 2 && dirs[0] == dirs[1];
        const unsigned a = find(e.first), b = find(e.second);
        piece[std::max(a, b)] = std::min(a, b);
    }
    std::size_t vertices = 0;
    for (unsigned v = 0; v < n; ++v) {
        if (around[v].empty()) continue;
        ++vertices;
        bool fan = true;
        std::map<unsigned, unsigned> link;  // neighbour -> its root in the link
        for (std::size_t i : around[v])
            for (int k = 0; k < 3; ++k)
                if (valid[i][k] != v) {
                    link[valid[i][k]] = valid[i][k];
                    fan = fan && edges[std::minmax(v, valid[i][k])].size() <= 2;
                }
        std::function<unsigned(unsigned)> root = [&](unsigned w) { return link[w] == w ? w : root(link[w]); };
        std::size_t components = link.size();
        for (std::size_t i : around[v]) {
            std::vector<unsigned> others;
            for (int k = 0; k < 3; ++k)
                if (valid[i][k] != v) others.push_back(valid[i][k]);
            const unsigned a = root(others[0]), b = root(others[1]);
            if (a != b) {
                link[a] = b;
                --components;
            }
        }
        r.nonManifoldVertices += !fan || components != 1;
    }
    r.eulerCharacteristic = int(vertices) - int(edges.size()) + int(valid.size());
    std::map<unsigned, long> chi;
    std::map<unsigned, bool> open;
    for (unsigned v = 0; v < n; ++v)
        if (!around[v].empty()) ++chi[find(v)], open[find(v)] = false;
    for (const auto& [e, dirs] : edges) {
        --chi[find(e.first)];
        if (dirs.size() != 2) open[find(e.first)] = true;
    }
    for (const openvdb::Vec3I& t : valid) ++chi[find(t[0])];
    r.pieces = chi.size();
    for (const auto& [root, c] : chi)
        if (!open[root]) {
            ++r.closedPieces;
            r.genus += int(1 - c / 2);
        }
    return r;
}

void expectSameTopology(const MeshTopology& a, const MeshTopology& b)
{
    EXPECT_EQ(a.boundaryEdges, b.boundaryEdges);
    EXPECT_EQ(a.nonManifoldEdges, b.nonManifoldEdges);
    EXPECT_EQ(a.nonManifoldVertices, b.nonManifoldVertices);
    EXPECT_EQ(a.inconsistentlyOrientedEdges, b.inconsistentlyOrientedEdges);
    EXPECT_EQ(a.degenerateTriangles, b.degenerateTriangles);
    EXPECT_EQ(a.eulerCharacteristic, b.eulerCharacteristic);
    EXPECT_EQ(a.pieces, b.pieces);
    EXPECT_EQ(a.closedPieces, b.closedPieces);
    EXPECT_EQ(a.genus, b.genus);
}

}  // namespace

TEST_F(Mesher, CheckTopologyMatchesABruteForceCheckForAnyThreadCount)
{
    // Closed spheres (one shuffled, so that triangle blocks reach every vertex range), a double
    // cone with a vertex of 40 triangles (past the closed-fan shortcut), then defects: flipped,
    // dropped and repeated triangles, extra triangles on random corners, invalid indices.
    std::mt19937 random(7);
    TriangleMesh mesh = marchingCubes(*makeSphere(3.0, 0.25).grid);
    const TriangleMesh ball = mesh;
    std::vector<unsigned> order(ball.points.size());
    std::iota(order.begin(), order.end(), 0u);
    std::shuffle(order.begin(), order.end(), random);
    for (openvdb::Vec3I t : ball.triangles) {
        const auto base = unsigned(mesh.points.size());
        mesh.triangles.emplace_back(base + order[t[0]], base + order[t[1]], base + order[t[2]]);
    }
    std::vector<openvdb::Vec3f> moved(ball.points.size());
    for (std::size_t v = 0; v < ball.points.size(); ++v) moved[order[v]] = ball.points[v] + openvdb::Vec3f(10.0f);
    mesh.points.insert(mesh.points.end(), moved.begin(), moved.end());
    const auto apex = unsigned(mesh.points.size());
    constexpr unsigned kRim = 40;
    mesh.points.push_back({20.0f, 0.0f, 1.0f});
    mesh.points.push_back({20.0f, 0.0f, -1.0f});
    for (unsigned i = 0; i < kRim; ++i) {
        const double angle = 2.0 * std::numbers::pi * i / kRim;
        mesh.points.push_back({float(20.0 + std::cos(angle)), float(std::sin(angle)), 0.0f});
        const unsigned a = apex + 2 + i, b = apex + 2 + (i + 1) % kRim;
        mesh.triangles.emplace_back(apex, a, b);
        mesh.triangles.emplace_back(apex + 1, b, a);
    }
    auto check = [&](const TriangleMesh& m) {
        const MeshTopology expected = bruteForceTopology(m);
        for (int threads : {1, 2, 3}) {
            tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
            expectSameTopology(checkTopology(m), expected);
        }
        return expected;
    };
    const MeshTopology closed = check(mesh);
    EXPECT_TRUE(closed.closedManifold());
    EXPECT_EQ(closed.pieces, 3u);
    EXPECT_EQ(closed.closedPieces, 3u);
    EXPECT_EQ(closed.eulerCharacteristic, 6);

    for (int trial = 0; trial < 6; ++trial) {
        TriangleMesh broken = mesh;
        std::uniform_int_distribution<std::size_t> pick(0, broken.triangles.size() - 1);
        std::uniform_int_distribution<unsigned> corner(0, unsigned(broken.points.size()) - 1);
        for (int k = 0; k < 3 * trial + 1; ++k) {
            std::swap(broken.triangles[pick(random)][1], broken.triangles[pick(random)][2]);
            broken.triangles.erase(broken.triangles.begin() + std::ptrdiff_t(pick(random)));
            broken.triangles.push_back(broken.triangles[pick(random)]);
            broken.triangles.emplace_back(corner(random), corner(random), corner(random));
        }
        broken.triangles.emplace_back(1u, 1u, 2u);
        broken.triangles.emplace_back(0u, 1u, unsigned(broken.points.size()));
        const MeshTopology t = check(broken);
        EXPECT_FALSE(t.closedManifold());
    }
}

TEST_F(Mesher, StlRoundTrip)
{
    const BandGrid s = makeSphere(12.0, 0.25);
    const TriangleMesh mesh = marchingCubes(*s.grid);
    TempDir dir;
    writeStl(mesh, dir.file("sphere.stl"));
    const std::string bytes = readBytes(dir.file("sphere.stl"));
    ASSERT_EQ(bytes.size(), 84 + 50 * mesh.triangles.size());
    EXPECT_EQ(bytes.substr(0, 80), "voxlat binary STL" + std::string(80 - 17, ' '));

    const TriangleMesh back = readStl(dir.file("sphere.stl"));
    EXPECT_EQ(back.triangles.size(), mesh.triangles.size());
    EXPECT_EQ(back.points.size(), mesh.points.size());  // welding restores the sharing
    EXPECT_NEAR(back.volume(), mesh.volume(), 1e-9 * mesh.volume());
    EXPECT_TRUE(checkTopology(back).closedManifold());
    EXPECT_EQ(dir.entries(), 1u);  // no temporary files left behind

    // ASCII STL of the tetrahedron.
    std::ofstream(dir.file("tet.stl"))
        << "solid t\n"
           "facet normal 0 0 -1\n outer loop\n vertex 0 0 0\n vertex 0 1 0\n vertex 1 0 0\n endloop\nendfacet\n"
           "facet normal 0 -1 0\n outer loop\n vertex 0 0 0\n vertex 1 0 0\n vertex 0 0 1\n endloop\nendfacet\n"
           "facet normal -1 0 0\n outer loop\n vertex 0 0 0\n vertex 0 0 1\n vertex 0 1 0\n endloop\nendfacet\n"
           "facet normal 1 1 1\n outer loop\n vertex 1 0 0\n vertex 0 1 0\n vertex -0 0 1e0\n endloop\nendfacet\n"
           "endsolid t\n";
    const TriangleMesh tet = readStl(dir.file("tet.stl"));
    EXPECT_EQ(tet.points.size(), 4u);
    EXPECT_EQ(tet.triangles.size(), 4u);
    EXPECT_TRUE(checkTopology(tet).closedManifold());
    EXPECT_NEAR(tet.volume(), 1.0 / 6.0, 1e-9);
}

TEST_F(Mesher, AWithdrawnFileOfATransactionIsNeverRenamed)
{
    // A file written ahead of its turn and then withdrawn (a mesh measured as it is written at a
    // level that then moves) leaves no temporary, and only the file written after it reaches its
    // path; the other files of the transaction are untouched.
    TempDir dir;
    const std::string path = dir.file("mesh.stl"), other = dir.file("report.json");
    {
        OutputTransaction transaction;
        auto write = [](const std::string& p, const std::string& bytes) {
            AtomicFile file(p);
            file.stream() << bytes;
            file.commit();
            return file.tempPath();
        };
        const std::string first = write(path, "at the solved level");
        write(other, "report");
        EXPECT_EQ(dir.entries(), 2u);
        transaction.withdraw(path);
        EXPECT_FALSE(fs::exists(first));
        EXPECT_EQ(dir.entries(), 1u);
        write(path, "at the moved level");
        EXPECT_FALSE(fs::exists(path));
        transaction.commit();
    }
    EXPECT_EQ(readBytes(path), "at the moved level");
    EXPECT_EQ(readBytes(other), "report");
    EXPECT_EQ(dir.entries(), 2u);
}

TEST_F(Mesher, AtomicFileLeavesNothingUnlessCommitted)
{
    TempDir dir;
    const std::string path = dir.file("out.bin");
    {
        AtomicFile file(path);
        file.stream() << "partial";
        EXPECT_TRUE(fs::exists(file.tempPath()));
        EXPECT_FALSE(fs::exists(path));
    }
    EXPECT_FALSE(fs::exists(path));
    EXPECT_EQ(dir.entries(), 0u);

    {
        AtomicFile file(path);
        file.stream() << "complete";
        file.commit();
        EXPECT_TRUE(file.committed());
    }
    EXPECT_EQ(readBytes(path), "complete");
    EXPECT_EQ(dir.entries(), 1u);

    // A failed write keeps the old file.
    try {
        AtomicFile file(path);
        file.stream() << "half";
        throw std::runtime_error("writer failed");
    } catch (const std::runtime_error&) {
    }
    EXPECT_EQ(readBytes(path), "complete");
    EXPECT_EQ(dir.entries(), 1u);

    const std::string missing = dir.file("no/such/dir/out.stl");
    try {
        AtomicFile file(missing);
        FAIL() << "opened a file in a missing directory";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find(missing), std::string::npos) << e.what();
    }
}

namespace {

std::string randomBytes(std::size_t n, unsigned seed)
{
    std::mt19937 rng(seed);
    std::string bytes(n, '\0');
    for (char& c : bytes) c = char(rng() & 0xff);
    return bytes;
}

/// Pages of @a path [from, to) in the page cache (mincore of a mapping).
std::size_t residentPages(const std::string& path, std::size_t from, std::size_t to)
{
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    const std::size_t size = std::size_t(fs::file_size(path));
    void* map = ::mmap(nullptr, size, PROT_READ, MAP_SHARED, fd, 0);
    ::close(fd);
    if (map == MAP_FAILED) return 0;
    const std::size_t page = std::size_t(::sysconf(_SC_PAGESIZE));
    std::vector<unsigned char> in((size + page - 1) / page);
    ::mincore(map, size, in.data());
    ::munmap(map, size);
    return std::size_t(std::count_if(in.begin() + std::ptrdiff_t(from / page), in.begin() + std::ptrdiff_t(to / page),
                                     [](unsigned char v) { return (v & 1) != 0; }));
}

}  // namespace

TEST_F(Mesher, ALargeFileGoesPastThePageCacheWithTheSameBytes)
{
    // 27 MB in writes of 1 byte to 3 MB (the streamed STL's 64 KB chunks and more), a header
    // patched by a seek at the end (as the streamed STL's count), then more bytes after it.
    TempDir dir;
    const std::string path = dir.file("big.stl");
    const std::string bytes = randomBytes((std::size_t(27) << 20) + 1234, 7);
    std::mt19937 rng(11);
    {
        AtomicFile file(path);
        std::ostream& out = file.stream();
        for (std::size_t at = 0; at < bytes.size();) {
            const std::size_t n = std::min(bytes.size() - at, std::size_t(1) + rng() % (std::size_t(3) << 20));
            out.write(bytes.data() + at, std::streamsize(n));
            at += n;
        }
        const std::streampos end = out.tellp();
        EXPECT_EQ(std::size_t(end), bytes.size());
        out.seekp(80);
        out.write("PATCH", 5);
        out.seekp(end);
        out.write("tail", 4);
        file.commit();
    }
    // Past the first 8 MB the bytes went past the page cache (looked at before the file is read back), on a file system
    // that takes direct writes (ext4, xfs, btrfs; tmpfs holds every file in the cache).
    struct statfs info {};
    if (::statfs(dir.path.c_str(), &info) == 0 &&
        (info.f_type == 0xEF53 || info.f_type == 0x58465342 || info.f_type == 0x9123683E)) {
        const std::size_t from = std::size_t(9) << 20, to = std::size_t(26) << 20;
        EXPECT_LT(residentPages(path, from, to), (to - from) / std::size_t(::sysconf(_SC_PAGESIZE)) / 4);
        EXPECT_EQ(residentPages(path, 0, std::size_t(4) << 20),
                  (std::size_t(4) << 20) / std::size_t(::sysconf(_SC_PAGESIZE)));
    }
    std::string expected = bytes + "tail";
    expected.replace(80, 5, "PATCH");
    EXPECT_TRUE(readBytes(path) == expected);
}

TEST_F(Mesher, DirectWritesAppendInOrderAndReportAFailedWrite)
{
    TempDir dir;
    const std::string path = dir.file("direct.bin");
    const std::string head = randomBytes(8192, 3), body = randomBytes((std::size_t(9) << 20) + 777, 5);
    {
        const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_CLOEXEC, 0644);
        ASSERT_GE(fd, 0);
        ASSERT_EQ(::write(fd, head.data(), head.size()), ssize_t(head.size()));
        EXPECT_EQ(DirectWrites::open(fd, 100), nullptr);  // not at a block boundary
        std::unique_ptr<DirectWrites> direct = DirectWrites::open(fd, off_t(head.size()));
        ASSERT_NE(direct, nullptr);
        std::mt19937 rng(13);
        for (std::size_t at = 0; at < body.size();) {
            const std::size_t n = std::min(body.size() - at, std::size_t(1) + rng() % 300000);
            direct->append(body.data() + at, n);
            at += n;
        }
        EXPECT_EQ(direct->finish(), 0);
        ::close(fd);
    }
    EXPECT_TRUE(readBytes(path) == head + body);
    // The tail past the last whole block goes through the caller's descriptor: read-only here,
    // so the write fails and finish() says why.
    {
        const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
        ASSERT_GE(fd, 0);
        std::unique_ptr<DirectWrites> direct = DirectWrites::open(fd, 0);
        ASSERT_NE(direct, nullptr);
        direct->append(body.data(), 5000);
        EXPECT_EQ(direct->finish(), EBADF);
        ::close(fd);
    }
}

TEST_F(Mesher, WriteMeshFormats)
{
    const BandGrid s = makeSphere(8.0, 0.5);
    const TriangleMesh mesh = marchingCubes(*s.grid);
    ASSERT_GT(mesh.triangles.size(), 100u);
    TempDir dir;
    for (const std::string name : {"m.ply", "m.obj", "M.STL"}) {
        writeMesh(mesh, dir.file(name));
        OpenMesh::TriMesh_ArrayKernelT<> back;
        OpenMesh::IO::Options options;
        ASSERT_TRUE(OpenMesh::IO::read_mesh(back, dir.file(name), options)) << name;
        EXPECT_EQ(back.n_faces(), mesh.triangles.size()) << name;
        EXPECT_EQ(back.n_vertices(), mesh.points.size()) << name;
    }
    // PLY is binary; STL through writeMesh is the same bytes as writeStl.
    EXPECT_NE(readBytes(dir.file("m.ply")).find("format binary_little_endian"), std::string::npos);
    writeStl(mesh, dir.file("direct.stl"));
    EXPECT_TRUE(readBytes(dir.file("direct.stl")) == readBytes(dir.file("M.STL")));
    EXPECT_EQ(dir.entries(), 4u);

    try {
        writeMesh(mesh, dir.file("m.xyz"));
        FAIL() << "accepted .xyz";
    } catch (const std::invalid_argument& e) {
        const std::string what = e.what();
        EXPECT_NE(what.find(".stl"), std::string::npos);
        EXPECT_NE(what.find(".ply"), std::string::npos);
        EXPECT_NE(what.find(".obj"), std::string::npos);
    }
    EXPECT_EQ(dir.entries(), 4u);
}

}  // namespace

TEST_F(Mesher, StlBytesMatchAFacetByFacetReference)
{
    // More facets than the writer's ring of chunk buffers holds (8 x 16384), with a degenerate
    // triangle; every facet checked byte by byte against a plain little-endian encoding, for one
    // thread and for four.
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> coord(-50.0f, 50.0f);
    TriangleMesh mesh;
    for (int i = 0; i < 60000; ++i) mesh.points.emplace_back(coord(rng), coord(rng), coord(rng));
    std::uniform_int_distribution<std::uint32_t> index(0, 59999);
    for (int i = 0; i < 200000; ++i) mesh.triangles.emplace_back(index(rng), index(rng), index(rng));
    mesh.triangles[1234] = openvdb::Vec3I(5, 5, 5);
    auto le = [](float f) {
        const auto u = std::bit_cast<std::uint32_t>(f);
        return std::string{char(u & 0xFF), char((u >> 8) & 0xFF), char((u >> 16) & 0xFF), char(u >> 24)};
    };
    std::string expected(80, ' ');
    expected.replace(0, 17, "voxlat binary STL");
    const auto count = std::uint32_t(mesh.triangles.size());
    expected +=
        std::string{char(count & 0xFF), char((count >> 8) & 0xFF), char((count >> 16) & 0xFF), char(count >> 24)};
    for (const openvdb::Vec3I& t : mesh.triangles) {
        const openvdb::Vec3d a(mesh.points[t[0]]), b(mesh.points[t[1]]), c(mesh.points[t[2]]);
        openvdb::Vec3d n = (b - a).cross(c - a);
        const double length = n.length();
        n = length > 0.0 ? n / length : openvdb::Vec3d(0.0);
        for (int k = 0; k < 3; ++k) expected += le(float(n[k]));
        for (const openvdb::Vec3I::value_type v : {t[0], t[1], t[2]})
            for (int k = 0; k < 3; ++k) expected += le(mesh.points[v][k]);
        expected += std::string(2, '\0');
    }
    TempDir dir;
    for (const int threads : {1, 4}) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        TriangleMesh::Measures measured;
        writeStl(mesh, dir.file("random.stl"), &measured);
        EXPECT_TRUE(readBytes(dir.file("random.stl")) == expected) << threads << " threads";
        // The writer's volume and area: the same terms as measure(), summed in another order.
        const TriangleMesh::Measures direct = mesh.measure();
        EXPECT_NEAR(measured.volume, direct.volume, 1e-9 * mesh.area());
        EXPECT_NEAR(measured.area, direct.area, 1e-12 * direct.area);
    }
}

TEST_F(Mesher, MeasureMatchesVolumeAndArea)
{
    auto grid = makeGyroid(48, 0.1, 1.6);
    const TriangleMesh mesh = marchingCubes(*grid, 0.0f);
    ASSERT_GT(mesh.triangles.size(), 10000u);
    const TriangleMesh::Measures m = mesh.measure();
    EXPECT_EQ(m.volume, mesh.volume());
    EXPECT_EQ(m.area, mesh.area());
    EXPECT_EQ(TriangleMesh{}.measure().area, 0.0);
}

namespace {

/// writeMarchingCubesStl() at @a path, on @a threads threads.
StreamedMeshCounts streamStl(const FloatGrid& grid, const std::string& path, int threads,
                             TriangleMesh::Measures* measures = nullptr, MarchingCubesStats* stats = nullptr)
{
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
    tbb::task_arena arena(threads);
    StreamedStl made;
    arena.execute([&] { made = writeMarchingCubesStl(grid, 0.0f, path, grid.indexToWorld(Vec3d(0.0)), {}, stats); });
    if (measures) *measures = made.measures;
    return made.counts;
}

}  // namespace

TEST_F(Mesher, StreamedStlHasTheBytesOfTheIndexedMesh)
{
    // Streaming computes every vertex where it is used instead of once by its owner: the file
    // must still be byte for byte writeStl(marchingCubes()), on shapes with inside tiles and
    // tile-block cubes (octahedron), a box-cut gyroid (centroids, ambiguous faces), random values
    // with ties, and a grid whose contract is violated (dropped cubes), on 1 and 2 threads.
    TempDir dir;
    const double size = 40.0;
    auto octahedron = [size](const Coord& ijk) {
        const Vec3d p = Vec3d(ijk.x(), ijk.y(), ijk.z()) - kCentre;
        return (std::abs(p.x()) + std::abs(p.y()) + std::abs(p.z()) - size) / std::sqrt(3.0);
    };
    auto violated = FloatGrid::create(1.0f);
    violated->tree().addTile(1, Coord(-8, 0, 0), -1.0f, true);
    fillLeaf(*violated, Coord(0), [](const Coord& ijk) { return ijk.y() < 4 ? -0.5 : 1.0; });
    const std::vector<std::pair<std::string, FloatGrid::Ptr>> grids{
        {"octahedron", makeBandGrid(octahedron, regionAround(size), 0.1).grid},
        {"sphere", makeSphere(30.3, 0.05).grid},
        {"gyroid", makeGyroid(72, 0.1, 2.3)},
        {"random", makeRandom(7, 3, 0.0f, false)},
        {"violated", violated}};
    std::size_t chunks = 0;
    for (const auto& [name, grid] : grids) {
        MarchingCubesStats indexedStats, streamedStats;
        const TriangleMesh mesh = marchingCubes(*grid, 0.0f, {}, &indexedStats);
        ASSERT_GT(mesh.triangles.size(), 0u) << name;
        TriangleMesh::Measures indexed;
        writeStl(mesh, dir.file(name + ".stl"), &indexed);
        TriangleMesh::Measures streamed;
        const StreamedMeshCounts counts = streamStl(*grid, dir.file(name + "-1.stl"), 1, &streamed, &streamedStats);
        streamStl(*grid, dir.file(name + "-2.stl"), 2);
        EXPECT_EQ(counts.triangles, mesh.triangles.size()) << name;
        EXPECT_EQ(counts.vertices, mesh.points.size()) << name;
        EXPECT_EQ(streamedStats.droppedCubes, indexedStats.droppedCubes) << name;
        EXPECT_EQ(streamedStats.skippedEdges, indexedStats.skippedEdges) << name;
        // The held mesh summed in the streamed chunks: the volume pass's double, bit for bit.
        EXPECT_EQ(streamedStats.chunkTriangleEnds, indexedStats.chunkTriangleEnds) << name;
        ASSERT_FALSE(indexedStats.chunkTriangleEnds.empty()) << name;
        EXPECT_EQ(indexedStats.chunkTriangleEnds.back(), mesh.triangles.size()) << name;
        chunks = std::max(chunks, indexedStats.chunkTriangleEnds.size());
        const Vec3d about = grid->indexToWorld(Vec3d(3.0, -2.0, 1.0));
        EXPECT_EQ(marchingCubesVolume(mesh, indexedStats, about), marchingCubesVolume(*grid, 0.0f, about)) << name;
        const std::string reference = readBytes(dir.file(name + ".stl"));
        EXPECT_TRUE(readBytes(dir.file(name + "-1.stl")) == reference) << name;
        EXPECT_TRUE(readBytes(dir.file(name + "-2.stl")) == reference) << name;
        // The same sums about another point: equal up to rounding (a mesh with holes has no
        // volume that is independent of the point).
        if (indexedStats.droppedCubes != 0) continue;
        EXPECT_NEAR(streamed.volume, indexed.volume, 1e-9 * std::abs(indexed.volume) + 1e-12) << name;
        EXPECT_NEAR(streamed.area, indexed.area, 1e-9 * indexed.area) << name;
    }
    EXPECT_EQ(dir.entries(), 3 * grids.size());  // no temporary left behind
    EXPECT_GT(chunks, 1u);                       // a mesh of several streamed chunks
}

namespace {

/// @a grid with a copy of its leaves and tiles added @a offset voxels away.
FloatGrid::Ptr withCopy(const FloatGrid& grid, const Coord& offset)
{
    FloatGrid::Ptr both = grid.deepCopy();
    for (auto leaf = grid.tree().cbeginLeaf(); leaf; ++leaf) {
        auto* copy = new FloatGrid::TreeType::LeafNodeType(*leaf);
        copy->setOrigin(leaf->origin() + offset);
        both->tree().addLeaf(copy);
    }
    auto tile = grid.tree().cbeginValueAll();
    tile.setMaxDepth(FloatGrid::TreeType::ValueAllCIter::LEAF_DEPTH - 1);  // tiles, not voxels
    for (; tile; ++tile)
        if (*tile != grid.background())
            both->tree().addTile(FloatGrid::TreeType::RootNodeType::LEVEL - tile.getDepth(), tile.getCoord() + offset,
                                 *tile, tile.isValueOn());
    return both;
}

}  // namespace

TEST_F(Mesher, FarApartBlocksMeshAsEachDoesAlone)
{
    // Two copies of a sphere 8192 voxels apart: the blocks' bounding box is nearly all empty, so
    // the mesher finds neighbours by hashing instead of through its dense array (which the other
    // tests use). The mesh is two copies of the sphere's, closed and manifold, and the streamed
    // STL has its bytes.
    TempDir dir;
    const BandGrid sphere = makeSphere(20.3, 0.1);
    ASSERT_GT(sphere.tiles, 0u);
    const FloatGrid::Ptr pair = withCopy(*sphere.grid, Coord(8192, 0, 0));
    const TriangleMesh one = marchingCubes(*sphere.grid, 0.0f);
    const TriangleMesh two = marchingCubes(*pair, 0.0f);
    ASSERT_GT(one.triangles.size(), 1000u);
    EXPECT_EQ(two.triangles.size(), 2 * one.triangles.size());
    EXPECT_EQ(two.points.size(), 2 * one.points.size());
    expectClosedManifold(two, "two spheres");
    EXPECT_NEAR(two.volume(), 2.0 * one.volume(), 1e-6 * one.volume());
    writeStl(two, dir.file("two.stl"));
    streamStl(*pair, dir.file("two-streamed.stl"), 2);
    EXPECT_TRUE(readBytes(dir.file("two-streamed.stl")) == readBytes(dir.file("two.stl")));
}

TEST_F(Mesher, StreamedStlLeavesNothingWhenInterrupted)
{
    // A consumer that fails half-way (a full disk, a cancel): the writer never committed, so the
    // folder holds no file, not even a temporary one.
    TempDir dir;
    const auto grid = makeSphere(40.3, 0.1).grid;  // several chunks
    {
        StlStreamWriter writer(dir.file("s.stl"), Vec3d(0.0));
        TriangleStream stream;
        std::vector<std::vector<char>> bytes(stream.slots);
        stream.format = [&](std::size_t, std::size_t slot, std::span<const TriangleCorners> triangles) {
            writer.format(triangles, bytes[slot]);
        };
        stream.write = [&](std::size_t chunk, std::size_t slot) {
            if (chunk == 1) throw std::runtime_error("disk full");
            writer.write(bytes[slot], {});
        };
        EXPECT_THROW(marchingCubesStreamed(*grid, 0.0f, stream), std::runtime_error);
    }
    EXPECT_EQ(dir.entries(), 0u);
}

TEST(MeshCheck, CoincidentVerticesAreCountedThoughTheMeshIsManifoldByIndex)
{
    // Two tetrahedra apart by index that touch at one point: closed and manifold by index, but
    // read by position (an STL) the point joins them. Every vertex of a group but the first
    // counts; a vertex at -0 and one at +0 are one position.
    TriangleMesh mesh;
    const std::vector<openvdb::Vec3f> a{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    for (const openvdb::Vec3f& p : a) mesh.points.push_back(p);
    for (const openvdb::Vec3f& p : a) mesh.points.push_back(openvdb::Vec3f(-0.0f, -0.0f, 0.0f) - p);
    for (std::uint32_t o : {0u, 4u}) {
        mesh.triangles.emplace_back(o + 0, o + 2, o + 1);
        mesh.triangles.emplace_back(o + 0, o + 1, o + 3);
        mesh.triangles.emplace_back(o + 0, o + 3, o + 2);
        mesh.triangles.emplace_back(o + 1, o + 2, o + 3);
    }
    EXPECT_TRUE(checkTopology(mesh).closedManifold());
    EXPECT_EQ(countCoincidentVertices(mesh), 1u);
    mesh.points[4] = openvdb::Vec3f(2.0f, 2.0f, 2.0f);
    EXPECT_EQ(countCoincidentVertices(mesh), 0u);
}

TEST(BoxVolumes, BoxesThatTileTheGridSumToTheMeshAndTheCountAndEachBoxStandsAlone)
{
    // A gyroid network cut by a ball (closed within the grid's points, with faces the asymptotic
    // decider resolves), on a grid of 0.25 mm voxels off the origin: summed over the boxes of
    // 8^3 cells that tile its points, the boxes' mesh volumes are marchingCubesVolume()'s and
    // their weighted counts the count of the points below zero. A box's two volumes read from
    // a grid that holds only a sample of boxes' points are those read from the whole grid.
    const double h = 0.25;
    const openvdb::math::Transform::Ptr xform = openvdb::math::Transform::createLinearTransform(h);
    xform->postTranslate(Vec3d(1.3, -0.7, 2.1));
    auto field = [](const Coord& c) {
        const Vec3d p = Vec3d(c.x(), c.y(), c.z()) * (2.0 * std::numbers::pi / 13.0);
        const double gyroid =
            std::sin(p.x()) * std::cos(p.y()) + std::sin(p.y()) * std::cos(p.z()) + std::sin(p.z()) * std::cos(p.x());
        const double ball = (Vec3d(c.x(), c.y(), c.z()) - Vec3d(20.0)).length() - 15.2;
        return float(std::max(gyroid - 0.3, ball / 4.0));
    };
    auto fill = [&](FloatGrid& grid, const std::vector<Coord>& boxes) {
        auto acc = grid.getAccessor();
        for (const Coord& o : boxes)
            for (int x = 0; x <= 8; ++x)
                for (int y = 0; y <= 8; ++y)
                    for (int z = 0; z <= 8; ++z) acc.setValue(o.offsetBy(x, y, z), field(o.offsetBy(x, y, z)));
    };
    std::vector<Coord> all, sample;
    for (int x = 0; x < 40; x += 8)
        for (int y = 0; y < 40; y += 8)
            for (int z = 0; z < 40; z += 8) {
                all.emplace_back(x, y, z);
                if ((x / 8 + 2 * (y / 8) + 4 * (z / 8)) % 3 == 0) sample.push_back(all.back());
            }
    const FloatGrid::Ptr whole = FloatGrid::create(1.0f);
    whole->setTransform(xform);
    fill(*whole, all);
    const std::vector<BoxVolumes> boxes = marchingCubesBoxVolumes(*whole, all, 8);
    double mesh = 0.0, voxels = 0.0;
    for (const BoxVolumes& b : boxes) {
        mesh += b.mesh;
        voxels += b.voxels;
    }
    std::uint64_t below = 0;
    for (int x = 0; x <= 40; ++x)
        for (int y = 0; y <= 40; ++y)
            for (int z = 0; z <= 40; ++z) below += field(Coord(x, y, z)) < 0.0f;
    const double volume = marchingCubesVolume(*whole, 0.0f, whole->indexToWorld(Vec3d(20.0)));
    ASSERT_GT(below, 5000u);
    EXPECT_NEAR(voxels, double(below), 1e-9 * double(below));
    // (The mesh's corners are floats, the faces' edge points doubles: a few 1e-8 of the volume.)
    EXPECT_NEAR(mesh * h * h * h, volume, 1e-6 * volume);
    // The mesh and the count differ (by a few tenths of a percent here): what the boxes measure.
    EXPECT_GT(std::abs(mesh - voxels), 1e-4 * voxels);
    const FloatGrid::Ptr part = FloatGrid::create(1.0f);
    part->setTransform(xform);
    fill(*part, sample);
    const std::vector<BoxVolumes> alone = marchingCubesBoxVolumes(*part, sample, 8);
    int crossed = 0;
    for (std::size_t n = 0; n < sample.size(); ++n) {
        const std::size_t at = std::size_t(std::find(all.begin(), all.end(), sample[n]) - all.begin());
        EXPECT_EQ(alone[n].voxels, boxes[at].voxels) << n;
        EXPECT_NEAR(alone[n].mesh, boxes[at].mesh, 1e-9) << n;
        crossed += boxes[at].mesh > 1e-6 && boxes[at].mesh < 512.0 - 1e-6;
    }
    EXPECT_GT(crossed, 10);
}
