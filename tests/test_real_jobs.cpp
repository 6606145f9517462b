// Real jobs end to end (issue 42): lattices in parts, drain holes, outputs that never collide,
// slices without a domain, traps largest first. The whole kind x placement x output matrix is
// tests/scripts/check_lattice_matrix.py (ctest: lattice_matrix).
#include "TestUtil.h"
#include "engine/checks/SheetWalls.h"
#include "engine/checks/Traps.h"
#include "engine/core/SparseEvaluator.h"
#include "engine/jobs/Job.h"
#include "engine/jobs/MeshOffset.h"
#include "engine/recipe/Recipe.h"
#include "fields/shapes/Boolean.h"
#include "fields/shapes/DrainChannels.h"
#include "fields/shapes/Sphere.h"
#include "mesher/checks/MeshCheck.h"
#include "mesher/extract/MarchingCubes.h"
#include "mesher/writers/AtomicFile.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <iomanip>
#include <nlohmann/json.hpp>
#include <sstream>

#include <array>
#include <cmath>
#include <fstream>
#include <numbers>
#include <random>

using namespace voxlat;
using namespace voxlat::test;

namespace {

/// A hollow ball: outer radius 5, a cavity of radius 3 (a shell with a sealed inside).
FieldPtr hollowBall()
{
    return std::make_shared<BooleanField>(
        BooleanOp::Difference,
        std::vector<FieldPtr>{std::make_shared<Sphere>(Vec3d(0.0), 5.0), std::make_shared<Sphere>(Vec3d(0.0), 3.0)});
}

std::string bracket()
{
    return (sourceDir() / "data" / "meshes" / "bracket.stl").string();
}

/// The volume a binary STL encloses, read from its bytes (divergence theorem about its first vertex).
double readMeshVolume(const std::filesystem::path& path)
{
    std::ifstream in(path, std::ios::binary);
    in.seekg(80);
    std::uint32_t n = 0;
    in.read(reinterpret_cast<char*>(&n), 4);
    double volume = 0.0;
    std::array<double, 3> origin{};
    for (std::uint32_t t = 0; t < n; ++t) {
        float f[12];
        in.read(reinterpret_cast<char*>(f), 48);
        in.ignore(2);
        std::array<std::array<double, 3>, 3> v{};
        for (int c = 0; c < 3; ++c)
            for (int a = 0; a < 3; ++a) v[c][a] = f[3 + 3 * c + a];
        if (t == 0) origin = v[0];
        for (auto& c : v)
            for (int a = 0; a < 3; ++a) c[a] -= origin[a];
        volume +=
            (v[0][0] * (v[1][1] * v[2][2] - v[1][2] * v[2][1]) - v[0][1] * (v[1][0] * v[2][2] - v[1][2] * v[2][0]) +
             v[0][2] * (v[1][0] * v[2][1] - v[1][1] * v[2][0])) /
            6.0;
    }
    return volume;
}

Recipe recipeText(const std::string& text, const TempDir& dir)
{
    return parseRecipe(text, (dir.path / "r.yaml").string(), dir.path);
}

}  // namespace

TEST(Traps, AHollowBallHasOneTrapOfItsCavitysVolume)
{
    // The cavity's samples against the brute-force count of lattice points inside radius 3
    // (the same lattice), and the lowest point at the cavity's bottom.
    const double h = 0.25;
    const Box3 box{Vec3d(-6.0), Vec3d(6.0)};
    const auto traps = findTraps(*hollowBall(), box, h);
    ASSERT_EQ(traps.size(), 1u);
    std::uint64_t inside = 0;
    const int n = int(std::ceil(12.0 / h));
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j)
            for (int k = 0; k < n; ++k) {
                const Vec3d p = box.min + (Vec3d(i, j, k) + Vec3d(0.5)) * h;
                if (p.length() - 3.0 >= 0.0 && 5.0 - p.length() >= 0.0) continue;  // solid shell: not void
                inside += p.length() < 3.0 + 1e-12 ? 1 : 0;
            }
    EXPECT_EQ(traps[0].samples, inside);
    EXPECT_NEAR(traps[0].volumeMm3, 4.0 / 3.0 * std::numbers::pi * 27.0, 0.03 * 4.0 / 3.0 * std::numbers::pi * 27.0);
    EXPECT_NEAR(traps[0].lowest.z(), -3.0, h);
    EXPECT_NEAR(traps[0].lowest.x(), 0.0, h);
    EXPECT_NEAR(traps[0].lowest.y(), 0.0, h);
    // A solid ball and an open cup have none.
    EXPECT_TRUE(findTraps(Sphere(Vec3d(0.0), 5.0), box, h).empty());
    // Largest first, the same for any thread count.
    const auto two = std::make_shared<BooleanField>(
        BooleanOp::Difference,
        std::vector<FieldPtr>{std::make_shared<Sphere>(Vec3d(0.0), 5.0), std::make_shared<Sphere>(Vec3d(0, 0, 2), 1.0),
                              std::make_shared<Sphere>(Vec3d(0, 0, -2), 2.0)});
    std::vector<Trap> one;
    {
        tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
        one = findTraps(*two, box, h);
    }
    const auto many = findTraps(*two, box, h);
    ASSERT_EQ(many.size(), 2u);
    EXPECT_GT(many[0].volumeMm3, many[1].volumeMm3);
    EXPECT_NEAR(many[0].centroid.z(), -2.0, h);
    ASSERT_EQ(one.size(), 2u);
    for (int t = 0; t < 2; ++t) EXPECT_EQ(one[t].samples, many[t].samples);
}

