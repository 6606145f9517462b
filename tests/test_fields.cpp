// Field nodes: TPMS values and gradients against the written equations and finite differences,
// bounds that contain every sampled value, primitives against their analytic distances.
#include "fields/core/Constant.h"
#include "fields/core/SinCos.h"
#include "fields/levels/LevelSolid.h"
#include "fields/maps/Ramp.h"
#include "fields/shapes/Boolean.h"
#include "fields/shapes/BoxField.h"
#include "fields/shapes/Cylinder.h"
#include "fields/shapes/Sphere.h"
#include "fields/shapes/Transform.h"
#include "fields/shapes/Unary.h"
#include "fields/tpms/TpmsEquations.h"
#include "fields/tpms/TpmsField.h"

#include "FieldChecks.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <numbers>
#include <random>
#include <thread>

using namespace voxlat;
using namespace voxlat::test;

namespace {

/// The reference table's equations written out by hand with std::sin/cos (independent of the
/// templated code under test).
double referenceTpms(TpmsType type, double x, double y, double z, double cell)
{
    const double k = 2 * std::numbers::pi / cell, X = k * x, Y = k * y, Z = k * z;
    using std::cos, std::sin;
    switch (type) {
        case TpmsType::Gyroid:
            return sin(X) * cos(Y) + sin(Y) * cos(Z) + sin(Z) * cos(X);
        case TpmsType::SchwarzP:
            return cos(X) + cos(Y) + cos(Z);
        case TpmsType::SchwarzD:
            return sin(X) * sin(Y) * sin(Z) + sin(X) * cos(Y) * cos(Z) + cos(X) * sin(Y) * cos(Z) +
                   cos(X) * cos(Y) * sin(Z);
        case TpmsType::IWP:
            return 2 * (cos(X) * cos(Y) + cos(Y) * cos(Z) + cos(Z) * cos(X)) - (cos(2 * X) + cos(2 * Y) + cos(2 * Z));
        case TpmsType::Neovius:
            return 3 * (cos(X) + cos(Y) + cos(Z)) + 4 * cos(X) * cos(Y) * cos(Z);
        case TpmsType::FischerKochS:
            return cos(2 * X) * sin(Y) * cos(Z) + cos(X) * cos(2 * Y) * sin(Z) + sin(X) * cos(Y) * cos(2 * Z);
        case TpmsType::Lidinoid:
            return (sin(2 * X) * cos(Y) * sin(Z) + sin(2 * Y) * cos(Z) * sin(X) + sin(2 * Z) * cos(X) * sin(Y)) -
                   (cos(2 * X) * cos(2 * Y) + cos(2 * Y) * cos(2 * Z) + cos(2 * Z) * cos(2 * X)) + 0.3;
        case TpmsType::SplitP:
            return 1.1 * (sin(2 * X) * cos(Y) * sin(Z) + sin(2 * Y) * cos(Z) * sin(X) + sin(2 * Z) * cos(X) * sin(Y)) -
                   0.2 * (cos(2 * X) * cos(2 * Y) + cos(2 * Y) * cos(2 * Z) + cos(2 * Z) * cos(2 * X)) -
                   0.4 * (cos(2 * X) + cos(2 * Y) + cos(2 * Z));
        case TpmsType::FRD:
            return 8 * cos(X) * cos(Y) * cos(Z) + cos(2 * X) * cos(2 * Y) * cos(2 * Z) -
                   (cos(2 * X) * cos(2 * Y) + cos(2 * Y) * cos(2 * Z) + cos(2 * Z) * cos(2 * X));
    }
    return 0;
}

const std::vector<TpmsType> kAllTpms{TpmsType::Gyroid,   TpmsType::SchwarzP, TpmsType::SchwarzD,
                                     TpmsType::IWP,      TpmsType::Neovius,  TpmsType::FischerKochS,
                                     TpmsType::Lidinoid, TpmsType::SplitP,   TpmsType::FRD};

}  // namespace

TEST(Tpms, ValuesMatchReferenceEquations)
{
    const auto pts = randomPoints(500, -20, 20, 1);
    for (TpmsType type : kAllTpms) {
        TpmsField f(type, Vec3d(7.5));
        std::vector<double> v(pts.size());
        f.values(pts, v);
        for (std::size_t n = 0; n < pts.size(); ++n)
            ASSERT_NEAR(v[n], referenceTpms(type, pts[n][0], pts[n][1], pts[n][2], 7.5), 1e-12) << tpmsName(type);
    }
}

