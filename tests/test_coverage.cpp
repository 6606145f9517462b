// The density solve's coverage samples: what solveDensity's coverage pass relies on when it walks
// the grid once per band instead of picking the bands' samples from the evaluated band's.
#include "FieldChecks.h"
#include "GridChecks.h"
#include "engine/core/GridMeasure.h"
#include "engine/core/KeptGridLeaves.h"
#include "engine/core/SparseEvaluator.h"
#include "engine/density/Coverage.h"
#include "engine/density/LeafSteps.h"
#include "engine/frames/StrutFrames.h"
#include "engine/frames/UnitCells.h"
#include "fields/core/BlockLattice.h"
#include "fields/core/GridValueMemo.h"
#include "fields/levels/LevelSolid.h"
#include "fields/shapes/Boolean.h"
#include "fields/shapes/Sphere.h"
#include "fields/struts/IsoRadius.h"
#include "fields/struts/StrutConvolution.h"
#include "fields/struts/StrutRows.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <random>
#include <string>

using namespace voxlat;
using namespace voxlat::test;
using namespace voxlat::coverage;

namespace {

/// The domain of isoRadiusGrid(): two 4 mm BCC cells a side at 0.1 mm, off the cells' lattice.
Domain isoRadiusDomain()
{
    return Domain::fromBox(Box3{Vec3d(-0.33, -0.27, -0.41), Vec3d(8.37, 8.21, 8.13)}, 0.1);
}

/// The domain's voxels and two more on every side (the grid's margin).
openvdb::CoordBBox isoRadiusRegion()
{
    return openvdb::CoordBBox(openvdb::Coord(-2), isoRadiusDomain().dims - openvdb::Coord(-1));
}

/// A strut lattice's iso-radius (graded end weights) evaluated over @a band with two voxels'
/// margin: leaves, inside and outside tiles (+-FLT_MAX), as a density solve evaluates it.
openvdb::FloatGrid::Ptr isoRadiusGrid(const Interval& band)
{
    const Frame f = boxFrame(presetUnitCell("bcc"), Vec3d(0.0), Vec3d(4.0), {2, 2, 2});
    std::vector<ConvolutionStrut> struts;
    for (const auto& e : f.struts) struts.push_back({f.nodes[e[0]], f.nodes[e[1]], 0.4, 1.0, 1.3});
    const auto raw = std::make_shared<StrutConvolution>(struts);
    const IsoRadius iso(raw, raw->peak(0), 0.4, 2.0 * raw->cutoffRadius(0));
    SparseOptions options;
    options.band = band;
    options.margin = 2;
    options.insideValue = -std::numeric_limits<float>::max();
    options.outsideValue = std::numeric_limits<float>::max();
    return evaluateSparse(iso, isoRadiusDomain(), options);
}

}  // namespace

TEST(Coverage, ANarrowerBandsSamplesAreTheWiderBandsPickedInOrder)
{
    // A strut lattice's iso-radius evaluated over a band (leaves, inside and outside tiles), the
    // region past the domain by two voxels: the samples of a band within the evaluated one are
    // that band's picks from the evaluated band's samples, in the same order and the same bits
    // (a voxel's step does not depend on the band), and the voxels below its low end are those
    // below the evaluated band's plus the evaluated samples between the two low ends.
    const openvdb::CoordBBox region = isoRadiusRegion();
    const auto grid = isoRadiusGrid(Interval(0.3, 0.9));
    const float lo = 0.3f, hi = 0.9f;
    const CoverageSamples wide = coverageSamples(*grid, region, lo, hi);
    ASSERT_GT(wide.size(), 10000u);
    for (const auto& [nlo, nhi] : {std::pair{0.45f, 0.62f}, std::pair{0.3f, 0.5f}, std::pair{0.61f, 0.9f}}) {
        const CoverageSamples narrow = coverageSamples(*grid, region, nlo, nhi);
        CoverageSamples picked;
        std::uint64_t between = 0;
        for (const CoverageSample& c : wide) {
            if (!(c.value < nlo || c.value > nhi)) picked.push_back(c);
            between += c.value < nlo;  // at or above lo: in the evaluated band
        }
        ASSERT_EQ(narrow.size(), picked.size()) << nlo;
        EXPECT_EQ(std::memcmp(narrow.data(), picked.data(), narrow.size() * sizeof(CoverageSample)), 0) << nlo;
        EXPECT_EQ(countBelow(*grid, region, nlo), countBelow(*grid, region, lo) + between) << nlo;
        EXPECT_GT(between + narrow.size(), 0u);
        // The leaves' voxels below the band counted in the samples' pass, with the tiles': every
        // voxel of the region (cut through leaves and the outside tiles) read one by one.
        std::uint64_t leavesBelow = 0;
        const CoverageSamples again = coverageSamples(*grid, region, nlo, nhi, {}, &leavesBelow);
        ASSERT_EQ(again.size(), narrow.size()) << nlo;
        std::uint64_t oneByOne = 0;
        const auto acc = grid->getConstAccessor();
        for (auto it = region.begin(); it; ++it) oneByOne += acc.getValue(*it) < nlo;
        EXPECT_GT(leavesBelow, 0u) << nlo;
        EXPECT_EQ(countTilesBelow(*grid, region, nlo) + leavesBelow, oneByOne) << nlo;
        EXPECT_EQ(countBelow(*grid, region, nlo), oneByOne) << nlo;
    }
}

