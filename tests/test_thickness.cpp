// Thickness in millimetres (gradient shift) and graded density: wall thickness measured on the
// evaluated grid, thin-wall volume fraction against the gyroid's surface area, anisotropic and
// rotation limits, graded density per slab counted on the grid, gradients against finite
// differences, bounds against sampled values, and the recipe errors.
#include "TestUtil.h"
#include "engine/jobs/Job.h"
#include "engine/recipe/ScalarMaps.h"
#include "fields/core/Constant.h"
#include "fields/levels/GradedLevel.h"
#include "fields/levels/GradientShift.h"
#include "fields/levels/LevelSolid.h"
#include "fields/maps/Ramp.h"
#include "fields/maps/SampledGrid.h"
#include "fields/shapes/Sphere.h"
#include "fields/tpms/TpmsField.h"

#include "FieldChecks.h"

#include <gtest/gtest.h>
#include <openvdb/tools/Interpolation.h>

#include <iostream>
#include <limits>
#include <numbers>
#include <random>

using namespace voxlat;
using namespace voxlat::test;

namespace {

constexpr double kPi = std::numbers::pi;

FieldPtr gyroid(double cell)
{
    return std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(cell));
}

std::shared_ptr<GradientShift> uniformShift(FieldPtr f, double m)
{
    ShiftSpec spec;
    spec.uniform = std::make_shared<ConstantField>(m);
    return std::make_shared<GradientShift>(std::move(f), spec);
}

std::shared_ptr<GradientShift> anisotropicShift(FieldPtr f, double d, double l, Vec3d b,
                                                ShiftRotation rotation = ShiftRotation::Rodrigues)
{
    ShiftSpec spec;
    spec.wall = std::make_shared<ConstantField>(d);
    spec.layer = std::make_shared<ConstantField>(l);
    spec.direction = b;
    spec.rotation = rotation;
    return std::make_shared<GradientShift>(std::move(f), spec);
}

/// Random points on f = 0 (Newton steps along the gradient), with their unit normals.
std::vector<std::pair<Vec3d, Vec3d>> surfacePoints(const FieldNode& f, int count, double lo, double hi, unsigned seed)
{
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(lo, hi);
    std::vector<std::pair<Vec3d, Vec3d>> out;
    while (int(out.size()) < count) {
        Vec3d p(u(rng), u(rng), u(rng));
        for (int it = 0; it < 30; ++it) {
            const auto [v, g] = f.valueAndGradient(p);
            p -= v / g.lengthSqr() * g;
        }
        const auto [v, g] = f.valueAndGradient(p);
        if (std::abs(v) < 1e-12 && g.length() > 1e-6 && p[0] > lo && p[0] < hi && p[1] > lo && p[1] < hi && p[2] > lo &&
            p[2] < hi)
            out.push_back({p, g / g.length()});
    }
    return out;
}

/// Distance between the two sign changes of @a value(t) around t = 0 (inside at t = 0), found by
/// stepping outward and bisecting.
template <typename Fn>
double chordAcross(Fn&& value, double step, double reach)
{
    auto crossing = [&](double dir) {
        double a = 0.0;
        for (double t = step; t <= reach; t += step) {
            if (value(dir * t) >= 0.0) {
                double b = t;
                for (int it = 0; it < 50; ++it) {
                    const double mid = 0.5 * (a + b);
                    (value(dir * mid) < 0.0 ? a : b) = mid;
                }
                return 0.5 * (a + b);
            }
            a = t;
        }
        return reach;
    };
    return crossing(1.0) + crossing(-1.0);
}

Recipe recipe(const std::string& text, const test::TempDir& dir)
{
    return parseRecipe(text, (dir.path / "test.yaml").string(), dir.path);
}

/// Expects building a job from @a text to fail with a message containing every one of @a parts.
void expectInputError(const std::string& text, std::initializer_list<std::string> parts)
{
    test::TempDir dir;
    dir.write("rho.csv", "z,density\n0,0.1\n10,1.5\n");
    try {
        Job job(recipe(text, dir));
        job.grid();
        ADD_FAILURE() << "no error for:\n" << text;
    } catch (const InputError& e) {
        for (const auto& p : parts) EXPECT_NE(std::string(e.what()).find(p), std::string::npos) << e.what();
    }
}

}  // namespace

TEST(GradientShift, WallThicknessOnTheGridIsTwiceTheShift)
{
    // The acceptance setting (8 mm cells, 0.6 mm walls, 0.05 mm voxels) on a corner of the part.
    test::TempDir dir;
    Job job(recipe(R"(
voxel: 0.05
domain: {box: [[0, 0, 0], [8, 8, 8]]}
fields:
  lattice: {tpms: gyroid, cell: 8, solid: sheet, thickness: 0.6}
result: lattice
)",
                   dir));
    const openvdb::FloatGrid& grid = job.grid();
    openvdb::tools::GridSampler<openvdb::FloatGrid, openvdb::tools::BoxSampler> sampler(grid);
    const auto f = gyroid(8.0);
    const auto points = surfacePoints(*f, 400, 1.0, 7.0, 7);
    double sum = 0.0, worst = 0.0;
    for (const auto& [p, n] : points) {
        // March along the normal of the mid-surface through the trilinearly interpolated grid.
        const double w = chordAcross([&](double t) { return double(sampler.wsSample(p + t * n)); }, 0.01, 1.0);
        sum += w;
        worst = std::max(worst, std::abs(w - 0.6));
        EXPECT_NEAR(w, 0.6, 0.05) << "at " << p;  // one voxel
    }
    EXPECT_NEAR(sum / points.size(), 0.6, 0.01);
    std::cout << "[ measured ] wall thickness on the grid: mean " << sum / points.size() << " mm, worst deviation "
              << worst << " mm (target 0.6 mm, voxel 0.05 mm)\n";
}

