// Engine core: sparse evaluation against brute force, determinism, density solve measured
// independently (Monte Carlo on the analytic field and mesh volume).
#include "TestUtil.h"
#include "engine/core/Errors.h"
#include "engine/core/GridMeasure.h"
#include "engine/core/HeldGridField.h"
#include "engine/core/KeptGridLeaves.h"
#include "engine/core/SparseEvaluator.h"
#include "engine/density/DensitySolver.h"
#include "engine/jobs/Job.h"
#include "fields/core/GridValueMemo.h"
#include "fields/levels/LevelSolid.h"
#include "fields/shapes/Boolean.h"
#include "fields/shapes/BoxField.h"
#include "fields/shapes/Sphere.h"
#include "fields/tpms/TpmsField.h"
#include "mesher/checks/MeshCheck.h"
#include "mesher/extract/MarchingCubes.h"
#include "mesher/writers/MeshWriters.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cstdio>
#include <limits>
#include <numbers>
#include <random>

using namespace voxlat;

namespace {

FieldPtr gyroidSolid(SolidSide side, double level, double cell = 10.0)
{
    return std::make_shared<LevelSolid>(std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(cell)), side, level);
}

FieldPtr clipped(FieldPtr f, const Domain& d)
{
    return std::make_shared<BooleanField>(BooleanOp::Intersection,
                                          std::vector<FieldPtr>{f, std::make_shared<BoxField>(d.box)});
}

/// Share of uniformly random points of the domain where the field is negative.
double monteCarloShare(const FieldNode& f, const Domain& d, int samples, unsigned seed)
{
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    int inside = 0;
    for (int n = 0; n < samples; ++n) {
        const Vec3d p = d.box.min + Vec3d(u(rng), u(rng), u(rng)) * d.box.extent();
        inside += f.value(p) < 0;
    }
    return double(inside) / samples;
}

}  // namespace

TEST(Domain, SnapsToWholeVoxels)
{
    const Domain d = Domain::fromBox(Box3{Vec3d(0), Vec3d(50, 10.04, 3)}, 0.1);
    EXPECT_EQ(d.dims, openvdb::Coord(500, 100, 30));
    EXPECT_NEAR(d.box.max[1], 10.0, 1e-12);
    EXPECT_NEAR(d.worldOf(openvdb::Coord(0))[0], 0.05, 1e-12);
    const auto xform = d.transform();
    const Vec3d w = xform->indexToWorld(openvdb::Coord(3, 4, 5));
    EXPECT_TRUE((w - d.worldOf(openvdb::Coord(3, 4, 5))).length() < 1e-12);
}

TEST(Domain, SubDomainKeepsTheVoxelLattice)
{
    const Domain d = Domain::fromBox(Box3{Vec3d(0), Vec3d(10)}, 0.5);
    const Domain s = d.subDomain(Box3{Vec3d(2.1, 0, 3), Vec3d(4.9, 10, 3.3)});
    EXPECT_EQ(s.dims, openvdb::Coord(6, 20, 1));  // centres 2.25..4.75, all, 3.25
    EXPECT_NEAR(s.worldOf(openvdb::Coord(0))[0], 2.25, 1e-12);
    EXPECT_NEAR(s.worldOf(openvdb::Coord(0))[2], 3.25, 1e-12);
    EXPECT_THROW(d.subDomain(Box3{Vec3d(20), Vec3d(30)}), std::invalid_argument);
}

TEST(SparseEvaluator, SignsMatchBruteForceEverywhere)
{
    const Domain d = Domain::fromBox(Box3{Vec3d(-1), Vec3d(12.2, 11, 9)}, 0.2);
    const FieldPtr f = clipped(gyroidSolid(SolidSide::Band, 0.4, 6.0), d);
    SparseStats stats;
    const auto grid = evaluateSparse(*f, d, SparseOptions{}, &stats);
    EXPECT_GT(stats.leaves, 0u);
    auto acc = grid->getConstAccessor();
    std::uint64_t checked = 0;
    for (int i = -1; i <= d.dims.x(); ++i)
        for (int j = -1; j <= d.dims.y(); ++j)
            for (int k = -1; k <= d.dims.z(); ++k) {
                const openvdb::Coord c(i, j, k);
                const double v = f->value(d.worldOf(c));
                const float g = acc.getValue(c);
                ASSERT_EQ(v < 0, g < 0) << c;
                if (acc.probeConstLeaf(c)) {
                    ASSERT_NEAR(g, v, 1e-6 * (1 + std::abs(v)));
                }
                ++checked;
            }
    EXPECT_EQ(checked, std::uint64_t(d.dims.x() + 2) * (d.dims.y() + 2) * (d.dims.z() + 2));
}

