// Aether's point and curve fields (issue 19): the point field against the analytic sum, the curve
// field against a brute-force distance, analytic gradients, conservative bounds, the recipe nodes.
#include "FieldChecks.h"
#include "TestUtil.h"
#include "engine/jobs/Job.h"
#include "fields/struts/DistanceFalloff.h"
#include "mesher/checks/MeshCheck.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

using namespace voxlat;
using namespace voxlat::test;

namespace {

double analyticKernel(Falloff f, double d, double sigma)
{
    if (f == Falloff::Inverse) return 1.0 / d;
    if (f == Falloff::InverseSquare) return 1.0 / (d * d);
    return std::exp(-d * d / (2 * sigma * sigma));
}

struct PointSet {
    std::vector<Vec3d> at;
    std::vector<double> w;
};

PointSet randomPointSet(unsigned seed, int n)
{
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0.0, 10.0), wd(0.2, 2.0);
    PointSet s;
    for (int i = 0; i < n; ++i) {
        s.at.emplace_back(u(rng), u(rng), u(rng));
        s.w.push_back(i % 5 == 4 ? -0.5 * wd(rng) : wd(rng));  // some negative weights too
    }
    return s;
}

std::shared_ptr<DistanceFalloff> pointField(const PointSet& s, Falloff f, double sigma)
{
    std::vector<FalloffSource> src;
    for (std::size_t i = 0; i < s.at.size(); ++i) src.push_back({{s.at[i]}, s.w[i]});
    return std::make_shared<DistanceFalloff>(src, f, sigma);
}

const Falloff kAll[] = {Falloff::Inverse, Falloff::InverseSquare, Falloff::Gaussian};

}  // namespace

TEST(PointField, MatchesTheAnalyticSumAtRandomPoints)
{
    const PointSet s = randomPointSet(7, 40);
    const double sigma = 1.3;
    for (const Falloff f : kAll) {
        const auto field = pointField(s, f, sigma);
        const auto pts = randomPoints(500, -3.0, 13.0, 11);
        std::vector<double> v(pts.size());
        field->values(pts, v);
        for (std::size_t n = 0; n < pts.size(); ++n) {
            double sum = 0.0, magnitude = 0.0;
            for (std::size_t i = 0; i < s.at.size(); ++i) {
                const double k = analyticKernel(f, (pts[n] - s.at[i]).length(), sigma);
                sum += s.w[i] * k;
                magnitude += std::abs(s.w[i] * k);
            }
            // Gaussian: the terms beyond 7.4 sigma (each below 1e-12 |w|) are dropped.
            EXPECT_NEAR(v[n], sum, 1e-12 * magnitude + (f == Falloff::Gaussian ? 1e-10 : 0.0)) << int(f);
        }
        // The per-leaf path gives the same bits as the point path.
        const GridBatch batch{Vec3d(1.05, 2.1, 3.15), Vec3d(0.13), 8, 8, 8};
        std::vector<double> grid(batch.size()), single(batch.size());
        field->gridValues(batch, grid);
        std::vector<Vec3d> bp;
        for (int i = 0; i < 8; ++i)
            for (int j = 0; j < 8; ++j)
                for (int k = 0; k < 8; ++k) bp.push_back(batch.point(i, j, k));
        field->values(bp, single);
        for (std::size_t n = 0; n < grid.size(); ++n) EXPECT_EQ(grid[n], single[n]);
    }
}

TEST(PointField, GradientsMatchFiniteDifferencesAndBoundsContainValues)
{
    const PointSet s = randomPointSet(3, 12);
    for (const Falloff f : kAll) {
        const auto field = pointField(s, f, 1.1);
        // Points away from the sources, where 1/d is smooth enough for central differences.
        std::vector<Vec3d> pts;
        for (const Vec3d& p : randomPoints(400, -2.0, 12.0, 5)) {
            bool far = true;
            for (const Vec3d& q : s.at) far = far && (p - q).length() > 0.5;
            if (far) pts.push_back(p);
        }
        ASSERT_GT(pts.size(), 100u);
        expectGradientsMatchFiniteDifferences(*field, pts, 1e-5, 1e-6);
        expectBoundsContainValues(*field, -2.0, 12.0, 3.0, 17);
    }
}

