// Frame fields and oriented cells: a constant frame against the rigid rotation (`rotate`),
// frames orthonormal and right-handed, exact gradients and frame derivatives against central
// differences, bounds against sampled values, the grid path against the point path, the recipe
// keys (`orient` node, `axes:` on tpms), bad input, and the acceptance recipe's mesh.
#include "FieldChecks.h"
#include "TestUtil.h"
#include "engine/jobs/Job.h"
#include "engine/recipe/ExprNodes.h"
#include "engine/recipe/Recipe.h"
#include "fields/core/Constant.h"
#include "fields/expr/ExprField.h"
#include "fields/expr/Expression.h"
#include "fields/frames/OrientField.h"
#include "fields/shapes/Transform.h"
#include "fields/tpms/TpmsField.h"
#include "mesher/checks/MeshCheck.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <random>

using namespace voxlat;
using namespace voxlat::test;

namespace {

std::shared_ptr<const VectorField> constant(const Vec3d& v)
{
    return std::make_shared<VectorField>(std::array<FieldPtr, 3>{std::make_shared<ConstantField>(v[0]),
                                                                 std::make_shared<ConstantField>(v[1]),
                                                                 std::make_shared<ConstantField>(v[2])});
}

FieldPtr equation(const std::string& text)
{
    return std::make_shared<ExprField>(std::make_shared<const ExprProgram>(ExprProgram::compile(
                                           text, [](const std::string&, bool) { return ExprSymbol{}; })),
                                       std::vector<FieldPtr>{});
}

std::shared_ptr<const VectorField> vectorOf(const std::string& x, const std::string& y, const std::string& z)
{
    return std::make_shared<VectorField>(std::array<FieldPtr, 3>{equation(x), equation(y), equation(z)});
}

/// A helix around the line x = y = 5 (tilted at most atan(7/6) from z inside [0, 10]^3).
std::shared_ptr<const VectorField> swirl()
{
    return vectorOf("-(y - 5)", "x - 5", "6");
}

/// A twist about z: the reference x axis turns by 0.1 rad per mm of height.
std::shared_ptr<const VectorField> twist()
{
    return vectorOf("cos(0.1*z)", "sin(0.1*z)", "0.2*x");
}

const FieldPtr kGyroid = std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(6.0));

std::string numbers(const Vec3d& v)
{
    char buf[128];
    std::snprintf(buf, sizeof buf, "[%.17g, %.17g, %.17g]", v[0], v[1], v[2]);
    return buf;
}

double maxAbs(const Mat3d& m)
{
    double r = 0.0;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) r = std::max(r, std::abs(m(i, j)));
    return r;
}

}  // namespace

TEST(Orient, ConstantFrameIsTheRigidRotation)
{
    // along = A e_z and x = A e_x give R = A: the oriented gyroid is the gyroid rotated by A
    // about the origin o (TransformField with translation o - A o).
    const Mat3d a = TransformField::rotation(Vec3d(1, 2, 3), 37.0);
    const Vec3d o(1.5, -2.0, 4.0);
    auto frame = std::make_shared<const FrameField>(constant(a.col(2) * 3.0), constant(a.col(0) + a.col(2)), "test");
    const OrientField oriented(kGyroid, frame, o);
    const TransformField rotated(kGyroid, a, o - a * o);
    const auto pts = randomPoints(500, -20.0, 20.0, 3);
    std::vector<double> v1(pts.size()), v2(pts.size());
    std::vector<Vec3d> g1(pts.size()), g2(pts.size());
    oriented.gradients(pts, v1, g1);
    rotated.gradients(pts, v2, g2);
    for (std::size_t i = 0; i < pts.size(); ++i) {
        EXPECT_NEAR(v1[i], v2[i], 1e-12);
        EXPECT_NEAR((g1[i] - g2[i]).length(), 0.0, 1e-12);
        EXPECT_NEAR(oriented.value(pts[i]), v2[i], 1e-12);
    }
    // A constant frame is bounded exactly: the same box of rotated points as the rigid rotation.
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(-20.0, 20.0), s(0.1, 6.0);
    for (int t = 0; t < 50; ++t) {
        const Vec3d min(u(rng), u(rng), u(rng));
        const Box3 box{min, min + Vec3d(s(rng), s(rng), s(rng))};
        const Interval b1 = oriented.bound(box), b2 = rotated.bound(box);
        EXPECT_NEAR(b1.lo, b2.lo, 1e-9);
        EXPECT_NEAR(b1.hi, b2.hi, 1e-9);
    }
}