TEST(DrainChannels, ValuesAreTheDifferenceWithCylinders)
{
    auto drained = std::make_shared<DrainedSolid>(hollowBall());
    EXPECT_THROW(drained->value(Vec3d(0.0)), std::logic_error);  // channels not set yet
    const DrainChannel c{Vec3d(0, 0, -2.5), Vec3d(0, 0, -7), 2.0};
    drained->setChannels({c});
    EXPECT_THROW(drained->setChannels({}), std::logic_error);
    const Cylinder cylinder(0.5 * (c.from + c.to), c.to - c.from, 1.0, (c.to - c.from).length());
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(-6.0, 6.0);
    std::vector<Vec3d> points;
    for (int i = 0; i < 2000; ++i) points.emplace_back(u(rng), u(rng), u(rng));
    std::vector<double> values(points.size());
    drained->values(points, values);
    for (std::size_t i = 0; i < points.size(); ++i)
        EXPECT_DOUBLE_EQ(values[i], std::max(hollowBall()->value(points[i]), -cylinder.value(points[i])));
    // The block path and the bound agree with the points.
    GridBatch batch;
    batch.origin = Vec3d(-1.0, -1.0, -6.0);
    batch.spacing = Vec3d(0.25);
    std::vector<double> grid(batch.size());
    drained->gridValues(batch, grid);
    const Interval b = drained->bound(batch.bounds());
    for (int i = 0, n = 0; i < 8; ++i)
        for (int j = 0; j < 8; ++j)
            for (int k = 0; k < 8; ++k, ++n) {
                EXPECT_DOUBLE_EQ(grid[std::size_t(n)], drained->value(batch.point(i, j, k)));
                EXPECT_TRUE(b.contains(grid[std::size_t(n)]));
            }
    // The channel opens the cavity: no trap is left.
    EXPECT_TRUE(findTraps(*drained, Box3{Vec3d(-6.0), Vec3d(6.0)}, 0.25).empty());
}

TEST(RealJobs, AShellWithDrainHasItsCavityOpenedAboveThePlate)
{
    TempDir dir;
    Job job(
        recipeText("voxel: 0.2\nfields:\n  ball: {sphere: {radius: 5}}\n"
                   "  hollow: {shell: {part: ball, thickness: 1, drain: {diameter: 2}}}\nresult: hollow\n",
                   dir));
    const TriangleMesh& mesh = job.mesh();
    EXPECT_TRUE(checkTopology(mesh).closedManifold());
    const auto report = job.report();
    const auto& drain = report["drain"]["hollow"];
    ASSERT_EQ(drain["traps_found"], 1) << drain.dump(1);
    ASSERT_EQ(drain["holes"].size(), 1u);
    EXPECT_EQ(drain["traps_left"], 0);
    // The ball's bottom stands on the plate: the channel leaves sideways, a radius above it.
    const auto& hole = drain["holes"][0];
    EXPECT_EQ(hole["direction"][2].get<double>(), 0.0) << hole.dump();
    EXPECT_GE(hole["position"][2].get<double>(), -5.0 + 1.0);
    // The mesh has the hole: its volume is the shell's less a channel through the 1 mm wall.
    const double shell = 4.0 / 3.0 * std::numbers::pi * (125.0 - 64.0);
    EXPECT_LT(mesh.volume(), shell);
    EXPECT_GT(mesh.volume(), shell - 2.0 * std::numbers::pi * 1.0 * 1.5);
}

TEST(RealJobs, DrainsFollowTheBuildDirection)
{
    // A hollow ball built along +x and along an oblique direction: the cavity's lowest point is
    // lowest along that direction, the ball's bottom along it stands on the plate, so the channel
    // leaves across the direction, a radius above the plate; the drained solid has no trap.
    const double root3 = std::sqrt(3.0);
    for (const Vec3d& up : {Vec3d(1, 0, 0), Vec3d(1, 1, 1) / root3}) {
        TempDir dir;
        const std::string build = up.y() == 0.0 ? "[1, 0, 0]" : "[1, 1, 1]";  // the recipe's (unnormalised) direction
        Job job(
            recipeText("voxel: 0.2\nfields:\n  ball: {sphere: {radius: 5}}\n"
                       "  hollow: {shell: {part: ball, thickness: 1, drain: {diameter: 2, build: " +
                           build + "}}}\nresult: hollow\n",
                       dir));
        const TriangleMesh& mesh = job.mesh();
        EXPECT_TRUE(checkTopology(mesh).closedManifold());
        const auto report = job.report();
        const auto& drain = report["drain"]["hollow"];
        ASSERT_EQ(drain["holes"].size(), 1u) << drain.dump(1);
        EXPECT_EQ(drain["traps_left"], 0);
        for (int a = 0; a < 3; ++a) EXPECT_NEAR(drain["build_direction"][a].get<double>(), up[a], 1e-12);
        const auto& hole = drain["holes"][0];
        const Vec3d from(hole["position"][0].get<double>(), hole["position"][1].get<double>(),
                         hole["position"][2].get<double>());
        const Vec3d along(hole["direction"][0].get<double>(), hole["direction"][1].get<double>(),
                          hole["direction"][2].get<double>());
        EXPECT_NEAR(along.dot(up), 0.0, 1e-12) << hole.dump();
        // The ball's bottom along up is at -5: the channel's axis is a radius (1 mm) above it.
        EXPECT_GE(from.dot(up), -5.0 + 1.0) << hole.dump();
        // It starts in the cavity near its lowest point (-3 along up), within a search sample.
        EXPECT_LT(from.dot(up), -3.0 + 1.0 + 0.5) << hole.dump();
        // Independently of the report: the mesh has lost the channel through the 1 mm wall.
        const double shell = 4.0 / 3.0 * std::numbers::pi * (125.0 - 64.0);
        EXPECT_LT(mesh.volume(), shell - 0.5 * std::numbers::pi * 1.0 * 1.0);
    }
    // A slices' drain builds along the printer's +z; a zero direction is refused.
    TempDir dir;
    std::string message = errorOf([&] {
        Job job(
            recipeText("voxel: 0.2\nfields:\n  ball: {sphere: {radius: 5}}\nresult: ball\n"
                       "outputs: {slices: {printer: sl1s, file: h.sl1s, drain: {diameter: 2, build: [1, 0, 0]}}}\n",
                       dir));
    });
    EXPECT_NE(message.find("r.yaml:5:"), std::string::npos) << message;
    EXPECT_NE(message.find("built along +z"), std::string::npos) << message;
    message = errorOf([&] {
        Job job(
            recipeText("voxel: 0.2\nfields:\n  ball: {sphere: {radius: 5}}\n"
                       "  hollow: {shell: {part: ball, thickness: 1, drain: {diameter: 2, build: [0, 0, 0]}}}\n"
                       "result: hollow\n",
                       dir));
    });
    EXPECT_NE(message.find("r.yaml:4:"), std::string::npos) << message;
    EXPECT_NE(message.find("zero length"), std::string::npos) << message;
}

