// User equations: values, gradients and bounds against the built-in nodes and hand-written
// references; batch paths against the point path; syntax errors with their positions.
#include "fields/expr/ExprField.h"
#include "fields/expr/Expression.h"
#include "fields/shapes/Sphere.h"
#include "fields/tpms/TpmsField.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

using namespace voxlat;

namespace {

const char* kGyroid =
    "sin(2*pi*x/$cell)*cos(2*pi*y/$cell) + sin(2*pi*y/$cell)*cos(2*pi*z/$cell) + "
    "sin(2*pi*z/$cell)*cos(2*pi*x/$cell)";

ExprProgram compileWith(const std::string& text, double cell = 7.0)
{
    return ExprProgram::compile(text, [cell](const std::string& name, bool isParam) {
        if (isParam && name == "cell") return ExprSymbol{ExprSymbol::Kind::Constant, cell, -1};
        if (!isParam && name == "ball") return ExprSymbol{ExprSymbol::Kind::Input, 0.0, 0};
        return ExprSymbol{};
    });
}

FieldPtr exprField(const std::string& text, std::vector<FieldPtr> inputs = {}, double cell = 7.0)
{
    return std::make_shared<ExprField>(std::make_shared<const ExprProgram>(compileWith(text, cell)), std::move(inputs));
}

std::vector<Vec3d> randomPoints(std::size_t n, double lo, double hi, unsigned seed = 7)
{
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> u(lo, hi);
    std::vector<Vec3d> p(n);
    for (auto& v : p) v = Vec3d(u(rng), u(rng), u(rng));
    return p;
}

std::string errorOf(const std::string& text)
{
    try {
        compileWith(text);
    } catch (const ExprError& e) {
        return std::string(e.what()) + " @" + std::to_string(e.position());
    }
    return "";
}

}  // namespace

TEST(Expr, GyroidMatchesTheBuiltInNode)
{
    const TpmsField builtin(TpmsType::Gyroid, Vec3d(7.0));
    const FieldPtr user = exprField(kGyroid);
    const auto pts = randomPoints(2000, -30, 30);
    std::vector<double> a(pts.size()), b(pts.size());
    std::vector<Vec3d> ga(pts.size()), gb(pts.size());
    builtin.gradients(pts, a, ga);
    user->gradients(pts, b, gb);
    double worst = 0, worstGrad = 0;
    for (std::size_t i = 0; i < pts.size(); ++i) {
        worst = std::max(worst, std::abs(a[i] - b[i]));
        worstGrad = std::max(worstGrad, (ga[i] - gb[i]).length());
    }
    EXPECT_LT(worst, 1e-12);
    EXPECT_LT(worstGrad, 1e-12);
    user->values(pts, b);
    for (std::size_t i = 0; i < pts.size(); ++i) EXPECT_NEAR(a[i], b[i], 1e-12);
}

TEST(Expr, GridValuesMatchPointValuesAndTheBuiltIn)
{
    const TpmsField builtin(TpmsType::Gyroid, Vec3d(7.0));
    const FieldPtr user = exprField(kGyroid);
    GridBatch batch;
    batch.origin = Vec3d(-3.3, 1.7, 12.05);
    batch.spacing = Vec3d(0.1, 0.2, 0.15);
    batch.nx = 8, batch.ny = 7, batch.nz = 5;  // not a cube: checks the axis layout
    std::vector<double> grid(batch.size()), builtinGrid(batch.size()), points(batch.size());
    user->gridValues(batch, grid);
    builtin.gridValues(batch, builtinGrid);
    std::vector<Vec3d> pts;
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j)
            for (int k = 0; k < batch.nz; ++k) pts.push_back(batch.point(i, j, k));
    user->values(pts, points);
    for (std::size_t n = 0; n < grid.size(); ++n) {
        EXPECT_EQ(grid[n], points[n]) << n;  // same operations, same order: the same bits
        EXPECT_NEAR(grid[n], builtinGrid[n], 1e-12) << n;
    }
}