TEST(GradientShift, ThinWallVolumeFractionMatchesSurfaceArea)
{
    // VF = (A / a^3) w for a sheet of thickness w, with A = 3.089 a^2 for the gyroid (reference §1).
    for (const double w : {0.2, 0.4}) {
        test::TempDir dir;
        Job job(
            recipe("voxel: 0.04\ndomain: {box: [[0, 0, 0], [8, 8, 8]]}\nfields:\n  s: {tpms: gyroid, cell: 8, "
                   "solid: sheet, thickness: " +
                       std::to_string(w) + "}\nresult: s\n",
                   dir));
        job.grid();
        const double vf = job.report()["result"]["volume_fraction"].get<double>();
        const double expected = 3.089 / 8.0 * w;
        EXPECT_NEAR(vf / expected, 1.0, 0.03) << "w = " << w;
        std::cout << "[ measured ] w = " << w << " mm: VF " << vf << " vs (A/a^3) w = " << expected << " ("
                  << 100.0 * (vf / expected - 1.0) << " %)\n";
    }
}

TEST(GradientShift, AnisotropicLimits)
{
    // Vertical walls (normal in the build plane) take the wall thickness, horizontal walls (normal
    // along the build direction) the layer height; with b = x the roles follow the axis.
    const auto f = gyroid(10.0);
    for (const Vec3d b : {Vec3d(0, 0, 1), Vec3d(1, 0, 0)}) {
        const int axis = b[0] == 1.0 ? 0 : 2;
        const auto sheet = anisotropicShift(f, 0.25, 0.1, b);  // shifts: walls 0.5 mm, layers 0.2 mm
        int vertical = 0, horizontal = 0;
        for (const auto& [p, n] : surfacePoints(*f, 3000, 0.0, 10.0, 11)) {
            const double along = std::abs(n[axis]);
            const double w = chordAcross([&](double t) { return sheet->value(p + t * n); }, 0.01, 1.0);
            // Along the normal the shift is s.n = d (1 - n_b^2) + l n_b^2 on each side.
            EXPECT_NEAR(w, 2 * (0.25 * (1 - along * along) + 0.1 * along * along), 0.02) << "at " << p;
            if (along <= 0.05) {
                EXPECT_NEAR(w, 0.5, 0.02) << "vertical wall at " << p;
                ++vertical;
            } else if (along >= 0.98) {
                EXPECT_NEAR(w, 0.2, 0.02) << "horizontal wall at " << p;
                ++horizontal;
            }
        }
        EXPECT_GT(vertical, 20);
        EXPECT_GT(horizontal, 3);
    }
}

TEST(GradientShift, ObliqueBuildKeepsWallAndLayerByDefault)
{
    // Issue 42: `build: [1, 1, 1]` with wall 0.3 / layer 0.8 and no `rotation:` gave 0.673 mm
    // walls both ways (the Rodrigues form mixes d and l off the axes). The default honours the
    // split for any direction: a wall whose normal makes an angle theta with the build direction
    // is 2 (d sin^2 theta + l cos^2 theta) thick, measured across the sheet along its normal.
    test::TempDir dir;
    Job job(
        recipe("voxel: 0.1\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n  s: {tpms: gyroid, cell: 10, "
               "solid: sheet, wall: 0.3, layer: 0.8, build: [1, 1, 1]}\nresult: s\n",
               dir));
    const FieldPtr sheet = job.field("s");
    const Vec3d b = Vec3d(1, 1, 1) / std::sqrt(3.0);
    const auto f = gyroid(10.0);
    int inPlane = 0, along = 0;
    for (const auto& [p, n] : surfacePoints(*f, 3000, 0.0, 10.0, 17)) {
        const double c = std::abs(n.dot(b));
        const double w = chordAcross([&](double t) { return sheet->value(p + t * n); }, 0.01, 2.0);
        EXPECT_NEAR(w, 2 * (0.15 * (1 - c * c) + 0.4 * c * c), 0.03) << "at " << p << ", cos theta " << c;
        if (c <= 0.05) ++inPlane;
        if (c >= 0.98) ++along;
    }
    EXPECT_GT(inPlane, 20);
    EXPECT_GT(along, 3);
}

