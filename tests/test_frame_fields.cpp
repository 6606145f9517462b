// Issue 19, part A: strut radii from any field (u, v, w over the frame's box), the domain from a
// finite frame, frame keys that are used or refused, and conformal frames between surfaces.
#include "TestUtil.h"
#include "engine/core/Errors.h"
#include "engine/frames/StrutFrames.h"
#include "engine/jobs/Job.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <numbers>

using namespace voxlat;
using namespace voxlat::test;

namespace {

/// The message of the InputError building @a text throws ("" when it builds).
std::string buildError(const std::string& text, const std::string& name = "r.yaml")
{
    try {
        Job job(parseRecipe(text, name, "."));
        job.frame();
    } catch (const InputError& e) {
        return e.what();
    }
    return "";
}

/// Every strut end of @a frame with its radius.
template <typename Fn>
void forEachEnd(const BeamFrame& frame, Fn&& fn)
{
    for (std::size_t j = 0; j < frame.struts.size(); ++j)
        for (int e = 0; e < 2; ++e) fn(frame.nodes[frame.struts[j][e]], frame.radii[j][e]);
}

}  // namespace

TEST(RadiusFromField, InlineExpressionAtEveryStrutEnd)
{
    // Capsules at level 0: the radius at each end is the field there, in mm.
    Job job(
        parseRecipe("voxel: 0.2\nfields:\n"
                    "  l: {struts: {cell: bcc, size: 2, count: [2, 2, 3]}, kernel: capsule, "
                    "radius: {expr: \"0.3 + 0.01*z\"}}\nresult: l\n",
                    "a.yaml", "."));
    const BeamFrame f = job.frame();
    ASSERT_EQ(f.struts.size(), 2u * 2u * 3u * 8u);  // bcc: 8 half-diagonals per cell, none shared
    std::size_t ends = 0;
    double zMax = 0.0;
    forEachEnd(f, [&](const Vec3d& p, double r) {
        EXPECT_DOUBLE_EQ(r, 0.3 + 0.01 * p[2]) << p;
        zMax = std::max(zMax, p[2]);
        ++ends;
    });
    EXPECT_EQ(ends, 2 * f.struts.size());
    EXPECT_DOUBLE_EQ(zMax, 6.0);
}

TEST(RadiusFromField, NamedFieldWithUnitBoxCoordinates)
{
    // The frame's box is [1, 5] x [0, 2] x [0, 6]: u = (x - 1) / 4, v = y / 2, w = z / 6. The field
    // comes before the lattice in `fields:` (it waits for the frame's box).
    const std::string text =
        "voxel: 0.25\nfields:\n"
        "  r: {expr: \"0.2 + 0.1*u + 0.05*v + 0.2*w*w\"}\n"
        "  l: {struts: {cell: grid, size: [2, 2, 3], count: [2, 1, 2], origin: [1, 0, 0]}, kernel: capsule, "
        "radius: r}\nresult: l\n";
    Job job(parseRecipe(text, "b.yaml", "."));
    const BeamFrame f = job.frame();
    ASSERT_FALSE(f.struts.empty());
    forEachEnd(f, [&](const Vec3d& p, double r) {
        const double u = (p[0] - 1) / 4, v = p[1] / 2, w = p[2] / 6;
        EXPECT_NEAR(r, 0.2 + 0.1 * u + 0.05 * v + 0.2 * w * w, 1e-14) << p;
    });
    // The same field as the radius of the Gaussian kernel: an isolated strut end's radius at
    // iso-value 1 is the field's value.
    Job gauss(
        parseRecipe("voxel: 0.25\nfields:\n"
                    "  r: {expr: \"0.3 + 0.2*u\"}\n"
                    "  l: {struts: {cell: grid, size: 2, count: [3, 1, 1]}, kernel: {gaussian: {sigma: 0.3}}, "
                    "radius: r}\nresult: l\n",
                    "c.yaml", "."));
    const BeamFrame g = gauss.frame();
    forEachEnd(g, [&](const Vec3d& p, double r) { EXPECT_NEAR(r, 0.3 + 0.2 * p[0] / 6, 1e-9) << p; });
}