TEST(PointField, GaussianLeavesSkipFarPointsWithoutChangingValues)
{
    // 2000 points spread over 100 mm: a leaf near one corner gathers a handful, and its bound is
    // exactly zero far from every point.
    const PointSet s = [] {
        PointSet p = randomPointSet(21, 2000);
        for (auto& q : p.at) q *= 10.0;
        for (auto& w : p.w) w = std::abs(w);
        return p;
    }();
    const auto field = pointField(s, Falloff::Gaussian, 0.8);
    const Box3 far{Vec3d(200.0), Vec3d(201.0)};
    EXPECT_EQ(field->bound(far).lo, -1e-300);
    EXPECT_LT(field->bound(far).hi, 1e-299);
    expectBoundsContainValues(*field, 0.0, 100.0, 4.0, 29);
}

TEST(CurveField, MatchesABruteForceDistance)
{
    // Two polylines; the distance by dense sampling of every segment (10^4 samples each).
    const std::vector<FalloffSource> curves{{{Vec3d(0, 0, 0), Vec3d(5, 0, 0), Vec3d(5, 4, 1), Vec3d(2, 6, 3)}, 1.5},
                                            {{Vec3d(8, 8, 8), Vec3d(3, 9, 2)}, 0.7}};
    const double sigma = 1.2;
    const auto pts = randomPoints(300, -2.0, 10.0, 41);
    for (const Falloff f : kAll) {
        DistanceFalloff field(curves, f, sigma);
        std::vector<double> v(pts.size());
        std::vector<Vec3d> g(pts.size());
        field.gradients(pts, v, g);
        for (std::size_t n = 0; n < pts.size(); ++n) {
            double sum = 0.0;
            for (const FalloffSource& c : curves) {
                double d = 1e300;
                for (std::size_t k = 0; k + 1 < c.vertices.size(); ++k)
                    for (int i = 0; i <= 10000; ++i)
                        d = std::min(
                            d, (pts[n] - (c.vertices[k] + (i / 1e4) * (c.vertices[k + 1] - c.vertices[k]))).length());
                sum += c.weight * analyticKernel(f, d, sigma);
            }
            // Sampling misses the nearest point by at most half a step (6.5e-4 mm): relative 1e-3.
            EXPECT_NEAR(v[n], sum, 2e-3 * std::abs(sum) + 1e-12) << int(f) << " at " << pts[n];
        }
        std::vector<Vec3d> away;
        for (const Vec3d& p : pts)
            if (std::abs(field.value(p)) < 50) away.push_back(p);
        expectGradientsMatchFiniteDifferences(field, away, 1e-4, 1e-6);
        expectBoundsContainValues(field, -2.0, 10.0, 3.0, 43);
    }
}

TEST(CurveField, StacksAreEvaluatedLeafByLeafWithTheirUnreadLeavesLeftOut)
{
    const std::vector<FalloffSource> curves{{{Vec3d(0, 0, 0), Vec3d(5, 0, 0), Vec3d(5, 4, 1), Vec3d(2, 6, 3)}, 1.5},
                                            {{Vec3d(8, 8, 8), Vec3d(3, 9, 2)}, 0.7}};
    for (const Falloff f : kAll) expectStackLeafByLeaf(DistanceFalloff(curves, f, 1.2), Vec3d(3.0, 1.0, -4.0), 0.1);
}