TEST(Coverage, StraddlingSamplesCoverTheBracketAsTheBandOfItsWidestStepEitherSideDoes)
{
    // The density solve bisects within the count's bracket [a, b] over straddlingSamples(): the
    // voxels whose coverage changes within it, the others counted (full) or left out (empty). At
    // every level of the bracket they cover what the band of the widest step either side holds
    // (its samples, and the voxels below it) covers; they are that band's samples whose ramp
    // meets (a, b), in its order and bits, fewer of them; the same on one thread and on two.
    const openvdb::CoordBBox region = isoRadiusRegion();
    const auto grid = isoRadiusGrid(Interval(0.2, 1.0));
    for (const auto& [a, b] : {std::pair{0.55, 0.6}, std::pair{0.4, 0.41}, std::pair{0.7, 0.75}}) {
        const float reach = widestCoverageStep(*grid, region, float(a), float(b));
        ASSERT_GT(reach, 0.0f);
        ASSERT_LT(reach, 0.2f) << "the band must lie within the evaluated one";
        const float lo = float(a - double(reach)), hi = float(b + double(reach));
        std::uint64_t leavesBelow = 0;
        const CoverageSamples band = coverageSamples(*grid, region, lo, hi, {}, &leavesBelow);
        const double bandBelow = double(countTilesBelow(*grid, region, lo) + leavesBelow);
        std::size_t told = 0;
        StraddlingSamples found;
        for (int threads : {1, 2}) {
            tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
            StraddlingSamples again = straddlingSamples(
                *grid, region, a, b, reach, {}, [&](std::size_t n) { told = n; }, Interval(float(a), float(b)));
            EXPECT_EQ(told, again.samples.size()) << a;
            // The same pass's count of the bracket: splitByBand()'s below (its leaves) and band.
            const BandSplit split = splitByBand(*grid, region, float(a), float(b));
            EXPECT_EQ(countTilesBelow(*grid, region, float(a)) + again.countBelow, split.below) << a;
            EXPECT_EQ(again.countWithin, split.band.size()) << a;
            EXPECT_GT(again.countWithin, 100u) << a;
            if (threads == 1) {
                found = std::move(again);
                continue;
            }
            ASSERT_EQ(again.samples.size(), found.samples.size()) << a;
            EXPECT_EQ(
                std::memcmp(again.samples.data(), found.samples.data(), found.samples.size() * sizeof(CoverageSample)),
                0)
                << a;
            EXPECT_EQ(again.fullyBelow, found.fullyBelow) << a;
        }
        // The band's samples whose ramp meets (a, b), in order.
        CoverageSamples meeting;
        for (const CoverageSample& c : band) {
            const double half = 0.5 * double(c.step);
            if (half > 0.0 ? c.value + half > a && c.value - half < b : c.value >= a && c.value < b)
                meeting.push_back(c);
        }
        ASSERT_EQ(found.samples.size(), meeting.size()) << a;
        EXPECT_EQ(std::memcmp(found.samples.data(), meeting.data(), meeting.size() * sizeof(CoverageSample)), 0) << a;
        EXPECT_GT(found.samples.size(), 100u) << a;
        EXPECT_LT(found.samples.size(), band.size()) << a << ": no fewer held";
        std::printf("bracket [%g, %g]: %zu samples held of the band's %zu\n", a, b, found.samples.size(), band.size());
        const double below = double(countTilesBelow(*grid, region, lo) + found.fullyBelow);
        for (double t : {0.0, 0.1, 0.5, 0.77, 1.0}) {
            const double level = a + t * (b - a);
            const double whole = bandBelow + coveredVoxels(band, level);
            EXPECT_NEAR(below + coveredVoxels(found.samples, level), whole, 1e-9 * whole) << a << " at " << level;
        }
    }
}