TEST(Tpms, GradientsMatchFiniteDifferences)
{
    const auto pts = randomPoints(100, -10, 10, 2);
    for (TpmsType type : kAllTpms) {
        SCOPED_TRACE(std::string(tpmsName(type)));
        expectGradientsMatchFiniteDifferences(TpmsField(type, Vec3d(6, 8, 10)), pts, 1e-6);
    }
}

TEST(Tpms, GyroidGradientMatchesHandDerivative)
{
    const double cell = 10, k = 2 * std::numbers::pi / cell;
    TpmsField f(TpmsType::Gyroid, Vec3d(cell));
    for (const Vec3d& p : randomPoints(200, -15, 15, 3)) {
        const double X = k * p[0], Y = k * p[1], Z = k * p[2];
        const Vec3d expected(k * (std::cos(X) * std::cos(Y) - std::sin(Z) * std::sin(X)),
                             k * (-std::sin(X) * std::sin(Y) + std::cos(Y) * std::cos(Z)),
                             k * (-std::sin(Y) * std::sin(Z) + std::cos(Z) * std::cos(X)));
        const Vec3d g = f.valueAndGradient(p).second;
        for (int a = 0; a < 3; ++a) EXPECT_NEAR(g[a], expected[a], 1e-12);
    }
}

TEST(Tpms, GyroidWrittenOutGivesTheDualNumbersDoubles)
{
    // gradients() writes the gyroid's derivative out instead of through dual numbers: the same
    // doubles, bit for bit, as the dual numbers from the same sines and cosines.
    const Vec3d cell(6, 8, 10);
    const auto pts = randomPoints(100, -20, 20, 4);
    const TpmsField f(TpmsType::Gyroid, cell);
    std::vector<double> v(pts.size());
    std::vector<Vec3d> g(pts.size());
    f.gradients(pts, v, g);
    double wave[3], angle[3][100], sn[3][100], cs[3][100];
    for (int a = 0; a < 3; ++a) {
        wave[a] = 2.0 * std::numbers::pi / cell[a];
        for (std::size_t n = 0; n < pts.size(); ++n) angle[a][n] = wave[a] * pts[n][a];
        sinCosBatch(angle[a], sn[a], cs[a], pts.size());
    }
    for (std::size_t n = 0; n < pts.size(); ++n) {
        const Dual3 x(angle[0][n], wave[0], 0, 0), y(angle[1][n], 0, wave[1], 0), z(angle[2][n], 0, 0, wave[2]);
        const Dual3 d = tpmsEquation(TpmsType::Gyroid, trigTermsFrom(sn[0][n], cs[0][n], x),
                                     trigTermsFrom(sn[1][n], cs[1][n], y), trigTermsFrom(sn[2][n], cs[2][n], z));
        ASSERT_EQ(v[n], d.v) << n;
        for (int a = 0; a < 3; ++a) ASSERT_EQ(g[n][a], d.d[a]) << n << " axis " << a;
    }
}

TEST(Tpms, CellSizePerAxisSetsPeriod)
{
    TpmsField f(TpmsType::SchwarzP, Vec3d(4, 6, 9));
    for (const Vec3d& p : randomPoints(50, -5, 5, 4)) {
        EXPECT_NEAR(f.value(p), f.value(p + Vec3d(4, 0, 0)), 1e-12);
        EXPECT_NEAR(f.value(p), f.value(p + Vec3d(0, 6, 0)), 1e-12);
        EXPECT_NEAR(f.value(p), f.value(p + Vec3d(0, 0, 9)), 1e-12);
    }
}

TEST(Periods, CommonPeriodRules)
{
    const double none = FieldNode::kNoPeriod, any = FieldNode::kInvariant;
    EXPECT_EQ(commonPeriod(none, 5), none);
    EXPECT_EQ(commonPeriod(any, 5), 5);
    EXPECT_EQ(commonPeriod(5, any), 5);
    EXPECT_EQ(commonPeriod(any, any), any);
    EXPECT_EQ(commonPeriod(5, 10), 10);
    EXPECT_DOUBLE_EQ(commonPeriod(0.1 * 3, 0.3), 0.3);  // equal up to rounding
    EXPECT_EQ(commonPeriod(5, 7.5), none);
}