TEST(PointField, RecipeSolidIsLevelMinusTheSum)
{
    // An isolated point of weight w with an inverse falloff is a ball of radius w / level.
    const std::string text =
        "voxel: 0.1\ndomain: {box: [[-3, -3, -3], [3, 3, 3]]}\nfields:\n"
        "  blob: {points: {at: [[0, 0, 0], [20, 0, 0]], weight: [2, 1], falloff: inverse}, level: 1.25}\n"
        "result: blob\n";
    Job job(parseRecipe(text, "points.yaml", "."));
    const FieldPtr f = job.field("blob");
    for (const Vec3d& p : {Vec3d(1.0, 0.3, -0.2), Vec3d(-1.5, 0.8, 0.4), Vec3d(0.2, 2.2, -1.0)}) {
        const double sum = 2.0 / p.length() + 1.0 / (p - Vec3d(20, 0, 0)).length();
        EXPECT_NEAR(f->value(p), 1.25 - sum, 1e-12);
    }
    const TriangleMesh& mesh = job.mesh();
    EXPECT_TRUE(checkTopology(mesh).closedManifold());

    // Points from a CSV with a weight column (and a header row): the same sum.
    TempDir dir;
    dir.write("pts.csv", "x,y,z,w\n0,0,0,2\n20,0,0,1\n");
    Job fromFile(
        parseRecipe("voxel: 0.5\ndomain: {box: [[-3, -3, -3], [3, 3, 3]]}\nfields:\n"
                    "  blob: {points: {file: pts.csv}, level: 1.25}\nresult: blob\n",
                    "file.yaml", dir.path));
    const Vec3d q(0.7, -0.4, 1.1);
    EXPECT_NEAR(fromFile.field("blob")->value(q), 1.25 - 2.0 / q.length() - 1.0 / (q - Vec3d(20, 0, 0)).length(),
                1e-12);

    // Gaussian curves from an OBJ file and a density solve.
    dir.write("c.obj", "v 0 0 0\nv 4 0 0\nv 4 4 0\nl 1 2 3\n");
    const std::string curves =
        "voxel: 0.2\ndomain: {box: [[-2, -2, -2], [6, 6, 2]]}\nfields:\n"
        "  tube: {curves: {file: c.obj, falloff: gaussian, sigma: 0.5}, density: 0.1}\nresult: tube\n";
    Job curveJob(parseRecipe(curves, "curves.yaml", dir.path));
    curveJob.solveLevels();
    const FieldPtr c = curveJob.field("tube");
    // The solid is a tube around the L: its radius r solves exp(-r^2 / 2 sigma^2) = level.
    const double level = c->value(Vec3d(2, 0, 0)) + 1.0;  // value = level - 1 on the curve
    const double r = 0.5 * std::sqrt(2 * std::log(1 / level));
    EXPECT_NEAR(c->value(Vec3d(2, r, 0)), 0.0, 1e-9);
    EXPECT_NEAR(c->value(Vec3d(4, 2, r)), 0.0, 1e-9);
}

TEST(PointField, BadKeysNameTheLine)
{
    const std::string head = "voxel: 0.2\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n";
    struct Case {
        std::string field, expect;
    };
    const std::vector<Case> cases{
        {"  b: {points: {at: [[1, 1, 1]], falloff: gaussian}}\n", "needs `sigma:`"},
        {"  b: {points: {at: [[1, 1, 1]], sigma: 1}}\n", "remove it"},
        {"  b: {points: {at: [[1, 1, 1]], weight: [1, 2]}}\n", "the weight list has 2 entries but there are 1 point"},
        {"  b: {points: {at: [[1, 1, 1]], falloff: cubic}}\n", "falloff is `inverse`"},
        {"  b: {points: {at: [[1, 1, 1]]}, level: 0}\n", "the level must be greater than zero"},
        {"  b: {curves: {polylines: [[[1, 1, 1]]]}}\n", "a polyline is a list of at least two points"},
        {"  b: {points: {at: [[1, 1, 1]], radius: 2}}\n", "radius"},
    };
    for (const Case& c : cases) {
        try {
            Job job(parseRecipe(head + c.field + "result: b\n", "bad.yaml", "."));
            ADD_FAILURE() << "no error for " << c.field;
        } catch (const InputError& e) {
            EXPECT_NE(std::string(e.what()).find("bad.yaml:4:"), std::string::npos) << e.what();
            EXPECT_NE(std::string(e.what()).find(c.expect), std::string::npos) << e.what();
        }
    }
}