namespace {

/// Sets the voxels of [-8, 40) x [-8, 32) x [-8, 24) in @a grid, but those @a hole(x, y, z) leaves
/// out, to a ramp of @a slope per voxel with noise of +-0.05, one in about @a every (at random,
/// seeded by @a seed) to @a special instead.
template <class Hole>
void noisyRamp(openvdb::FloatGrid& grid, unsigned seed, const std::array<float, 3>& slope, unsigned every,
               float special, Hole hole)
{
    auto acc = grid.getAccessor();
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> noise(-0.05f, 0.05f);
    for (int x = -8; x < 40; ++x)
        for (int y = -8; y < 32; ++y)
            for (int z = -8; z < 24; ++z) {
                if (hole(x, y, z)) continue;
                float v = slope[0] * float(x) + slope[1] * float(y) + slope[2] * float(z) + noise(rng);
                if (rng() % every == 0) v = special;
                acc.setValue(openvdb::Coord(x, y, z), v);
            }
}

}  // namespace

TEST(Coverage, TheBandSplitIsEachRegionVoxelReadVoxelByVoxel)
{
    // splitByBand against every voxel read through the grid one by one, leaf by leaf in the
    // tree's order: those below the band counted (active tiles below it whole), those in it
    // collected in order, NaN and those above dropped. Leaves cut by the region and leaves
    // inside it, on several threads: the same values in the same order on one thread.
    openvdb::FloatGrid grid(std::numeric_limits<float>::max());
    noisyRamp(grid, 11, {0.02f, -0.03f, 0.025f}, 89, std::numeric_limits<float>::quiet_NaN(),
              [](int, int, int) { return false; });
    // An active tile below the band (a level-2 node's, 128^3 voxels) partly in the region.
    grid.tree().addTile(2, openvdb::Coord(-128, 0, 0), -1.0f, true);
    const openvdb::CoordBBox region(openvdb::Coord(-13, -5, -2), openvdb::Coord(35, 27, 21));
    const float lo = -0.2f, hi = 0.4f;
    std::uint64_t below = 0;
    std::vector<float> band;
    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    grid.tree().getNodes(leaves);
    for (const auto* leaf : leaves)
        for (int i = 0; i < 512; ++i) {
            const float v = leaf->getValue(i);
            if (!region.isInside(leaf->offsetToGlobalCoord(i))) continue;
            if (v < lo)
                ++below;
            else if (v <= hi)
                band.push_back(v);
        }
    // The tile's voxels in the region (it replaced the leaves it covers).
    std::uint64_t inTile = 0;
    for (auto it = region.begin(); it; ++it)
        if (!grid.tree().probeConstLeaf(*it) && grid.tree().isValueOn(*it) && grid.tree().getValue(*it) < lo) ++inTile;
    EXPECT_EQ(inTile, 13u * 28u * 22u);
    below += inTile;
    ASSERT_GT(band.size(), 1000u);
    for (const int threads : {1, 2}) {
        tbb::global_control control(tbb::global_control::max_allowed_parallelism, threads);
        const BandSplit split = splitByBand(grid, region, lo, hi);
        EXPECT_EQ(split.below, below) << threads;
        ASSERT_EQ(split.band.size(), band.size()) << threads;
        EXPECT_EQ(std::memcmp(split.band.data(), band.data(), band.size() * sizeof(float)), 0) << threads;
    }
}

TEST(Coverage, SamplesAreEachBandVoxelsCentralDifferencesReadVoxelByVoxel)
{
    // coverageSamples (and widestCoverageStep) against every voxel read through the grid one by
    // one: a band voxel inside the region, its change along each axis the central difference,
    // one-sided where a neighbour is outside the region, in no leaf, or masked (1e30 and up).
    // Leaves wholly inside the region take a faster path (neighbours from the neighbouring
    // leaves' buffers): the grid mixes those with leaves cut by the region, leaves with no
    // neighbour leaf on some faces, and masked voxels.
    openvdb::FloatGrid grid(std::numeric_limits<float>::max());
    // Holes of whole leaves: the leaf at (16, 8, 8) and the row x in [32, 40) at y < 0; masked
    // voxels (1e30).
    noisyRamp(grid, 7, {0.02f, 0.03f, -0.025f}, 97, 1e30f, [](int x, int y, int z) {
        return (x >= 16 && x < 24 && y >= 8 && y < 16 && z >= 8 && z < 16) || (x >= 32 && y < 0);
    });
    const auto acc = grid.getConstAccessor();
    const openvdb::CoordBBox region(openvdb::Coord(-3, -5, -2), openvdb::Coord(35, 27, 21));
    const float lo = -0.3f, hi = 0.6f;
    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    grid.tree().getNodes(leaves);
    CoverageSamples reference;
    float widest = 0.0f;
    for (const auto* leaf : leaves)
        for (int i = 0; i < 512; ++i) {
            const openvdb::Coord c = leaf->offsetToGlobalCoord(i);
            const float v = leaf->getValue(i);
            if (v < lo || v > hi || !region.isInside(c)) continue;
            std::array<double, 3> d{};
            for (int a = 0; a < 3; ++a) {
                openvdb::Coord up = c, down = c;
                up[a] += 1;
                down[a] -= 1;
                float upValue = 0.0f, downValue = 0.0f;
                const bool hasUp =
                    region.isInside(up) && acc.probeConstLeaf(up) && (upValue = acc.getValue(up)) < 1e30f;
                const bool hasDown =
                    region.isInside(down) && acc.probeConstLeaf(down) && (downValue = acc.getValue(down)) < 1e30f;
                d[a] = axisChange(v, upValue, hasUp, downValue, hasDown);
            }
            reference.push_back({v, float(std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]))});
            widest = std::max(widest, reference.back().step);
        }
    const CoverageSamples samples = coverageSamples(grid, region, lo, hi);
    ASSERT_GT(reference.size(), 10000u);
    ASSERT_EQ(samples.size(), reference.size());
    EXPECT_EQ(std::memcmp(samples.data(), reference.data(), samples.size() * sizeof(CoverageSample)), 0);
    EXPECT_EQ(widestCoverageStep(grid, region, lo, hi), widest);
}