TEST(Periods, ReportedPeriodsRepeatTheField)
{
    // Every period a node reports must repeat its values; a node that cannot know says none.
    auto expectRepeats = [](const FieldNode& f, const std::array<double, 3>& expected, const char* what) {
        for (int a = 0; a < 3; ++a) {
            const double p = f.period(a);
            if (std::isinf(expected[a]))
                EXPECT_TRUE(std::isinf(p)) << what << " axis " << a;
            else
                EXPECT_NEAR(p, expected[a], 1e-12 * std::max(1.0, expected[a])) << what << " axis " << a;
            if (p == FieldNode::kNoPeriod) continue;
            Vec3d step(0.0);
            step[a] = std::isinf(p) ? 123.4 : p;
            for (const Vec3d& x : randomPoints(40, -6, 6, 20 + a))
                EXPECT_NEAR(f.value(x), f.value(x + step), 1e-10 * (1 + std::abs(f.value(x)))) << what << " axis " << a;
        }
    };
    const double none = FieldNode::kNoPeriod, any = FieldNode::kInvariant;
    for (TpmsType type : kAllTpms) expectRepeats(TpmsField(type, Vec3d(4, 6, 9)), {4, 6, 9}, "tpms");
    auto gyroid = std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(4, 6, 9));
    auto p2 = std::make_shared<TpmsField>(TpmsType::SchwarzP, Vec3d(2));
    expectRepeats(LevelSolid(gyroid, SolidSide::Band, 0.3), {4, 6, 9}, "sheet");
    expectRepeats(UnaryField(gyroid, UnaryOp::Abs), {4, 6, 9}, "abs");
    expectRepeats(BooleanField(BooleanOp::Union, {gyroid, p2}), {4, 6, none}, "union");  // 9 is not a multiple of 2
    expectRepeats(TransformField(p2, TransformField::rotation(Vec3d(0, 0, 1), 30), Vec3d(1, 2, 3)), {none, none, 2},
                  "rotated about z");
    // A quarter turn about x takes the child's y to z and its z to y.
    expectRepeats(TransformField(gyroid, TransformField::rotation(Vec3d(1, 0, 0), 90), Vec3d(0)), {4, 9, 6},
                  "quarter turn");
    Mat3d scale = Mat3d::zero();
    scale(0, 0) = 2, scale(1, 1) = 1, scale(2, 2) = 0.5;
    expectRepeats(TransformField(gyroid, scale, Vec3d(1, 2, 3)), {8, 6, 4.5}, "scaled");
    expectRepeats(RampField(0, 0, 1, 0.1, 0.3), {none, any, any}, "ramp along x");
    expectRepeats(ConstantField(2), {any, any, any}, "constant");
    expectRepeats(BooleanField(BooleanOp::Intersection, {gyroid, std::make_shared<RampField>(0, 0, 1, 0.1, 0.3)}),
                  {none, 6, 9}, "clipped along x");
    expectRepeats(Sphere(Vec3d(0), 1), {none, none, none}, "sphere");
}

TEST(SinCos, WithinThreeAndAHalfUlpAndTheSameWhereverAnAngleFallsInABatch)
{
    // Against long double sin and cos: at most 3.5 units in the last place (SLEEF's u35 bound, plus
    // the rounding of the reference), over the angles TPMS coordinates reach and a few exact ones.
    std::mt19937_64 random(17);
    std::uniform_real_distribution<double> uniform(-3000.0, 3000.0);
    std::vector<double> x = {0.0, -0.0, std::numbers::pi / 2, std::numbers::pi, 1e-300, 1e-8, -2.5, 700.125};
    for (int i = 0; i < 20000; ++i) x.push_back(uniform(random));
    std::vector<double> s(x.size()), c(x.size());
    sinCosBatch(x.data(), s.data(), c.data(), x.size());
    for (std::size_t i = 0; i < x.size(); ++i) {
        const long double rs = std::sin((long double)x[i]), rc = std::cos((long double)x[i]);
        // An ulp of the exact value, and the absolute rounding floor near zero.
        auto ulp = [](long double v) { return std::max(std::abs(std::nextafter(double(v), 2.0) - double(v)), 1e-300); };
        ASSERT_LE(std::abs((long double)s[i] - rs), 3.51L * ulp(rs)) << x[i];
        ASSERT_LE(std::abs((long double)c[i] - rc), 3.51L * ulp(rc)) << x[i];
    }
    EXPECT_EQ(s[0], 0.0);
    EXPECT_EQ(c[0], 1.0);
    // Every angle gets the same doubles at any position and in any batch length (the tails of a
    // batch go through the same vector function).
    for (std::size_t offset = 0; offset < 5; ++offset)
        for (std::size_t n = 1; n <= 9; ++n) {
            double ps[9], pc[9];
            sinCosBatch(x.data() + 8 + offset, ps, pc, n);
            for (std::size_t k = 0; k < n; ++k) {
                ASSERT_EQ(ps[k], s[8 + offset + k]);
                ASSERT_EQ(pc[k], c[8 + offset + k]);
            }
        }
}