TEST(RealJobs, StrutsFillAPartForTheInfillsDensity)
{
    // Issue 42's first report: `radius:` on a lattice an infill solves crashed (the level was set
    // twice), and without it the lattice demanded one.
    for (const std::string radius : {", radius: 0.5", ""}) {
        TempDir dir;
        Job job(recipeText("voxel: 0.15\nfields:\n  part: {mesh: " + bracket() +
                               "}\n  bcc: {struts: {cell: bcc, size: 5}, kernel: {gaussian: {sigma: 0.5}}" + radius +
                               "}\n  lattice: {infill: {part: part, lattice: bcc, skin: 0, density: 0.20}}\nresult: "
                               "lattice\n",
                           dir));
        const TriangleMesh& mesh = job.mesh();
        EXPECT_TRUE(checkTopology(mesh).closedManifold());
        const auto report = job.report();
        EXPECT_EQ(report["fields"]["bcc"]["density_measured_on"], "the inside of `part`");
        // Measured from the mesh over the part's own volume (its STL): 1 % at 0.15 mm (1.01 % at 0.2).
        const double part = report["parts"]["part"]["mesh_volume_mm3"].get<double>();
        EXPECT_NEAR(mesh.volume() / part, 0.20, 0.01 * 0.20) << "radius`" << radius << "`";
    }
}

TEST(RealJobs, AFixedLatticeInADensityInfillIsRefusedNamingBoth)
{
    TempDir dir;
    const std::string message = errorOf([&] {
        Job job(
            recipeText("voxel: 0.2\nfields:\n  part: {mesh: " + bracket() +
                           "}\n  g: {tpms: gyroid, cell: 6, solid: sheet, thickness: 0.4}\n"
                           "  lattice: {infill: {part: part, lattice: g, skin: 1, density: 0.20}}\nresult: lattice\n",
                       dir));
    });
    EXPECT_NE(message.find("r.yaml:5:"), std::string::npos) << message;
    EXPECT_NE(message.find("sets its own size"), std::string::npos) << message;
}

TEST(RealJobs, StrutsWithinAPartStayInsideIt)
{
    // `within:` a part: the density is the part's share and the struts' solid ends at its
    // surface (before, the capsules stood a radius out and the report measured the box).
    TempDir dir;
    Job job(recipeText("voxel: 0.2\nfields:\n  part: {mesh: " + bracket() +
                           "}\n  lattice: {struts: {cell: bcc, size: 5, within: part}, kernel: {gaussian: {sigma: "
                           "0.5}}, density: 0.20}\nresult: lattice\n",
                       dir));
    const TriangleMesh& mesh = job.mesh();
    const auto report = job.report();
    EXPECT_EQ(report["fields"]["lattice"]["density_measured_on"], "the inside of `part`");
    const double part = report["parts"]["part"]["mesh_volume_mm3"].get<double>();
    EXPECT_NEAR(mesh.volume() / part, 0.20, 0.01 * 0.20);
    const FieldPtr bracketField = job.field("part");
    double outside = 0.0;
    for (const auto& p : mesh.points) outside = std::max(outside, bracketField->value(Vec3d(p[0], p[1], p[2])));
    EXPECT_LT(outside, 0.2) << "a vertex stands " << outside << " mm out of the part";
}

TEST(RealJobs, OutputsThatWouldShareAFileAreRefusedAtLoad)
{
    TempDir dir;
    const std::string head =
        "voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n  lattice: {tpms: gyroid, "
        "cell: 5, density: 0.3, solid: sheet}\nresult: lattice\n";
    for (const auto& [outputs, words] : std::vector<std::pair<std::string, std::string>>{
             {"outputs: {mesh: [a.stl, {file: a.stl}]}", "two outputs write `a.stl`"},
             {"outputs: {frame: a.obj, mesh: a.obj}", "two outputs write `a.obj`"},
             {"outputs: {properties: report.json}", "the run's report"},
             {"outputs: {mesh: p.stl, slices: {printer: sl1s, file: s.sl1s, preview: p.stl.preview.png}}",
              "two outputs write `p.stl.preview.png`"},
             {"outputs: {slices: {printer: sl1s, file: s.sl1s, preview: ../victim.png}}", "leaves it"},
             {"outputs: {slices: {printer: sl1s, file: s.sl1s, preview: /tmp/victim.png}}", "leaves it"}}) {
        const std::string message = errorOf([&] { recipeText(head + outputs + "\n", dir); });
        EXPECT_NE(message.find("r.yaml:6:"), std::string::npos) << outputs << ": " << message;
        EXPECT_NE(message.find(words), std::string::npos) << outputs << ": " << message;
    }
    // A mesh and slices of one part: each side file after its output's whole name.
    const Recipe r = recipeText(head + "outputs: {slices: {printer: sl1s, file: conv.sl1s}, mesh: conv.stl}\n", dir);
    std::vector<std::string> sides;
    for (const OutputSpec& o : r.outputs) sides.insert(sides.end(), o.sideFiles.begin(), o.sideFiles.end());
    EXPECT_EQ(sides, (std::vector<std::string>{"conv.stl.preview.png", "conv.sl1s.preview.png"}));
}

