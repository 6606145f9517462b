// Periodic lattices: a box of identical cells tabled one period deep (PeriodicTiling) and its
// density measured on one period of the interior (periodicPieces), each against the direct way.
#include "TestUtil.h"
#include "engine/core/SparseEvaluator.h"
#include "engine/density/DensitySolver.h"
#include "engine/frames/StrutFrames.h"
#include "engine/frames/UnitCells.h"
#include "engine/jobs/Job.h"
#include "fields/core/PointField.h"
#include "fields/maps/PeriodicTiling.h"
#include "fields/struts/IsoRadius.h"
#include "fields/struts/StrutConvolution.h"
#include "fields/struts/StrutIndex.h"
#include "fields/struts/TiledInterior.h"
#include "mesher/checks/MeshCheck.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include <atomic>
#include <cstring>
#include <map>
#include <random>

using namespace voxlat;
using namespace voxlat::test;

namespace {

/// A box of cells x cells x cells BCC cells of @a size mm as convolution struts, in mm form.
struct BccBox {
    Box3 box;
    double reach = 0.0;
    std::shared_ptr<IsoRadius> iso;
};

BccBox bccBox(int cells, double size, double sigma)
{
    const Frame f = boxFrame(presetUnitCell("bcc"), Vec3d(0.0), Vec3d(size), {cells, cells, cells});
    std::vector<ConvolutionStrut> struts;
    for (const auto& e : f.struts) struts.push_back({f.nodes[e[0]], f.nodes[e[1]], sigma, 1.0, 1.0});
    auto raw = std::make_shared<StrutConvolution>(struts);
    BccBox b;
    b.box = f.bounds();
    b.reach = raw->cutoffRadius(0);
    b.iso = std::make_shared<IsoRadius>(raw, raw->peak(0), sigma, 2.0 * b.reach);
    return b;
}

/// g = x + 0.3 y: planes at every level, so the cube-plane coverage of each voxel is exact and
/// the share of [0, 1]^3 below level L is known in closed form.
struct TiltedPlane final : PointField<TiltedPlane> {
    template <class T>
    T eval(const T& x, const T& y, const T&) const
    {
        return x + T(0.3) * y;
    }
};

/// Share of [0, 1]^3 with x + 0.3 y < L, for 0 <= L <= 1.3.
double tiltedPlaneShare(double level)
{
    if (level <= 0.3) return level * level / 0.6;
    if (level <= 1.0) return level - 0.15;
    const double over = level - 1.0;  // the corner x + 0.3 y >= L cut off at x = 1
    return 1.0 - (0.3 - over) * (0.3 - over) / 0.6;
}

/// Largest difference between two fields' gridValues over every leaf of @a d.
double largestLeafDifference(const FieldNode& a, const FieldNode& b, const Domain& d)
{
    std::vector<double> va(512), vb(512);
    double worst = 0.0;
    for (int x = -8; x < d.dims.x() + 8; x += 8)
        for (int y = -8; y < d.dims.y() + 8; y += 8)
            for (int z = -8; z < d.dims.z() + 8; z += 8) {
                GridBatch batch;
                batch.origin = d.worldOf(openvdb::Coord(x, y, z));
                batch.spacing = Vec3d(d.voxel);
                a.gridValues(batch, va);
                b.gridValues(batch, vb);
                for (int i = 0; i < 512; ++i) worst = std::max(worst, std::abs(va[i] - vb[i]));
            }
    return worst;
}

}  // namespace

TEST(PeriodicTiling, GridValuesMatchTheFieldEverywhere)
{
    // 6^3 cells of 2 mm, sigma 0.25 (cut-off 1.07 mm): zones, folded interior and the outside.
    const BccBox b = bccBox(6, 2.0, 0.25);
    const PeriodicTiling tiled(b.iso, b.box, Vec3d(2.0), b.reach);
    const Domain d = Domain::fromBox(Box3{Vec3d(-1.0), Vec3d(13.0)}, 0.1);
    EXPECT_LT(largestLeafDifference(tiled, *b.iso, d), 1e-9);
    // The values did come from a table, and one much smaller than the domain.
    EXPECT_GT(tiled.tabledValues(), 0u);
    EXPECT_LT(tiled.tabledValues(), d.voxelCount() / 4);
    // A BCC box is its own mirror image along every axis: the high zone reads the low zone's
    // images and the period's pairs of images share a slot, the values still the field's (up to
    // the rounding of evaluating at the image), in a table half the size per axis (zones of 21 positions, periods of
    // 20: 62 -> 31).
    const PeriodicTiling mirrored(b.iso, b.box, Vec3d(2.0), b.reach, {true, true, true});
    EXPECT_LT(largestLeafDifference(mirrored, *b.iso, d), 1e-9);
    EXPECT_GT(mirrored.tabledValues(), 0u);
    EXPECT_LE(double(mirrored.tabledValues()), std::pow(0.5, 3) * double(tiled.tabledValues()));
}