TEST(RadiusFromField, WithDensityTheFieldIsShiftedByTheSolvedLevel)
{
    Job job(
        parseRecipe("voxel: 0.1\nfields:\n"
                    "  l: {struts: {cell: bcc, size: 3, count: 2}, kernel: capsule, density: 0.15, "
                    "radius: {expr: \"0.2 + 0.2*w\"}}\nresult: l\n",
                    "d.yaml", "."));
    const BeamFrame f = job.frame();
    const double level = job.report()["fields"]["l"]["level"].get<double>();
    EXPECT_GT(std::abs(level), 1e-4);
    forEachEnd(f, [&](const Vec3d& p, double r) { EXPECT_NEAR(r, 0.2 + 0.2 * p[2] / 6 + level, 1e-12) << p; });
    // The density is met on the grid.
    const nlohmann::json density = job.report()["fields"]["l"];
    EXPECT_NEAR(density["achieved_density"].get<double>(), 0.15, 0.01) << density.dump();
    // Gaussian convolution: the solved iso-value t shifts every squared radius by the same
    // 2 sigma^2 ln(1/t), so r^2 - R^2 is one number over all strut ends.
    Job gauss(
        parseRecipe("voxel: 0.1\nfields:\n"
                    "  l: {struts: {cell: bcc, size: 3, count: 2}, kernel: {gaussian: {sigma: 0.3}}, "
                    "density: 0.35, radius: {expr: \"0.3 + 0.1*u\"}}\nresult: l\n",
                    "g.yaml", "."));
    const BeamFrame g = gauss.frame();
    std::vector<double> shifts;
    forEachEnd(g, [&](const Vec3d& p, double r) {
        const double R = 0.3 + 0.1 * p[0] / 6;
        shifts.push_back(r * r - R * R);
    });
    const auto [lo, hi] = std::minmax_element(shifts.begin(), shifts.end());
    EXPECT_GT(std::abs(*lo), 1e-3);
    EXPECT_NEAR(*lo, *hi, 1e-9);
    EXPECT_NEAR(gauss.report()["fields"]["l"]["achieved_density"].get<double>(), 0.35, 0.01);
}

TEST(RadiusFromField, ErrorsNameTheRadius)
{
    const std::string head = "voxel: 0.25\nfields:\n";
    // A radius that is not positive at some strut end.
    std::string e = buildError(head +
                               "  l: {struts: {cell: grid, size: 2, count: 2}, kernel: capsule, "
                               "radius: {expr: \"0.5 - 0.2*x\"}}\nresult: l\n");
    EXPECT_NE(e.find("r.yaml:3:"), std::string::npos) << e;
    EXPECT_NE(e.find("a radius must be greater than zero"), std::string::npos) << e;
    // u, v, w outside a strut radius.
    e = buildError(head +
                   "  g: {expr: \"x*x + y*y + z*z - 4 - u\"}\nresult: g\ndomain: {box: [[-3, -3, -3], [3, 3, 3]]}\n");
    EXPECT_NE(e.find("r.yaml:3:"), std::string::npos) << e;
    EXPECT_NE(e.find("unit-box coordinate"), std::string::npos) << e;
    // ... even in a field nobody uses.
    e = buildError(head + "  q: {expr: \"u\"}\n  g: {sphere: {radius: 2}}\nresult: g\n");
    EXPECT_NE(e.find("r.yaml:3:"), std::string::npos) << e;
    EXPECT_NE(e.find("unit-box coordinate"), std::string::npos) << e;
    // An unknown field name.
    e = buildError(head + "  l: {struts: {cell: grid, size: 2, count: 2}, kernel: capsule, radius: rr}\nresult: l\n");
    EXPECT_NE(e.find("rr"), std::string::npos) << e;
    // IntraLattice's habit, an equation as the gradient: pointed to the form that takes one.
    e = buildError(head +
                   "  l: {struts: {cell: grid, size: 2, count: 2}, kernel: capsule, "
                   "radius: {gradient: \"x*y\", min: 0.2, max: 0.5}}\nresult: l\n");
    EXPECT_NE(e.find("unknown gradient `x*y`"), std::string::npos) << e;
    EXPECT_NE(e.find("give `radius: {expr: \"x*y\"}`"), std::string::npos) << e;
}