namespace {

/// A ball whose value is @a bad within 0.25 mm of @a at: what a recipe's equation can make
/// (sqrt of a negative, a division by zero). Bounds say nothing, so every leaf is evaluated.
class BrokenBall final : public FieldNode {
public:
    BrokenBall(double bad, const Vec3d& at) : mBad(bad), mAt(at) {}
    void values(std::span<const Vec3d> points, std::span<double> out) const override
    {
        for (std::size_t n = 0; n < points.size(); ++n)
            out[n] = (points[n] - mAt).length() < 0.25 ? mBad : (points[n] - Vec3d(5.0)).length() - 3.0;
    }
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override
    {
        values(points, out);
        for (Vec3d& g : grad) g = Vec3d(0.0);
    }
    Interval bound(const Box3&) const override { return Interval(-1e300, 1e300); }

private:
    double mBad;
    Vec3d mAt;
};

}  // namespace

TEST(SparseEvaluator, NonFiniteValuesAreAnErrorNamingThePoint)
{
    // NaN, +inf and -inf anywhere in one leaf, on 1 and 2 threads: a JobError that names a point
    // where it happened (within the 0.25 mm ball) and says what to check.
    const Domain d = Domain::fromBox(Box3{Vec3d(0), Vec3d(10)}, 0.1);
    const Vec3d at(7.31, 2.47, 5.02);
    for (const double bad : {std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity(),
                             -std::numeric_limits<double>::infinity()}) {
        for (const int threads : {1, 2}) {
            tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
            try {
                evaluateSparse(BrokenBall(bad, at), d, SparseOptions{});
                FAIL() << "no error for " << bad;
            } catch (const JobError& e) {
                const std::string message = e.what();
                EXPECT_NE(message.find("not finite"), std::string::npos) << message;
                EXPECT_NE(message.find("check divisions"), std::string::npos) << message;
                double x = 0, y = 0, z = 0;
                ASSERT_EQ(std::sscanf(message.c_str() + message.find("at (") + 4, "%lf, %lf, %lf", &x, &y, &z), 3)
                    << message;
                EXPECT_LT((Vec3d(x, y, z) - at).length(), 0.25 + 1e-9) << message;
            }
        }
        // A finite field of the same shape evaluates.
        EXPECT_NO_THROW(evaluateSparse(BrokenBall(1.0, at), d, SparseOptions{}));
    }
}

TEST(SparseEvaluator, CountsTheDomainsInsideVoxelsAsItEvaluates)
{
    // The count made while leaves are evaluated equals a brute-force count of the domain's voxel
    // centres below zero, with leaves cut by the domain's faces, inside leaf tiles and 128^3
    // inside tiles (a sphere large enough to hold one) all present.
    const Domain d = Domain::fromBox(Box3{Vec3d(-1), Vec3d(12.3, 11.1, 9.7)}, 0.2);
    const Domain big = Domain::fromBox(Box3{Vec3d(-40.0), Vec3d(40.1)}, 0.2);  // a 128^3 tile inside
    const std::vector<std::pair<FieldPtr, Domain>> cases{
        {clipped(gyroidSolid(SolidSide::Band, 0.4, 6.0), d), d},
        {clipped(gyroidSolid(SolidSide::Below, 0.3, 6.0), d), d},
        {clipped(std::make_shared<Sphere>(Vec3d(0.31), 38.03), big), big}};  // no centre exactly on it
    for (const auto& [f, dom] : cases) {
        SparseStats stats;
        const auto grid = evaluateSparse(*f, dom, SparseOptions{}, &stats);
        std::uint64_t brute = 0;
        for (int i = 0; i < dom.dims.x(); ++i)
            for (int j = 0; j < dom.dims.y(); ++j)
                for (int k = 0; k < dom.dims.z(); ++k) brute += f->value(dom.worldOf(openvdb::Coord(i, j, k))) < 0;
        EXPECT_EQ(stats.domainVoxelsBelowZero, brute);
        EXPECT_EQ(stats.domainVoxelsBelowZero, countBelow(*grid, dom.indexBox(), 0.0f));
    }
    bool blockTile = false;  // the sphere's grid holds a whole 128^3 inside tile
    const auto sphereGrid = evaluateSparse(*cases[2].first, big, SparseOptions{});
    for (auto it = sphereGrid->cbeginValueOn(); it; ++it) blockTile |= it.getLevel() == 2;
    EXPECT_TRUE(blockTile);
}

