// Checks of a result: its connected pieces counted on the grid.
#include "engine/checks/Pieces.h"
#include "engine/checks/SurfaceThickness.h"
#include "engine/core/SparseEvaluator.h"
#include "fields/shapes/Boolean.h"
#include "fields/shapes/BoxField.h"
#include "fields/shapes/Sphere.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <atomic>
#include <functional>
#include <mutex>
#include <random>

using namespace voxlat;

namespace {

/// A grid of voxels set by hand: @a solid(i, j, k) below zero, the rest background.
openvdb::FloatGrid::Ptr handGrid(int n, const std::function<bool(int, int, int)>& solid)
{
    auto grid = openvdb::FloatGrid::create(1.0f);
    auto acc = grid->getAccessor();
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j)
            for (int k = 0; k < n; ++k)
                if (solid(i, j, k)) acc.setValue(openvdb::Coord(i, j, k), -1.0f);
    return grid;
}

}  // namespace

TEST(Pieces, FaceNeighboursJoinEdgesAndCornersDoNot)
{
    // Two 3^3 cubes meeting along an edge only, and a third meeting the first along a face.
    auto inCube = [](int i, int j, int k, int x, int y, int z) {
        return i >= x && i < x + 3 && j >= y && j < y + 3 && k >= z && k < z + 3;
    };
    const auto grid = handGrid(20, [&](int i, int j, int k) {
        return inCube(i, j, k, 2, 2, 2) || inCube(i, j, k, 5, 5, 2) || inCube(i, j, k, 2, 2, 5);
    });
    const PieceCount count = countPieces(*grid);
    ASSERT_EQ(count.pieces.size(), 2u);
    EXPECT_EQ(count.pieces[0].voxels, 54u);  // the two face-joined cubes
    EXPECT_EQ(count.pieces[1].voxels, 27u);
    EXPECT_EQ(count.pieces[1].bounds, openvdb::CoordBBox(openvdb::Coord(5, 5, 2), openvdb::Coord(7, 7, 4)));
    EXPECT_EQ(count.solidVoxels, 81u);
}

TEST(Pieces, FarApartBlocksAreFoundWithoutTheDenseIndex)
{
    // Solids thousands of voxels apart, each across several leaves: the blocks' bounding box is
    // nearly all empty, so neighbours are found by search instead of the dense index the other
    // tests use. A bar crossing four leaves stays one piece; two cubes far from it and from each
    // other are two more.
    auto grid = openvdb::FloatGrid::create(1.0f);
    auto acc = grid->getAccessor();
    auto fill = [&](const openvdb::Coord& lo, const openvdb::Coord& hi) {
        for (auto it = openvdb::CoordBBox(lo, hi).begin(); it; ++it) acc.setValue(*it, -1.0f);
    };
    fill(openvdb::Coord(-5, 3, 3), openvdb::Coord(20, 5, 6));        // 26 x 3 x 4, four leaves along x
    fill(openvdb::Coord(6000, 4, 4), openvdb::Coord(6009, 13, 13));  // 10^3
    fill(openvdb::Coord(-3000, 4, 4), openvdb::Coord(-2995, 9, 9));  // 6^3
    const PieceCount count = countPieces(*grid);
    ASSERT_EQ(count.pieces.size(), 3u);
    EXPECT_EQ(count.pieces[0].voxels, 1000u);
    EXPECT_EQ(count.pieces[1].voxels, 312u);
    EXPECT_EQ(count.pieces[1].bounds, openvdb::CoordBBox(openvdb::Coord(-5, 3, 3), openvdb::Coord(20, 5, 6)));
    EXPECT_EQ(count.pieces[2].voxels, 216u);
    EXPECT_EQ(count.solidVoxels, 1528u);
}