TEST(RealJobs, AMeshAndSlicesOfOneRecipeWriteEverythingAndSlicesNeedNoDomain)
{
    // Issue 42: both wrote conv.preview.png (exit 3, no report, files left), and slices asked for
    // a `domain:` that a mesh takes from the part.
    TempDir dir;
    const auto recipe = dir.write("conv.yaml",
                                  "voxel: 0.25\nfields:\n  ball: {sphere: {radius: 4, center: [0, 0, 4]}}\n"
                                  "  g: {tpms: gyroid, cell: 4, solid: sheet, level: 0.4}\n"
                                  "  part: {infill: {part: ball, lattice: g, skin: 0.5}}\nresult: part\n"
                                  "outputs: {slices: {printer: sl1s, layer: 0.5, file: conv.sl1s}, mesh: "
                                  "conv.stl}\n");
    std::string out;
    ASSERT_EQ(runCommand(voxlatBinary() + " -q run " + recipe.string() + " --out " + (dir.path / "out").string(), &out),
              0)
        << out;
    auto files = listFolder(dir.path / "out");
    std::sort(files.begin(), files.end());
    EXPECT_EQ(files, (std::vector<std::string>{"conv.sl1s", "conv.sl1s.preview.png", "conv.stl", "conv.stl.preview.png",
                                               "report.html", "report.json"}));
    const auto report = nlohmann::json::parse(readFile(dir.path / "out" / "report.json"));
    const auto& box = report["slices"][0]["part_box"];
    EXPECT_EQ(box["from"], "result's bounding box");
    EXPECT_NEAR(box["min"][2].get<double>(), 0.0, 1e-9);  // the ball stands on the plate
    EXPECT_NEAR(box["max"][2].get<double>(), 8.0, 1e-9);
    // The sealed inside is the largest trap, listed first, and the warning points at `drain:`.
    const auto& traps = report["slices"][0]["printability"]["resin_traps"];
    ASSERT_GE(traps.size(), 1u);
    for (std::size_t i = 1; i < traps.size(); ++i)
        EXPECT_GE(traps[i - 1]["volume_mm3"].get<double>(), traps[i]["volume_mm3"].get<double>());
    EXPECT_GT(traps[0]["volume_mm3"].get<double>(), 50.0);
    EXPECT_NE(out.find("drain: {diameter"), std::string::npos) << out;
}

TEST(RealJobs, GradedSummaryPrintsNoBlankValues)
{
    std::string out;
    TempDir dir;
    ASSERT_EQ(runCommand(voxlatBinary() + " run " + (sourceDir() / "data/recipes/gyroid-graded.yaml").string() +
                             " --set voxel=0.5 --no-preview --out " + (dir.path / "o").string(),
                         &out),
              0)
        << out;
    EXPECT_EQ(out.find("level ,"), std::string::npos) << out;
    EXPECT_EQ(out.find("density  ("), std::string::npos) << out;
    EXPECT_EQ(out.find("null"), std::string::npos) << out;
}

TEST(RealJobs, RegisteredTemporariesAreRemovedBySignalCleanUp)
{
    TempDir dir;
    const std::string a = (dir.path / "x.stl.tmp-1").string();
    std::ofstream(a) << "half";
    registerTemporary(a);
    removeTemporaries();
    EXPECT_FALSE(std::filesystem::exists(a));
    unregisterTemporary(a);
    // An AtomicFile's temporary is registered while it exists.
    {
        AtomicFile f((dir.path / "y.stl").string());
        f.stream() << "data";
        removeTemporaries();  // what a second signal does
        EXPECT_FALSE(std::filesystem::exists(f.tempPath()));
    }
    EXPECT_FALSE(std::filesystem::exists(dir.path / "y.stl"));
}

TEST(RealJobs, BoxFramesAreUniformUpToTheDomainsFaces)
{
    // A BCC box frame filling its domain (4 mm cells, sigma 0.4, 15 %): with `edges: cut` (the
    // default) the struts at the faces are as thick as inside, so the field repeats across a face
    // cell; laid as written (`edges: frame`) the face struts thin (no neighbour beyond).
    auto field = [](const std::string& edges) {
        TempDir dir;
        Job job(
            recipeText("voxel: 0.2\ndomain: {box: [[0, 0, 0], [16, 16, 16]]}\nfields:\n  lattice: {struts: "
                       "{cell: bcc, size: 4" +
                           edges + "}, kernel: {gaussian: {sigma: 0.4}}, density: 0.15}\nresult: lattice\n",
                       dir));
        return job.field("lattice");
    };
    for (const auto& [edges, uniform] :
         std::vector<std::pair<std::string, bool>>{{"", true}, {", edges: cut", true}, {", edges: frame", false}}) {
        const FieldPtr f = field(edges);
        // A point on the strut from a face corner (0, 4, 4) towards the cell centre (2, 6, 6), and
        // its image one cell inside: the same value when the lattice is uniform.
        const Vec3d face(0.3, 4.3, 4.3), inner(4.3, 4.3, 4.3);
        const double a = f->value(face), b = f->value(inner);
        if (uniform)
            EXPECT_NEAR(a, b, 1e-6) << edges;
        else
            EXPECT_GT(a, b + 1e-3) << edges << ": the face strut is not thinner";
    }
}