TEST(SparseEvaluator, WorkFollowsTheSurface)
{
    // A sphere in a large domain: evaluated leaves scale with the surface, inside becomes tiles.
    const Domain d = Domain::fromBox(Box3{Vec3d(-20), Vec3d(20)}, 0.1);
    const auto sphere = std::make_shared<Sphere>(Vec3d(0), 15.0);
    SparseStats stats;
    const auto grid = evaluateSparse(*clipped(sphere, d), d, SparseOptions{}, &stats);
    const double surfaceLeaves = 4 * std::numbers::pi * 15 * 15 / (0.8 * 0.8);
    const double allLeaves = double(d.voxelCount()) / 512;
    EXPECT_LT(double(stats.leaves), 3.0 * surfaceLeaves);
    EXPECT_LT(double(stats.leaves), 0.15 * allLeaves);
    EXPECT_GT(stats.insideTiles, 0u);
    const double volume = double(countBelow(*grid, d.indexBox(), 0.0f)) * 1e-3;
    EXPECT_NEAR(volume, 4.0 / 3.0 * std::numbers::pi * 15 * 15 * 15, 0.002 * 14137.0);
}

TEST(SparseEvaluator, RefusesJobsThatDoNotFitInMemory)
{
    const Domain d = Domain::fromBox(Box3{Vec3d(0), Vec3d(20)}, 0.05);
    SparseOptions options;
    options.maxLeaves = 100;
    try {
        evaluateSparse(*gyroidSolid(SolidSide::Below, 0.0, 5.0), d, options);
        FAIL() << "expected a JobError";
    } catch (const JobError& e) {
        EXPECT_NE(std::string(e.what()).find("raise `voxel:`"), std::string::npos) << e.what();
    }
}

TEST(SparseEvaluator, StacksAsTallAsTheDomainsHeightRepays)
{
    auto height = [](int nz) {
        Domain d;
        d.dims = openvdb::Coord(16, 16, nz);
        return d;
    };
    // The frames the stacks serve: W2g's 50 mm at 0.1 mm, a 40 mm cube, a 2 mm plate at 0.05 mm,
    // report.html's coarse grid of that plate (four voxels deep).
    EXPECT_EQ(stackLeavesFor(height(500), 16), 16);
    EXPECT_EQ(stackLeavesFor(height(400), 16), 8);
    EXPECT_EQ(stackLeavesFor(height(40), 16), 8);
    EXPECT_EQ(stackLeavesFor(height(4), 16), 1);
    EXPECT_EQ(stackLeavesFor(height(500), 8), 8);
    EXPECT_EQ(stackLeavesFor(height(500), 1), 1);
    // Every height and cap: a power of two within the cap, and no allowed height costs less
    // (the voxels along z its stacks cover, times 1 + 1/s), counted here stack by stack.
    for (const int most : {1, 2, 4, 8, 16})
        for (int nz = 1; nz <= 700; ++nz) {
            const int s = stackLeavesFor(height(nz), most);
            ASSERT_TRUE(s >= 1 && s <= most && (s & (s - 1)) == 0) << nz << " " << most << ": " << s;
            auto cost = [nz](int t) {
                int covered = 0;
                while (covered < nz) covered += 8 * t;
                return covered * (1.0 + 1.0 / t);
            };
            for (int t = 1; t <= most; t *= 2)
                ASSERT_LE(cost(s), cost(t)) << nz << " " << most << ": " << s << " " << t;
        }
}

TEST(SparseEvaluator, IdenticalForAnyThreadCount)
{
    const Domain d = Domain::fromBox(Box3{Vec3d(0), Vec3d(16, 16, 12)}, 0.1);
    const FieldPtr f = clipped(gyroidSolid(SolidSide::Below, 0.2, 7.0), d);
    auto run = [&](int threads) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        return marchingCubes(*evaluateSparse(*f, d, SparseOptions{}), 0.0f);
    };
    const TriangleMesh one = run(1), many = run(4);
    ASSERT_EQ(one.points.size(), many.points.size());
    ASSERT_EQ(one.triangles.size(), many.triangles.size());
    EXPECT_TRUE(std::equal(one.points.begin(), one.points.end(), many.points.begin()));
    EXPECT_TRUE(std::equal(one.triangles.begin(), one.triangles.end(), many.triangles.begin()));
}