TEST(Pieces, PiecesAcrossLeavesAndTilesMatchTheirVolumes)
{
    // Two balls (one large enough to hold inside tiles) and a bar joining nothing: three pieces
    // whose voxel counts are those of the grid, whatever the thread count.
    const Domain d = Domain::fromBox(Box3{Vec3d(0), Vec3d(60)}, 0.25);
    std::vector<FieldPtr> parts{std::make_shared<Sphere>(Vec3d(20, 20, 20), 15.0),
                                std::make_shared<Sphere>(Vec3d(48, 48, 48), 5.0),
                                std::make_shared<BoxField>(Box3{Vec3d(45, 5, 5), Vec3d(55, 8, 8)})};
    const auto field = std::make_shared<BooleanField>(BooleanOp::Union, parts);
    SparseOptions options;
    options.clipToDomain = true;
    const auto grid = evaluateSparse(*field, d, options);
    std::uint64_t inside = 0;
    for (auto it = grid->cbeginValueOn(); it; ++it)
        if (*it < 0.0f) inside += it.getVoxelCount();
    const PieceCount all = countPieces(*grid);
    ASSERT_EQ(all.pieces.size(), 3u);
    EXPECT_EQ(all.solidVoxels, inside);
    // The big ball: 4/3 pi 15^3 / 0.25^3 voxels, to the grid's staircase.
    EXPECT_NEAR(double(all.pieces[0].voxels), 4.0 / 3.0 * M_PI * 15 * 15 * 15 / (0.25 * 0.25 * 0.25), 0.01 * 904779);
    EXPECT_NEAR(double(all.pieces[1].voxels), 4.0 / 3.0 * M_PI * 125 / (0.25 * 0.25 * 0.25), 0.03 * 33510);
    EXPECT_EQ(all.pieces[2].voxels, 40u * 12u * 12u);  // the bar: exactly its voxel centres
    for (int threads : {1, 3}) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        const PieceCount again = countPieces(*grid);
        ASSERT_EQ(again.pieces.size(), all.pieces.size());
        for (std::size_t i = 0; i < all.pieces.size(); ++i) {
            EXPECT_EQ(again.pieces[i].voxels, all.pieces[i].voxels);
            EXPECT_EQ(again.pieces[i].bounds, all.pieces[i].bounds);
        }
    }
}

TEST(Pieces, GatheringAndCountingCallTheirInterrupter)
{
    // A cancel reaches both passes (issue 42: a 20 mm strut plate spent over a second in them
    // unchecked): the interrupter is called, a throw from it stops the pass, and the count with an
    // interrupter that never throws is the count without one.
    const Domain d = Domain::fromBox(Box3{Vec3d(0), Vec3d(32)}, 0.1);
    const auto grid = evaluateSparse(Sphere(Vec3d(16), 15.0), d, SparseOptions{});
    const std::vector<SolidBlock> blocks = solidBlocks(*grid);
    ASSERT_GT(blocks.size(), 4096u);
    std::atomic<int> calls{0};
    const std::function<void()> count = [&] { ++calls; };
    EXPECT_EQ(solidBlocks(*grid, {}, count).size(), blocks.size());
    EXPECT_GT(calls.load(), 1);
    calls = 0;
    const PieceCount counted = countPieces(blocks, count);
    EXPECT_GT(calls.load(), int(blocks.size() / 256));  // at least once per run of 256 blocks
    const PieceCount plain = countPieces(blocks);
    EXPECT_EQ(counted.solidVoxels, plain.solidVoxels);
    EXPECT_EQ(counted.pieces.size(), plain.pieces.size());
    struct Stop {};
    const std::function<void()> stop = [] { throw Stop{}; };
    EXPECT_THROW((void)solidBlocks(*grid, {}, stop), Stop);
    EXPECT_THROW((void)countPieces(blocks, stop), Stop);
}