namespace {

/// Same leaves (topology) and the same bits in every one.
void expectSameGrid(const openvdb::FloatGrid& a, const openvdb::FloatGrid& b, const std::string& what)
{
    EXPECT_TRUE(a.tree().hasSameTopology(b.tree())) << what;
    ASSERT_EQ(a.tree().leafCount(), b.tree().leafCount()) << what;
    EXPECT_EQ(mismatchedVoxels(a, b), 0u) << what;
    // Tiles: the same sign everywhere the domain's index box reaches.
    const openvdb::CoordBBox box = a.evalActiveVoxelBoundingBox();
    EXPECT_EQ(countBelow(a, box, 0.6f), countBelow(b, box, 0.6f)) << what;
}

/// @a held, culled with held values deciding leaves (FieldNode::heldRange), against @a fresh:
/// the same leaves but those whose voxels and ring lie on one side (heldCullMismatches), the
/// same sign everywhere. Returns how many leaves it left out.
std::uint64_t expectSameGridUpToHeldTiles(const openvdb::FloatGrid& fresh, const openvdb::FloatGrid& held,
                                          const std::string& what)
{
    std::uint64_t left = 0;
    EXPECT_EQ(heldCullMismatches(fresh, held, &left), 0u) << what;
    const openvdb::CoordBBox box = fresh.evalActiveVoxelBoundingBox();
    EXPECT_EQ(countBelow(fresh, box, 0.0f), countBelow(held, box, 0.0f)) << what;
    return left;
}
}  // namespace