TEST(GradientShift, RotationSpecialCasesAreExact)
{
    const double d = 0.3, l = 0.1;
    const Vec3d m(d, d, l);
    EXPECT_EQ(GradientShift::rotatedMagnitudes(Vec3d(0, 0, 1), d, l), m);
    EXPECT_EQ(GradientShift::rotatedMagnitudes(Vec3d(0, 0, -1), d, l), m);
    // A quarter turn to x puts the layer height on x.
    EXPECT_TRUE((GradientShift::rotatedMagnitudes(Vec3d(1, 0, 0), d, l) - Vec3d(l, d, d)).length() < 1e-15);
    EXPECT_TRUE((GradientShift::rotatedMagnitudes(Vec3d(0, -1, 0), d, l) - Vec3d(d, l, d)).length() < 1e-15);
    // The whole field: b = -z gives the same bytes as b = +z.
    const auto f = gyroid(8.0);
    const auto up = anisotropicShift(f, d, l, Vec3d(0, 0, 1)), down = anisotropicShift(f, d, l, Vec3d(0, 0, -1));
    const auto pts = randomPoints(300, 0.0, 8.0, 3);
    std::vector<double> a(pts.size()), c(pts.size());
    up->values(pts, a);
    down->values(pts, c);
    EXPECT_EQ(a, c);
}

TEST(GradientShift, RotationIsContinuousAtTheSpecialCases)
{
    const double d = 0.3, l = 0.1;
    const Vec3d m(d, d, l);
    for (const double eps : {1e-3, 1e-6, 1e-9}) {
        for (int k = 0; k < 64; ++k) {
            const double phi = 2 * kPi * k / 64;
            const Vec3d tilt(eps * std::cos(phi), eps * std::sin(phi), 0.0);
            // Near +z: from every azimuth.
            Vec3d b = Vec3d(0, 0, 1) + tilt;
            b.normalize();
            EXPECT_LT((GradientShift::rotatedMagnitudes(b, d, l) - m).length(), 4 * eps * (d + l)) << phi;
            // Near -z the tensor form is continuous from every azimuth ...
            b = Vec3d(0, 0, -1) + tilt;
            b.normalize();
            for (const Vec3d& n : {Vec3d(1, 0, 0), Vec3d(0, 1, 0), Vec3d(0, 0, 1), Vec3d(0.6, 0, 0.8)}) {
                const Vec3d s = GradientShift::anisotropicShift(n, b, d, l, ShiftRotation::Tensor);
                const Vec3d s0 = GradientShift::anisotropicShift(n, Vec3d(0, 0, -1), d, l, ShiftRotation::Tensor);
                EXPECT_LT((s - s0).length(), 4 * eps * (d + l));
            }
            // ... and the Rodrigues form along the meridians of the axes and diagonals (phi = k pi/4),
            // the neighbours of the half-turn about x that defines b = -z.
            if (k % 8 == 0) {
                EXPECT_LT((GradientShift::rotatedMagnitudes(b, d, l) - m).length(), 4 * eps * (d + l)) << phi;
            }
        }
    }
    // The Rodrigues magnitude vector cannot be continuous at -z from every azimuth: its limit there
    // is (d |cos 2phi + sin 2phi|, d |sin 2phi - cos 2phi|, l). Documented, and checked here.
    const double phi = kPi / 8;
    Vec3d b(1e-7 * std::cos(phi), 1e-7 * std::sin(phi), -1.0);
    b.normalize();
    EXPECT_NEAR(GradientShift::rotatedMagnitudes(b, d, l)[0], d * std::sqrt(2.0), 1e-6);
    // The tensor form with d = l is uniform for any direction.
    const Vec3d n = Vec3d(0.2, -0.5, 0.7).unit();
    const Vec3d s = GradientShift::anisotropicShift(n, Vec3d(0.3, 0.4, -0.1).unit(), d, d, ShiftRotation::Tensor);
    EXPECT_LT((s - d * n).length(), 1e-15);
}

TEST(GradientShift, GradientsMatchFiniteDifferences)
{
    const auto f = gyroid(8.0);
    const auto pts = randomPoints(60, 0.0, 16.0, 5);
    expectGradientsMatchFiniteDifferences(*uniformShift(f, 0.3), pts, 1e-5, 1e-6);
    expectGradientsMatchFiniteDifferences(*anisotropicShift(f, 0.3, 0.15, Vec3d(1, 2, 3)), pts, 1e-5, 1e-6);
    expectGradientsMatchFiniteDifferences(*anisotropicShift(f, 0.3, 0.15, Vec3d(1, 2, 3), ShiftRotation::Tensor), pts,
                                          1e-5, 1e-6);
    // Magnitudes and direction from fields.
    ShiftSpec spec;
    spec.wall = std::make_shared<RampField>(0, 0.0, 16.0, 0.1, 0.4);
    spec.layer = std::make_shared<ConstantField>(0.1);
    spec.directionGradient = std::make_shared<Sphere>(Vec3d(8, 8, -20), 1.0);
    expectGradientsMatchFiniteDifferences(GradientShift(f, spec), pts, 1e-5, 1e-6);
}