TEST(FiniteFrameDomain, CountWireframeWithinAndBetweenGiveTheDomain)
{
    TempDir dir;
    dir.write("w.csv", "x1,y1,z1,x2,y2,z2\n0,0,0,6,0,0\n6,0,0,6,4,0\n6,4,0,6,4,4\n");
    for (const std::string& frame :
         {std::string("{cell: bcc, size: 2, count: [3, 2, 2]}"), std::string("{wireframe: w.csv}"),
          std::string("{cell: grid, size: 1, within: ball}"),
          std::string("{cell: grid, between: [s1, {point: [3, 2, 6]}], cells: [3, 2, 2]}")}) {
        const std::string text =
            "voxel: 0.2\nfields:\n  ball: {sphere: {radius: 2.2, center: [3, 2, 2]}}\n"
            "  s1: {surface: {x: \"6*u\", y: \"4*v\", z: \"0\"}}\n"
            "  l: {struts: " +
            frame + ", kernel: capsule, radius: 0.4}\nresult: l\noutputs: {mesh: l.stl}\n";
        const auto recipe = dir.write("f.yaml", text);
        // The frame's box grown by the reach (0.4 mm), plus three voxels of margin on voxel lines.
        Job job(parseRecipe(text, (dir.path / "f.yaml").string(), dir.path));
        const BeamFrame f = job.frame();
        Box3 frameBox{Vec3d(1e300), Vec3d(-1e300)};
        for (const Vec3d& p : f.nodes)
            for (int a = 0; a < 3; ++a) {
                frameBox.min[a] = std::min(frameBox.min[a], p[a]);
                frameBox.max[a] = std::max(frameBox.max[a], p[a]);
            }
        const Box3& box = job.domain().box;
        for (int a = 0; a < 3; ++a) {
            EXPECT_LE(box.min[a], frameBox.min[a] - 0.4) << frame;
            EXPECT_GE(box.min[a], frameBox.min[a] - 0.4 - 4 * 0.2 - 1e-9) << frame;
            EXPECT_GE(box.max[a], frameBox.max[a] + 0.4) << frame;
            EXPECT_LE(box.max[a], frameBox.max[a] + 0.4 + 4 * 0.2 + 1e-9) << frame;
        }
        // The command line runs it without `domain:`.
        std::string out;
        EXPECT_EQ(
            runCommand(voxlatBinary() + " -q run " + recipe.string() + " --out " + (dir.path / "o").string(), &out), 0)
            << frame << "\n"
            << out;
        EXPECT_EQ(out.find("unbounded"), std::string::npos) << out;
        EXPECT_TRUE(std::filesystem::exists(dir.path / "o" / "l.stl")) << frame;
        std::filesystem::remove_all(dir.path / "o");
    }
    // A box frame without count still needs a domain to fill, and says so.
    const std::string e = buildError(
        "voxel: 0.2\nfields:\n  l: {struts: {cell: bcc, size: 2}, kernel: capsule, radius: 0.4}\nresult: l\n");
    EXPECT_NE(e.find("give `count:` or a `domain:`"), std::string::npos) << e;
    EXPECT_EQ(e.find("unbounded"), std::string::npos) << e;
}

TEST(FiniteFrameDomain, GaussianReachIsTheCutoff)
{
    // Convolution struts are zero beyond their cut-off radius: the domain reaches that far only.
    Job job(parseRecipe(
        "voxel: 0.2\nfields:\n  l: {struts: {cell: bcc, size: 2, count: 2}, kernel: {gaussian: {sigma: 0.3}}, "
        "density: 0.2}\nresult: l\n",
        "g.yaml", "."));
    const auto& box = job.domain().box;
    for (int a = 0; a < 3; ++a) {
        EXPECT_LT(box.min[a], -0.3);
        EXPECT_GT(box.min[a], -3.0);
        EXPECT_GT(box.max[a], 4.3);
        EXPECT_LT(box.max[a], 7.0);
    }
}

