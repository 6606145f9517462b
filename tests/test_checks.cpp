// Checks of a result: its connected pieces counted on the grid.
#include "engine/checks/Pieces.h"
#include "engine/core/SparseEvaluator.h"
#include "fields/Boolean.h"
#include "fields/BoxField.h"
#include "fields/Sphere.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

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