TEST(Orient, RecipeOrientMatchesRotateNode)
{
    const Mat3d a = TransformField::rotation(Vec3d(-1, 0.5, 2), 71.0);
    const std::string text =
        "voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n"
        "  g: {tpms: schwarz-d, cell: 5, level: 0.1}\n"
        "  turned: {rotate: {axis: [-1, 0.5, 2], degrees: 71}, field: g}\n"
        "  oriented: {orient: {along: " +
        numbers(a.col(2)) + ", x: " + numbers(a.col(0)) + "}, field: g}\nresult: oriented\n";
    Job job(parseRecipe(text, "o.yaml", "."));
    const FieldPtr turned = job.field("turned"), oriented = job.field("oriented");
    for (const Vec3d& p : randomPoints(300, -5.0, 15.0, 9))
        EXPECT_NEAR(oriented->value(p), turned->value(p), 1e-12) << p;
    // Same grid, voxel for voxel (the job's own evaluation through the grid path).
    const std::string rotatedText = text.substr(0, text.rfind("result:")) + "result: turned\n";
    Job other(parseRecipe(rotatedText, "r.yaml", "."));
    job.grid();
    other.grid();
    const double voxels = 20.0 * 20.0 * 20.0;  // values agree to 1e-12: at most a voxel on the surface may flip
    EXPECT_NEAR(job.report()["result"]["volume_fraction"].get<double>(),
                other.report()["result"]["volume_fraction"].get<double>(), 1.0 / voxels);
}

TEST(Orient, FramesAreOrthonormalAndFollowTheirDirections)
{
    const FrameField withDefault(swirl(), nullptr, "swirl"), withReference(swirl(), twist(), "swirl+twist");
    const auto pts = randomPoints(400, 0.0, 10.0, 4);
    std::vector<Mat3d> r(pts.size());
    std::vector<Vec3d> z(pts.size()), x(pts.size());
    swirl()->directions(pts, z);
    twist()->directions(pts, x);
    for (const FrameField* f : {&withDefault, &withReference}) {
        f->frames(pts, r);
        for (std::size_t i = 0; i < pts.size(); ++i) {
            EXPECT_LT(maxAbs(r[i].transpose() * r[i] - Mat3d::identity()), 1e-14);
            EXPECT_NEAR(r[i].det(), 1.0, 1e-14);
            EXPECT_LT((r[i].col(2) - z[i].unit()).length(), 1e-15);
            // ex lies in the plane of z and the reference, on the reference's side.
            const Vec3d ref = f == &withDefault ? Vec3d(1, 0, 0) : x[i];
            EXPECT_NEAR(r[i].col(0).dot(z[i].cross(ref)), 0.0, 1e-14);
            EXPECT_GT(r[i].col(0).dot(ref), 0.0);
        }
    }
    // The default reference switches to world y where z is near world x.
    const FrameField nearX(constant(Vec3d(1, 0.1, 0)), nullptr, "near x");
    std::vector<Mat3d> one(1);
    nearX.frames(std::vector<Vec3d>{Vec3d(0.0)}, one);
    EXPECT_NEAR(one[0].col(0).dot(Vec3d(0, 1, 0)), std::sqrt(1.0 - 0.01 / 1.01), 1e-15);
    EXPECT_NEAR(one[0].col(0).dot(Vec3d(1, 0.1, 0)), 0.0, 1e-15);
    // A reference parallel to z falls back to the default.
    const FrameField parallel(constant(Vec3d(0, 0, 2)), constant(Vec3d(0, 0, -1)), "parallel");
    parallel.frames(std::vector<Vec3d>{Vec3d(0.0)}, one);
    EXPECT_LT(maxAbs(one[0] - Mat3d::identity()), 1e-15);
}

