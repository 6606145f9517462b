// Skin-following frames (issue 6): cells between two offset surfaces of a part, for struts and
// TPMS. Depths against analytic parts, strut counts and sharing, the inverse map, bounds,
// continuity across cell faces, bad input, recipes end to end.
#include "TestUtil.h"
#include "engine/core/Errors.h"
#include "engine/frames/SkinFrame.h"
#include "engine/jobs/Job.h"
#include "engine/parts/MeshSdf.h"
#include "fields/frames/SkinMap.h"
#include "fields/shapes/BoxField.h"
#include "fields/shapes/MeshDistance.h"
#include "fields/shapes/Sphere.h"
#include "fields/tpms/TpmsField.h"
#include "mesher/checks/MeshCheck.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <random>
#include <set>

using namespace voxlat;
using namespace voxlat::test;

namespace {

/// Depth of each hex corner below the part's surface, for a part whose distance is @a d.
double depthOf(const FieldNode& d, const Vec3d& p)
{
    return -d.value(p);
}

std::shared_ptr<const SkinCells> sphereCells(const SkinLayout& layout, SkinCellStats& stats, double radius = 10.0)
{
    const auto ball = std::make_shared<Sphere>(Vec3d(1.0, 2.0, 3.0), radius);
    return buildSkinCells(ball, *ball->support(), layout, stats);
}

/// Every corner of every cell lies on the offset surface of its layer: depth a + k (b - a) / L,
/// with the w = 0 corners of outer cells at a and w = 1 one layer deeper than w = 0.
void expectCornersAtDepths(const FieldNode& distance, const SkinCells& cells, const SkinLayout& layout, double tol)
{
    const double step = (layout.inner - layout.outer) / layout.layers;
    double worst = 0.0;
    for (std::size_t h = 0; h < cells.size(); ++h)
        for (int i = 0; i < 8; ++i) {
            const double depth = depthOf(distance, cells.corners()[cells.hex(h)[i]]);
            const double k = std::round((depth - layout.outer) / step);
            worst = std::max(worst, std::abs(depth - (layout.outer + k * step)));
            EXPECT_GE(k, 0);
            EXPECT_LE(k, layout.layers);
            if (cells.outer(h) && i < 4) {
                EXPECT_NEAR(depth, layout.outer, tol);
            }
            if (i < 4) {
                EXPECT_NEAR(depthOf(distance, cells.corners()[cells.hex(h)[i + 4]]) - depth, step, 2 * tol);
            }
        }
    EXPECT_LE(worst, tol);
}

}  // namespace

TEST(SkinFrame, CornersLieAtTheRequestedDepthsOnASphere)
{
    // An exact distance: Newton stops at 1e-5 of the cell size, so corners sit there.
    const SkinLayout layout{1.0, 5.0, 2, 2.0};
    SkinCellStats stats;
    const auto cells = sphereCells(layout, stats);
    const Sphere ball(Vec3d(1.0, 2.0, 3.0), 10.0);
    EXPECT_EQ(stats.dropped, 0u);
    EXPECT_EQ(stats.hexes, stats.quads * 2);
    EXPECT_EQ(cells->size(), stats.hexes);
    // Quads about the cell size: the outer surface (radius 9) divided into cells of ~2 mm.
    const double area = 4 * std::numbers::pi * 81.0;
    EXPECT_GT(double(stats.quads), 0.5 * area / 4.0);
    EXPECT_LT(double(stats.quads), 2.0 * area / 4.0);
    expectCornersAtDepths(ball, *cells, layout, 1e-5 * layout.size);
    // Seams (neighbours turned against each other) gather round the contour's irregular
    // vertices: 151 of the 720 edges of this coarse sphere (9 mm radius, 2 mm cells).
    EXPECT_LT(stats.seamEdges, stats.quads / 2);
}

TEST(SkinFrame, CornersLieAtTheRequestedDepthsInABoxField)
{
    // A box's inside distance has creases on its medial planes; corners still reach their depth.
    const SkinLayout layout{0.5, 2.5, 1, 1.5};
    const auto box = std::make_shared<BoxField>(Box3{Vec3d(0.0), Vec3d(12.0, 10.0, 8.0)});
    SkinCellStats stats;
    const auto cells = buildSkinCells(box, *box->support(), layout, stats);
    EXPECT_GT(cells->size(), 100u);
    expectCornersAtDepths(*box, *cells, layout, 1e-5 * layout.size);
}