TEST(PeriodicTiling, SpacingThatDoesNotDivideThePeriodEvaluatesTheField)
{
    const BccBox b = bccBox(6, 2.0, 0.25);
    const PeriodicTiling tiled(b.iso, b.box, Vec3d(2.0), b.reach);
    const Domain d = Domain::fromBox(Box3{Vec3d(0.0), Vec3d(12.0)}, 0.13);
    EXPECT_EQ(largestLeafDifference(tiled, *b.iso, d), 0.0);
    EXPECT_EQ(tiled.tabledValues(), 0u);
    // Slice-like batches (one sample in z, layer after layer) start no tables either.
    std::vector<double> direct(64), viaTiling(64);
    for (int layer = 0; layer < 20; ++layer) {
        GridBatch g;
        g.origin = Vec3d(3.0, 3.0, 0.05 + 0.5 * layer);
        g.spacing = Vec3d(0.1, 0.1, 1.0);
        g.nz = 1;
        tiled.gridValues(g, viaTiling);
        b.iso->gridValues(g, direct);
        EXPECT_EQ(viaTiling, direct);
    }
    EXPECT_EQ(tiled.tabledValues(), 0u);
}

TEST(PeriodicTiling, BoundContainsSampledValues)
{
    const BccBox b = bccBox(6, 2.0, 0.25);
    const PeriodicTiling tiled(b.iso, b.box, Vec3d(2.0), b.reach);
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> corner(-1.0, 12.0), size(0.05, 2.0), u(0.0, 1.0);
    for (int n = 0; n < 300; ++n) {
        Box3 box;
        box.min = Vec3d(corner(rng), corner(rng), corner(rng));
        box.max = box.min + Vec3d(size(rng), size(rng), size(rng));
        // Twice: the second answer comes from the cache.
        for (int again = 0; again < 2; ++again) {
            const Interval bound = tiled.bound(box);
            for (int s = 0; s < 40; ++s) {
                const Vec3d p = box.min + Vec3d(u(rng), u(rng), u(rng)) * box.extent();
                const double v = b.iso->value(p);
                ASSERT_LE(bound.lo, v) << "box at " << box.min;
                ASSERT_GE(bound.hi, v) << "box at " << box.min;
            }
        }
    }
}

TEST(PeriodicTiling, SameGridForAnyThreadCount)
{
    const BccBox b = bccBox(6, 2.0, 0.25);
    const Domain d = Domain::fromBox(b.box, 0.05);
    auto run = [&](int threads) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        // A fresh tiling each time: the table is built by however many threads there are.
        const auto solid = std::make_shared<LevelSolid>(
            std::make_shared<PeriodicTiling>(b.iso, b.box, Vec3d(2.0), b.reach), SolidSide::Below, 0.2);
        SparseOptions options;
        options.band = Interval(-0.1, 0.1);
        return evaluateSparse(*solid, d, options);
    };
    const auto one = run(1), three = run(3);
    std::vector<const openvdb::FloatTree::LeafNodeType*> a, c;
    one->tree().getNodes(a);
    three->tree().getNodes(c);
    ASSERT_EQ(a.size(), c.size());
    ASSERT_GT(a.size(), 0u);
    for (std::size_t n = 0; n < a.size(); ++n) {
        ASSERT_EQ(a[n]->origin(), c[n]->origin());
        ASSERT_EQ(std::memcmp(a[n]->buffer().data(), c[n]->buffer().data(), 512 * sizeof(float)), 0);
    }
}