TEST(FrameKeys, RefusedKeysNameThemselves)
{
    const std::string head =
        "voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n"
        "  ball: {sphere: {radius: 4, center: [5, 5, 5]}}\n";
    const struct {
        std::string frame, key;
    } cases[] = {
        {"{cell: grid, size: 2, within: ball, origin: [1, 1, 1]}", "origin"},
        {"{cell: grid, size: 2, within: ball, count: 3}", "count"},
        {"{cell: grid, size: 2, cylinder: {radius: 4, height: 5, cells: [2, 8, 1]}}", "size"},
        {"{cell: grid, count: 2, cylinder: {radius: 4, height: 5, cells: [2, 8, 1]}}", "count"},
        {"{cell: grid, origin: [0, 0, 0], cylinder: {radius: 4, height: 5, cells: [2, 8, 1]}}", "origin"},
        {"{cell: grid, within: ball, cylinder: {radius: 4, height: 5, cells: [2, 8, 1]}}", "within"},
        {"{cell: grid, min_length: 0.1, cylinder: {radius: 4, height: 5, cells: [2, 8, 1]}}", "min_length"},
        {"{cell: grid, size: 2, count: 2, min_length: 0.1}", "min_length"},
        {"{cell: grid, size: 2, count: 2, cells: [1, 1, 1]}", "cells"},
        {"{wireframe: w.csv, min_length: 0.1}", "min_length"},
        {"{cell: grid, size: 2, between: [s, {point: [0, 0, 5]}], cells: [1, 1, 1]}", "size"},
    };
    for (const auto& c : cases) {
        const std::string e =
            buildError(head + "  l: {struts: " + c.frame + ", kernel: capsule, radius: 0.3}\nresult: l\n");
        EXPECT_NE(e.find("r.yaml:5:"), std::string::npos) << c.frame << ": " << e;
        EXPECT_NE(e.find("remove `" + c.key + "`"), std::string::npos) << c.frame << ": " << e;
        EXPECT_NE(e.find("`" + c.key + "` has no use in"), std::string::npos) << c.frame << ": " << e;
    }
    // Two kernels at once.
    const std::string k = buildError(head +
                                     "  l: {struts: {cell: grid, size: 2, count: 2}, kernel: {capsule: {blend: "
                                     "0.2}, gaussian: {sigma: 0.3}}, radius: 0.3}\nresult: l\n");
    EXPECT_NE(k.find("r.yaml:5:"), std::string::npos) << k;
    EXPECT_NE(k.find("not both"), std::string::npos) << k;
    // Two layouts at once: the second one's key has no use in the first.
    const std::string e = buildError(head +
                                     "  l: {struts: {cell: grid, sphere: {radius: 4, cells: [2, 4, 1]}, "
                                     "cylinder: {radius: 4, height: 5, cells: [2, 8, 1]}}, kernel: capsule, "
                                     "radius: 0.3}\nresult: l\n");
    EXPECT_NE(e.find("`sphere` has no use in a cylinder frame"), std::string::npos) << e;
}

TEST(FrameKeys, RefusedKeysExitTwoAndWriteNothing)
{
    TempDir dir;
    const auto recipe = dir.write(
        "k.yaml",
        "voxel: 0.5\nfields:\n  l: {struts: {cell: grid, origin: [0, 0, 0], cylinder: {radius: 4, height: 5, cells: "
        "[2, 8, 1]}}, kernel: capsule, radius: 0.3}\nresult: l\noutputs: {mesh: l.stl}\n");
    std::string out;
    EXPECT_EQ(runCommand(voxlatBinary() + " -q run " + recipe.string() + " --out " + (dir.path / "o").string(), &out),
              2)
        << out;
    EXPECT_NE(out.find("k.yaml:3:"), std::string::npos) << out;
    EXPECT_NE(out.find("remove `origin`"), std::string::npos) << out;
    EXPECT_FALSE(std::filesystem::exists(dir.path / "o" / "l.stl"));
}