TEST(Density, GyroidAtLevelZeroFillsHalf)
{
    const Domain d = Domain::fromBox(Box3{Vec3d(0), Vec3d(20)}, 0.1);
    const auto grid = evaluateSparse(*clipped(gyroidSolid(SolidSide::Below, 0.0), d), d, SparseOptions{});
    const double share = double(countBelow(*grid, d.indexBox(), 0.0f)) / double(d.voxelCount());
    EXPECT_NEAR(share, 0.5, 0.005);
    EXPECT_NEAR(monteCarloShare(*gyroidSolid(SolidSide::Below, 0.0), d, 400000, 1), 0.5, 0.005);
}

TEST(Density, SolveHitsTargetMeasuredIndependently)
{
    // Odd domain (not whole cells) so the target is not met by symmetry alone.
    const Domain d = Domain::fromBox(Box3{Vec3d(0), Vec3d(23, 17, 19)}, 0.1);
    struct Case {
        SolidSide side;
        double target;
    };
    for (const Case c : {Case{SolidSide::Below, 0.30}, Case{SolidSide::Band, 0.20}, Case{SolidSide::Below, 0.12}}) {
        auto solid = LevelSolid::unsolved(std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(10)), c.side);
        const DensitySolution s = solveDensity(*solid->indicator(), d, c.target);
        solid->solve(solid->levelFromIndicator(s.level));
        EXPECT_NEAR(s.achieved, c.target, 0.005 * c.target);
        // Independent 1: Monte Carlo over the analytic field (3 sigma ~ 0.25 % relative).
        const double mc = monteCarloShare(*solid, d, 2'000'000, 7);
        EXPECT_NEAR(mc, c.target, 0.005 * c.target) << "monte carlo";
        // Independent 2: the enclosed volume of the capped mesh.
        const auto grid = evaluateSparse(*clipped(solid, d), d, SparseOptions{});
        const TriangleMesh mesh = marchingCubes(*grid, 0.0f);
        const double domainVolume = d.box.extent()[0] * d.box.extent()[1] * d.box.extent()[2];
        EXPECT_NEAR(mesh.volume() / domainVolume, c.target, 0.005 * c.target) << "mesh volume";
    }
}

namespace {
/// The share of the domain the marching-cubes mesh of @a solid encloses.
double meshedShare(const std::shared_ptr<LevelSolid>& solid, const Domain& d)
{
    const TriangleMesh mesh = marchingCubes(*evaluateSparse(*clipped(solid, d), d, SparseOptions{}), 0.0f);
    const Vec3d e = d.box.extent();
    return mesh.volume() / (e[0] * e[1] * e[2]);
}
}  // namespace

TEST(Density, ValueTiesFallBackToSubVoxelCoverage)
{
    // Whole cells on a coarse symmetric grid: gyroid symmetries repeat every value many times,
    // so counting voxel centres cannot land near 30 %; the coverage measure must.
    const Domain d = Domain::fromBox(Box3{Vec3d(0), Vec3d(12)}, 0.25);
    auto solid = LevelSolid::unsolved(std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(6)), SolidSide::Below);
    const DensitySolution s = solveDensity(*solid->indicator(), d, 0.30);
    EXPECT_TRUE(s.coverage);
    EXPECT_NEAR(s.achieved, 0.30, 0.0015);
    solid->solve(s.level);
    // Independent: the volume of the part that is actually meshed (at 24 voxels a cell the
    // voxelised part differs from the analytic one by ~2 %, so Monte Carlo is not the reference).
    // The coverage measure and marching cubes differ by about 2 % here; a job aims the level at
    // the mesh (Job::aimLevelsAtMesh): one step along the solve's slope brings the mesh to 0.5 %.
    const double share = meshedShare(solid, d);
    EXPECT_NEAR(share, 0.30, 0.03 * 0.30);
    ASSERT_GT(s.slope, 0.0);
    solid->correct(s.level + (0.30 - share) / s.slope);
    EXPECT_NEAR(meshedShare(solid, d), 0.30, 0.0015);
}