TEST(DensityPieces, TileTheBoxAndMatchTheWholeBoxOnTheSameLattice)
{
    const BccBox b = bccBox(4, 4.0, 0.5);
    // 80 samples per axis: zones of 12, 2 periods of 20 and 16 more samples between them, so
    // four segments per axis (zone, 16 samples x 3, 4 samples x 2, zone); with the mirror
    // (a BCC box is symmetric) the high zone is the low one counted twice, and each part of the
    // period is its own mirror image, so its first half is counted twice: three segments
    // (zone, 8 samples x 6, 2 samples x 4) of 22 samples instead of 40 per axis.
    const std::vector<DensityPiece> pieces = periodicPieces(b.box, Vec3d(4.0), b.reach, 0.2);
    const std::vector<DensityPiece> mirrored = periodicPieces(b.box, Vec3d(4.0), b.reach, 0.2, {true, true, true});
    ASSERT_EQ(pieces.size(), 64u);
    ASSERT_EQ(mirrored.size(), 27u);
    auto samples = [](const std::vector<DensityPiece>& set) {
        std::uint64_t n = 0;
        for (const DensityPiece& p : set) n += p.domain.voxelCount();
        return n;
    };
    EXPECT_EQ(samples(mirrored), 22u * 22u * 22u);
    // A BCC box is also its own image when x and y are swapped: one of each piece and its
    // transpose, counted twice (6 of the 9 x-y pairs).
    const std::vector<DensityPiece> swapped = periodicPieces(b.box, Vec3d(4.0), b.reach, 0.2, {true, true, true}, true);
    ASSERT_EQ(swapped.size(), 18u);
    const DensityPiece whole{Domain::fromBox(b.box, pieces.front().domain.voxel), 1.0};
    for (const auto* set : {&pieces, &mirrored, &swapped}) {
        double voxels = 0.0;
        for (const DensityPiece& p : *set) voxels += p.weight * double(p.domain.voxelCount());
        EXPECT_EQ(voxels, double(whole.domain.voxelCount()));
    }
    // The same lattice over the whole box: the pieces are translates (and mirror images) of its
    // parts, so the same measure gives the same level.
    const DensitySolution fromBox = solveDensity(*b.iso, std::span(&whole, 1), 0.25);
    for (const auto* set : {&pieces, &mirrored, &swapped}) {
        const DensitySolution fromPieces = solveDensity(*b.iso, *set, 0.25);
        EXPECT_NEAR(fromPieces.level, fromBox.level, 1e-5);
        EXPECT_NEAR(fromPieces.achieved, 0.25, 1e-6);
    }
    // Too few cells to fold twice: no pieces, the caller measures the whole box.
    EXPECT_TRUE(periodicPieces(Box3{Vec3d(0.0), Vec3d(12.0)}, Vec3d(4.0), b.reach, 0.1).empty());
}

namespace {

/// 3^3 BCC cells of 5 mm (sigma 0.5, 20 %: the acceptance recipe's cells) at @a voxel.
std::string bccBoxRecipe(double voxel)
{
    return "voxel: " + std::to_string(voxel) +
           "\ndomain: {box: [[0, 0, 0], [15, 15, 15]]}\n"
           "fields:\n  lattice: {struts: {cell: bcc, size: 5}, kernel: {gaussian: {sigma: 0.5}}, density: 0.20}\n"
           "result: lattice\n";
}

/// The mesh, the independent measure, holds 20 % of the 15 mm box (within 0.5 % relative) and is
/// closed and manifold.
void expectMeshHoldsTheTarget(Job& job)
{
    const TriangleMesh& mesh = job.mesh();
    EXPECT_NEAR(mesh.volume() / (15.0 * 15.0 * 15.0), 0.20, 0.005 * 0.20);
    EXPECT_TRUE(checkTopology(mesh).closedManifold());
}

}  // namespace