TEST(GradientShift, GridValuesMatchPointValuesAndBoundsContainThem)
{
    const auto f = gyroid(8.0);
    const auto sheet = anisotropicShift(f, 0.3, 0.15, Vec3d(0, 1, 1));
    GridBatch batch;
    batch.origin = Vec3d(1.3, -2.1, 0.7);
    batch.spacing = Vec3d(0.05);
    std::vector<double> grid(512), points(512);
    sheet->gridValues(batch, grid);
    std::vector<Vec3d> p;
    for (int i = 0; i < 8; ++i)
        for (int j = 0; j < 8; ++j)
            for (int k = 0; k < 8; ++k) p.push_back(batch.point(i, j, k));
    sheet->values(p, points);
    for (int i = 0; i < 512; ++i) EXPECT_NEAR(grid[i], points[i], 1e-13);
    // The TPMS separable gradients agree with the point ones.
    std::vector<double> v1(512), v2(512);
    std::vector<Vec3d> g1(512), g2(512);
    f->gridGradients(batch, v1, g1);
    f->gradients(p, v2, g2);
    for (int i = 0; i < 512; ++i) {
        EXPECT_NEAR(v1[i], v2[i], 1e-12);
        EXPECT_LT((g1[i] - g2[i]).length(), 1e-12);
    }
    expectBoundsContainValues(*sheet, 0.0, 16.0, 2.0, 9);
    expectBoundsContainValues(*uniformShift(f, 0.3), 0.0, 16.0, 2.0, 10);
}

TEST(GradientShift, TpmsShiftedValuesMatchPointValues)
{
    // The angle-addition fast path against the generic one (2N points through values()), for every
    // TPMS, small shifts (polynomial sin/cos) and large ones (libm).
    std::mt19937 rng(21);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (const std::string& name : tpmsNames()) {
        TpmsType type;
        ASSERT_TRUE(parseTpmsType(name, type));
        const TpmsField f(type, Vec3d(7.0, 8.0, 9.0));
        GridBatch batch;
        batch.origin = Vec3d(-3.1, 2.2, 10.7);
        batch.spacing = Vec3d(0.07, 0.05, 0.09);
        for (const double size : {0.3, 3.0}) {
            std::vector<Vec3d> shift(512);
            for (auto& s : shift) s = size * Vec3d(u(rng), u(rng), u(rng));
            std::vector<double> p1(512), m1(512), p2(512), m2(512);
            f.gridValuesShifted(batch, shift, p1, m1);
            f.FieldNode::gridValuesShifted(batch, shift, p2, m2);
            for (int i = 0; i < 512; ++i) {
                EXPECT_NEAR(p1[i], p2[i], 1e-13) << name;
                EXPECT_NEAR(m1[i], m2[i], 1e-13) << name;
            }
        }
    }
}

TEST(DensityTable, InvertsMonotonicallyAndMatchesTheCatalog)
{
    const auto f = gyroid(5.0);
    const DensityTable network(*f, Box3{Vec3d(0.0), Vec3d(5.0)});
    const DensityTable sheet(*std::make_shared<LevelSolid>(f, SolidSide::Band, 0.0)->indicator(),
                             Box3{Vec3d(0.0), Vec3d(5.0)});
    for (std::size_t i = 1; i < network.levels().size(); ++i) EXPECT_LE(network.levels()[i - 1], network.levels()[i]);
    for (double rho = 0.05; rho < 0.96; rho += 0.05) {
        EXPECT_NEAR(network.densityAt(network.levelAt(rho)), rho, 1e-9);
        EXPECT_NEAR(sheet.densityAt(sheet.levelAt(rho)), rho, 1e-9);
    }
    // The catalog's linear fits (reference §1): network 50 + 32.8 c %, sheet t = 0.3 -> 19.29 %.
    EXPECT_NEAR(network.levelAt(0.5), 0.0, 1e-3);
    EXPECT_NEAR(network.densityAt(0.3), 0.50 + 0.328 * 0.3, 0.01);
    EXPECT_NEAR(sheet.densityAt(0.3), 0.1929, 0.005);
    // Independent Monte Carlo check of one entry.
    std::mt19937 rng(1);
    std::uniform_real_distribution<double> u(0.0, 5.0);
    const double level = network.levelAt(0.2);
    int inside = 0, total = 200000;
    for (int n = 0; n < total; ++n) inside += f->value(Vec3d(u(rng), u(rng), u(rng))) < level;
    EXPECT_NEAR(double(inside) / total, 0.2, 0.004);
}

