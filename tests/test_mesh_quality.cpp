// Meshes users can use (issue 16): vertices projected onto the true surface, error-bounded
// decimation, 3MF output. Every distance here is measured with the test's own formulas (a
// sphere's exact distance, the gyroid's equation and gradient written out), not with the code
// under test.

#include "TestUtil.h"
#include "engine/core/SparseEvaluator.h"
#include "engine/jobs/Job.h"
#include "fields/Boolean.h"
#include "fields/BoxField.h"
#include "fields/LevelSolid.h"
#include "fields/TpmsField.h"
#include "mesher/extract/Decimation.h"
#include "mesher/extract/MarchingCubes.h"
#include "mesher/extract/MeshCheck.h"
#include "mesher/extract/SurfaceProjection.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <functional>
#include <numbers>

namespace {

using namespace voxlat;

/// |p - c|^2 - R^2: a sphere whose field is not a distance, so marching cubes' straight-line
/// interpolation misses the surface by a visible share of the voxel.
class SquaredSphere final : public FieldNode {
public:
    SquaredSphere(const Vec3d& c, double r) : mC(c), mR(r) {}
    void values(std::span<const Vec3d> p, std::span<double> out) const override
    {
        for (std::size_t i = 0; i < p.size(); ++i) out[i] = (p[i] - mC).lengthSqr() - mR * mR;
    }
    void gradients(std::span<const Vec3d> p, std::span<double> out, std::span<Vec3d> g) const override
    {
        for (std::size_t i = 0; i < p.size(); ++i) {
            out[i] = (p[i] - mC).lengthSqr() - mR * mR;
            g[i] = 2.0 * (p[i] - mC);
        }
    }
    Interval bound(const Box3& b) const override
    {
        double lo = 0.0, hi = 0.0;
        for (int a = 0; a < 3; ++a) {
            const double below = b.min[a] - mC[a], above = mC[a] - b.max[a];
            const double gap = std::max({0.0, below, above});
            lo += gap * gap;
            hi += std::max((b.min[a] - mC[a]) * (b.min[a] - mC[a]), (b.max[a] - mC[a]) * (b.max[a] - mC[a]));
        }
        return {lo - mR * mR, hi - mR * mR};
    }

private:
    Vec3d mC;
    double mR;
};

/// The test's own gyroid: sin(kx)cos(ky) + sin(ky)cos(kz) + sin(kz)cos(kx), k = 2 pi / cell, and
/// its first-order signed distance (G - c) / |grad G| for the network G < c.
double gyroidDistance(const Vec3d& p, double cell, double c)
{
    const double k = 2.0 * std::numbers::pi / cell;
    const double sx = std::sin(k * p.x()), cx = std::cos(k * p.x()), sy = std::sin(k * p.y()), cy = std::cos(k * p.y()),
                 sz = std::sin(k * p.z()), cz = std::cos(k * p.z());
    const double g = sx * cy + sy * cz + sz * cx;
    const Vec3d grad(k * (cx * cy - sz * sx), k * (cy * cz - sx * sy), k * (cz * cx - sy * sz));
    return (g - c) / grad.length();
}

/// Exact signed distance to an axis-aligned box (the test's own).
double boxDistance(const Vec3d& p, const Box3& b)
{
    Vec3d q;
    for (int a = 0; a < 3; ++a) q[a] = std::abs(p[a] - b.center()[a]) - 0.5 * b.extent()[a];
    const Vec3d outside(std::max(q.x(), 0.0), std::max(q.y(), 0.0), std::max(q.z(), 0.0));
    return outside.length() + std::min(std::max({q.x(), q.y(), q.z()}), 0.0);
}

FieldPtr clipped(FieldPtr f, const Box3& box)
{
    return std::make_shared<BooleanField>(BooleanOp::Intersection,
                                          std::vector<FieldPtr>{f, std::make_shared<BoxField>(box)});
}

TriangleMesh marchingCubesOf(const FieldNode& f, const Domain& d)
{
    SparseOptions options;
    options.clipToDomain = true;
    return marchingCubes(*evaluateSparse(f, d, options), 0.0f);
}

Vec3d at(const TriangleMesh& m, unsigned v)
{
    return {m.points[v].x(), m.points[v].y(), m.points[v].z()};
}

double maxOverVertices(const TriangleMesh& m, const std::function<double(const Vec3d&)>& distance)
{
    double worst = 0.0;
    for (unsigned v = 0; v < m.points.size(); ++v) worst = std::max(worst, std::abs(distance(at(m, v))));
    return worst;
}

/// Largest |distance| over every triangle sampled at spacing @a h (corners, edges, interior).
double maxOverTriangles(const TriangleMesh& m, const std::function<double(const Vec3d&)>& distance, double h)
{
    double worst = 0.0;
    for (const openvdb::Vec3I& t : m.triangles) {
        const Vec3d a = at(m, t[0]), e1 = at(m, t[1]) - a, e2 = at(m, t[2]) - a;
        const int n = std::max(1, int(std::ceil(std::max({e1.length(), e2.length(), (e2 - e1).length()}) / h)));
        for (int i = 0; i <= n; ++i)
            for (int j = 0; i + j <= n; ++j)
                worst = std::max(worst, std::abs(distance(a + (double(i) / n) * e1 + (double(j) / n) * e2)));
    }
    return worst;
}

/// No triangle of @a after turned over against the same triangle of @a before.
std::size_t flippedTriangles(const TriangleMesh& before, const TriangleMesh& after)
{
    std::size_t flipped = 0;
    for (const openvdb::Vec3I& t : before.triangles) {
        const Vec3d n0 = (at(before, t[1]) - at(before, t[0])).cross(at(before, t[2]) - at(before, t[0]));
        const Vec3d n1 = (at(after, t[1]) - at(after, t[0])).cross(at(after, t[2]) - at(after, t[0]));
        flipped += n1.dot(n0) <= 0.0;
    }
    return flipped;
}

void expectClosedManifold(const TriangleMesh& m)
{
    const MeshTopology t = checkTopology(m);
    EXPECT_EQ(t.boundaryEdges, 0u);
    EXPECT_EQ(t.nonManifoldEdges, 0u);
    EXPECT_EQ(t.nonManifoldVertices, 0u);
    EXPECT_EQ(t.inconsistentlyOrientedEdges, 0u);
    EXPECT_EQ(t.degenerateTriangles, 0u);
}

struct GyroidCase {
    double cell = 5.0, level = 0.3, voxel = 0.1;
    Box3 box{Vec3d(0.0), Vec3d(6.0, 5.5, 5.0)};
    FieldPtr field() const
    {
        return clipped(std::make_shared<LevelSolid>(std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(cell)),
                                                    SolidSide::Below, level),
                       box);
    }
    /// The solid is the intersection of the network and the box: its signed distance is about
    /// the larger of the two.
    double distance(const Vec3d& p) const { return std::max(gyroidDistance(p, cell, level), boxDistance(p, box)); }
};