TEST(Pieces, LeavesHandedToAVisitorCountAsTheKeptGrid)
{
    // The tolerance mesh's way (Job::evaluateRecipeGrid without the grid): the leaves' solid bits
    // gathered by the evaluator's visitor, in no fixed order, plus the tiles of the grid it returns,
    // give the pieces of the grid itself: same count, voxels and bounds, for any thread count.
    const Domain d = Domain::fromBox(Box3{Vec3d(0), Vec3d(40)}, 0.25);
    std::vector<FieldPtr> parts{std::make_shared<Sphere>(Vec3d(14, 14, 14), 11.0),
                                std::make_shared<Sphere>(Vec3d(33, 33, 33), 4.0),
                                std::make_shared<Sphere>(Vec3d(34, 6, 20), 0.3)};
    const auto field = std::make_shared<BooleanField>(BooleanOp::Union, parts);
    SparseOptions options;
    options.clipToDomain = true;
    const PieceCount kept = countPieces(*evaluateSparse(*field, d, options));
    ASSERT_EQ(kept.pieces.size(), 3u);
    for (int threads : {1, 2, 4}) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        std::mutex mutex;
        std::vector<SolidBlock> leaves;
        SparseOptions visited = options;
        visited.leafVisitor = [&](const openvdb::Coord& origin, const float* values) {
            SolidBlock b;
            b.origin = origin;
            b.bits.fill(0);
            for (int i = 0; i < 512; ++i)
                if (values[i] < 0.0f) b.bits[std::size_t(i >> 6)] |= std::uint64_t(1) << (i & 63);
            const std::lock_guard<std::mutex> lock(mutex);
            leaves.push_back(b);
        };
        const auto tiles = evaluateSparse(*field, d, visited);
        ASSERT_EQ(tiles->tree().leafCount(), 0u);
        ASSERT_FALSE(leaves.empty());
        const PieceCount count = countPieces(solidBlocks(*tiles, std::move(leaves)));
        EXPECT_EQ(count.solidVoxels, kept.solidVoxels);
        ASSERT_EQ(count.pieces.size(), kept.pieces.size());
        for (std::size_t i = 0; i < kept.pieces.size(); ++i) {
            EXPECT_EQ(count.pieces[i].voxels, kept.pieces[i].voxels);
            EXPECT_EQ(count.pieces[i].bounds, kept.pieces[i].bounds);
        }
    }
}