TEST(RealJobs, SlicesDrainAnyResultAndTheirChecksFindNoTrap)
{
    // `drain:` under `slices:`: a hollow ball made by a difference (no shell, no part to leave):
    // the cavity is opened, the slices' 2D printability check finds no trap, and the mesh of the
    // same run has the channel too.
    TempDir dir;
    Job job(
        recipeText("voxel: 0.2\nfields:\n  outer: {sphere: {radius: 5}}\n  inner: {sphere: {radius: 3}}\n"
                   "  hollow: {difference: [outer, inner]}\nresult: hollow\n"
                   "outputs: {mesh: h.stl, slices: {printer: sl1s, layer: 0.2, file: h.sl1s, drain: {diameter: "
                   "2}}}\n",
                   dir));
    job.writeOutputs(dir.path / "out", false);
    const auto report = job.report();
    const auto& drain = report["drain"]["hollow"];
    ASSERT_EQ(drain["traps_found"], 1) << drain.dump(1);
    ASSERT_EQ(drain["holes"].size(), 1u);
    EXPECT_EQ(drain["traps_left"], 0);
    EXPECT_NEAR(drain["trap_volume_mm3"].get<double>(), 4.0 / 3.0 * std::numbers::pi * 27.0, 0.15 * 113.1);
    const auto& printability = report["slices"][0]["printability"];
    EXPECT_EQ(printability["resin_traps_above_crumb"], 0) << printability.dump(1);
    // A 2 mm channel through the 2 mm wall: about 2 pi mm^3 less than the hollow ball.
    const double hollow = 4.0 / 3.0 * std::numbers::pi * (125.0 - 27.0);
    const double volume = report["mesh"]["volume_mm3"].get<double>();
    EXPECT_LT(volume, hollow - 0.5 * 2.0 * std::numbers::pi);
    EXPECT_GT(volume, hollow - 3.0 * 2.0 * std::numbers::pi);
}

TEST(RealJobs, SlicesDrainIsRefusedOnAResultThatDrainsItself)
{
    TempDir dir;
    const std::string message = errorOf([&] {
        Job job(
            recipeText("voxel: 0.2\nfields:\n  ball: {sphere: {radius: 5}}\n"
                       "  hollow: {shell: {part: ball, thickness: 1, drain: {diameter: 2}}}\nresult: hollow\n"
                       "outputs: {slices: {printer: sl1s, file: h.sl1s, drain: {diameter: 2}}}\n",
                       dir));
    });
    EXPECT_NE(message.find("r.yaml:6:"), std::string::npos) << message;
    EXPECT_NE(message.find("drains its traps already"), std::string::npos) << message;
}

TEST(RealJobs, TheLevelIsAimedAtTheMeshSoTheMeshHoldsTheDensity)
{
    // A gyroid over a box at a coarse voxel: its marching-cubes mesh holds another share than the
    // solve's voxels (5.6 % light at 0.5 mm). The job measures the share the mesh will hold from
    // its grid before making it and moves the level by the solve's slope: the file written holds
    // the density (measured here from its bytes and the domain).
    auto run = [](double voxel, const std::string& mesh, nlohmann::json& report, double& meshShare) {
        TempDir dir;
        Job job(recipeText("voxel: " + std::to_string(voxel) +
                               "\ndomain: {box: [[0, 0, 0], [12, 12, 12]]}\nfields:\n  g: {tpms: gyroid, "
                               "cell: 6, density: 0.3}\nresult: g\noutputs: {mesh: " +
                               mesh + "}\n",
                           dir));
        job.writeOutputs(dir.path / "out", false, false);
        report = job.report();
        const auto lo = report["domain"]["min"], hi = report["domain"]["max"];
        double box = 1.0;
        for (int a = 0; a < 3; ++a) box *= hi[a].get<double>() - lo[a].get<double>();
        meshShare = readMeshVolume(dir.path / "out" / "g.stl") / box;
    };
    nlohmann::json raw;
    double share = 0.0;
    run(0.5, "g.stl", raw, share);
    const auto& g = raw["fields"]["g"];
    ASSERT_TRUE(g.contains("mesh_aim")) << g.dump(1);
    const double before = g["mesh_aim"]["density_from_mesh_at_solved_level"].get<double>();
    EXPECT_GT(std::abs(before / 0.3 - 1.0), 0.01) << "0.5 mm was expected to leave the solved level's mesh off";
    EXPECT_TRUE(g["mesh_aim"]["moved"].get<bool>());
    EXPECT_NEAR(g["density_from_mesh"].get<double>(), share, 1e-6);
    EXPECT_NEAR(share, 0.3, 0.01 * 0.3) << "the mesh at the aimed level, " << before << " at the solved level";
    for (const auto& w : raw.value("warnings", nlohmann::json::array()))
        EXPECT_NE(w["code"], "density_from_mesh") << w.dump();

    // Meshes made otherwise hold another share than the grid's marching cubes at the same level
    // (at 0.4 mm: projected 0.2949 and BCC 0.2906 where marching cubes hold 0.2858): the job
    // measures the share of the mesh it will make (projected: the field's marching cubes past the
    // box, vertices projected, cut by the box; BCC: its tetrahedra) and aims the level at it.
    for (const std::string mesh :
         {"{file: g.stl, project: on}", "{file: g.stl, tolerance: 0.02}", "{file: g.stl, extractor: bcc}"}) {
        nlohmann::json finished;
        run(0.4, mesh, finished, share);
        const auto& f = finished["fields"]["g"];
        ASSERT_TRUE(f.contains("mesh_aim")) << mesh << f.dump(1);
        const auto& aim = f["mesh_aim"];
        EXPECT_EQ(aim["measure"].get<std::string>().find("marching-cubes mesh of the recipe's grid"), std::string::npos)
            << mesh << aim.dump(1);
        EXPECT_TRUE(aim["moved"].get<bool>()) << mesh << aim.dump(1);
        EXPECT_NEAR(f["density_from_mesh"].get<double>(), share, 1e-6) << mesh;
        EXPECT_NEAR(share, 0.3, 0.01 * 0.3) << mesh << aim.dump(1);
        for (const auto& w : finished.value("warnings", nlohmann::json::array()))
            EXPECT_NE(w["code"], "density_from_mesh") << mesh << w.dump();
    }
}