TEST(SurfaceProjection, SphereVerticesWithinOnePercentOfTheVoxel)
{
    const double voxel = 0.2, radius = 3.7;
    const Vec3d centre(5.03, 4.98, 5.01);
    const SquaredSphere sphere(centre, radius);
    const Domain d = Domain::fromBox(Box3{Vec3d(0.0), Vec3d(10.0)}, voxel);
    const TriangleMesh raw = marchingCubesOf(sphere, d);
    auto distance = [&](const Vec3d& p) { return (p - centre).length() - radius; };
    TriangleMesh projected = raw;
    const ProjectionStats stats = projectToSurface(projected, sphere, {0.0, 0.5 * voxel, 1e-6, 12});
    const double rawWorst = maxOverVertices(raw, distance), worst = maxOverVertices(projected, distance);
    RecordProperty("raw_max_vertex_deviation_voxels", std::to_string(rawWorst / voxel));
    RecordProperty("projected_max_vertex_deviation_voxels", std::to_string(worst / voxel));
    EXPECT_LT(worst, 0.01 * voxel);
    EXPECT_LT(worst, 1e-4 * rawWorst + 1e-5);  // in fact down to float rounding
    EXPECT_EQ(stats.vertices, raw.points.size());
    EXPECT_EQ(flippedTriangles(raw, projected), 0u);
    expectClosedManifold(projected);
    // The chords between vertices on the sphere sag by about edge^2 / (8 R): inside the sphere.
    EXPECT_LT(maxOverTriangles(projected, distance, 0.25 * voxel), maxOverTriangles(raw, distance, 0.25 * voxel));
}