TEST(Expr, EveryFunctionAgainstTheStandardLibrary)
{
    struct Case {
        const char* text;
        double (*ref)(double, double, double);
    };
    const Case cases[] = {
        {"sin(x) + cos(y) * tan(z / 4)",
         [](double x, double y, double z) { return std::sin(x) + std::cos(y) * std::tan(z / 4); }},
        {"asin(x/20) - acos(y/20) + atan(z)",
         [](double x, double y, double z) { return std::asin(x / 20) - std::acos(y / 20) + std::atan(z); }},
        {"atan2(y, x) + sinh(x/10) * cosh(y/10) - tanh(z)",
         [](double x, double y, double z) {
             return std::atan2(y, x) + std::sinh(x / 10) * std::cosh(y / 10) - std::tanh(z);
         }},
        {"abs(x) - sign(y) + floor(z) + ceil(x*y)",
         [](double x, double y, double z) {
             return std::abs(x) - (y > 0 ? 1.0 : (y < 0 ? -1.0 : 0.0)) + std::floor(z) + std::ceil(x * y);
         }},
        {"min(x, y, z) + max(x, 2*y) + sqrt(abs(z)) * exp(-x*x/50)",
         [](double x, double y, double z) {
             return std::min({x, y, z}) + std::max(x, 2 * y) + std::sqrt(std::abs(z)) * std::exp(-x * x / 50);
         }},
        {"log(1 + x*x) + pow(abs(y) + 1, 1.5) + x^3 - y**2 + 2^-1",
         [](double x, double y, double) {
             return std::log(1 + x * x) + std::pow(std::abs(y) + 1, 1.5) + x * x * x - y * y + 0.5;
         }},
        {"mod(x, 3) + x % -2.5 + hypot(y, z)",
         [](double x, double y, double z) {
             return (x - 3 * std::floor(x / 3)) + (x + 2.5 * std::floor(x / -2.5)) + std::sqrt(y * y + z * z);
         }},
        {"clamp(x, -1, 2) + smoothstep(-3, 5, y) + mix(x, y, 0.25) - -z + tau/pi*e",
         [](double x, double y, double z) {
             double t = std::clamp((y + 3) / 8, 0.0, 1.0);
             return std::clamp(x, -1.0, 2.0) + t * t * (3 - 2 * t) + (x + (y - x) * 0.25) + z + 2 * std::numbers::e;
         }},
    };
    const auto pts = randomPoints(500, -9, 9, 3);
    for (const Case& c : cases) {
        const FieldPtr f = exprField(c.text);
        std::vector<double> v(pts.size());
        f->values(pts, v);
        for (std::size_t i = 0; i < pts.size(); ++i) {
            const double ref = c.ref(pts[i][0], pts[i][1], pts[i][2]);
            ASSERT_NEAR(v[i], ref, 1e-12 * std::max(1.0, std::abs(ref))) << c.text << " at " << pts[i];
        }
    }
}

TEST(Expr, GradientsAreExactDerivatives)
{
    // Analytic gradients of a mixed expression against central differences (step 1e-6).
    const char* texts[] = {"sin(x*y) + z^3/10 - exp(-z*z/40)*cos(y)", "atan2(y, x) * hypot(x, z) + log(2 + x*x)",
                           "pow(1.5 + sin(x), 2.5) + tanh(y/3) * asin(z/20) + smoothstep(-4, 4, x*z/3)",
                           "mod(x, 2.5) + clamp(y, -2, 3) + min(x, y) * max(z, 0.1) - abs(y - z)"};
    const auto pts = randomPoints(300, -6, 6, 11);
    for (const char* text : texts) {
        const FieldPtr f = exprField(text);
        std::vector<double> v(pts.size());
        std::vector<Vec3d> g(pts.size());
        f->gradients(pts, v, g);
        for (std::size_t i = 0; i < pts.size(); ++i) {
            EXPECT_NEAR(v[i], f->value(pts[i]), 1e-13 * std::max(1.0, std::abs(v[i])));
            for (int a = 0; a < 3; ++a) {
                const double h = 1e-6;
                Vec3d p = pts[i], q = pts[i];
                p[a] += h;
                q[a] -= h;
                const double fd = (f->value(p) - f->value(q)) / (2 * h);
                // Skip the rare sample whose difference stencil straddles a kink (mod, min, abs, clamp).
                const double fd2 = (f->value(pts[i] + (p - pts[i]) * 0.5) - f->value(pts[i] + (q - pts[i]) * 0.5)) / h;
                if (std::abs(fd - fd2) > 1e-4) continue;
                EXPECT_NEAR(g[i][a], fd, 1e-5 * std::max(1.0, std::abs(fd)))
                    << text << " axis " << a << " at " << pts[i];
            }
        }
    }
}