TEST(BetweenFrame, NodesLieOnBothSurfacesAndBetween)
{
    // S1 a wavy sheet, S2 a tilted plane above it; grid cells map every grid node exactly.
    const int nu = 4, nv = 3, nw = 2;
    auto s1 = [](double u, double v) {
        return Vec3d(10 * u, 8 * v, 0.5 * std::sin(2 * std::numbers::pi * u) * std::cos(std::numbers::pi * v));
    };
    auto s2 = [](double u, double v) { return Vec3d(1 + 9 * u, 8 * v + 0.5 * u, 5 + u + 0.5 * v); };
    Job job(
        parseRecipe("voxel: 0.25\nfields:\n"
                    "  bottom: {surface: {x: \"10*u\", y: \"8*v\", z: \"0.5*sin(2*pi*u)*cos(pi*v)\"}}\n"
                    "  l: {struts: {cell: grid, between: [bottom, {surface: {x: \"1 + 9*u\", y: \"8*v + 0.5*u\", "
                    "z: \"5 + u + 0.5*v\"}}], cells: [4, 3, 2]}, kernel: capsule, radius: 0.3}\nresult: l\n",
                    "b.yaml", "."));
    const BeamFrame f = job.frame();
    // A grid cell's nodes are its corners: exactly the (nu+1)(nv+1)(nw+1) grid nodes.
    ASSERT_EQ(f.nodes.size(), std::size_t((nu + 1) * (nv + 1) * (nw + 1)));
    // Struts: the grid's edges.
    EXPECT_EQ(f.struts.size(),
              std::size_t(nu * (nv + 1) * (nw + 1) + (nu + 1) * nv * (nw + 1) + (nu + 1) * (nv + 1) * nw));
    for (int i = 0; i <= nu; ++i)
        for (int j = 0; j <= nv; ++j)
            for (int k = 0; k <= nw; ++k) {
                const double u = double(i) / nu, v = double(j) / nv, w = double(k) / nw;
                const Vec3d expected = (1 - w) * s1(u, v) + w * s2(u, v);
                double nearest = 1e300;
                for (const Vec3d& p : f.nodes) nearest = std::min(nearest, (p - expected).length());
                EXPECT_LT(nearest, 1e-12) << i << " " << j << " " << k;
            }
    // On the surfaces (k = 0 and k = nw) the nodes are the surfaces' points.
    std::size_t onS1 = 0, onS2 = 0;
    for (const Vec3d& p : f.nodes)
        for (int i = 0; i <= nu; ++i)
            for (int j = 0; j <= nv; ++j) {
                onS1 += (p - s1(double(i) / nu, double(j) / nv)).length() < 1e-12;
                onS2 += (p - s2(double(i) / nu, double(j) / nv)).length() < 1e-12;
            }
    EXPECT_EQ(onS1, std::size_t((nu + 1) * (nv + 1)));
    EXPECT_EQ(onS2, std::size_t((nu + 1) * (nv + 1)));
}

TEST(BetweenFrame, CellNodesAreMappedTrilinearly)
{
    // A bcc cell's centre node goes to the mean of its hexahedron's eight corners.
    Job job(
        parseRecipe("voxel: 0.25\nfields:\n"
                    "  a: {surface: {x: \"4*u\", y: \"4*v + u*v\", z: \"u*u\"}}\n"
                    "  l: {struts: {cell: bcc, between: [a, {surface: {x: \"4*u + v\", y: \"4*v\", z: \"3 + v\"}}], "
                    "cells: [1, 1, 1]}, kernel: capsule, radius: 0.3}\nresult: l\n",
                    "t.yaml", "."));
    const BeamFrame f = job.frame();
    ASSERT_EQ(f.nodes.size(), 9u);
    auto a = [](double u, double v) { return Vec3d(4 * u, 4 * v + u * v, u * u); };
    auto b = [](double u, double v) { return Vec3d(4 * u + v, 4 * v, 3 + v); };
    Vec3d centre(0.0);
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 2; ++j) centre += 0.125 * (a(i, j) + b(i, j));
    double nearest = 1e300;
    for (const Vec3d& p : f.nodes) nearest = std::min(nearest, (p - centre).length());
    EXPECT_LT(nearest, 1e-12);
}