TEST(RealJobs, TheMeshsShareIsPredictedSoItsGridIsMadeOnce)
{
    // A gyroid written as an equation, over a box at 0.25 mm (solved on the job's own voxels): the
    // marching-cubes mesh at the solved level holds about 2 % less than the solve's coverage. The
    // job predicts that share from a sample of its grid's boxes (estimateMeshOffset) and moves the
    // level first, so its grid and its file are made once, at a level whose file holds the density
    // (measured from the file's bytes). The prediction lies within 0.1 % of the share a mesh at the
    // solved level holds (the same recipe with that level given), with the level's meaning kept:
    // the report's level is the one the file was made at.
    const std::string field =
        "expr: \"sin(2*pi*x/6)*cos(2*pi*y/6) + sin(2*pi*y/6)*cos(2*pi*z/6) + "
        "sin(2*pi*z/6)*cos(2*pi*x/6)\", solid: network";
    auto run = [&](const std::string& size, nlohmann::json& report, double& share) {
        TempDir dir;
        Job job(recipeText("voxel: 0.25\ndomain: {box: [[0, 0, 0], [12, 12, 12]]}\nfields:\n  g: {" + field + ", " +
                               size + "}\nresult: g\nallow: [pieces]\noutputs: {mesh: g.stl}\n",
                           dir));
        job.writeOutputs(dir.path / "out", false, false);
        report = job.report();
        share = readMeshVolume(dir.path / "out" / "g.stl") / (12.0 * 12.0 * 12.0);
    };
    nlohmann::json aimed;
    double share = 0.0;
    run("density: 0.3", aimed, share);
    const auto& g = aimed["fields"]["g"];
    ASSERT_TRUE(g.contains("mesh_aim")) << g.dump(1);
    const auto& aim = g["mesh_aim"];
    ASSERT_TRUE(aim.contains("prediction")) << aim.dump(1);
    const auto& prediction = aim["prediction"];
    EXPECT_TRUE(prediction["moved"].get<bool>()) << aim.dump(1);
    EXPECT_GT(prediction["crossed_boxes"].get<int>(), 10) << aim.dump(1);
    EXPECT_TRUE(aim.contains("density_from_mesh_at_predicted_level")) << aim.dump(1);
    EXPECT_FALSE(aim.contains("density_from_mesh_at_solved_level")) << aim.dump(1);
    EXPECT_EQ(aim["steps"].get<int>(), 0) << aim.dump(1);
    EXPECT_FALSE(aimed["timings_s"].contains("evaluate at the predicted level")) << "the grid was made twice";
    EXPECT_NEAR(share, 0.3, 0.005 * 0.3) << aim.dump(1);
    EXPECT_NEAR(g["density_from_mesh"].get<double>(), share, 1e-6);
    // The mesh at the solved level, and at the level the report gives.
    for (const bool solvedLevel : {true, false}) {
        const double level = solvedLevel ? aim["solved_level"].get<double>() : g["level"].get<double>();
        nlohmann::json given;
        double at = 0.0;
        std::ostringstream size;
        size << std::setprecision(17) << "level: " << level;
        run(size.str(), given, at);
        if (solvedLevel) {
            const double predicted = prediction["density_from_mesh_at_solved_level"].get<double>();
            EXPECT_GT(std::abs(at / 0.3 - 1.0), 0.01) << "0.25 mm was expected to leave the solved level's mesh off";
            EXPECT_NEAR(predicted, at, 0.001 * at) << aim.dump(1);
        } else {
            EXPECT_NEAR(at, share, 1e-9) << "the report's level is not the one the file was made at";
        }
    }
}

TEST(RealJobs, TheMeshOffsetOfEveryBoxIsTheGridsMeshLessItsCoverage)
{
    // estimateMeshOffset() sampling every box: the volume the marching-cubes mesh of the job's grid
    // encloses (the grid evaluateSparse makes with the domain's box clipped in, every leaf
    // evaluated) less the sub-voxel coverage of the domain's voxels (central
    // differences; the field's own values, as the solve reads them, not the box's clip), or less
    // their count, for a ball that pokes out of the box and a pair of them that meet.
    const Domain d = Domain::fromBox(Box3{Vec3d(0.3, -0.2, 0.1), Vec3d(6.6, 4.9, 4.8)}, 0.25);
    const auto one = std::make_shared<Sphere>(Vec3d(3.1, 2.4, 3.9), 2.2);
    const auto two = std::make_shared<Sphere>(Vec3d(1.9, 2.0, 1.7), 1.3);
    const std::vector<std::pair<std::string, FieldPtr>> fields{
        {"ball", one}, {"pair", std::make_shared<BooleanField>(BooleanOp::Union, std::vector<FieldPtr>{one, two})}};
    for (const auto& [name, field] : fields) {
        SparseOptions options;
        options.clipToDomain = true;
        options.band = Interval(-1e30, 1e30);  // every leaf: the grid's values everywhere
        const openvdb::FloatGrid::Ptr grid = evaluateSparse(*field, d, options);
        const double h3 = std::pow(d.voxel, 3);
        const double mesh = marchingCubesVolume(*grid, 0.0f, d.box.center());
        // The coverage the solve measures: the field's own values, not clipped by the box.
        options.clipToDomain = false;
        const openvdb::FloatGrid::Ptr unclipped = evaluateSparse(*field, d, options);
        const auto acc = unclipped->getConstAccessor();
        double coverage = 0.0;
        for (auto it = d.indexBox().begin(); it; ++it) {
            const openvdb::Coord c = *it;
            const double v = acc.getValue(c);
            double sum = 0.0;
            for (int a = 0; a < 3; ++a) {
                openvdb::Coord up = c, down = c;
                up[a] += 1;
                down[a] -= 1;
                const double change = 0.5 * (double(acc.getValue(up)) - double(acc.getValue(down)));
                sum += change * change;
            }
            const double step = std::sqrt(sum);
            coverage += step > 0.0 ? std::clamp(0.5 - v / step, 0.0, 1.0) : double(v < 0.0);
        }
        const double exact = mesh - coverage * h3;
        const MeshOffset all = estimateMeshOffset(*field, d, 1);
        // The count's offset: the same mesh less the voxels below zero.
        std::uint64_t below = 0;
        for (auto it = d.indexBox().begin(); it; ++it) below += acc.getValue(*it) < 0.0f;
        EXPECT_NEAR(estimateMeshOffset(*field, d, 1, false).volume, mesh - double(below) * h3, 1e-6 * mesh) << name;
        EXPECT_EQ(all.sampled, all.boxes) << name;
        EXPECT_EQ(all.boxes, meshOffsetBoxes(d)) << name;
        EXPECT_GT(all.crossed, 10u) << name;
        EXPECT_GT(std::abs(exact), 1e-4 * mesh) << name;  // an offset to find
        EXPECT_NEAR(all.volume, exact, 1e-6 * mesh) << name;
        const MeshOffset quarter = estimateMeshOffset(*field, d, 4);
        EXPECT_LT(quarter.sampled, all.sampled / 2) << name;
        EXPECT_GT(quarter.sampled, 0u) << name;
    }
}