TEST(SurfaceProjection, GyroidCutByItsBoxVerticesWithinOnePercentOfTheVoxel)
{
    const GyroidCase g;
    const FieldPtr field = g.field();
    const Domain d = Domain::fromBox(g.box, g.voxel);
    const TriangleMesh raw = marchingCubesOf(*field, d);
    TriangleMesh projected = raw;
    const ProjectionStats stats = projectToSurface(projected, *field, {0.0, 0.5 * g.voxel, 1e-6, 12});
    auto distance = [&](const Vec3d& p) { return g.distance(p); };
    const double rawWorst = maxOverVertices(raw, distance), worst = maxOverVertices(projected, distance);
    RecordProperty("raw_max_vertex_deviation_voxels", std::to_string(rawWorst / g.voxel));
    RecordProperty("projected_max_vertex_deviation_voxels", std::to_string(worst / g.voxel));
    EXPECT_GT(rawWorst, 0.01 * g.voxel);
    EXPECT_LT(worst, 0.01 * g.voxel);
    EXPECT_LT(stats.maxAfter, 0.01 * g.voxel);
    EXPECT_GT(stats.maxBefore, stats.maxAfter);
    EXPECT_EQ(flippedTriangles(raw, projected), 0u);
    expectClosedManifold(projected);
}

TEST(SurfaceProjection, SameBytesForAnyThreadCount)
{
    const GyroidCase g;
    const FieldPtr field = g.field();
    const TriangleMesh raw = marchingCubesOf(*field, Domain::fromBox(g.box, g.voxel));
    auto project = [&](int threads) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        TriangleMesh m = raw;
        projectToSurface(m, *field, {0.0, 0.5 * g.voxel, 1e-6, 12});
        return m.points;
    };
    const auto one = project(1);
    EXPECT_TRUE(one == project(2));
    EXPECT_TRUE(one == project(3));
}

TEST(SurfaceProjection, NoTriangleTurnsOverWhenTheFieldPullsHard)
{
    // A field whose level set is far from where the grid says (the grid made from a sphere of
    // radius 3, projected onto one of radius 3.3): every vertex wants to move 0.3 mm but may move
    // only 0.1; nothing turns over and the mesh stays closed.
    const double voxel = 0.2;
    const SquaredSphere grid(Vec3d(5.0), 3.0), target(Vec3d(5.0), 3.3);
    const TriangleMesh raw = marchingCubesOf(grid, Domain::fromBox(Box3{Vec3d(0.0), Vec3d(10.0)}, voxel));
    TriangleMesh projected = raw;
    const ProjectionStats stats = projectToSurface(projected, target, {0.0, 0.5 * voxel, 1e-6, 12});
    EXPECT_EQ(stats.limited, raw.points.size());
    for (unsigned v = 0; v < raw.points.size(); ++v)
        EXPECT_LE((at(projected, v) - at(raw, v)).length(), 0.5 * voxel + 1e-5);  // + float rounding
    EXPECT_EQ(flippedTriangles(raw, projected), 0u);
    expectClosedManifold(projected);
}

}  // namespace