TEST(GradedDensity, SlabsFollowTheRampWithinOnePercent)
{
    // Counted on the evaluated grid, voxel by voxel, independently of the table and the report.
    struct Case {
        std::string lattice;
        double from, to;
    };
    for (const Case& c : {Case{"{tpms: gyroid, cell: 6, solid: network", 0.10, 0.40},
                          Case{"{tpms: schwarz-p, cell: 6, solid: sheet", 0.30, 0.10}}) {
        test::TempDir dir;
        const std::string text =
            "voxel: 0.1\ndomain: {box: [[0, 0, 0], [12, 12, 30]]}\nfields:\n  lattice: " + c.lattice +
            ", density: {ramp: {axis: z, from: " + std::to_string(c.from) + ", to: " + std::to_string(c.to) +
            "}}}\nresult: lattice\n";
        Job job(recipe(text, dir));
        const openvdb::FloatGrid& grid = job.grid();
        auto acc = grid.getConstAccessor();
        const auto report = job.report()["fields"]["lattice"]["slabs"];
        ASSERT_EQ(report["slabs"].size(), 5u);
        for (int s = 0; s < 5; ++s) {
            std::uint64_t inside = 0, total = 0;
            for (int i = 0; i < 120; ++i)
                for (int j = 0; j < 120; ++j)
                    for (int k = 60 * s; k < 60 * (s + 1); ++k, ++total)
                        inside += acc.getValue(openvdb::Coord(i, j, k)) < 0.0f;
            const double achieved = double(inside) / double(total);
            const double target = c.from + (c.to - c.from) * (6.0 * s + 3.0) / 30.0;  // mean of a linear ramp
            EXPECT_NEAR(achieved, target, 0.01) << c.lattice << " slab " << s;
            EXPECT_NEAR(report["slabs"][s]["achieved"].get<double>(), achieved, 1e-12);
            EXPECT_NEAR(report["slabs"][s]["target"].get<double>(), target, 1e-3);
            std::cout << "[ measured ] " << c.lattice << "} slab " << s << ": target " << target << ", achieved "
                      << achieved << "\n";
        }
    }
}

TEST(GradedDensity, FieldsAndFilesDriveTheDensity)
{
    // A 1-D profile from a file reproduces the ramp it samples; a field by name and a distance ramp
    // give the densities they describe at sample points.
    test::TempDir dir;
    dir.write("rho.csv", "# z profile\nz,density\n0,0.1\n15,0.25\n30,0.4\n");
    const std::string base = "voxel: 0.5\ndomain: {box: [[0, 0, 0], [12, 12, 30]]}\nfields:\n";
    Job fromFile(recipe(base + "  lattice: {tpms: gyroid, cell: 6, density: {file: rho.csv}}\nresult: lattice\n", dir));
    Job fromRamp(recipe(
        base + "  lattice: {tpms: gyroid, cell: 6, density: {ramp: {axis: z, from: 0.1, to: 0.4}}}\nresult: lattice\n",
        dir));
    const auto pts = randomPoints(200, 0.0, 12.0, 4);
    std::vector<double> a(pts.size()), b(pts.size());
    fromFile.field("lattice")->values(pts, a);
    fromRamp.field("lattice")->values(pts, b);
    for (std::size_t i = 0; i < pts.size(); ++i) EXPECT_NEAR(a[i], b[i], 1e-9);

    Job byName(recipe(
        base +
            "  rho: {distance-ramp: {field: {sphere: {center: [6, 6, 15], radius: 2}}, from: 0.4, to: 0.1, over: 10}}\n"
            "  lattice: {tpms: gyroid, cell: 6, solid: sheet, density: rho}\nresult: lattice\n",
        dir));
    const auto rho = byName.field("rho");
    // |distance| from a sphere of radius 2: 0 on it, 5 mm at z = 22, 2 mm at the centre.
    EXPECT_NEAR(rho->value(Vec3d(6, 6, 17)), 0.4, 1e-12);
    EXPECT_NEAR(rho->value(Vec3d(6, 6, 22)), 0.25, 1e-12);
    EXPECT_NEAR(rho->value(Vec3d(6, 6, 15)), 0.4 - 0.3 * 0.2, 1e-12);
    EXPECT_NEAR(rho->value(Vec3d(6, 6, 29)), 0.1, 1e-12);

    // The graded node's gradient and bound.
    const auto graded = std::dynamic_pointer_cast<const GradedLevel>(byName.field("lattice"));
    ASSERT_TRUE(graded);
    expectGradientsMatchFiniteDifferences(*graded, randomPoints(40, 1.0, 11.0, 8), 1e-4, 1e-6);
    expectBoundsContainValues(*graded, 0.0, 10.0, 2.0, 12);
}

TEST(SampledGrid, InterpolatesTrilinearly)
{
    std::array<std::vector<double>, 3> coords{std::vector<double>{0, 1, 3}, std::vector<double>{0, 2},
                                              std::vector<double>{-1, 0, 1, 2}};
    std::vector<double> values;
    auto linear = [](double x, double y, double z) { return 0.5 + 0.1 * x - 0.05 * y + 0.02 * z; };
    for (double x : coords[0])
        for (double y : coords[1])
            for (double z : coords[2]) values.push_back(linear(x, y, z));
    const SampledGridField g(coords, values);
    for (const Vec3d& p : randomPoints(100, 0.0, 1.9, 2)) EXPECT_NEAR(g.value(p), linear(p[0], p[1], p[2]), 1e-12);
    EXPECT_NEAR(g.value(Vec3d(10, 1, 0)), linear(3, 1, 0), 1e-12);  // clamped outside
    expectGradientsMatchFiniteDifferences(g, randomPoints(30, 0.05, 1.9, 6), 1e-6, 1e-6);
    expectBoundsContainValues(g, 0.0, 3.0, 1.0, 1);
}