TEST(RealJobs, AStreamedStlIsMeasuredAsItIsWrittenAndHasTheLevelOfAMeshHeldWhole)
{
    // A raw STL that is the mesh's only use is written as it is made, and the aim measures its
    // share from that writing (not from a marching-cubes pass of its own): at a level that stays
    // (0.1 mm) the file is meshed once; at one that moves (0.5 mm) the file written at the solved
    // level is withdrawn and written again. Either way the level and the file's bytes are those
    // of the same recipe meshed whole (Job::writeMesh(): the aim's own marching-cubes volume).
    for (const double voxel : {0.1, 0.5}) {
        const std::string text = "voxel: " + std::to_string(voxel) +
                                 "\ndomain: {box: [[0, 0, 0], [12, 12, 12]]}\nfields:\n  g: {tpms: gyroid, "
                                 "cell: 6, density: 0.3}\nresult: g\noutputs: {mesh: g.stl}\n";
        TempDir streamedDir, wholeDir;
        Job streamed(recipeText(text, streamedDir));
        streamed.writeOutputs(streamedDir.path / "out", false, false);
        Job whole(recipeText(text, wholeDir));
        std::filesystem::create_directories(wholeDir.path / "out");
        whole.writeMesh(wholeDir.path / "out" / "g.stl");
        const nlohmann::json s = streamed.report(), w = whole.report();
        const auto& aim = s["fields"]["g"]["mesh_aim"];
        EXPECT_NE(aim["measure"].get<std::string>().find("as its STL is written"), std::string::npos) << aim.dump(1);
        EXPECT_EQ(aim["moved"], w["fields"]["g"]["mesh_aim"]["moved"]) << voxel;
        EXPECT_EQ(aim["moved"].get<bool>(), voxel > 0.2) << aim.dump(1);
        EXPECT_EQ(s["fields"]["g"]["level"].get<double>(), w["fields"]["g"]["level"].get<double>()) << voxel;
        EXPECT_EQ(aim["density_from_mesh_at_solved_level"].get<double>(),
                  w["fields"]["g"]["mesh_aim"]["density_from_mesh_at_solved_level"].get<double>());
        EXPECT_TRUE(readFile(streamedDir.path / "out" / "g.stl") == readFile(wholeDir.path / "out" / "g.stl"))
            << voxel << ": the streamed file differs from the mesh held whole";
        // Meshed once when the level stays; a withdrawn file leaves no temporary behind.
        EXPECT_EQ(s["timings_s"].contains("measure the mesh's share"), aim["moved"].get<bool>())
            << s["timings_s"].dump(1);
        std::vector<std::string> files;
        for (const auto& e : std::filesystem::directory_iterator(streamedDir.path / "out"))
            files.push_back(e.path().filename().string());
        std::sort(files.begin(), files.end());
        EXPECT_EQ(files, (std::vector<std::string>{"g.stl", "report.json"})) << voxel;
    }
}

TEST(RealJobs, ADrainedInfillsProjectedMeshIsAimedAtItsSharpenedCreases)
{
    // A gyroid infill of the bracket with a 1 mm skin and a drain: the part less its channels has
    // creases of its own, so the aim measures the projected mesh made as the finished one is
    // (creases sharpened), and the file written holds the density of the core within 1 %
    // (report.json's own measure: the core's volume from the part and the skin). Before the aim:
    // -2.1 % at 0.15 mm.
    TempDir dir;
    Job job(recipeText("voxel: 0.25\nfields:\n  part: {mesh: " + bracket() +
                           "}\n  g: {tpms: gyroid, cell: 6}\n"
                           "  filled: {infill: {part: part, lattice: g, skin: 1, density: 0.2, drain: {diameter: 2}}}\n"
                           "result: filled\noutputs: {mesh: {file: m.stl, project: on}}\n",
                       dir));
    job.writeOutputs(dir.path / "out", false, false);
    const nlohmann::json report = job.report();
    const auto& g = report["fields"]["g"];
    ASSERT_TRUE(g.contains("mesh_aim")) << g.dump(1);
    EXPECT_NE(g["mesh_aim"]["measure"].get<std::string>().find("creases sharpened"), std::string::npos)
        << g["mesh_aim"].dump(1);
    ASSERT_TRUE(g.contains("density_from_mesh")) << g.dump(1);
    EXPECT_NEAR(g["density_from_mesh"].get<double>(), 0.2, 0.01 * 0.2) << g["mesh_aim"].dump(1);
    // Its creases split and its vertices projected, the mesh is one surface: closed and
    // manifold by position too (no split point on another vertex), no two triangles crossing.
    const auto& mesh = report["mesh"];
    EXPECT_TRUE(mesh["closed_manifold"].get<bool>()) << mesh.dump(1);
    EXPECT_EQ(mesh["coincident_vertices"].get<std::size_t>(), 0u);
    EXPECT_EQ(mesh["self_intersections"].get<std::size_t>(), 0u);
}