TEST(Mesh, InvariantsOnSeveralFieldsAndDomains)
{
    struct Case {
        FieldPtr field;
        Box3 box;
        double voxel;
    };
    const auto sphere = std::make_shared<Sphere>(Vec3d(5, 5, 5), 4.0);
    const auto gyroid = gyroidSolid(SolidSide::Band, 0.3, 4.0);
    const std::vector<Case> cases{
        {gyroidSolid(SolidSide::Below, 0.0, 5.0), Box3{Vec3d(0), Vec3d(10)}, 0.1},
        {gyroid, Box3{Vec3d(-3.3), Vec3d(7, 6.1, 5)}, 0.13},
        {std::make_shared<BooleanField>(BooleanOp::Difference, std::vector<FieldPtr>{sphere, gyroid}),
         Box3{Vec3d(0), Vec3d(10)}, 0.1},  // sphere cut by a sheet, wholly inside the domain
        {std::make_shared<BooleanField>(BooleanOp::Union, std::vector<FieldPtr>{sphere, gyroid}, 0.5),
         Box3{Vec3d(2), Vec3d(9, 8, 11)}, 0.15},
        {std::make_shared<LevelSolid>(std::make_shared<TpmsField>(TpmsType::IWP, Vec3d(6)), SolidSide::Below, 0.5),
         Box3{Vec3d(0), Vec3d(12)}, 0.2},
    };
    for (std::size_t n = 0; n < cases.size(); ++n) {
        SCOPED_TRACE("case " + std::to_string(n));
        const Domain d = Domain::fromBox(cases[n].box, cases[n].voxel);
        const auto grid = evaluateSparse(*clipped(cases[n].field, d), d, SparseOptions{});
        MarchingCubesStats stats;
        const TriangleMesh mesh = marchingCubes(*grid, 0.0f, {}, &stats);
        ASSERT_GT(mesh.triangles.size(), 100u);
        EXPECT_EQ(stats.skippedEdges, 0u);
        const MeshTopology t = checkTopology(mesh);
        EXPECT_EQ(t.boundaryEdges, 0u);
        EXPECT_EQ(t.nonManifoldEdges, 0u);
        EXPECT_EQ(t.nonManifoldVertices, 0u);
        EXPECT_EQ(t.inconsistentlyOrientedEdges, 0u);
        EXPECT_EQ(t.degenerateTriangles, 0u);
        const double gridVolume = double(countBelow(*grid, d.indexBox(), 0.0f)) * std::pow(d.voxel, 3);
        EXPECT_NEAR(mesh.volume(), gridVolume, 0.01 * gridVolume);
    }
}

TEST(Density, ASolidIsSolvedOnceAndNeverUsedBefore)
{
    // Build -> solve -> evaluate: the order is enforced, so a node is immutable once it can be read.
    auto solid = LevelSolid::unsolved(std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(6)), SolidSide::Below);
    std::vector<Vec3d> p{Vec3d(1, 2, 3)};
    std::vector<double> v(1);
    EXPECT_FALSE(solid->isSolved());
    EXPECT_THROW(solid->values(p, v), std::logic_error);
    EXPECT_THROW(solid->bound(Box3{Vec3d(0), Vec3d(1)}), std::logic_error);
    EXPECT_THROW((void)solid->level(), std::logic_error);
    solid->solve(0.25);
    solid->values(p, v);
    const TpmsField raw(TpmsType::Gyroid, Vec3d(6));
    EXPECT_DOUBLE_EQ(v[0], raw.value(p[0]) - 0.25);
    EXPECT_THROW(solid->solve(0.3), std::logic_error);
    EXPECT_DOUBLE_EQ(solid->level(), 0.25);
    // A solid made at a level is immutable from the start.
    LevelSolid fixed(std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(6)), SolidSide::Below, 0.1);
    EXPECT_THROW(fixed.solve(0.2), std::logic_error);
}