TEST(ThicknessRecipes, AcceptanceRecipesLoadUnchanged)
{
    const auto shift = loadRecipe((test::sourceDir() / "data/recipes/gyroid-shift.yaml").string());
    Job job(shift);
    EXPECT_NE(job.report()["domain"]["voxels"].get<std::uint64_t>(), 0u);
    EXPECT_FALSE(job.report().contains("warnings"));  // 0.6 mm is 7.5 % of 8 mm
    // The acceptance sheet, cropped to one cell: walls within one voxel of 0.6 mm by volume.
    test::TempDir dir;
    std::string out;
    ASSERT_EQ(test::runCommand(test::voxlatBinary() + " -q run " +
                                   (test::sourceDir() / "data/recipes/gyroid-shift.yaml").string() +
                                   " --set 'domain.box=[[0,0,0],[8,8,8]]' --out " + dir.path.string(),
                               &out),
              0)
        << out;
    const auto report = nlohmann::json::parse(test::readFile(dir.path / "report.json"));
    EXPECT_NEAR(report["result"]["volume_fraction"].get<double>(), 3.089 / 8.0 * 0.6, 0.03 * 3.089 / 8.0 * 0.6);

    const auto graded = loadRecipe((test::sourceDir() / "data/recipes/gyroid-graded.yaml").string());
    Job gradedJob(graded);
    EXPECT_EQ(gradedJob.report()["domain"]["max"][2].get<double>(), 30.0);
}

TEST(ThicknessRecipes, BadInputIsRejectedWithTheLine)
{
    const std::string head = "voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n";
    expectInputError(
        head + "  s: {tpms: gyroid, cell: 8, solid: sheet, wall: 0.4, layer: 0.2, build: [0, 0, 0]}\nresult: s\n",
        {"test.yaml:4:", "zero length"});
    expectInputError(head + "  s: {tpms: gyroid, cell: 8, solid: sheet, thickness: 0.4, rotation: tensor}\nresult: s\n",
                     {"only matters"});
    expectInputError(head + "  s: {tpms: gyroid, cell: 8, solid: network, thickness: 0.4}\nresult: s\n",
                     {"solid: sheet"});
    expectInputError(head + "  s: {tpms: gyroid, cell: 8, solid: sheet, thickness: 0.4, level: 0.3}\nresult: s\n",
                     {"not both"});
    expectInputError(head + "  s: {tpms: gyroid, cell: 8, solid: sheet, wall: 0.4}\nresult: s\n", {"layer"});
    expectInputError(head + "  s: {tpms: gyroid, cell: 8, solid: sheet, thickness: 0}\nresult: s\n",
                     {"greater than zero"});
    expectInputError(head + "  s: {tpms: gyroid, cell: 8, density: {ramp: {axis: z, from: 0.1, to: 1.2}}}\nresult: s\n",
                     {"test.yaml:4:", "density", "1.2"});
    expectInputError(head + "  s: {tpms: gyroid, cell: 8, density: {ramp: {axis: w, from: 0.1, to: 0.2}}}\nresult: s\n",
                     {"x, y or z"});
    expectInputError(head + "  rho: {sphere: {radius: 3}}\n  s: {tpms: gyroid, cell: 8, density: rho}\nresult: s\n",
                     {"density", "reaches", " at ("});
    expectInputError(head + "  s: {tpms: gyroid, cell: 8, density: {file: rho.csv}}\nresult: s\n", {"reaches"});
    expectInputError(head + "  s: {tpms: gyroid, cell: 8, density: {file: missing.csv}}\nresult: s\n", {"missing.csv"});
}

TEST(ThicknessRecipes, ThickWallsWarnWithNumbers)
{
    test::TempDir dir;
    Job job(recipe(
        "voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n  s: {tpms: gyroid, cell: 8, solid: sheet, "
        "thickness: 1.2}\nresult: s\n",
        dir));
    const auto report = job.report();
    ASSERT_TRUE(report.contains("warnings"));
    EXPECT_EQ(report["warnings"][0]["code"], "thick_walls");
    EXPECT_EQ(report["warnings"][0]["wall_mm"], 1.2);
    const std::string w = report["warnings"][0]["message"];
    EXPECT_NE(w.find("1.2 mm"), std::string::npos) << w;
    EXPECT_NE(w.find("15 %"), std::string::npos) << w;
}

TEST(ThicknessRecipes, ZeroDirectionFieldFailsAndWritesNothing)
{
    test::TempDir dir;
    const auto path = dir.write("bad.yaml", R"(voxel: 0.25
domain: {box: [[0, 0, 0], [4, 4, 4]]}
fields:
  lattice: {tpms: gyroid, cell: 4, solid: sheet, wall: 0.4, layer: 0.2, build: [0, 0, 0.0001]}
  flat: {tpms: gyroid, cell: 4, solid: sheet, wall: 0.4, layer: 0.2, build: [0, 0, {ramp: {axis: z, from: 0, to: 0}}]}
result: flat
outputs: {mesh: out.stl}
)");
    std::string out;
    EXPECT_NE(test::runCommand(
                  test::voxlatBinary() + " -q run " + path.string() + " --out " + (dir.path / "out").string(), &out),
              0);
    EXPECT_NE(out.find("build direction is zero"), std::string::npos) << out;
    EXPECT_FALSE(std::filesystem::exists(dir.path / "out" / "out.stl"));
}