TEST(Coverage, KnownValuesProveLeavesStraddlingWithoutTheirBoundsAndFindTheSameGrid)
{
    // A strut lattice's iso-radius evaluated sparsely with and without values known in advance:
    // the coarse samples a density solve takes (KnownSamples, every third voxel, past the domain
    // by the margin; one sample in the band proves it met), and a grid of the field's values
    // held by a memo under a level (FieldNode::meets() through LevelSolid, GridValueMemo,
    // KeptGridLeaves; with the domain's clip). The grids are the same, bit for bit, tiles
    // included, and far fewer bounds are taken; the held values also decide the leaves whose
    // voxels and ring they hold on one side (heldRange): tiles there, the same signs.
    const Frame f = boxFrame(presetUnitCell("bcc"), Vec3d(0.0), Vec3d(4.0), {2, 2, 2});
    std::vector<ConvolutionStrut> struts;
    for (const auto& e : f.struts) struts.push_back({f.nodes[e[0]], f.nodes[e[1]], 0.4, 1.0, 1.3});
    const auto raw = std::make_shared<StrutConvolution>(struts);
    const auto iso = std::make_shared<IsoRadius>(raw, raw->peak(0), 0.4, 2.0 * raw->cutoffRadius(0));
    const Domain d = Domain::fromBox(Box3{Vec3d(-0.33, -0.27, -0.41), Vec3d(8.37, 8.21, 8.13)}, 0.1);
    SparseOptions options;
    options.band = Interval(0.45, 0.62);
    options.margin = 2;
    options.insideValue = -std::numeric_limits<float>::max();
    options.outsideValue = std::numeric_limits<float>::max();

    KnownSamples known;
    known.stride = 3;
    known.origin = openvdb::Coord(known.stride / 2 - options.margin);
    std::vector<Vec3d> points;
    for (int a = 0; a < 3; ++a) known.count[a] = (d.dims[a] + 2 * options.margin + known.stride - 1) / known.stride;
    for (int i = 0; i < known.count[0]; ++i)
        for (int j = 0; j < known.count[1]; ++j)
            for (int k = 0; k < known.count[2]; ++k)
                points.push_back(
                    d.worldOf(known.origin + openvdb::Coord(i * known.stride, j * known.stride, k * known.stride)));
    std::vector<double> v(points.size());
    iso->values(points, v);
    known.values.assign(v.begin(), v.end());

    const auto counted = std::make_shared<CountedField>(iso);
    const auto plain = evaluateSparse(*counted, d, options);
    const int allBounds = counted->bounds.exchange(0);
    ASSERT_GT(plain->tree().leafCount(), 500u);
    SparseOptions withKnown = options;
    withKnown.known = &known;
    expectSameGrid(*plain, *evaluateSparse(*counted, d, withKnown), "band met");
    const int metBounds = counted->bounds.exchange(0);
    EXPECT_LT(metBounds, allBounds * 3 / 4);

    // KnownSamples::meets against the samples in the box enumerated one by one.
    std::mt19937 rng(11);
    std::uniform_int_distribution<int> corner(-4, 90), size(0, 12);
    for (int trial = 0; trial < 2000; ++trial) {
        const openvdb::Coord lo(corner(rng), corner(rng), corner(rng));
        const openvdb::CoordBBox box(lo, lo + openvdb::Coord(size(rng), size(rng), size(rng)));
        BandMet met(options.band);
        bool expected = false;
        for (int i = 0; i < known.count[0]; ++i)
            for (int j = 0; j < known.count[1]; ++j)
                for (int k = 0; k < known.count[2]; ++k)
                    if (box.isInside(known.origin +
                                     openvdb::Coord(i * known.stride, j * known.stride, k * known.stride)))
                        expected = met.add(known.values[(std::size_t(i) * known.count[1] + j) * known.count[2] + k]) ||
                                   expected;
        EXPECT_EQ(known.meets(box, options.band), expected) << "trial " << trial;
    }

    // A level above a memo holding a grid of its values (as a density solve hands it over), with
    // the domain's clip, at levels within the grid's band: the grid a memo holding nothing gives.
    SparseOptions region = options;
    region.band = Interval(0.4, 0.7);
    const auto grid = evaluateSparse(*std::make_shared<GridValueMemo>(iso), d, region);
    // A memo of @a field holding a copy of the grid (and no bound yet).
    auto holding = [&](const FieldPtr& field) {
        const auto held = std::make_shared<GridValueMemo>(field);
        held->keep(true, 0);
        held->keepLeaves(std::make_unique<KeptGridLeaves>(grid->deepCopy(), d), std::size_t(1) << 30);
        return held;
    };
    const auto counter = std::make_shared<CountedField>(iso);
    const auto memo = holding(counter);
    SparseOptions clipped;
    clipped.clipToDomain = true;
    std::uint64_t leftOut = 0;
    for (const double level : {0.45, 0.55, 0.65}) {
        const auto fresh = std::make_shared<CountedField>(iso);
        const auto expected =
            evaluateSparse(LevelSolid(std::make_shared<GridValueMemo>(fresh), SolidSide::Below, level), d, clipped);
        counter->bounds = 0;
        const auto held = evaluateSparse(LevelSolid(memo, SolidSide::Below, level), d, clipped);
        leftOut += expectSameGridUpToHeldTiles(*expected, *held, "held, level " + std::to_string(level));
        EXPECT_LT(counter->bounds.load(), fresh->bounds.load() * 3 / 4) << level;
    }

    // The same level solid in a sharp boolean with a sphere (a lattice trimmed `within:` a part
    // is its intersection): the held values prove through it (BooleanField::meets) where the
    // sphere's bound keeps them, and decide leaves with the sphere's bound folded in
    // (BooleanField::heldRange; blended too). The same grid as a memo holding nothing gives but
    // for leaves on one side, with fewer of the lattice's bounds.
    // (The sphere keeps the held values where it is negative for an intersection, positive for a
    // union or a difference: large for the one, small for the others.)
    const auto large = std::make_shared<Sphere>(Vec3d(4.0, 4.0, 4.0), 5.5);
    const auto small = std::make_shared<Sphere>(Vec3d(4.0, 4.0, 4.0), 1.5);
    for (const BooleanOp op : {BooleanOp::Intersection, BooleanOp::Union, BooleanOp::Difference})
        for (const double blend : {0.0, 0.3}) {
            const FieldPtr sphere = op == BooleanOp::Intersection ? large : small;
            const auto fresh = std::make_shared<CountedField>(iso);
            const auto freshSolid =
                std::make_shared<LevelSolid>(std::make_shared<GridValueMemo>(fresh), SolidSide::Below, 0.55);
            const auto heldCounter = std::make_shared<CountedField>(iso);
            const auto heldSolid = std::make_shared<LevelSolid>(holding(heldCounter), SolidSide::Below, 0.55);
            const BooleanField expectedField(op, {freshSolid, sphere}, blend);
            const BooleanField heldField(op, {heldSolid, sphere}, blend);
            const auto expected = evaluateSparse(expectedField, d, clipped);
            const auto held = evaluateSparse(heldField, d, clipped);
            const std::string what = "boolean " + std::to_string(int(op)) + ", blend " + std::to_string(blend);
            leftOut += expectSameGridUpToHeldTiles(*expected, *held, what);
            ASSERT_GT(fresh->bounds.load(), 200) << what;
            EXPECT_LT(heldCounter->bounds.load(), fresh->bounds.load() * 9 / 10) << what;
        }
    EXPECT_GT(leftOut, 0u);  // the held values decided leaves whose bounds straddled

    // BooleanField::meets against its bound: whenever it proves a box, the bound meets the band.
    std::uniform_real_distribution<double> at(-0.5, 8.5), edge(0.05, 1.5), lowEnd(-0.3, 0.3);
    int proved = 0;
    for (int trial = 0; trial < 3000; ++trial) {
        const Vec3d lo(at(rng), at(rng), at(rng));
        const Box3 box{lo, lo + Vec3d(edge(rng), edge(rng), edge(rng))};
        const double a = lowEnd(rng);
        const Interval band(a, a + 0.1);
        for (const BooleanOp op : {BooleanOp::Intersection, BooleanOp::Union, BooleanOp::Difference}) {
            const BooleanField sharp(op, {std::make_shared<LevelSolid>(memo, SolidSide::Below, 0.55),
                                          op == BooleanOp::Intersection ? large : small});
            if (!sharp.meets(box, band)) continue;
            ++proved;
            const Interval b = sharp.bound(box);
            EXPECT_TRUE(b.lo <= band.hi && b.hi >= band.lo) << "trial " << trial << ", op " << int(op);
        }
    }
    EXPECT_GT(proved, 100);
}