TEST(Pieces, RandomVoxelsMatchABruteForceFloodFill)
{
    // Random solids near the percolation threshold of face-connected voxels (about 31 %), so that
    // pieces wind through and across many leaves, with negative coordinates and a tile: every
    // piece's size and bounds against a flood fill over a dense array.
    const int n = 44, lo = -13;  // voxels lo .. lo + n - 1 on every axis, leaves cut at odd places
    for (const double share : {0.2, 0.31, 0.45}) {
        std::mt19937 random(unsigned(share * 1000));
        std::bernoulli_distribution solid(share);
        std::vector<char> dense(std::size_t(n * n * n));
        for (char& c : dense) c = solid(random);
        // An inside tile of 8^3 (a leaf-sized tile at level 1): its voxels are solid in the array too.
        const openvdb::Coord tile(8, 8, 8);
        auto grid = openvdb::FloatGrid::create(1.0f);
        auto acc = grid->getAccessor();
        auto at = [&](int i, int j, int k) -> char& {
            return dense[std::size_t(((i - lo) * n + (j - lo)) * n + (k - lo))];
        };
        for (int i = lo; i < lo + n; ++i)
            for (int j = lo; j < lo + n; ++j)
                for (int k = lo; k < lo + n; ++k) {
                    const bool inTile = i >= 8 && i < 16 && j >= 8 && j < 16 && k >= 8 && k < 16;
                    if (inTile)
                        at(i, j, k) = 1;
                    else if (at(i, j, k))
                        acc.setValue(openvdb::Coord(i, j, k), -0.5f);
                    else if (solid(random))
                        acc.setValue(openvdb::Coord(i, j, k), 0.5f);  // outside voxels in leaves
                }
        grid->tree().addTile(1, tile, -1.0f, true);

        // The brute force: a flood fill over the dense array.
        std::vector<std::pair<std::uint64_t, openvdb::CoordBBox>> expected;
        std::vector<char> seen(dense.size(), 0);
        std::uint64_t solidVoxels = 0;
        for (int i = lo; i < lo + n; ++i)
            for (int j = lo; j < lo + n; ++j)
                for (int k = lo; k < lo + n; ++k) {
                    const std::size_t s = std::size_t(((i - lo) * n + (j - lo)) * n + (k - lo));
                    if (!dense[s] || seen[s]) continue;
                    std::vector<openvdb::Coord> stack{openvdb::Coord(i, j, k)};
                    seen[s] = 1;
                    std::uint64_t voxels = 0;
                    openvdb::CoordBBox box;
                    while (!stack.empty()) {
                        const openvdb::Coord c = stack.back();
                        stack.pop_back();
                        ++voxels;
                        box.expand(c);
                        for (int axis = 0; axis < 3; ++axis)
                            for (int d : {-1, 1}) {
                                openvdb::Coord m = c;
                                m[axis] += d;
                                if (m[axis] < lo || m[axis] >= lo + n) continue;
                                const std::size_t t = std::size_t(((m.x() - lo) * n + (m.y() - lo)) * n + (m.z() - lo));
                                if (dense[t] && !seen[t]) {
                                    seen[t] = 1;
                                    stack.push_back(m);
                                }
                            }
                    }
                    solidVoxels += voxels;
                    expected.emplace_back(voxels, box);
                }
        auto order = [](const auto& a, const auto& b) {
            if (a.first != b.first) return a.first > b.first;
            return a.second.min() < b.second.min() ||
                   (a.second.min() == b.second.min() && a.second.max() < b.second.max());
        };
        std::sort(expected.begin(), expected.end(), order);
        for (int threads : {1, 2, 3}) {
            tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
            const PieceCount count = countPieces(*grid);
            EXPECT_EQ(count.solidVoxels, solidVoxels);
            std::vector<std::pair<std::uint64_t, openvdb::CoordBBox>> got;
            for (const Piece& p : count.pieces) got.emplace_back(p.voxels, p.bounds);
            for (std::size_t i = 1; i < got.size(); ++i) EXPECT_GE(got[i - 1].first, got[i].first);  // largest first
            std::sort(got.begin(), got.end(), order);
            ASSERT_EQ(got.size(), expected.size()) << "share " << share;
            EXPECT_GT(expected.size(), 5u);
            for (std::size_t i = 0; i < got.size(); ++i) {
                EXPECT_EQ(got[i].first, expected[i].first);
                EXPECT_EQ(got[i].second, expected[i].second);
            }
        }
    }
}

TEST(SurfaceThickness, ChordsThroughABallAreItsDiameter)
{
    // A ball of radius 3: from any surface point the chord along the inward normal is the
    // diameter. Points 0.04 mm off the surface (in or out, as a decimated mesh's are) give it too.
    const voxlat::Sphere ball(voxlat::Vec3d(1, 2, 3), 3.0);
    std::vector<openvdb::Vec3f> points;
    std::mt19937 random(7);
    std::normal_distribution<double> gauss;
    for (int k = 0; k < 200; ++k) {
        voxlat::Vec3d d(gauss(random), gauss(random), gauss(random));
        d.normalize();
        const double r = 3.0 + (k % 3 - 1) * 0.04;
        points.emplace_back(float(1 + r * d.x()), float(2 + r * d.y()), float(3 + r * d.z()));
    }
    const std::vector<float> chords = voxlat::surfaceThickness(ball, points, 0.05, 10.0);
    for (float c : chords) EXPECT_NEAR(c, 6.0, 0.01);
    // Not closed within `most`: given as `most`.
    for (float c : voxlat::surfaceThickness(ball, points, 0.05, 4.0)) EXPECT_EQ(c, 4.0f);
}