TEST(Tpms, GridBatchFastPathEqualsPointPath)
{
    for (TpmsType type : kAllTpms) {
        TpmsField f(type, Vec3d(5, 7, 9));
        GridBatch batch;
        batch.origin = Vec3d(-3.05, 1.15, 7.25);
        batch.spacing = Vec3d(0.1, 0.2, 0.3);
        std::vector<double> fast(batch.size()), slow(batch.size());
        f.gridValues(batch, fast);
        f.FieldNode::gridValues(batch, slow);
        for (std::size_t n = 0; n < fast.size(); ++n) ASSERT_EQ(fast[n], slow[n]);
    }
}

namespace {

/// A 9 x 8 x 11 batch at @a origin (sizes that differ per axis, so a swapped index shows).
GridBatch unevenBatch(const Vec3d& origin, const Vec3d& spacing)
{
    GridBatch batch;
    batch.origin = origin;
    batch.spacing = spacing;
    batch.nx = 9;
    batch.ny = 8;
    batch.nz = 11;
    return batch;
}

}  // namespace

TEST(Fields, BoxGridValuesAreItsPointValues)
{
    // BoxField's grid path (q per axis, once per row) gives eval()'s doubles bit for bit, for
    // batches inside, across and outside the box (the sparse evaluator clips with it).
    const BoxField box(Box3{Vec3d(-1.3, 0.2, 2.0), Vec3d(4.1, 3.3, 2.7)});
    for (const Vec3d& origin : {Vec3d(-2.05, -0.35, 1.85), Vec3d(0.15, 1.05, 2.15), Vec3d(5.0, 4.0, 3.0)}) {
        const GridBatch batch = unevenBatch(origin, Vec3d(0.1, 0.13, 0.07));
        std::vector<double> fast(batch.size()), slow(batch.size());
        box.gridValues(batch, fast);
        box.FieldNode::gridValues(batch, slow);
        for (std::size_t n = 0; n < fast.size(); ++n) ASSERT_EQ(fast[n], slow[n]) << n;
    }
}

TEST(Fields, CylinderGridValuesAreItsPointValues)
{
    // Cylinder's grid path (the axial term per index along a coordinate axis, the radial one per
    // column) gives distance()'s doubles bit for bit, for batches inside, across the mantle and
    // the caps, and outside, along x, y and z (a negative axis and a tilted one take the points).
    // Compared as bits: a wrong path could still agree in value at a few points.
    for (const Vec3d& axis : {Vec3d(1, 0, 0), Vec3d(0, 3, 0), Vec3d(0, 0, 1), Vec3d(0, 0, -1), Vec3d(0.3, -0.2, 1.0)}) {
        const Cylinder cyl(Vec3d(0.4, -0.3, 1.1), axis, 1.7, 2.9);
        for (const Vec3d& origin :
             {Vec3d(-2.05, -0.35, 0.85), Vec3d(0.15, -1.05, -0.4), Vec3d(-0.3, 0.2, 2.1), Vec3d(3.0, 4.0, 5.0)}) {
            const GridBatch batch = unevenBatch(origin, Vec3d(0.21, 0.13, 0.17));
            std::vector<double> fast(batch.size()), slow(batch.size());
            cyl.gridValues(batch, fast);
            cyl.FieldNode::gridValues(batch, slow);
            std::size_t inside = 0;
            for (std::size_t n = 0; n < fast.size(); ++n) {
                ASSERT_EQ(std::memcmp(&fast[n], &slow[n], sizeof(double)), 0) << n << ": " << fast[n] << " " << slow[n];
                inside += slow[n] < 0.0;
            }
            if (origin == Vec3d(-0.3, 0.2, 2.1)) EXPECT_GT(inside, 0u);  // a batch across the surface
        }
    }
}