TEST(Coverage, BisectionSetsAsideSamplesWithoutABreakpointInItsBracketAndFindsTheLevel)
{
    // bisectCoverage against a plain serial bisection of the coverage sum, written out here (every
    // sample summed at every step, in order): the same level to within 1e-12 of the bracket, on
    // samples with ramps of many widths and value ties (step 0); the level found covers what was
    // wanted to within a sample (a tie's jump) and the coverage sum crosses `wanted` there; and the
    // level is the same double on one thread and on two.
    auto coverage = [](const CoverageSample& s, double level) {
        return s.step > 0.0f ? std::clamp(0.5 + (level - s.value) / s.step, 0.0, 1.0) : double(s.value < level);
    };
    auto serialSum = [&](const CoverageSamples& samples, double level) {
        double covered = 0.0;
        for (const CoverageSample& s : samples) covered += coverage(s, level);
        return covered;
    };
    auto plain = [&](const CoverageSamples& samples, double fullyBelow, double wanted, double a, double b) {
        for (int iteration = 0; iteration < 60; ++iteration) {
            const double mid = 0.5 * (a + b);
            (fullyBelow + serialSum(samples, mid) < wanted ? a : b) = mid;
        }
        return 0.5 * (a + b);
    };
    // Trials of up to 12 parallel blocks of 8192 samples, whole and partial; voxels below counted
    // in whole numbers (small, and past 2^40) or not; bisected on one thread and on two.
    std::mt19937 rng(38);
    std::uniform_real_distribution<double> value(-1.0, 1.0), width(0.0, 0.3), share(0.05, 0.95);
    double worst = 0.0;
    for (int trial = 0; trial < 48; ++trial) {
        const std::size_t n = trial < 40 ? std::size_t(2000 + 500 * trial) : std::size_t(8192 * (trial - 35) - 7);
        CoverageSamples samples(n);
        for (CoverageSample& s : samples) {
            s.value = float(value(rng));
            s.step = trial % 4 == 0 || rng() % 7 == 0 ? 0.0f : float(width(rng));
        }
        double below = double(rng() % 1000);
        if (trial % 3 == 1) below += 0x1p40;
        if (trial % 5 == 2) below += 0.375;
        const double wanted = below + share(rng) * double(samples.size());
        const double reference = plain(samples, below, wanted, -1.5, 1.5);
        double first = 0.0;
        for (int threads : {1, 2}) {
            tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
            const CoverageLevel found = bisectCoverage(samples, below, wanted, -1.5, 1.5);
            const double level = found.level;
            if (threads == 1) first = level;
            // What it covers there and its slope over the bracket's middle half [-0.75, 0.75],
            // against the serial sums.
            const double slack = 1e-9 * (below + double(n));
            EXPECT_NEAR(found.covered, below + serialSum(samples, level), slack) << "trial " << trial;
            EXPECT_NEAR(found.slope, (serialSum(samples, 0.75) - serialSum(samples, -0.75)) / 1.5, 1e-9 * double(n))
                << "trial " << trial;
            EXPECT_EQ(level, first) << "trial " << trial;
            worst = std::max(worst, std::abs(level - reference));
            EXPECT_LE(std::abs(level - reference), 3e-12) << "trial " << trial << ", " << threads << " threads";
            EXPECT_NEAR(below + coveredVoxels(samples, level), wanted, 1.0 + 1e-6) << "trial " << trial;
            // The sum crosses `wanted` at the level (rounding of a sum near 2^40 allowed).
            EXPECT_LE(below + serialSum(samples, level - 1e-9), wanted + slack) << "trial " << trial;
            EXPECT_GE(below + serialSum(samples, level + 1e-9), wanted - slack) << "trial " << trial;
            // The one-pass sums at several levels are the one-level sums.
            const std::array<double, 2> levels{level - 0.1, level + 0.1};
            std::array<double, 2> both{};
            coveredVoxels(samples, levels, both);
            EXPECT_EQ(both[0], coveredVoxels(samples, levels[0]));
            EXPECT_EQ(both[1], coveredVoxels(samples, levels[1]));
            EXPECT_NEAR(both[1], serialSum(samples, levels[1]), 1e-9 * double(n));
        }
    }
    std::printf("worst |level - plain bisection| %.3g\n", worst);
}