TEST(SkinFrame, MeshPartCornersWithinHalfAVoxelOfTheExactDepth)
{
    // A cube mesh converted at voxel h: the grid holds exact distances to the triangles, and its
    // trilinear interpolant is exact where the distance is linear (off the medial planes) and
    // within h / 2 of it where a cell straddles a crease, so corners are within h / 2 of depth.
    const double h = 0.25;
    auto xform = openvdb::math::Transform::createLinearTransform(h);
    const auto grid = meshToSdf(cubeMesh(0.0, 12.0), *xform, 3.0f, 40.0f);
    const auto distance = std::make_shared<MeshDistance>(grid, Box3{Vec3d(-h), Vec3d(12.0 + h)});
    const SkinLayout layout{1.0, 3.0, 2, 2.0};
    SkinCellStats stats;
    const auto cells = buildSkinCells(distance, Box3{Vec3d(0.0), Vec3d(12.0)}, layout, stats);
    const BoxField exact(Box3{Vec3d(0.0), Vec3d(12.0)});
    expectCornersAtDepths(exact, *cells, layout, 0.5 * h);
}

TEST(SkinFrame, GridStrutsCountAndShareEveryNode)
{
    // The grid cell puts nodes on the corners only: the frame is the quad mesh's edges on every
    // layer plus one strut per vertex between layers, each once: struts = 2 Q (L + 1) + V L on a
    // closed quad mesh (E = 2 Q), nodes = V (L + 1).
    const SkinLayout layout{1.0, 4.0, 3, 2.0};
    SkinCellStats stats;
    const auto cells = sphereCells(layout, stats);
    ASSERT_EQ(stats.dropped, 0u);
    const Frame frame = skinFrame(presetUnitCell("grid"), *cells);
    EXPECT_EQ(frame.nodes.size(), stats.vertices * 4);
    EXPECT_EQ(frame.struts.size(), 2 * stats.quads * 4 + stats.vertices * 3);
    std::set<std::pair<int, int>> unique;
    for (const auto& s : frame.struts) EXPECT_TRUE(unique.insert({s[0], s[1]}).second);
}

TEST(SkinFrame, BccNodesAreSharedByEveryCellAroundThem)
{
    const SkinLayout layout{1.0, 5.0, 2, 2.0};
    SkinCellStats stats;
    const auto cells = sphereCells(layout, stats);
    const UnitCell bcc = presetUnitCell("bcc");
    ASSERT_TRUE(quarterTurnSymmetric(bcc));
    const Frame frame = skinFrame(bcc, *cells);
    // bcc: eight struts from the corners to the centre in each cell, none shared.
    EXPECT_EQ(frame.struts.size(), 8 * cells->size());
    EXPECT_EQ(frame.nodes.size(), stats.vertices * 3 + cells->size());
    // A corner node has one strut per cell that has it as a corner.
    std::map<int, int> cellsAtCorner;
    for (std::size_t h = 0; h < cells->size(); ++h)
        for (int c : cells->hex(h)) ++cellsAtCorner[c];
    std::vector<int> degree(frame.nodes.size(), 0);
    for (const auto& s : frame.struts) {
        ++degree[s[0]];
        ++degree[s[1]];
    }
    std::size_t corners = 0;
    for (const auto& [c, count] : cellsAtCorner) {
        const Vec3d p = cells->corners()[c];
        int found = -1;
        for (std::size_t n = 0; n < frame.nodes.size(); ++n)
            if ((frame.nodes[n] - p).length() < 1e-9) found = int(n);
        ASSERT_GE(found, 0);
        EXPECT_EQ(degree[found], count);
        ++corners;
    }
    EXPECT_EQ(corners, stats.vertices * 3);
    // The others are the cell centres, with eight struts each.
    EXPECT_EQ(std::count(degree.begin(), degree.end(), 8) >= long(cells->size()), true);
    std::set<std::pair<int, int>> unique;
    for (const auto& s : frame.struts) EXPECT_TRUE(unique.insert({s[0], s[1]}).second);
}

TEST(SkinFrame, QuarterTurnSymmetryOfPresets)
{
    for (const char* name : {"grid", "bcc", "fcc", "octet", "kelvin"})
        EXPECT_TRUE(quarterTurnSymmetric(presetUnitCell(name))) << name;
    EXPECT_FALSE(quarterTurnSymmetric(presetUnitCell("honeycomb")));
}