TEST(Orient, FrameDerivativesMatchCentralDifferences)
{
    const FrameField frame(swirl(), twist(), "swirl+twist");
    const auto pts = randomPoints(100, 0.0, 10.0, 8);
    std::vector<Mat3d> r(pts.size());
    std::vector<std::array<Mat3d, 3>> dr(pts.size());
    frame.frameDerivatives(pts, r, dr);
    std::vector<Mat3d> plain(pts.size());
    frame.frames(pts, plain);
    const double h = 1e-5;
    for (std::size_t i = 0; i < pts.size(); ++i) {
        EXPECT_LT(maxAbs(r[i] - plain[i]), 1e-15);
        for (int k = 0; k < 3; ++k) {
            std::vector<Vec3d> pm{pts[i], pts[i]};
            pm[0][k] += h;
            pm[1][k] -= h;
            std::vector<Mat3d> f(2);
            frame.frames(pm, f);
            const Mat3d fd = (f[0] - f[1]) * (1.0 / (2 * h));
            EXPECT_LT(maxAbs(dr[i][k] - fd), 1e-6 * (1.0 + maxAbs(fd))) << "axis " << k << " at " << pts[i];
        }
    }
}

TEST(Orient, GradientsMatchCentralDifferences)
{
    const Vec3d o(5, 5, 5);
    const OrientField swirled(kGyroid, std::make_shared<const FrameField>(swirl(), nullptr, "swirl"), o);
    const OrientField twisted(kGyroid, std::make_shared<const FrameField>(swirl(), twist(), "swirl+twist"), o);
    expectGradientsMatchFiniteDifferences(swirled, randomPoints(200, 0.0, 10.0, 11), 1e-6);
    expectGradientsMatchFiniteDifferences(twisted, randomPoints(200, 0.0, 10.0, 12), 1e-6);
}

TEST(Orient, BoundsContainValues)
{
    const Vec3d o(5, 5, 5);
    const OrientField swirled(kGyroid, std::make_shared<const FrameField>(swirl(), nullptr, "swirl"), o);
    const OrientField twisted(kGyroid, std::make_shared<const FrameField>(swirl(), twist(), "swirl+twist"), o);
    // Radial about o: frames cannot be bounded over boxes near o (the ball fallback), and the
    // default reference switches where the direction passes near x.
    const OrientField radial(
        kGyroid, std::make_shared<const FrameField>(vectorOf("x - 5", "y - 5", "z - 5"), nullptr, "radial"), o);
    for (const OrientField* f : {&swirled, &twisted, &radial}) {
        expectBoundsContainValues(*f, 0.0, 10.0, 3.0, 21);
        expectBoundsContainValues(*f, 0.0, 10.0, 0.5, 22);
    }
    // Bounds that cull: over leaf-sized boxes (0.8 mm) of a slowly turning frame, the bound
    // decides the sign of at least a third as many boxes as the rigid rotation by the frame at
    // each box's centre (measured: about half as many).
    const OrientField slow(kGyroid,
                           std::make_shared<const FrameField>(vectorOf("-(y - 5)", "x - 5", "40"),
                                                              vectorOf("cos(0.02*z)", "sin(0.02*z)", "0"), "slow"),
                           o);
    std::mt19937 rng(2);
    std::uniform_real_distribution<double> u(0.0, 9.2);
    int decided = 0, rigidDecided = 0;
    for (int t = 0; t < 400; ++t) {
        const Box3 box{Vec3d(u(rng), u(rng), u(rng)), Vec3d(0.0)};
        const Box3 leaf{box.min, box.min + Vec3d(0.8)};
        const Interval b = slow.bound(leaf);
        decided += b.lo > 0.0 || b.hi < 0.0;
        std::vector<Mat3d> rc(1);
        slow.frame().frames(std::vector<Vec3d>{leaf.center()}, rc);
        const Interval r = TransformField(kGyroid, rc[0], o - rc[0] * o).bound(leaf);
        rigidDecided += r.lo > 0.0 || r.hi < 0.0;
    }
    EXPECT_GT(rigidDecided, 40);
    EXPECT_GE(3 * decided, rigidDecided) << decided << " vs " << rigidDecided;
}