TEST(Coverage, CoarseBlocksOfAnyDepthVisitEveryLatticePointOnce)
{
    // The coarse pass samples a convolution lattice's region in blocks 64 samples tall
    // (BlockLattice::depth): every lattice point is visited once, at its own position, whatever
    // the depth, and the blocks' batches are 8 x 8 x depth at most.
    struct Linear final : FieldNode {
        void values(std::span<const Vec3d> points, std::span<double> out) const override
        {
            for (std::size_t n = 0; n < points.size(); ++n)
                out[n] = points[n].x() + 2.0 * points[n].y() + 3.0 * points[n].z();
        }
        void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override
        {
            values(points, out);
            for (Vec3d& g : grad.first(points.size())) g = Vec3d(1.0, 2.0, 3.0);
        }
        Interval bound(const Box3&) const override { return {-1e300, 1e300}; }
    } field;
    for (const int depth : {8, 64}) {
        BlockLattice lattice;
        lattice.base = Vec3d(-1.25, 0.5, 3.0);
        lattice.step = Vec3d(0.1);
        lattice.offset = Vec3d(1.5);
        lattice.stride = {2, 2, 2};
        lattice.count = {13, 9, 150};
        lattice.depth = depth;
        std::vector<int> visits(std::size_t(13 * 9 * 150), 0);
        std::mutex mutex;
        double worst = 0.0;
        sampleBlocks(field, lattice, [&](std::size_t, const GridBatch& batch, auto first, std::span<const double> v) {
            std::lock_guard<std::mutex> lock(mutex);
            ASSERT_LE(batch.nx, 8);
            ASSERT_LE(batch.ny, 8);
            ASSERT_LE(batch.nz, depth);
            std::size_t n = 0;
            for (int i = 0; i < batch.nx; ++i)
                for (int j = 0; j < batch.ny; ++j)
                    for (int k = 0; k < batch.nz; ++k, ++n) {
                        const int x = first[0] + i, y = first[1] + j, z = first[2] + k;
                        ++visits[(std::size_t(x) * 9 + y) * 150 + z];
                        const Vec3d p =
                            lattice.base + Vec3d((x * 2 + 1.5) * 0.1, (y * 2 + 1.5) * 0.1, (z * 2 + 1.5) * 0.1);
                        worst = std::max(worst, std::abs(v[n] - (p.x() + 2.0 * p.y() + 3.0 * p.z())));
                    }
        });
        EXPECT_EQ(std::count(visits.begin(), visits.end(), 1), std::ptrdiff_t(visits.size())) << depth;
        EXPECT_LT(worst, 1e-12) << depth;
    }
}