TEST(DensityPieces, BoxOfCellsHitsTheTargetOnTheMesh)
{
    // 3^3 BCC cells of 5 mm (sigma 0.5, 20 %, the acceptance recipe's cells): folded twice per
    // axis. The mesh's own volume is the independent measure.
    Job job(parseRecipe(bccBoxRecipe(0.1), "bcc.yaml", "."));
    job.solveLevels();
    ASSERT_TRUE(job.report()["fields"]["lattice"].contains("density_sampling"));
    // BCC is its own mirror image along every axis: one face zone per axis, and each part of the
    // period measured by its half (twice) and its middle sample: four segments; and its own image
    // with x and y swapped: 10 of the 16 x-y pairs.
    EXPECT_EQ(job.report()["fields"]["lattice"]["density_sampling"], "one period of the interior (40 weighted pieces)");
    expectMeshHoldsTheTarget(job);
}

TEST(DensityPieces, CoarseJobVoxelKeepsTheLevel)
{
    // The density is a property of the field, not of the job's voxels: a 0.25 mm job measures
    // one period at no more than sigma / 8 a step, as finely as a 0.1 mm job (before: 0.2 mm gave
    // a level 0.0045 mm above the 0.1 mm one, 1 % more material).
    auto level = [](double voxel) {
        Job job(parseRecipe(bccBoxRecipe(voxel), "bcc.yaml", "."));
        job.solveLevels();
        return job.report()["fields"]["lattice"]["level_radius_mm"].get<double>();
    };
    EXPECT_NEAR(level(0.25), level(0.1), 0.0006);
}

TEST(DensityPieces, AsymmetricCellMeasuresBothFaceZones)
{
    // A grid cell with one body diagonal: valid (its faces carry the corners), periodic, but no
    // mirror maps the diagonal onto a strut, so both face zones of every axis are measured
    // (four segments per axis); swapping x and y keeps it: 10 of the 16 x-y pairs.
    const std::string text =
        "voxel: 0.1\ndomain: {box: [[0, 0, 0], [15, 15, 15]]}\n"
        "fields:\n  lattice: {struts: {cell: {lines: [[[0, 0, 0], [1, 0, 0]], [[0, 1, 0], [1, 1, 0]], "
        "[[0, 0, 1], [1, 0, 1]], [[0, 1, 1], [1, 1, 1]], [[0, 0, 0], [0, 1, 0]], [[1, 0, 0], [1, 1, 0]], "
        "[[0, 0, 1], [0, 1, 1]], [[1, 0, 1], [1, 1, 1]], [[0, 0, 0], [0, 0, 1]], [[1, 0, 0], [1, 0, 1]], "
        "[[0, 1, 0], [0, 1, 1]], [[1, 1, 0], [1, 1, 1]], [[0, 0, 0], [1, 1, 1]]]}, size: 5}, "
        "kernel: {gaussian: {sigma: 0.5}}, density: 0.20}\n"
        "result: lattice\n";
    Job job(parseRecipe(text, "diagonal.yaml", "."));
    job.solveLevels();
    EXPECT_EQ(job.report()["fields"]["lattice"]["density_sampling"], "one period of the interior (40 weighted pieces)");
    expectMeshHoldsTheTarget(job);
}

TEST(DensityPieces, PlaneFieldGivesTheExactLevel)
{
    // The level from the pieces' measure against the closed form, on one piece and on the box
    // split in two along z (unequal thicknesses, one counted twice against a thinner copy).
    const TiltedPlane plane;
    const Domain whole = Domain::fromBox(Box3{Vec3d(0.0), Vec3d(1.0)}, 1.0 / 40);
    for (const double target : {0.05, 0.2, 0.5, 0.9}) {
        // Solve share(L) = target for the reference by bisection on the closed form.
        double lo = 0.0, hi = 1.3;
        for (int i = 0; i < 100; ++i) (tiltedPlaneShare(0.5 * (lo + hi)) < target ? lo : hi) = 0.5 * (lo + hi);
        const double exact = 0.5 * (lo + hi);
        // The samples are stored as floats: about 1e-7 of the values.
        const DensityPiece one{whole, 1.0};
        const DensitySolution s1 = solveDensity(plane, std::span(&one, 1), target);
        EXPECT_NEAR(s1.level, exact, 1e-6) << "target " << target;
        EXPECT_NEAR(s1.achieved, target, 1e-9);
        // The field does not depend on z: z in [0, 0.25] counted twice and z in [0.5, 1] once.
        DensityPiece low{Domain::fromBox(Box3{Vec3d(0.0), Vec3d(1.0, 1.0, 0.25)}, 1.0 / 40), 2.0};
        DensityPiece high{Domain::fromBox(Box3{Vec3d(0.0, 0.0, 0.5), Vec3d(1.0)}, 1.0 / 40), 1.0};
        const std::vector<DensityPiece> two{low, high};
        const DensitySolution s2 = solveDensity(plane, two, target);
        EXPECT_NEAR(s2.level, exact, 1e-6) << "target " << target;
        EXPECT_EQ(s2.domainVoxels, whole.voxelCount());
    }
}