TEST(RealJobs, TwoLatticesInOneMeshSayTheirShareIsNotMeasuredFromIt)
{
    // The mesh of a union holds both lattices: neither's share of its region can be read from
    // it. report.json says so for each (with what `achieved_density` is), and gives no number.
    TempDir dir;
    Job job(
        recipeText("voxel: 0.5\ndomain: {box: [[0, 0, 0], [12, 12, 12]]}\nfields:\n"
                   "  a: {tpms: gyroid, cell: 6, density: 0.15}\n"
                   "  b: {tpms: schwarz-p, cell: 6, density: 0.15}\n"
                   "  both: {union: [a, b]}\nresult: both\noutputs: {mesh: m.stl}\n",
                   dir));
    job.writeOutputs(dir.path / "out", false, false);
    const nlohmann::json report = job.report();
    for (const char* name : {"a", "b"}) {
        const auto& f = report["fields"][name];
        EXPECT_FALSE(f.contains("density_from_mesh")) << f.dump(1);
        ASSERT_TRUE(f.contains("density_from_mesh_not_measured")) << f.dump(1);
        EXPECT_NE(f["density_from_mesh_not_measured"].get<std::string>().find("voxels"), std::string::npos);
    }
}

TEST(RealJobs, CapsuleStrutsInABoxHoldTheirDensityByMonteCarlo)
{
    // Capsule struts (a distance field) of 10 mm X cells in a 20 mm box at 0.25 mm: the solve's
    // bracket was a tenth of a voxel's step wide, and its coverage measure stopped at the bracket's
    // end: 0.0974 reported for 0.1 asked while the solid held 0.103. The level solved now holds
    // the density by an independent measure: the field sampled at random points of the box.
    TempDir dir;
    Job job(
        recipeText("voxel: 0.25\ndomain: {box: [[0, 0, 0], [20, 20, 20]]}\nfields:\n  s: {struts: {cell: x, "
                   "size: 10}, kernel: capsule, density: 0.1}\nresult: s\n",
                   dir));
    const FieldPtr f = job.field("s");
    const nlohmann::json report = job.report();
    const auto& entry = report["fields"]["s"];
    EXPECT_NEAR(entry["achieved_density"].get<double>(), 0.1, 0.001) << entry.dump(1);
    std::mt19937_64 rng(42);
    std::uniform_real_distribution<double> u(0.0, 20.0);
    constexpr std::size_t kPoints = 400000;
    std::vector<Vec3d> points(kPoints);
    for (Vec3d& p : points) p = Vec3d(u(rng), u(rng), u(rng));
    std::vector<double> values(kPoints);
    for (std::size_t b = 0; b < kPoints; b += 1024) {
        const std::size_t n = std::min<std::size_t>(1024, kPoints - b);
        f->values(std::span<const Vec3d>(points).subspan(b, n), std::span<double>(values).subspan(b, n));
    }
    const double inside = double(std::count_if(values.begin(), values.end(), [](double v) { return v < 0.0; }));
    const double share = inside / double(kPoints);
    const double sigma = std::sqrt(0.1 * 0.9 / double(kPoints));  // 0.00047
    EXPECT_NEAR(share, 0.1, 4.0 * sigma) << "Monte Carlo over the box";
}

TEST(SheetWalls, AShellAroundASphereMeasuresItsThickness)
{
    // mid: |p| - 4, the sheet | |p| - 4 | <= 0.3: every chord along the normal is 0.6 exactly.
    class Shell final : public FieldNode {
    public:
        explicit Shell(bool sheet) : mSheet(sheet) {}
        void values(std::span<const Vec3d> points, std::span<double> out) const override
        {
            for (std::size_t i = 0; i < points.size(); ++i) {
                const double d = points[i].length() - 4.0;
                out[i] = mSheet ? std::abs(d) - 0.3 : d;
            }
        }
        void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override
        {
            values(points, out);
            for (std::size_t i = 0; i < points.size(); ++i) grad[i] = points[i] / points[i].length();
        }
        Interval bound(const Box3&) const override { return Interval(-1e9, 1e9); }

    private:
        bool mSheet;
    };
    const SheetWallStats s = measureSheetWalls(Shell(false), Shell(true), Box3{Vec3d(-5.0), Vec3d(5.0)}, 0.6);
    ASSERT_GT(s.samples, 100u);
    EXPECT_NEAR(s.mean, 0.6, 1e-5);
    EXPECT_NEAR(s.min, 0.6, 1e-5);
    EXPECT_NEAR(s.max, 0.6, 1e-5);
}

TEST(RealJobs, SheetWallsAreMeasuredAndAMissIsWarned)
{
    // `thickness:` shifts the surface along its gradient, exact to first order: a gyroid's thin
    // walls come out as asked; where the walls are thick against their curvature they do not,
    // and the job says so with the numbers.
    auto walls = [](const std::string& tpms, double cell, double thickness) {
        TempDir dir;
        Job job(recipeText("voxel: 0.2\ndomain: {box: [[0, 0, 0], [" + std::to_string(cell) +
                               ", 4, 4]]}\nfields:\n  g: {tpms: " + tpms + ", cell: " + std::to_string(cell) +
                               ", solid: sheet, thickness: " + std::to_string(thickness) + "}\nresult: g\n",
                           dir));
        job.solveLevels();
        return job.report();
    };
    const auto thin = walls("gyroid", 8.0, 0.3);
    const auto& g = thin["fields"]["g"]["walls_measured"];
    EXPECT_NEAR(g["mean_mm"].get<double>(), 0.3, 0.02 * 0.3) << g.dump();
    for (const auto& w : thin.value("warnings", nlohmann::json::array())) EXPECT_NE(w["code"], "wall_thickness");
    const auto thick = walls("lidinoid", 3.0, 0.5);
    bool warned = false;
    for (const auto& w : thick.value("warnings", nlohmann::json::array()))
        warned = warned || w["code"] == "wall_thickness";
    const auto& l = thick["fields"]["g"]["walls_measured"];
    EXPECT_TRUE(warned) << l.dump();
    EXPECT_TRUE(std::abs(l["mean_mm"].get<double>() / 0.5 - 1.0) > 0.02 || l["p01_mm"].get<double>() < 0.45)
        << l.dump();
}