TEST(SkinMap, LocalCoordinatesRoundTrip)
{
    const SkinLayout layout{1.0, 5.0, 2, 2.0};
    SkinCellStats stats;
    const auto cells = sphereCells(layout, stats);
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    double worst = 0.0;
    int found = 0;
    for (int n = 0; n < 5000; ++n) {
        const std::size_t h = std::size_t(u(rng) * double(cells->size())) % cells->size();
        const Vec3d t(u(rng), u(rng), u(rng));
        const Vec3d p = cells->map(h, t);
        Vec3d back;
        ASSERT_TRUE(cells->inverse(h, p, back));
        worst = std::max(worst, (back - t).length());
        // Any cell that claims p maps its coordinates back onto p.
        Vec3d local;
        const int g = cells->locate(p, local);
        ASSERT_GE(g, 0);
        EXPECT_LT((cells->map(std::size_t(g), local) - p).length(), 1e-9);
        found += g == int(h);
    }
    EXPECT_LT(worst, 1e-8);
    EXPECT_GT(found, 4900);  // others lie on faces shared with a lower-numbered cell
    // Points outside the shell are in no cell.
    Vec3d local;
    EXPECT_LT(cells->locate(Vec3d(1.0, 2.0, 3.0), local), 0);        // the centre
    EXPECT_LT(cells->locate(Vec3d(1.0, 2.0, 3.0 + 9.8), local), 0);  // inside the skin
    EXPECT_LT(cells->locate(Vec3d(1.0, 2.0, 3.0 + 4.5), local), 0);  // deeper than b
    EXPECT_GE(cells->locate(Vec3d(1.0, 2.0, 3.0 + 7.0), local), 0);  // in the layers
}

TEST(SkinMap, BoundsContainSamplesAndGradientsMatch)
{
    const SkinLayout layout{1.0, 4.0, 1, 3.0, 0.5};
    SkinCellStats stats;
    const auto ball = std::make_shared<Sphere>(Vec3d(0.0), 10.0);
    const auto cells = buildSkinCells(ball, *ball->support(), layout, stats);
    const auto gyroid = std::make_shared<TpmsField>(TpmsType::Gyroid, Vec3d(3.0));
    const SkinMapField f(gyroid, cells, Vec3d(3.0), 3.0);
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> u(-12.0, 12.0), s(0.1, 4.0), t(0.0, 1.0);
    int inside = 0;
    for (int n = 0; n < 400; ++n) {
        const Vec3d c(u(rng), u(rng), u(rng));
        const Box3 box{c, c + Vec3d(s(rng))};
        const Interval b = f.bound(box);
        for (int k = 0; k < 27; ++k) {
            const Vec3d p = box.min + Vec3d(t(rng), t(rng), t(rng)) * box.extent();
            const double v = f.value(p);
            EXPECT_TRUE(b.contains(v)) << v << " not in [" << b.lo << ", " << b.hi << "]";
            inside += v != 3.0;
        }
    }
    EXPECT_GT(inside, 500);
    // The outer extension: between the outer chord faces and the sphere of radius 9 the lattice
    // continues, and stops there; outside radius 9 (in the skin) it is outside.
    for (int n = 0; n < 2000; ++n) {
        Vec3d d(u(rng), u(rng), u(rng));
        d.normalize();
        Vec3d q;
        EXPECT_FALSE(f.toCell(d * 9.02, q));
        EXPECT_TRUE(f.toCell(d * 8.98, q));
        EXPECT_TRUE(f.toCell(d * 6.02, q));
        EXPECT_FALSE(f.toCell(d * 5.6, q));  // chords of the inner sphere stay within 0.4 mm
    }
    // Gradients against central differences, inside cells (away from faces).
    int checked = 0;
    for (std::size_t h = 0; h < cells->size() && checked < 200; h += 7) {
        const Vec3d p = cells->map(h, Vec3d(0.3 + 0.4 * t(rng), 0.3 + 0.4 * t(rng), 0.3 + 0.4 * t(rng)));
        const auto [v, g] = f.valueAndGradient(p);
        EXPECT_NEAR(v, f.value(p), 1e-12);
        for (int a = 0; a < 3; ++a) {
            Vec3d e(0.0);
            e[a] = 1e-6;
            EXPECT_NEAR(g[a], (f.value(p + e) - f.value(p - e)) / 2e-6, 1e-5 * (1 + g.length()));
        }
        ++checked;
    }
}