TEST(DensityPieces, SameLevelForAnyThreadCount)
{
    const BccBox b = bccBox(5, 2.0, 0.25);
    const std::vector<DensityPiece> pieces = periodicPieces(b.box, Vec3d(2.0), b.reach, 0.06);
    ASSERT_GE(pieces.size(), 27u);
    auto solve = [&](int threads) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        return solveDensity(*b.iso, pieces, 0.2);
    };
    const DensitySolution one = solve(1), three = solve(3);
    EXPECT_EQ(one.level, three.level);
    EXPECT_EQ(one.achieved, three.achieved);
    EXPECT_NEAR(one.achieved, 0.2, 1e-9);
}

namespace {

/// The BCC box of bccBox() with weights growing along z (1 at z = 0 to 1.5 at the top): the
/// field repeats along x and y only.
BccBox gradedBccBox(int cells, double size, double sigma)
{
    const Frame f = boxFrame(presetUnitCell("bcc"), Vec3d(0.0), Vec3d(size), {cells, cells, cells});
    const double top = cells * size;
    std::vector<ConvolutionStrut> struts;
    for (const auto& e : f.struts) {
        const Vec3d a = f.nodes[e[0]], b = f.nodes[e[1]];
        struts.push_back({a, b, sigma, 1.0 + 0.5 * a.z() / top, 1.0 + 0.5 * b.z() / top});
    }
    auto raw = std::make_shared<StrutConvolution>(struts);
    BccBox g;
    g.box = f.bounds();
    g.reach = raw->cutoffRadius(0);
    double peak = 0.0;
    for (std::size_t j = 0; j < raw->strutCount(); ++j) peak = std::max(peak, raw->peak(j));
    g.iso = std::make_shared<IsoRadius>(raw, peak, sigma, 2.0 * g.reach);
    return g;
}

}  // namespace

TEST(PeriodicTiling, PeriodZeroAlongAnAxisTablesItAsItIs)
{
    // Weights graded along z: folding along x and y only (period 0 along z) gives the field's
    // own values everywhere, from a table far smaller than the domain.
    const BccBox b = gradedBccBox(6, 2.0, 0.25);
    const PeriodicTiling tiled(b.iso, b.box, Vec3d(2.0, 2.0, 0.0), b.reach);
    const Domain d = Domain::fromBox(Box3{Vec3d(-1.0), Vec3d(13.0)}, 0.1);
    EXPECT_LT(largestLeafDifference(tiled, *b.iso, d), 1e-9);
    EXPECT_GT(tiled.tabledValues(), 0u);
    EXPECT_LT(tiled.tabledValues(), d.voxelCount() / 2);
    // Folding z as well would be wrong for this field: the check above can fail.
    const PeriodicTiling wrong(b.iso, b.box, Vec3d(2.0), b.reach);
    EXPECT_GT(largestLeafDifference(wrong, *b.iso, d), 1e-3);
    EXPECT_THROW(PeriodicTiling(b.iso, b.box, Vec3d(0.0), b.reach), std::invalid_argument);
}

TEST(PeriodicTiling, MirrorsOnlyWhereTheFieldIsSymmetric)
{
    // Radii graded along z: mirror images across x and y only (z is tabled as it is).
    const BccBox b = gradedBccBox(4, 4.0, 0.5);
    const PeriodicTiling tiled(b.iso, b.box, Vec3d(4.0, 4.0, 0.0), b.reach, {true, true, false});
    const Domain d = Domain::fromBox(Box3{b.box.min - Vec3d(0.5), b.box.max + Vec3d(0.5)}, 0.1);
    EXPECT_LT(largestLeafDifference(tiled, *b.iso, d), 1e-9);
    EXPECT_GT(tiled.tabledValues(), 0u);
    // Claiming a mirror along z, where the radii differ, is visible: the check above has teeth.
    const PeriodicTiling wrong(b.iso, b.box, Vec3d(4.0, 4.0, 0.0), b.reach, {true, true, true});
    EXPECT_GT(largestLeafDifference(wrong, *b.iso, d), 1e-3);
}