TEST(Orient, FrameBoundsContainFrames)
{
    // Slow and fast turning, a reference, and a direction that crosses the default reference's
    // switch (|ez . x| = 0.9 near y = +-1.6 along this one).
    const FrameField frames[] = {FrameField(swirl(), nullptr, "swirl"), FrameField(swirl(), twist(), "swirl+twist"),
                                 FrameField(vectorOf("1", "0.3*(y - 5)", "0.3*(z - 5)"), nullptr, "near x")};
    std::mt19937 rng(31);
    std::uniform_real_distribution<double> corner(0.0, 10.0), side(0.05, 3.0), t(0.0, 1.0);
    int bounded = 0;
    for (const FrameField& frame : frames)
        for (int trial = 0; trial < 200; ++trial) {
            const Vec3d min(corner(rng), corner(rng), corner(rng));
            const Box3 box{min, min + Vec3d(side(rng), side(rng), side(rng))};
            const std::optional<FrameBound> b = frame.bound(box);
            if (!b) continue;
            ++bounded;
            std::vector<Vec3d> pts(50);
            for (auto& p : pts) p = box.min + Vec3d(t(rng), t(rng), t(rng)) * box.extent();
            std::vector<Mat3d> r(pts.size());
            frame.frames(pts, r);
            for (const Mat3d& m : r)
                for (int row = 0; row < 3; ++row)
                    for (int axis = 0; axis < 3; ++axis) {
                        EXPECT_LE((*b)[row][axis].lo, m(row, axis) + 1e-12);
                        EXPECT_GE((*b)[row][axis].hi, m(row, axis) - 1e-12);
                    }
        }
    EXPECT_GT(bounded, 500);
}

TEST(Orient, GridPathMatchesPointPath)
{
    const OrientField twisted(kGyroid, std::make_shared<const FrameField>(swirl(), twist(), "swirl+twist"), Vec3d(5));
    GridBatch batch;
    batch.origin = Vec3d(1.3, 2.1, 0.7);
    batch.spacing = Vec3d(0.1, 0.12, 0.09);
    std::vector<double> grid(batch.size()), points(batch.size());
    twisted.gridValues(batch, grid);
    std::vector<Vec3d> p;
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j)
            for (int k = 0; k < batch.nz; ++k) p.push_back(batch.point(i, j, k));
    twisted.values(p, points);
    for (std::size_t n = 0; n < p.size(); ++n) EXPECT_NEAR(grid[n], points[n], 1e-12);
}

TEST(Orient, TpmsAxesKeyIsTheOrientNodeWithItsDensitySolved)
{
    const std::string head =
        "voxel: 0.25\ndomain: {box: [[0, 0, 0], [12, 12, 12]]}\nfields:\n"
        "  swirl: {vector: [\"-(y - 6)\", \"x - 6\", 8]}\n";
    Job keyed(parseRecipe(
        head + "  f: {tpms: gyroid, cell: 6, level: 0.2, axes: {along: swirl, origin: [6, 6, 6]}}\n"
               "  g: {orient: {along: swirl, origin: [6, 6, 6]}, field: {tpms: gyroid, cell: 6, level: 0.2}}\n"
               "result: f\n",
        "k.yaml", "."));
    const FieldPtr f = keyed.field("f"), g = keyed.field("g");
    for (const Vec3d& p : randomPoints(200, 0.0, 12.0, 13)) EXPECT_NEAR(f->value(p), g->value(p), 1e-12);
    // With `density:` the level is solved on the oriented cells.
    Job solved(parseRecipe(head +
                               "  f: {tpms: gyroid, cell: 6, density: 0.3, axes: {along: swirl, origin: [6, 6, 6]}}\n"
                               "result: f\n",
                           "d.yaml", "."));
    solved.grid();
    EXPECT_NEAR(solved.report()["result"]["volume_fraction"].get<double>(), 0.3, 0.002);
    // A graded density takes its table from the plain cell (rotated cells have the same one).
    Job graded(parseRecipe(head +
                               "  f: {tpms: gyroid, cell: 6, solid: sheet, axes: {along: swirl, origin: [6, 6, 6]},\n"
                               "      density: {ramp: {axis: z, from: 0.15, to: 0.35}}}\nresult: f\n",
                           "g.yaml", "."));
    graded.grid();
    const double fraction = graded.report()["result"]["volume_fraction"].get<double>();
    EXPECT_NEAR(fraction, 0.25, 0.02);
}