TEST(BetweenFrame, AxisAndPoint)
{
    // A cylinder of radius 5 around z, cells towards its axis: the inner nodes are on the axis,
    // at the height of their outer node; the seam u = 0 / u = 1 merges.
    const int nu = 8, nv = 2, nw = 2;
    Job job(
        parseRecipe("voxel: 0.25\nfields:\n"
                    "  wall: {surface: {x: \"5*cos(tau*u)\", y: \"5*sin(tau*u)\", z: \"6*v\"}}\n"
                    "  l: {struts: {cell: grid, between: [wall, {axis: [[0, 0, -1], [0, 0, 1]]}], "
                    "cells: [8, 2, 2]}, kernel: capsule, radius: 0.3}\nresult: l\n",
                    "ax.yaml", "."));
    const BeamFrame f = job.frame();
    // Nodes: nu around (seam merged) times (nv + 1) heights times nw rings, plus one on the axis per height.
    EXPECT_EQ(f.nodes.size(), std::size_t(nu * (nv + 1) * nw + (nv + 1)));
    for (int i = 0; i < nu; ++i)
        for (int j = 0; j <= nv; ++j)
            for (int k = 0; k <= nw; ++k) {
                const double u = double(i) / nu, v = double(j) / nv, w = double(k) / nw;
                const double r = 5 * (1 - w);
                const Vec3d expected(r * std::cos(2 * std::numbers::pi * u), r * std::sin(2 * std::numbers::pi * u),
                                     6 * v);
                double nearest = 1e300;
                for (const Vec3d& p : f.nodes) nearest = std::min(nearest, (p - expected).length());
                EXPECT_LT(nearest, 1e-12) << i << " " << j << " " << k;
            }
    // To a point: every node of the last layer is the point.
    Job cone(
        parseRecipe("voxel: 0.25\nfields:\n"
                    "  base: {surface: {x: \"6*u\", y: \"6*v\", z: \"0\"}}\n"
                    "  l: {struts: {cell: grid, between: [base, {point: [3, 3, 8]}], cells: [2, 2, 2]}, "
                    "kernel: capsule, radius: 0.3}\nresult: l\n",
                    "pt.yaml", "."));
    const BeamFrame c = cone.frame();
    EXPECT_EQ(c.nodes.size(), std::size_t(9 + 9 + 1));
    std::size_t apex = 0;
    for (const Vec3d& p : c.nodes) apex += p == Vec3d(3, 3, 8);
    EXPECT_EQ(apex, 1u);
    for (std::size_t j = 0; j < c.struts.size(); ++j)
        EXPECT_GT((c.nodes[c.struts[j][0]] - c.nodes[c.struts[j][1]]).length(), 0.1);
}

TEST(BetweenFrame, Errors)
{
    const std::string head = "voxel: 0.5\nfields:\n  s: {surface: {x: \"u\", y: \"v\", z: \"0\"}}\n";
    std::string e = buildError(head + "  g: {surface: {x: \"x\", y: \"v\", z: \"0\"}}\nresult: s\n");
    EXPECT_NE(e.find("r.yaml:4:"), std::string::npos) << e;
    EXPECT_NE(e.find("not in `x`"), std::string::npos) << e;
    e = buildError(head + "result: s\n");
    EXPECT_NE(e.find("is a surface"), std::string::npos) << e;
    e = buildError(head +
                   "  l: {struts: {cell: grid, between: [s], cells: 1}, kernel: capsule, radius: 0.1}\nresult: l\n");
    EXPECT_NE(e.find("r.yaml:4:"), std::string::npos) << e;
    EXPECT_NE(e.find("two surfaces"), std::string::npos) << e;
    e = buildError(head +
                   "  l: {struts: {cell: grid, between: [s, {axis: [[0, 0, 0], [0, 0, 0]]}], cells: 1}, "
                   "kernel: capsule, radius: 0.1}\nresult: l\n");
    EXPECT_NE(e.find("no direction"), std::string::npos) << e;
    e = buildError(head +
                   "  l: {struts: {cell: grid, between: [s, {point: [0, 0, 1]}]}, kernel: capsule, "
                   "radius: 0.1}\nresult: l\n");
    EXPECT_NE(e.find("give `cells:"), std::string::npos) << e;
}