TEST(Expr, BoundsContainEverySampledValue)
{
    const char* texts[] = {kGyroid, "sin(x*y) + z^3/10 - exp(-z*z/40)*cos(y)",
                           "tan(x/3) + atan2(y, x) + sqrt(abs(z)) - log(1 + y*y)",
                           "mod(x, 2.5) * smoothstep(-1, 1, y) + pow(abs(z) + 0.5, -1.5) + 1/(x - 0.3)",
                           "floor(x) + sign(y) + min(x, y, z) - max(x*x, z) + asin(clamp(y/10, -1, 1)) + cosh(z/4)"};
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> u(-8, 8), w(0.01, 3);
    for (const char* text : texts) {
        const FieldPtr f = exprField(text);
        for (int trial = 0; trial < 200; ++trial) {
            const Vec3d lo(u(rng), u(rng), u(rng));
            const Box3 box{lo, lo + Vec3d(w(rng), w(rng), w(rng))};
            const Interval b = f->bound(box);
            ASSERT_LE(b.lo, b.hi);
            std::uniform_real_distribution<double> ux(box.min[0], box.max[0]), uy(box.min[1], box.max[1]),
                uz(box.min[2], box.max[2]);
            for (int s = 0; s < 64; ++s) {
                const double v = f->value(Vec3d(ux(rng), uy(rng), uz(rng)));
                if (std::isnan(v)) continue;
                ASSERT_TRUE(b.lo <= v && v <= b.hi) << text << ": " << v << " outside [" << b.lo << ", " << b.hi << "]";
            }
        }
    }
    // Tight where it matters for culling: the user gyroid's bound equals the built-in's.
    const TpmsField builtin(TpmsType::Gyroid, Vec3d(7.0));
    const Box3 box{Vec3d(0.1, 0.2, 0.3), Vec3d(0.9, 0.8, 1.1)};
    EXPECT_NEAR(exprField(kGyroid)->bound(box).lo, builtin.bound(box).lo, 1e-12);
    EXPECT_NEAR(exprField(kGyroid)->bound(box).hi, builtin.bound(box).hi, 1e-12);
}

TEST(Expr, InputFieldsCarryValuesGradientsAndBounds)
{
    const auto ball = std::make_shared<Sphere>(Vec3d(1, 2, 3), 4.0);
    const FieldPtr f = exprField("max(ball, -ball - 1) + 0.5*x", {ball});
    const auto pts = randomPoints(200, -8, 8);
    for (const Vec3d& p : pts) {
        const double s = (p - Vec3d(1, 2, 3)).length() - 4.0;
        const auto [v, g] = f->valueAndGradient(p);
        EXPECT_NEAR(v, std::max(s, -s - 1) + 0.5 * p[0], 1e-12);
        const Vec3d n = (p - Vec3d(1, 2, 3)) / (p - Vec3d(1, 2, 3)).length();
        const Vec3d expect = (s >= -s - 1 ? n : -n) + Vec3d(0.5, 0, 0);
        EXPECT_LT((g - expect).length(), 1e-12);
    }
    const Box3 box{Vec3d(-1, -1, -1), Vec3d(2, 2, 2)};
    const Interval b = f->bound(box);
    for (const Vec3d& p : randomPoints(500, -1, 2)) {
        EXPECT_LE(b.lo, f->value(p));
        EXPECT_GE(b.hi, f->value(p));
    }
}