TEST(Orient, BadInputNamesTheLine)
{
    auto errorOf = [](const std::string& fields) -> std::string {
        try {
            Job job(
                parseRecipe("voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n"
                            "  g: {tpms: gyroid, cell: 5}\n  swirl: {vector: [\"-y\", x, 1]}\n" +
                                fields + "result: f\n",
                            "bad.yaml", "."));
            return "";
        } catch (const InputError& e) {
            return e.what();
        }
    };
    auto expectHas = [](const std::string& text, const std::string& part) {
        EXPECT_NE(text.find(part), std::string::npos) << text;
    };
    const std::string zero = errorOf("  f: {orient: {along: [0, 0, 0]}, field: g}\n");
    expectHas(zero, "bad.yaml:6:");
    expectHas(zero, "must not be the zero vector");
    const std::string unknown = errorOf("  f: {orient: {along: swirll}, field: g}\n");
    expectHas(unknown, "bad.yaml:6:");
    expectHas(unknown, "swirl");
    expectHas(errorOf("  f: {orient: {along: [0, 0, 1], x: [0, 0, -2]}, field: g}\n"), "parallel");
    expectHas(errorOf("  f: {orient: {origin: [0, 0, 0]}, field: g}\n"), "`along`");
    expectHas(errorOf("  f: {orient: {alng: swirl}, field: g}\n"), "did you mean `along`");
    expectHas(errorOf("  f: {orient: {along: g}, field: g}\n"), "expected a direction");
    expectHas(errorOf("  f: {tpms: gyroid, cell: 5, axes: {along: [0, 0, 0]}}\n"), "bad.yaml:6:");
}

TEST(Orient, ZeroDirectionAtAPointFailsAndWritesNothing)
{
    const FrameField frame(vectorOf("x - 5", "0", "0"), nullptr, "field `f`");
    std::vector<Mat3d> r(1);
    try {
        frame.frames(std::vector<Vec3d>{Vec3d(5, 1, 2)}, r);
        ADD_FAILURE() << "no error";
    } catch (const std::domain_error& e) {
        EXPECT_NE(std::string(e.what()).find("field `f`: the cells' z direction is zero"), std::string::npos);
        EXPECT_NE(std::string(e.what()).find("(5, 1, 2)"), std::string::npos) << e.what();
    }
    TempDir dir;
    const auto path = dir.write("bad.yaml", R"(voxel: 0.5
domain: {box: [[0, 0, 0], [4, 4, 4]]}
fields:
  f: {tpms: gyroid, cell: 4, axes: {along: {vector: ["x - 2.25", 0, 0]}}}
result: f
outputs: {mesh: out.stl}
)");
    std::string out;
    EXPECT_NE(runCommand(voxlatBinary() + " -q run " + path.string() + " --out " + (dir.path / "out").string(), &out),
              0);
    EXPECT_NE(out.find("the cells' z direction is zero"), std::string::npos) << out;
    EXPECT_FALSE(std::filesystem::exists(dir.path / "out" / "out.stl"));
}

TEST(Orient, AcceptanceRecipeMeshesWatertight)
{
    Job job(loadRecipe((sourceDir() / "data/recipes/gyroid-oriented.yaml").string(), {"voxel=0.4"}));
    const TriangleMesh& mesh = job.mesh();
    ASSERT_GT(mesh.triangles.size(), 1000u);
    const MeshTopology topology = checkTopology(mesh);
    EXPECT_TRUE(topology.closedManifold())
        << topology.boundaryEdges << " boundary, " << topology.nonManifoldEdges << " non-manifold edges";
}