TEST(Tpms, LevelInOnePassAndCachedAxisTermsGiveTheSameDoubles)
{
    // A sheet or network of a TPMS applies its level as the TPMS makes its values, and the TPMS
    // keeps the last axis terms per thread; both must give exactly the doubles of the plain
    // two-pass evaluation on a fresh thread, for slices (the slicer's 66 x 66 batches, the
    // gyroid's own loop) and for volumes, whatever was evaluated before.
    auto evaluate = [](const FieldNode& f, const GridBatch& batch) {
        std::vector<double> out(batch.size());
        f.gridValues(batch, out);
        return out;
    };
    auto onFreshThread = [&](const FieldNode& f, const GridBatch& batch) {
        std::vector<double> out;
        std::thread([&] { out = evaluate(f, batch); }).join();
        return out;
    };
    auto apply = [](std::vector<double> v, SolidSide side, double level) {
        for (double& x : v)
            x = side == SolidSide::Below ? x - level : side == SolidSide::Band ? std::abs(x) - level : level - x;
        return v;
    };
    std::vector<GridBatch> batches;
    for (int k = 0; k < 4; ++k) {
        GridBatch slice;
        slice.origin = Vec3d(-3.05 + 3.2 * (k % 2), 1.15 + 3.2 * (k / 2), 7.25);
        slice.spacing = Vec3d(0.05, 0.05, 1.0);
        slice.nx = 66;
        slice.ny = 66;
        slice.nz = 1;
        batches.push_back(slice);
    }
    GridBatch volume;
    volume.origin = Vec3d(0.3, -0.7, 1.1);
    volume.spacing = Vec3d(0.1, 0.2, 0.15);
    volume.nx = 20;
    volume.ny = 17;
    volume.nz = 18;
    batches.push_back(volume);
    for (TpmsType type : kAllTpms) {
        auto tpms = std::make_shared<TpmsField>(type, Vec3d(5, 7, 9));
        for (SolidSide side : {SolidSide::Below, SolidSide::Band, SolidSide::Above}) {
            const LevelSolid solid(tpms, side, 0.3);
            // Twice over the batches, so the second round finds the first round's terms.
            for (int round = 0; round < 2; ++round)
                for (const GridBatch& batch : batches) {
                    SCOPED_TRACE(std::string(tpmsName(type)) + " side " + std::to_string(int(side)) + " round " +
                                 std::to_string(round));
                    const std::vector<double> raw = onFreshThread(*tpms, batch);
                    ASSERT_TRUE(evaluate(*tpms, batch) == raw);
                    ASSERT_TRUE(evaluate(solid, batch) == apply(raw, side, 0.3));
                }
        }
    }
}

TEST(Tpms, BoundsContainValues)
{
    for (TpmsType type : kAllTpms) {
        SCOPED_TRACE(std::string(tpmsName(type)));
        expectBoundsContainValues(TpmsField(type, Vec3d(5)), -10, 10, 3, 5);
    }
}

TEST(Tpms, LevelSolidSidesAndGradients)
{
    auto raw = std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(10));
    const auto pts = randomPoints(100, -10, 10, 6);
    for (SolidSide side : {SolidSide::Below, SolidSide::Band, SolidSide::Above}) {
        LevelSolid s(raw, side, 0.3);
        for (const Vec3d& p : pts) {
            const double f = raw->value(p);
            const double expected = side == SolidSide::Below  ? f - 0.3
                                    : side == SolidSide::Band ? std::abs(f) - 0.3
                                                              : 0.3 - f;
            EXPECT_DOUBLE_EQ(s.value(p), expected);
            // The indicator's sub-level set at levelFromIndicator^-1 is the same solid.
            const double g = s.indicator()->value(p);
            const double indicatorLevel = side == SolidSide::Above ? -0.3 : 0.3;
            EXPECT_EQ(g < indicatorLevel, s.value(p) < 0);
        }
        expectGradientsMatchFiniteDifferences(s, pts, 1e-6);
        expectBoundsContainValues(s, -10, 10, 3, 7);
    }
}