TEST(DensityPieces, AxisThatDoesNotRepeatIsOneSegment)
{
    const BccBox b = gradedBccBox(4, 4.0, 0.5);
    // x and y: zone, two partial periods, zone (four segments); z: the whole axis.
    const std::vector<DensityPiece> pieces = periodicPieces(b.box, Vec3d(4.0, 4.0, 0.0), b.reach, 0.2);
    ASSERT_EQ(pieces.size(), 16u);
    const DensityPiece whole{Domain::fromBox(b.box, pieces.front().domain.voxel), 1.0};
    double voxels = 0.0;
    for (const DensityPiece& p : pieces) {
        voxels += p.weight * double(p.domain.voxelCount());
        EXPECT_EQ(p.domain.dims.z(), whole.domain.dims.z());
    }
    EXPECT_EQ(voxels, double(whole.domain.voxelCount()));
    const DensitySolution fromBox = solveDensity(*b.iso, std::span(&whole, 1), 0.25);
    const DensitySolution fromPieces = solveDensity(*b.iso, pieces, 0.25);
    EXPECT_NEAR(fromPieces.level, fromBox.level, 1e-5);
    // Periods that differ between the axes that fold: no pieces.
    EXPECT_TRUE(periodicPieces(b.box, Vec3d(4.0, 2.0, 0.0), b.reach, 0.2).empty());
}

namespace {
/// A 15 mm box of BCC struts (5 mm cells, sigma 0.5) whose radii are graded by @a radius, solved
/// for a density of 0.2: report.json says it measured @a sampling, and the mesh holds the target.
void expectGradedStrutsHitTheTarget(const std::string& radius, const std::string& sampling)
{
    Job job(
        parseRecipe("voxel: 0.1\ndomain: {box: [[0, 0, 0], [15, 15, 15]]}\nfields:\n"
                    "  lattice: {struts: {cell: bcc, size: 5}, kernel: {gaussian: {sigma: 0.5}}, "
                    "radius: " +
                        radius + ", density: 0.20}\nresult: lattice\n",
                    "graded.yaml", "."));
    job.solveLevels();
    EXPECT_EQ(job.report()["fields"]["lattice"]["density_sampling"], sampling);
    const TriangleMesh& mesh = job.mesh();
    EXPECT_NEAR(mesh.volume() / (15.0 * 15.0 * 15.0), 0.20, 0.01 * 0.20);
    EXPECT_TRUE(checkTopology(mesh).closedManifold());
}
}  // namespace

TEST(DensityPieces, RadiiGradedAlongAnAxisHitTheTargetOnTheMesh)
{
    // Radii graded linearly along z: tabled and measured one period deep across x and y.
    // BCC mirrors along x and y (the radii depend on z only): four segments each (the face zone,
    // halves and middles of the period), one along z; x and y swapped: 10 of the 16 pairs.
    expectGradedStrutsHitTheTarget("{gradient: linear, min: 0.4, max: 0.6, axis: z}",
                                   "one period of the interior (10 weighted pieces)");
}

TEST(DensityPieces, RadiiGradedFromTheCentreHitTheTargetOnTheMesh)
{
    // Radii graded from the centre along x (|2u - 1|: x alone sets them) are tabled one period
    // deep across y and z like a linear gradient (the tables' values are the field's:
    // PeriodicTiling.PeriodZeroAlongAnAxisTablesItAsItIs), and the density measured on pieces
    // that fold y and z: the mesh must hold the target. BCC mirrors along y and z: four segments
    // each, one along x; no x-y swap (x is graded).
    expectGradedStrutsHitTheTarget("{gradient: centred, min: 0.4, max: 0.6}",
                                   "one period of the interior (16 weighted pieces)");
}