TEST(Expr, FoldsConstantsAndSharesRepeatedWork)
{
    // 2*pi/7 folds to one constant; sin(x*k) appears twice but is computed once.
    const ExprProgram p = compileWith("sin(x*(2*pi/7)) + sin(x*(2*pi/7))*cos(y)");
    EXPECT_LE(p.size(), 8u) << p.listing();
    EXPECT_TRUE(compileWith("2*pi/$cell + sqrt(16)").isConstant());
    EXPECT_NEAR(exprField("2*pi/$cell + sqrt(16)")->value(Vec3d(1, 2, 3)), 2 * std::numbers::pi / 7 + 4, 1e-15);
    EXPECT_EQ(exprField("-2^2")->value(Vec3d(0.0)), -4.0);       // ^ binds tighter than unary minus
    EXPECT_EQ(exprField("2^3^2")->value(Vec3d(0.0)), 512.0);     // and is right-associative
    EXPECT_EQ(exprField("1 - 2 - 3")->value(Vec3d(0.0)), -4.0);  // - is left-associative
}

TEST(Expr, SyntaxErrorsPointAtTheProblem)
{
    EXPECT_EQ(errorOf("sin(x) +"), "the equation ends too early: expected a number, a name or `(` @8");
    EXPECT_EQ(errorOf("sin(x"), "expected `,` or `)` in the arguments of `sin` @5");
    EXPECT_EQ(errorOf("(x + y"), "expected `)` to close the `(` at character 1 @6");
    EXPECT_EQ(errorOf("x + y)"), "unexpected `)`: there is no `(` to close @5");
    EXPECT_EQ(errorOf("x y"), "unexpected `y` after a complete expression; missing an operator? @2");
    EXPECT_EQ(errorOf("x + # y"), "unexpected `#`: expected a number, a name or `(` @4");
    EXPECT_EQ(errorOf("sn(x)"), "unknown function `sn`; did you mean `sin`? @0");
    EXPECT_EQ(errorOf("atan2(x)"), "`atan2` takes 2 arguments, got 1 @0");
    EXPECT_EQ(errorOf("1 + sin"), "`sin` is a function: write sin(...) @4");
    EXPECT_EQ(errorOf("x + cel"), "unknown name `cel` @4");
    EXPECT_EQ(errorOf("x + $cel"), "unknown parameter `$cel` @4");
    EXPECT_EQ(errorOf(""), "the equation is empty @0");
    EXPECT_EQ(exprCaret("sin(x) +", 8), "    sin(x) +\n            ^");
    EXPECT_EQ(exprCaret("a +\n  b c", 8), "      b c\n        ^");
}

TEST(Expr, DeepNestingIsAnErrorNotAStackOverflow)
{
    // Minimal inputs from the adversarial run: 10,000 parentheses, 100,000 unary minus signs.
    const std::string parens = std::string(10000, '(') + "x" + std::string(10000, ')');
    EXPECT_NE(errorOf(parens).find("nests deeper than"), std::string::npos) << errorOf(parens);
    const std::string minus = std::string(100000, '-') + "x";
    EXPECT_NE(errorOf(minus).find("nests deeper than"), std::string::npos) << errorOf(minus);
    std::string powers = "x";
    for (int i = 0; i < 20000; ++i) powers += "^x";  // right-associative: nests
    EXPECT_NE(errorOf(powers).find("nests deeper than"), std::string::npos) << errorOf(powers);
    // Ordinary nesting still compiles and evaluates.
    const std::string fifty = std::string(50, '(') + "x + 1" + std::string(50, ')');
    EXPECT_EQ(errorOf(fifty), "");
    const FieldPtr f = exprField(std::string(100, '-') + "x");  // an even number of signs
    EXPECT_DOUBLE_EQ(f->value(Vec3d(2.5, 0, 0)), 2.5);
}