TEST(Primitives, DistancesAreExact)
{
    Sphere sphere(Vec3d(1, 2, 3), 4);
    EXPECT_NEAR(sphere.value(Vec3d(1, 2, 3)), -4, 1e-12);
    EXPECT_NEAR(sphere.value(Vec3d(1, 2, 10)), 3, 1e-12);
    BoxField box(Box3{Vec3d(0), Vec3d(2, 4, 6)});
    EXPECT_NEAR(box.value(Vec3d(1, 2, 3)), -1, 1e-12);  // nearest face x
    EXPECT_NEAR(box.value(Vec3d(5, 2, 3)), 3, 1e-12);   // face
    EXPECT_NEAR(box.value(Vec3d(5, 8, 3)), 5, 1e-12);   // edge: 3-4-5
    Cylinder cyl(Vec3d(0), Vec3d(0, 0, 2), 1, 4);
    EXPECT_NEAR(cyl.value(Vec3d(0, 0, 0)), -1, 1e-12);
    EXPECT_NEAR(cyl.value(Vec3d(3, 0, 0)), 2, 1e-12);
    EXPECT_NEAR(cyl.value(Vec3d(0, 0, 5)), 3, 1e-12);
    EXPECT_NEAR(cyl.value(Vec3d(4, 0, 6)), 5, 1e-12);  // rim: 3-4-5
    const auto pts = randomPoints(100, -6, 6, 8);
    for (const FieldNode* f : std::initializer_list<const FieldNode*>{&sphere, &box, &cyl}) {
        expectGradientsMatchFiniteDifferences(*f, pts, 1e-5);
        expectBoundsContainValues(*f, -6, 6, 4, 9);
    }
}

TEST(Booleans, HardAndSmoothCombinations)
{
    auto a = std::make_shared<Sphere>(Vec3d(0), 2.0), b = std::make_shared<Sphere>(Vec3d(2, 0, 0), 2.0);
    BooleanField uni(BooleanOp::Union, {a, b}), inter(BooleanOp::Intersection, {a, b}),
        diff(BooleanOp::Difference, {a, b}), smooth(BooleanOp::Union, {a, b}, 1.0);
    const auto pts = randomPoints(200, -4, 6, 10);
    for (const Vec3d& p : pts) {
        const double va = a->value(p), vb = b->value(p);
        EXPECT_DOUBLE_EQ(uni.value(p), std::min(va, vb));
        EXPECT_DOUBLE_EQ(inter.value(p), std::max(va, vb));
        EXPECT_DOUBLE_EQ(diff.value(p), std::max(va, -vb));
        EXPECT_LE(smooth.value(p), std::min(va, vb) + 1e-12);
        EXPECT_GE(smooth.value(p), std::min(va, vb) - 0.25 - 1e-12);
    }
    for (const FieldNode* f : std::initializer_list<const FieldNode*>{&uni, &inter, &diff, &smooth}) {
        expectGradientsMatchFiniteDifferences(*f, pts, 1e-4);
        expectBoundsContainValues(*f, -5, 5, 3, 11);
    }
}

TEST(Transforms, MoveTheChild)
{
    auto s = std::make_shared<Sphere>(Vec3d(1, 0, 0), 1.0);
    TransformField moved(s, Mat3d::identity(), Vec3d(0, 5, 0));
    EXPECT_NEAR(moved.value(Vec3d(1, 5, 0)), -1, 1e-12);
    TransformField turned(s, TransformField::rotation(Vec3d(0, 0, 1), 90), Vec3d(0));
    EXPECT_NEAR(turned.value(Vec3d(0, 1, 0)), -1, 1e-12);  // (1,0,0) rotated to (0,1,0)
    auto g = std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(5));
    Mat3d scale = Mat3d::zero();
    scale(0, 0) = 2, scale(1, 1) = 1, scale(2, 2) = 0.5;
    TransformField scaled(g, scale, Vec3d(1, 2, 3));
    GridBatch batch;
    batch.origin = Vec3d(0.3, -1, 2);
    batch.spacing = Vec3d(0.1);
    std::vector<double> fast(batch.size()), slow(batch.size());
    scaled.gridValues(batch, fast);
    scaled.FieldNode::gridValues(batch, slow);
    for (std::size_t n = 0; n < fast.size(); ++n) EXPECT_NEAR(fast[n], slow[n], 1e-12);
    const auto pts = randomPoints(100, -5, 5, 12);
    for (const FieldNode* f : std::initializer_list<const FieldNode*>{&moved, &turned, &scaled}) {
        expectGradientsMatchFiniteDifferences(*f, pts, 1e-5);
        expectBoundsContainValues(*f, -5, 5, 3, 13);
    }
}