TEST(TiledInterior, ATrimmedFrameReadsItsUntrimmedTableOnlyBeyondTheReachOfWhatTheTrimChanged)
{
    // 8^3 BCC cells of 2 mm trimmed to a ball (the struts across its surface cut there), sigma
    // 0.25: deeper inside than the cut-off from every strut the trim removed or cut, the trimmed
    // frame's field is the untrimmed box frame's, read from that frame's table of one period.
    const double sigma = 0.25;
    const Vec3d centre(8.0, 8.2, 7.9);
    const double radius = 7.0;
    const Box3 fill{Vec3d(0.0), Vec3d(16.0)};
    const UnitCell cell = presetUnitCell("bcc");
    const Frame trimmed = clippedFrame(
        cell, fill, Vec3d(2.0), [&](const Vec3d& p) { return (p - centre).length() - radius; }, 0.2);
    const Frame untrimmed = clippedFrame(
        cell, fill, Vec3d(2.0), [](const Vec3d&) { return -1.0; }, 0.0);
    // The struts one frame holds and the other does not, by their ends (either order).
    auto ends = [](const Frame& f, std::size_t j) {
        Vec3d a = f.nodes[f.struts[j][0]], b = f.nodes[f.struts[j][1]];
        if (std::lexicographical_compare(b.asPointer(), b.asPointer() + 3, a.asPointer(), a.asPointer() + 3))
            std::swap(a, b);
        return std::array<double, 6>{a[0], a[1], a[2], b[0], b[1], b[2]};
    };
    std::map<std::array<double, 6>, int> count;
    for (std::size_t j = 0; j < trimmed.struts.size(); ++j) count[ends(trimmed, j)] += 1;
    for (std::size_t j = 0; j < untrimmed.struts.size(); ++j) count[ends(untrimmed, j)] += 2;
    std::vector<std::array<Vec3d, 2>> differing;
    for (const auto& [e, c] : count)
        if (c != 3) differing.push_back({Vec3d(e[0], e[1], e[2]), Vec3d(e[3], e[4], e[5])});
    // Some struts are cut or removed, and a good share of them are left as they were.
    ASSERT_GT(differing.size(), 50u);
    ASSERT_LT(differing.size(), untrimmed.struts.size());
    auto convolution = [&](const Frame& f) {
        std::vector<ConvolutionStrut> struts;
        for (const auto& e : f.struts) struts.push_back({f.nodes[e[0]], f.nodes[e[1]], sigma, 1.0, 1.0});
        return std::make_shared<StrutConvolution>(struts);
    };
    const auto rawTrimmed = convolution(trimmed), rawUntrimmed = convolution(untrimmed);
    const double reach = rawUntrimmed->cutoffRadius(0), peak = rawUntrimmed->peak(0);
    const auto exact = std::make_shared<IsoRadius>(rawTrimmed, peak, sigma, 2.0 * reach);
    const auto same = std::make_shared<IsoRadius>(rawUntrimmed, peak, sigma, 2.0 * reach);
    const auto table = std::make_shared<PeriodicTiling>(same, untrimmed.box(), Vec3d(2.0), reach,
                                                        std::array<bool, 3>{true, true, true});
    const TiledInterior tiled(exact, [=] { return TiledInterior::Parts{table, differing, reach}; });

    // Every leaf and every stack of eight leaves (runs of far and near leaves in one batch) of a
    // domain past the frame (and past the differing struts' reach, where nothing is marked): the
    // trimmed frame's own values, up to rounding.
    const Domain d = Domain::fromBox(Box3{Vec3d(-1.0), Vec3d(17.0)}, 0.1);
    std::vector<double> a(8 * 8 * 64), b(a.size());
    double worst = 0.0;
    int farLeaves = 0, nearLeaves = 0, mixedStacks = 0;
    for (const int depth : {8, 64})
        for (int x = -8; x < d.dims.x() + 8; x += 8)
            for (int y = -8; y < d.dims.y() + 8; y += 8)
                for (int z = -8; z < d.dims.z() + 8; z += depth) {
                    GridBatch batch;
                    batch.origin = d.worldOf(openvdb::Coord(x, y, z));
                    batch.spacing = Vec3d(d.voxel);
                    batch.nz = depth;
                    tiled.gridValues(batch, std::span<double>(a.data(), batch.size()));
                    exact->gridValues(batch, std::span<double>(b.data(), batch.size()));
                    for (std::size_t i = 0; i < batch.size(); ++i) worst = std::max(worst, std::abs(a[i] - b[i]));
                    if (depth == 8) {
                        (tiled.far(batch.bounds()) ? farLeaves : nearLeaves) += 1;
                        continue;
                    }
                    int far = 0;
                    for (int m = 0; m < 8; ++m) {
                        GridBatch leaf = batch;
                        leaf.origin[2] += 8 * m * d.voxel;
                        leaf.nz = 8;
                        far += tiled.far(leaf.bounds()) ? 1 : 0;
                    }
                    mixedStacks += far > 0 && far < 8 ? 1 : 0;
                }
    EXPECT_LT(worst, 1e-9);
    // Both ways were taken, in the same stacks too.
    EXPECT_GT(farLeaves, 1000);
    EXPECT_GT(nearLeaves, 1000);
    EXPECT_GT(mixedStacks, 50);
    EXPECT_GT(table->tabledValues(), 0u);

    // A leaf called far is farther than the reach from every differing strut at each of its
    // points (every other point along each axis, brute force).
    int checked = 0;
    for (int x = -8; x < d.dims.x() + 8; x += 8)
        for (int y = -8; y < d.dims.y() + 8; y += 8)
            for (int z = -8; z < d.dims.z() + 8; z += 8) {
                GridBatch leaf;
                leaf.origin = d.worldOf(openvdb::Coord(x, y, z));
                leaf.spacing = Vec3d(d.voxel);
                if (!tiled.far(leaf.bounds()) || (x + y + z) % 3 != 0) continue;
                ++checked;
                double nearest = std::numeric_limits<double>::infinity();
                for (int i = 0; i < 8; i += 2)
                    for (int j = 0; j < 8; j += 2)
                        for (int k = 0; k < 8; k += 2)
                            for (const auto& [s0, s1] : differing)
                                nearest = std::min(nearest, pointSegmentDistanceSqr(leaf.point(i, j, k), s0, s1));
                ASSERT_GT(std::sqrt(nearest), reach) << "leaf at " << x << " " << y << " " << z;
            }
    EXPECT_GT(checked, 100);
}