TEST(Coverage, LeafStepsInLanesAreTheVoxelByVoxelStepsAndSortsBitForBit)
{
    // LeafSteps.h's whole-leaf loops (the baseline build's, and the AVX-512F and AVX2 forms where
    // the CPU has them) against each voxel's step taken one by one from its six neighbours (axisChange():
    // one-sided where a neighbour is absent or 1e30 and up): the same floats, and the same sorting
    // over a bracket as straddlingSamples()' voxel-by-voxel switch. Leaves of noise around a band,
    // with masked values, tiles' +-FLT_MAX and absent neighbour leaves mixed in.
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> uniform(-1.0f, 1.0f);
    auto randomLeaf = [&](std::vector<float>& values) {
        values.resize(512);
        for (float& v : values) {
            const unsigned kind = rng() % 40;
            v = kind == 0   ? 1e30f
                : kind == 1 ? std::numeric_limits<float>::max()
                : kind == 2 ? -std::numeric_limits<float>::max()
                : kind == 3 ? 0.25f  // ties: steps of 0 where all neighbours share it
                            : 0.3f * uniform(rng);
        }
    };
    const int kStride[3] = {64, 8, 1}, kShift[3] = {6, 3, 0};
    for (int round = 0; round < 40; ++round) {
        std::vector<float> data, next[3][2];
        randomLeaf(data);
        LeafWithNeighbours leaf{data.data(), {}};
        for (int a = 0; a < 3; ++a)
            for (int side = 0; side < 2; ++side) {
                randomLeaf(next[a][side]);
                leaf.next[a][side] = rng() % 5 == 0 ? leafNoNeighbours() : next[a][side].data();
            }
        float steps[512], wide[512];
        leafStepsLoop(leaf, steps);
        for (int i = 0; i < 512; ++i) {
            std::array<double, 3> d{};
            for (int a = 0; a < 3; ++a) {
                const int local = (i >> kShift[a]) & 7, stride = kStride[a];
                const float up = local < 7 ? data[i + stride] : leaf.next[a][1][i - 7 * stride];
                const float down = local > 0 ? data[i - stride] : leaf.next[a][0][i + 7 * stride];
                d[a] = axisChange(data[i], up, up < 1e30f, down, down < 1e30f);
            }
            const float step = float(std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]));
            ASSERT_EQ(std::memcmp(&steps[i], &step, sizeof(float)), 0) << round << " voxel " << i;
        }
        const double a = 0.05 * uniform(rng), b = a + 0.02;
        const StraddleBounds bounds{a, b, float(a - 0.1), float(b + 0.1), float(a), float(b)};
        // The voxel-by-voxel sort (straddlingSamples()' own for leaves at the region's edge).
        LeafStraddle expected;
        for (int i = 0; i < 512; ++i) {
            const float v = data[i];
            expected.countBelow += v < bounds.countLo;
            expected.countWithin += !(v < bounds.countLo) && v <= bounds.countHi;
            expected.below += v < bounds.lo;
            if (v < bounds.lo || v > bounds.hi) continue;
            const double half = 0.5 * double(steps[i]);
            const bool full = half > 0.0 ? v + half <= a : v < a;
            const bool empty = half > 0.0 ? v - half >= b : !(v < b);
            expected.below += full;
            if (!full && !empty) expected.changing[i / 64] |= std::uint64_t(1) << (i % 64);
        }
        auto expectSorted = [&](const LeafStraddle& got, const char* form) {
            EXPECT_EQ(got.below, expected.below) << form << " " << round;
            EXPECT_EQ(got.countBelow, expected.countBelow) << form << " " << round;
            EXPECT_EQ(got.countWithin, expected.countWithin) << form << " " << round;
            for (int w = 0; w < 8; ++w) EXPECT_EQ(got.changing[w], expected.changing[w]) << form << " " << round;
        };
        expectSorted(leafStraddleLoop(data.data(), steps, bounds), "loop");
        float widest = 0.0f;
        bool meets = false;
        for (int i = 0; i < 512; ++i)
            if (!(data[i] < bounds.lo || data[i] > bounds.hi)) {
                meets = true;
                if (steps[i] < 1e29f) widest = std::max(widest, steps[i]);
            }
        EXPECT_EQ(leafWidestLoop(data.data(), steps, bounds.lo, bounds.hi), widest) << round;
        EXPECT_EQ(leafMeetsLoop(data.data(), bounds.lo, bounds.hi), meets) << round;
        // An empty band: no voxel meets it.
        EXPECT_FALSE(leafMeetsLoop(data.data(), 2.0f, 3.0f)) << round;
        // The lane forms the CPU can run: the steps of the band's voxels (those the passes read),
        // and of every voxel for a band holding them all.
        struct Lanes {
            const char* name;
            const LeafStepForms* form;
        };
        const Lanes lanes[] = {{"avx512", hasAvx512Rows() ? avx512LeafSteps() : nullptr},
                               {"avx2", hasAvx2Rows() ? avx2LeafSteps() : nullptr}};
        for (const auto& [name, form] : lanes) {
            if (!form) continue;
            form->steps(leaf, wide, bounds.lo, bounds.hi);
            for (int i = 0; i < 512; ++i) {
                if (!(data[i] < bounds.lo || data[i] > bounds.hi)) {
                    EXPECT_EQ(std::memcmp(&steps[i], &wide[i], sizeof(float)), 0) << name << round << " voxel " << i;
                }
            }
            form->steps(leaf, wide, -kNoNeighbour, kNoNeighbour);
            EXPECT_EQ(std::memcmp(steps, wide, sizeof(steps)), 0) << name << round;
            expectSorted(form->straddle(data.data(), steps, bounds), name);
            EXPECT_EQ(form->widest(data.data(), steps, bounds.lo, bounds.hi), widest) << name << round;
            EXPECT_EQ(form->meets(data.data(), bounds.lo, bounds.hi), meets) << name << round;
            EXPECT_FALSE(form->meets(data.data(), 2.0f, 3.0f)) << name << round;
        }
    }
}