TEST(Job, AnEstimatedVolumeStatesItsStandardError)
{
    // `voxlat info` above its voxel budget: the volume estimated from random points, one per cell
    // (report.json's `result.estimated`), checked against the sphere's analytic volume and its
    // stated standard error; the same points give the same estimate again.
    const std::string text =
        "voxel: 0.05\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n"
        "  s: {sphere: {radius: 4, center: [5, 5, 5]}}\nresult: s\n";
    voxlat::Job job(voxlat::parseRecipe(text, "r.yaml", "."));
    ASSERT_TRUE(job.measureVolume(std::uint64_t(1) << 18));  // 8e6 voxels over a budget of 2.6e5
    const nlohmann::json report = job.report();
    const nlohmann::json& r = report["result"];
    const nlohmann::json& e = r["estimated"];
    const double sphere = 4.0 / 3.0 * std::numbers::pi * 64.0;
    const double error = e["standard_error_mm3"].get<double>(), points = e["points"].get<double>();
    EXPECT_NEAR(points, double(1 << 14), 0.1 * double(1 << 14));
    EXPECT_GT(error, 0.0);
    // One point per cell: far below the error of as many independent points (only the cells the
    // sphere's surface crosses vary), and the estimate within four of its standard errors.
    const double p = sphere / 1000.0;
    EXPECT_LT(error, 0.7 * std::sqrt(p * (1.0 - p) / points) * 1000.0);
    EXPECT_NEAR(r["volume_mm3"].get<double>(), sphere, 4.0 * error);
    voxlat::Job again(voxlat::parseRecipe(text, "r.yaml", "."));
    ASSERT_TRUE(again.measureVolume(std::uint64_t(1) << 18));
    EXPECT_EQ(again.report()["result"]["volume_mm3"].get<double>(), r["volume_mm3"].get<double>());
    // The exact count (no budget) has no estimate.
    voxlat::Job exact(voxlat::parseRecipe(text, "r.yaml", "."));
    EXPECT_FALSE(exact.measureVolume(std::numeric_limits<std::uint64_t>::max()));
    const nlohmann::json counted = exact.report();
    EXPECT_FALSE(counted["result"].contains("estimated"));
    EXPECT_NEAR(counted["result"]["volume_mm3"].get<double>(), sphere, 0.002 * sphere);
}

namespace {

/// f(p) = a . p + c, for tests whose reference is linear.
class LinearTestField final : public FieldNode {
public:
    LinearTestField(const Vec3d& a, double c) : mA(a), mC(c) {}
    double at(const Vec3d& p) const { return mA.dot(p) + mC; }
    void values(std::span<const Vec3d> points, std::span<double> out) const override
    {
        for (std::size_t n = 0; n < points.size(); ++n) out[n] = at(points[n]);
    }
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override
    {
        values(points, out);
        for (Vec3d& g : grad) g = mA;
    }
    Interval bound(const Box3& box) const override
    {
        double lo = mC, hi = mC;
        for (int a = 0; a < 3; ++a) {
            lo += std::min(mA[a] * box.min[a], mA[a] * box.max[a]);
            hi += std::max(mA[a] * box.min[a], mA[a] * box.max[a]);
        }
        return {lo, hi};
    }

private:
    Vec3d mA;
    double mC;
};

}  // namespace