TEST(ThicknessRecipes, BuildDirectionFromAVectorField)
{
    // A `vector:` field named as the build direction must give the same walls as the same
    // direction written as three component fields.
    const std::string head = R"(voxel: 0.25
domain: {box: [[0, 0, 0], [8, 8, 8]]}
fields:
  tilt: {vector: ["x - 4", 1, 2]}
  tx: {expr: "x - 4"}
)";
    const auto build = [&](const std::string& direction) {
        const Recipe r =
            parseRecipe(head + "  s: {tpms: gyroid, cell: 8, solid: sheet, wall: 0.4, layer: 0.2, build: " + direction +
                            "}\nresult: s\n",
                        "v.yaml", ".");
        Job job(r);
        return job.field("s");
    };
    const FieldPtr byVector = build("tilt"), byComponents = build("[tx, 1, 2]");
    for (const Vec3d& p : randomPoints(50, 0.5, 7.5, 21)) EXPECT_DOUBLE_EQ(byVector->value(p), byComponents->value(p));
    // And it differs from the default +z build direction, so the field was really used.
    const FieldPtr vertical = build("[0, 0, 1]");
    double largest = 0.0;
    for (const Vec3d& p : randomPoints(200, 0.5, 7.5, 22))
        largest = std::max(largest, std::abs(byVector->value(p) - vertical->value(p)));
    EXPECT_GT(largest, 1e-3);
}

namespace {

/// The distance from @a x to the zero set of @a f near it: Newton onto the surface, then the
/// foot point slid until x - y is along the normal (a few rounds; exact for small distances).
double distanceToSurface(const FieldNode& f, const Vec3d& x)
{
    Vec3d y = x;
    for (int round = 0; round < 30; ++round) {
        for (int k = 0; k < 20; ++k) {
            const auto [v, g] = f.valueAndGradient(y);
            y -= (v / g.lengthSqr()) * g;
        }
        const Vec3d n = f.valueAndGradient(y).second.unit();
        const Vec3d d = x - y;
        y += d - d.dot(n) * n;  // the tangential part: towards the foot point
    }
    for (int k = 0; k < 20; ++k) {
        const auto [v, g] = f.valueAndGradient(y);
        y -= (v / g.lengthSqr()) * g;
    }
    return (x - y).length();
}

}  // namespace

TEST(Offset, GyroidNetworkMovesByTheOffsetInMillimetres)
{
    // The offset network's surface (mesh vertices moved onto it) lies m from the original
    // surface, along its normal, within a small fraction of the 0.1 mm voxel.
    const FieldPtr original = gyroid(10.0);
    for (const double m : {0.3, -0.3}) {
        const std::string text =
            "voxel: 0.1\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n"
            "  g: {tpms: gyroid, cell: 10, offset: " +
            std::to_string(m) + "}\nresult: g\n";
        Job job(parseRecipe(text, "offset.yaml", "."));
        MeshOptions projected;
        projected.project = true;
        const TriangleMesh& mesh = job.mesh(projected);
        double worst = 0.0, sum = 0.0;
        int n = 0;
        for (std::size_t i = 0; i < mesh.points.size(); i += 7) {
            const Vec3d p(mesh.points[i][0], mesh.points[i][1], mesh.points[i][2]);
            if (std::min({p[0], p[1], p[2]}) < 0.5 || std::max({p[0], p[1], p[2]}) > 9.5) continue;
            // The solid grows for m > 0: the vertex is outside the original (f > 0) by m.
            EXPECT_EQ(original->value(p) > 0.0, m > 0.0);
            const double err = std::abs(distanceToSurface(*original, p) - std::abs(m));
            worst = std::max(worst, err);
            sum += err;
            ++n;
        }
        ASSERT_GT(n, 1000);
        EXPECT_LT(worst, 0.002) << "m = " << m;  // a fiftieth of a voxel (measured: 0.0002 mm)
        EXPECT_LT(sum / n, 0.0005) << "m = " << m;
        std::cout << "offset " << m << " mm: |distance - m| max " << worst << " mm, mean " << sum / n << " mm over "
                  << n << " vertices\n";
    }
}