TEST(TiledInterior, MakesItsPartsOnceOnTheFirstGridBatchMoreThanOneSampleThick)
{
    // Slices (batches one sample thick) and point queries read the exact field and never make
    // the parts (an untrimmed frame and its table: seconds on a build plate); the first grid
    // batch makes them once, whichever threads ask at the same time.
    const BccBox b = bccBox(4, 2.0, 0.25);
    std::atomic<int> made{0};
    const TiledInterior tiled(b.iso, [&] {
        ++made;
        return TiledInterior::Parts{b.iso, {{Vec3d(0.0), Vec3d(1.0)}}, b.reach};
    });
    std::vector<double> out(512);
    const std::vector<Vec3d> points = {Vec3d(1.0, 2.0, 3.0), Vec3d(4.0, 4.0, 4.0)};
    tiled.values(points, std::span<double>(out.data(), points.size()));
    GridBatch plane;
    plane.origin = Vec3d(0.05);
    plane.spacing = Vec3d(0.1);
    plane.nx = plane.ny = 10;
    plane.nz = 1;
    tiled.gridValues(plane, std::span<double>(out.data(), plane.size()));
    std::vector<signed char> side(1);
    tiled.planeValues(plane, 8, Interval{-0.1, 0.1}, std::span<double>(out.data(), plane.size()), side, {});
    EXPECT_EQ(made.load(), 0);
    tbb::parallel_for(0, 64, [&](int m) {
        GridBatch leaf;
        leaf.origin = Vec3d(0.05 + 0.8 * (m % 8), 0.05 + 0.8 * (m / 8), 0.05);
        leaf.spacing = Vec3d(0.1);
        std::vector<double> values(512), exact(512);
        tiled.gridValues(leaf, values);
        b.iso->gridValues(leaf, exact);
        EXPECT_EQ(values, exact);  // the same field on both sides here: the same doubles
    });
    EXPECT_EQ(made.load(), 1);
}