TEST(HeldGridField, TrilinearWithinLeavesTheFieldElsewhereAndMeetsFromHeldVoxels)
{
    // A grid holding a linear field's values in the leaves of a 24 x 24 x 16 voxel block (0.1 mm
    // voxels, centres at (i + 1/2) 0.1): trilinear reproduces a linear field, so every point whose
    // eight voxels lie in leaves reads it (to the floats' rounding); every other point reads the
    // operand, here the same plane 100 higher, so which one answered shows.
    const LinearTestField held(Vec3d(0.3, -0.2, 0.7), 0.1);
    const auto operand = std::make_shared<LinearTestField>(Vec3d(0.3, -0.2, 0.7), 100.1);
    auto grid = openvdb::FloatGrid::create(1.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(0.1));
    grid->transform().postTranslate(openvdb::Vec3d(0.05));
    const openvdb::CoordBBox filled(openvdb::Coord(0), openvdb::Coord(23, 23, 15));
    {
        auto acc = grid->getAccessor();
        for (auto ijk = filled.begin(); ijk; ++ijk) {
            const openvdb::Vec3d w = grid->indexToWorld(*ijk);
            acc.setValue(*ijk, float(held.at(Vec3d(w.x(), w.y(), w.z()))));
        }
    }
    ASSERT_EQ(grid->tree().leafCount(), 18u);
    const HeldGridField field(operand, grid);
    std::mt19937 rng(41);
    std::uniform_real_distribution<double> u(-0.6, 3.0);
    std::vector<Vec3d> points(4000);
    for (Vec3d& p : points) p = Vec3d(u(rng), u(rng), u(rng));
    std::vector<double> out(points.size());
    field.values(points, out);
    int inside = 0, outside = 0;
    for (std::size_t n = 0; n < points.size(); ++n) {
        // Index coordinates: the eight voxels around lie in [0, 23]^2 x [0, 15].
        const Vec3d x = points[n] / 0.1 - Vec3d(0.5);
        const bool covered =
            x.x() >= 0.0 && x.y() >= 0.0 && x.z() >= 0.0 && x.x() < 23.0 && x.y() < 23.0 && x.z() < 15.0;
        if (covered) {
            EXPECT_NEAR(out[n], held.at(points[n]), 2e-6) << n;
            ++inside;
        } else if (x.x() < -1.0 || x.y() < -1.0 || x.z() < -1.0 || x.x() > 24.0 || x.y() > 24.0 || x.z() > 16.0) {
            EXPECT_EQ(out[n], operand->at(points[n])) << n;
            ++outside;
        }
    }
    EXPECT_GT(inside, 100);
    EXPECT_GT(outside, 1000);
    // A batch across the block's face: the values() of its points.
    GridBatch batch;
    batch.origin = Vec3d(0.93, 0.41, 1.22);
    batch.spacing = Vec3d(0.07);
    batch.nx = 5;
    batch.ny = 6;
    batch.nz = 14;
    std::vector<Vec3d> batchPoints;
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j)
            for (int k = 0; k < batch.nz; ++k) batchPoints.push_back(batch.point(i, j, k));
    std::vector<double> a(batch.size()), b(batch.size());
    field.gridValues(batch, a);
    field.values(batchPoints, b);
    EXPECT_EQ(a, b);
    EXPECT_GT(std::count_if(b.begin(), b.end(), [](double v) { return v > 50.0; }), 10);
    EXPECT_GT(std::count_if(b.begin(), b.end(), [](double v) { return v < 50.0; }), 10);
    // meets(): proven by held voxels with centres in the box, never by the operand.
    const Box3 box{Vec3d(0.2, 0.2, 0.2), Vec3d(1.0, 1.0, 1.0)};
    const double mid = held.at(Vec3d(0.6, 0.6, 0.6));
    EXPECT_TRUE(field.meets(box, {mid, mid}));
    EXPECT_FALSE(field.meets(box, {held.bound(box).hi + 0.01, held.bound(box).hi + 0.02}));
    EXPECT_FALSE(field.meets(Box3{Vec3d(-0.6), Vec3d(-0.2)}, {-1e9, 1e9}));  // no leaves there
}