TEST(Offset, RecipeErrorsNameTheKey)
{
    const std::string head = "voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n";
    struct Case {
        std::string field, expect;
    };
    const std::vector<Case> cases{
        {"  g: {tpms: gyroid, cell: 10, solid: sheet, level: 0.3, offset: 0.2}\n", "a sheet takes `thickness:`"},
        {"  g: {tpms: gyroid, cell: 10, solid: sheet, thickness: 0.5, offset: 0.2}\n", "a sheet takes `thickness:`"},
        {"  g: {tpms: gyroid, cell: 10, density: 0.3, offset: 0.2}\n", "not both"},
    };
    for (const Case& c : cases) {
        try {
            Job job(parseRecipe(head + c.field + "result: g\n", "bad.yaml", "."));
            ADD_FAILURE() << "no error for " << c.field;
        } catch (const InputError& e) {
            EXPECT_NE(std::string(e.what()).find("bad.yaml:4:"), std::string::npos) << e.what();
            EXPECT_NE(std::string(e.what()).find(c.expect), std::string::npos) << e.what();
        }
    }
}

TEST(ThicknessRecipes, WallsThinnerThanTwoVoxelsWarnBeforeEvaluation)
{
    test::TempDir dir;
    auto warningsOf = [](const nlohmann::json& report) {
        std::vector<std::string> codes;
        if (report.contains("warnings"))
            for (const auto& w : report["warnings"]) codes.push_back(w["code"]);
        return codes;
    };
    // Walls in millimetres: 0.15 mm on 0.1 mm voxels is less than two voxels.
    Job thin(
        recipe("voxel: 0.1\ndomain: {box: [[0, 0, 0], [4, 4, 4]]}\nfields:\n  s: {tpms: gyroid, cell: 4, "
               "solid: sheet, thickness: 0.15}\nresult: s\n",
               dir));
    thin.solveLevels();
    const auto report = thin.report();
    EXPECT_EQ(report["fields"]["s"]["thinnest_wall_mm"].get<double>(), 0.15);
    ASSERT_EQ(warningsOf(report), std::vector<std::string>{"sub_voxel_features"});
    const std::string w = report["warnings"][0]["message"];
    EXPECT_NE(w.find("its thinnest walls are 0.15 mm across, less than two voxels (0.2 mm)"), std::string::npos) << w;
    EXPECT_NE(w.find("use `voxel: 0.075`"), std::string::npos) << w;
    // 0.3 mm walls are fine there.
    Job fine(
        recipe("voxel: 0.1\ndomain: {box: [[0, 0, 0], [4, 4, 4]]}\nfields:\n  s: {tpms: gyroid, cell: 4, "
               "solid: sheet, thickness: 0.3}\nresult: s\n",
               dir));
    fine.solveLevels();
    EXPECT_TRUE(warningsOf(fine.report()).empty());
}

TEST(ThicknessRecipes, ALevelSheetsThinnestWallMatchesRaysAcrossIt)
{
    // A sheet |f| <= t: the job's thinnest wall (from the steepest gradient on the mid-surface)
    // against walls measured independently: from points on f = 0, march along the normal both
    // ways to |f| = t and take the distance between the two crossings.
    test::TempDir dir;
    const double cell = 5.0, t = 0.15;
    Job job(
        recipe("voxel: 0.2\ndomain: {box: [[0, 0, 0], [5, 5, 5]]}\nfields:\n  s: {tpms: schwarz-p, cell: 5, "
               "solid: sheet, level: 0.15}\nresult: s\n",
               dir));
    job.solveLevels();
    const double reported = job.report()["fields"]["s"]["thinnest_wall_mm"].get<double>();
    const TpmsField f(TpmsType::SchwarzP, Vec3d(cell));
    auto value = [&](const Vec3d& p) {
        double v = 0.0;
        f.values(std::span<const Vec3d>(&p, 1), std::span<double>(&v, 1));
        return v;
    };
    auto crossing = [&](Vec3d p, const Vec3d& dir, double target) {
        // |f| grows from 0 along dir: step out, then bisect.
        double lo = 0.0, hi = 0.0;
        while (std::abs(value(p + dir * hi)) < target) lo = hi, hi += 0.01;
        for (int i = 0; i < 50; ++i) {
            const double mid = 0.5 * (lo + hi);
            (std::abs(value(p + dir * mid)) < target ? lo : hi) = mid;
        }
        return 0.5 * (lo + hi);
    };
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(0.0, cell);
    double measured = std::numeric_limits<double>::infinity();
    int samples = 0;
    while (samples < 4000) {
        // A point on the mid-surface: bisect f along x between a sign change.
        Vec3d a(u(rng), u(rng), u(rng)), b = a + Vec3d(0.5, 0.0, 0.0);
        if (value(a) * value(b) > 0.0) continue;
        for (int i = 0; i < 60; ++i) {
            const Vec3d m = 0.5 * (a + b);
            (value(m) * value(a) > 0.0 ? a : b) = m;
        }
        const Vec3d p = 0.5 * (a + b);
        double v = 0.0;
        Vec3d g;
        f.gradients(std::span<const Vec3d>(&p, 1), std::span<double>(&v, 1), std::span<Vec3d>(&g, 1));
        if (g.length() < 1e-6) continue;
        const Vec3d n = g / g.length();
        measured = std::min(measured, crossing(p, n, t) + crossing(p, -n, t));
        ++samples;
    }
    EXPECT_NEAR(reported, measured, 0.03 * measured) << "reported " << reported << ", measured " << measured;
}