TEST(SkinMap, ContinuousAcrossFacesOffTheSeams)
{
    // Values on each face shared by two cells, computed from either side: equal everywhere for
    // Schwarz P (the same after a quarter turn about z), and for the gyroid equal except on faces
    // at seam edges and between layers never broken.
    const SkinLayout layout{1.0, 5.0, 2, 2.0};
    SkinCellStats stats;
    const auto cells = sphereCells(layout, stats);
    const Vec3d cell(2.0);
    const auto schwarz = std::make_shared<TpmsField>(TpmsType::SchwarzP, cell);
    const auto gyroid = std::make_shared<TpmsField>(TpmsType::Gyroid, cell);
    // Faces by their four corner ids.
    std::map<std::array<int, 4>, std::vector<std::pair<std::size_t, int>>> faces;
    const int faceCorners[6][4] = {{0, 2, 4, 6}, {1, 3, 5, 7}, {0, 1, 4, 5}, {2, 3, 6, 7}, {0, 1, 2, 3}, {4, 5, 6, 7}};
    for (std::size_t h = 0; h < cells->size(); ++h)
        for (int f = 0; f < 6; ++f) {
            std::array<int, 4> key;
            for (int i = 0; i < 4; ++i) key[i] = cells->hex(h)[faceCorners[f][i]];
            std::sort(key.begin(), key.end());
            faces[key].push_back({h, f});
        }
    std::size_t shared = 0, lateralBroken = 0, layerBroken = 0;
    double worstP = 0.0;
    for (const auto& [key, users] : faces) {
        if (users.size() != 2) continue;
        ++shared;
        const auto [ha, fa] = users[0];
        const auto [hb, fb] = users[1];
        double worstG = 0.0;
        for (double s : {0.2, 0.5, 0.7})
            for (double r : {0.1, 0.5, 0.9}) {
                Vec3d ta(s, r, 0.0);
                const int axis = fa / 2;  // 0: u fixed, 1: v fixed, 2: w fixed
                ta = axis == 0 ? Vec3d(fa % 2, s, r) : axis == 1 ? Vec3d(s, fa % 2, r) : Vec3d(s, r, fa % 2);
                const Vec3d p = cells->map(ha, ta);
                Vec3d tb;
                ASSERT_TRUE(cells->inverse(hb, p, tb));
                const Vec3d qa(ta[0] * 2, ta[1] * 2, ta[2] * 2), qb(tb[0] * 2, tb[1] * 2, tb[2] * 2);
                worstP = std::max(worstP, std::abs(schwarz->value(qa) - schwarz->value(qb)));
                worstG = std::max(worstG, std::abs(gyroid->value(qa) - gyroid->value(qb)));
            }
        if (worstG > 1e-6) ++(fa / 2 == 2 ? layerBroken : lateralBroken);
    }
    EXPECT_GT(shared, 2 * stats.quads);
    EXPECT_LT(worstP, 1e-6);
    EXPECT_EQ(layerBroken, 0u);
    EXPECT_LE(lateralBroken, stats.seamEdges * std::size_t(layout.layers));
    EXPECT_GT(lateralBroken, 0u);  // seams are real for the gyroid
}

TEST(SkinFrame, BadInputNamesFileAndLine)
{
    TempDir dir;
    auto run = [&](const std::string& fields) {
        const std::string text = "voxel: 0.5\nfields:\n  ball: {sphere: {radius: 6}}\n" + fields + "result: lat\n";
        return errorOf([&] {
            Job job(parseRecipe(text, "skin.yaml", dir.path));
            job.solveLevels();
        });
    };
    // Each broken recipe line and what its message must say.
    const std::pair<const char*, const char*> cases[] = {
        {"  lat: {struts: {cell: bcc, size: 2, skin: {part: ball, depth: [3, 2]}}, kernel: capsule, radius: 0.3}\n",
         "greater than the outer"},  // b <= a
        {"  lat: {struts: {cell: bcc, size: 2, skin: {depth: [1, 2]}}, kernel: capsule, radius: 0.3}\n",
         "part:"},  // no part
        {"  lat: {tpms: gyroid, cell: 2, level: 0, frame: {skin: {part: ball, depth: [7, 8]}}}\n",
         "no interior 7 mm below"},  // no interior at the outer depth
        {"  lat: {tpms: gyroid, cell: 2, level: 0, frame: {skin: {part: ball, depth: [1, 9]}}}\n",
         "no cell reaches 9 mm"},  // no cell at the inner depth
        {"  lat: {tpms: gyroid, cell: 2, level: 0, frame: {skin: {part: ball, depht: [1, 2]}}}\n",
         "depth"},  // a misspelt key
    };
    for (const auto& [fields, expected] : cases) {
        const std::string e = run(fields);
        EXPECT_NE(e.find("skin.yaml:4:"), std::string::npos) << e;
        EXPECT_NE(e.find(expected), std::string::npos) << e;
    }
}