TEST(HeldRange, KeptLeavesGiveTheRangeOfTheirVoxelsOnlyWhereTheyHoldEveryOne)
{
    // A memo holding a grid of a linear field's values (KeptGridLeaves) in the leaves of a
    // 24 x 16 x 16 voxel block of a 0.1 mm domain, the leaf at (8, 8, 8) left without values.
    const Domain d = Domain::fromBox(Box3{Vec3d(-0.2, 0.1, 0.0), Vec3d(3.0, 3.3, 3.2)}, 0.1);
    const auto operand = std::make_shared<LinearTestField>(Vec3d(0.3, -0.2, 0.7), 0.1);
    auto grid = openvdb::FloatGrid::create(std::numeric_limits<float>::max());
    {
        auto acc = grid->getAccessor();
        for (auto ijk = openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(23, 15, 15)).begin(); ijk; ++ijk)
            acc.setValue(*ijk, float(operand->at(d.worldOf(*ijk))));
        openvdb::FloatGrid::TreeType::LeafNodeType::Buffer none(openvdb::PartialCreate(), 0.0f);
        grid->tree().probeLeaf(openvdb::Coord(8))->buffer().swap(none);
    }
    const auto memo = std::make_shared<GridValueMemo>(operand);
    memo->keep(true, 0);
    memo->keepLeaves(std::make_unique<KeptGridLeaves>(grid, d), 0);
    auto pointsAt = [&](openvdb::Coord lo, int nx, int ny, int nz) {
        GridBatch points;
        points.origin = d.worldOf(lo);
        points.spacing = Vec3d(d.voxel);
        points.nx = nx;
        points.ny = ny;
        points.nz = nz;
        return points;
    };
    // The range of the floats at the points, brute force.
    auto brute = [&](const openvdb::Coord& first, const GridBatch& points) {
        float lo = std::numeric_limits<float>::max(), hi = -lo;
        for (int i = 0; i < points.nx; ++i)
            for (int j = 0; j < points.ny; ++j)
                for (int k = 0; k < points.nz; ++k) {
                    const float v = float(operand->at(d.worldOf(first + openvdb::Coord(i, j, k))));
                    lo = std::min(lo, v);
                    hi = std::max(hi, v);
                }
        return Interval(lo, hi);
    };
    const GridBatch across = pointsAt(openvdb::Coord(3, 2, 9), 15, 5, 6);  // three leaves with values
    // Their range widened by an eighth of its width either side (about a bound's: the cull keeps
    // about the leaves a bound keeps).
    const std::optional<Interval> held = memo->heldRange(across);
    ASSERT_TRUE(held);
    const Interval exact = brute(openvdb::Coord(3, 2, 9), across);
    EXPECT_GT(exact.hi - exact.lo, 0.1);
    EXPECT_EQ(held->lo, exact.lo - 0.125 * (exact.hi - exact.lo));
    EXPECT_EQ(held->hi, exact.hi + 0.125 * (exact.hi - exact.lo));
    // Past the leaves, into the leaf without values, off the voxel lattice, or at another
    // spacing: nothing held.
    EXPECT_FALSE(memo->heldRange(pointsAt(openvdb::Coord(20, 2, 2), 5, 3, 3)));
    EXPECT_FALSE(memo->heldRange(pointsAt(openvdb::Coord(-1, 2, 2), 3, 3, 3)));
    EXPECT_FALSE(memo->heldRange(pointsAt(openvdb::Coord(7, 7, 7), 2, 2, 2)));
    GridBatch shifted = across;
    shifted.origin += Vec3d(1e-9);
    EXPECT_FALSE(memo->heldRange(shifted));
    GridBatch coarse = across;
    coarse.spacing = Vec3d(0.2);
    EXPECT_FALSE(memo->heldRange(coarse));
    // A solid at a level moves it as its bound; an intersection with a sphere folds the
    // sphere's bound over the points' box in.
    const auto below = std::make_shared<LevelSolid>(memo, SolidSide::Below, 0.25);
    const LevelSolid above(memo, SolidSide::Above, 0.25);
    EXPECT_EQ(below->heldRange(across)->lo, held->lo - 0.25);
    EXPECT_EQ(above.heldRange(across)->hi, 0.25 - held->lo);
    const auto ball = std::make_shared<Sphere>(Vec3d(1.0, 1.0, 1.0), 0.3);
    const BooleanField cut(BooleanOp::Intersection, {below, ball});
    const Interval folded = max(*below->heldRange(across), ball->bound(across.bounds()));
    EXPECT_EQ(cut.heldRange(across)->lo, folded.lo);
    EXPECT_EQ(cut.heldRange(across)->hi, folded.hi);
    EXPECT_FALSE(BooleanField(BooleanOp::Union, {ball, ball}).heldRange(across));
    memo->keep(false);
    EXPECT_FALSE(memo->heldRange(across));
}

TEST(HeldGridField, APictureFromTheHeldGridMatchesOneFromTheField)
{
    // Job::pageMesh's use: a sphere's fine grid (0.04 mm) read back on a coarse one (0.2 mm, the
    // domain clipped as the page does) gives a closed mesh holding the volume the field's own
    // coarse mesh holds (within a thousandth of the ball), and near the exact ball's (marching
    // cubes' chords at 0.2 mm on a 1 mm ball hold 2.4 % less, read back or not).
    const auto sphere = std::make_shared<Sphere>(Vec3d(0.0), 1.0);
    const Box3 box{Vec3d(-1.3), Vec3d(1.3)};
    SparseOptions options;
    options.clipToDomain = true;
    const openvdb::FloatGrid::Ptr fine = evaluateSparse(*sphere, Domain::fromBox(box, 0.04), options);
    const Domain coarse = Domain::fromBox(box, 0.2);
    const TriangleMesh fromField = marchingCubes(*evaluateSparse(*sphere, coarse, options), 0.0f);
    const TriangleMesh fromHeld = marchingCubes(*evaluateSparse(HeldGridField(sphere, fine), coarse, options), 0.0f);
    EXPECT_TRUE(checkTopology(fromHeld).closedManifold());
    const double ball = 4.0 / 3.0 * std::numbers::pi;
    EXPECT_NEAR(fromHeld.volume(), fromField.volume(), 1e-3 * ball);
    EXPECT_NEAR(fromHeld.volume(), ball, 0.04 * ball);
}