TEST(SkinFrame, InfillDensityIsMeasuredInsideTheCells)
{
    // A skin-following gyroid sheet in an infill: its density is its share of the core within
    // the cells; checked by points independent of the solver's grid.
    const std::string text = R"(voxel: 0.2
fields:
  ball: {sphere: {radius: 8}}
  gyroid: {tpms: gyroid, cell: 2, solid: sheet, frame: {skin: {part: ball, depth: 0.6, layers: 2}}}
  lat: {infill: {part: ball, lattice: gyroid, skin: 0.6, density: 0.3}}
result: lat
allow: [pieces]
)";
    TempDir dir;
    Job job(parseRecipe(text, "skin.yaml", dir.path));
    job.solveLevels();
    const auto report = job.report();
    EXPECT_NEAR(report["fields"]["gyroid"]["achieved_density"].get<double>(), 0.3, 0.003);
    EXPECT_EQ(report["skin_frames"]["gyroid"]["layers"], 2);
    const FieldPtr lattice = job.field("gyroid");
    const Sphere ball(Vec3d(0.0), 8.0);
    std::uint64_t space = 0, inside = 0;
    const double phi[3] = {0.8191725134, 0.6710436067, 0.5497004779};
    const auto& gyroid = dynamic_cast<const LevelSolid&>(*lattice);
    const auto& map = dynamic_cast<const SkinMapField&>(*gyroid.raw());
    for (int n = 0; n < 400000; ++n) {
        Vec3d p, q;
        for (int a = 0; a < 3; ++a) p[a] = -8.0 + std::fmod(0.5 + n * phi[a], 1.0) * 16.0;
        if (ball.value(p) + 0.6 >= 0.0 || !map.toCell(p, q)) continue;
        ++space;
        inside += lattice->value(p) < 0.0;
    }
    ASSERT_GT(space, 50000u);
    EXPECT_NEAR(double(inside) / double(space), 0.3, 0.006);
    // The result meshes watertight.
    EXPECT_TRUE(checkTopology(job.mesh()).closedManifold());
}

TEST(SkinFrame, StrutSkinRecipeSolvesDensityInTheCells)
{
    const std::string text = R"(voxel: 0.2
domain: {box: [[-9, -9, -9], [9, 9, 9]]}
fields:
  ball: {sphere: {radius: 8}}
  lat: {struts: {cell: bcc, size: 2.5, skin: {part: ball, depth: [0.5, 3]}}, kernel: capsule, density: 0.2}
result: lat
)";
    TempDir dir;
    Job job(parseRecipe(text, "skin.yaml", dir.path));
    job.solveLevels();
    const auto report = job.report();
    EXPECT_NEAR(report["fields"]["lat"]["achieved_density"].get<double>(), 0.2, 0.002);
    EXPECT_EQ(report["fields"]["lat"]["density_measured_in"], "the cells of the skin frame");
    EXPECT_TRUE(checkTopology(job.mesh()).closedManifold());
}

TEST(SkinFrame, BracketRecipeRunsAndMeshesWatertight)
{
    Job job(loadRecipe((sourceDir() / "data/recipes/bracket-skin-lattice.yaml").string()));
    const TriangleMesh& mesh = job.mesh();
    EXPECT_GT(mesh.triangles.size(), 10000u);
    EXPECT_TRUE(checkTopology(mesh).closedManifold());
    const auto report = job.report();
    EXPECT_GT(report["skin_frames"]["schwarz"]["cells"].get<int>(), 100);
    EXPECT_NEAR(report["fields"]["schwarz"]["achieved_density"].get<double>(), 0.3, 0.003);
}
