// Printability checks on hand-made layer stacks whose islands, cavities and thin features are
// known exactly: a ball floating over a plate, a ball on the plate, a closed and a drained hollow
// sphere, one- and two-pixel lines; and the periodic replay against analysing every layer.
#include "engine/checks/Printability.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <numbers>
#include <random>
#include <tuple>

using namespace voxlat;

namespace {

constexpr int kSide = 48;

/// A layer image of kSide x kSide pixels, exposed where @a inside(i, j) holds.
LayerImage makeLayer(int index, const std::function<bool(int, int)>& inside)
{
    LayerImage image;
    image.index = index;
    image.nx = image.ny = kSide;
    image.pixels.assign(std::size_t(kSide) * kSide, 0);
    for (int j = 0; j < kSide; ++j)
        for (int i = 0; i < kSide; ++i)
            if (inside(i, j)) image.pixels[std::size_t(j) * kSide + i] = 255;
    return image;
}

LayerGeometry unitGeometry()
{
    LayerGeometry g;
    g.nx = g.ny = kSide;
    g.pitchX = g.pitchY = 1.0;
    g.layer = 1.0;
    g.z0 = 0.0;
    g.x = [](double i) { return i + 0.5; };
    g.y = [](double j) { return j + 0.5; };
    return g;
}

/// Runs the checks over @a layers images made by @a inside(i, j, k).
nlohmann::json check(int layers, const std::function<bool(int, int, int)>& inside, int period = 0)
{
    PrintabilityCheck checker(unitGeometry(), layers, period);
    for (int k = 0; k < layers; ++k) {
        LayerFeatures f;
        if (checker.needsImage(k)) f = analyseLayer(makeLayer(k, [&](int i, int j) { return inside(i, j, k); }));
        checker.addLayer(k, std::move(f));
    }
    return checker.report();
}

bool inBall(int i, int j, int k, double cx, double cy, double cz, double r)
{
    const double x = i + 0.5 - cx, y = j + 0.5 - cy, z = k + 0.5 - cz;
    return x * x + y * y + z * z <= r * r;
}

}  // namespace

TEST(Printability, ABallFloatingOverAPlateIsOneIslandAtItsLowestLayer)
{
    // Plate: layers 0-3 everywhere; ball of radius 8 centred at (20, 28, 20): nothing in between.
    const auto report = check(30, [](int i, int j, int k) { return k < 4 || inBall(i, j, k, 20, 28, 20, 8); });
    ASSERT_EQ(report["island_count"], 1);
    const auto& island = report["islands"][0];
    const int lowest = int(std::ceil(20 - 8 - 0.5));  // first layer whose centre is inside the ball
    EXPECT_EQ(island["layer"], lowest);
    EXPECT_NEAR(island["x"].get<double>(), 20.0, 0.5);
    EXPECT_NEAR(island["y"].get<double>(), 28.0, 0.5);
    EXPECT_NEAR(island["z"].get<double>(), lowest + 0.5, 1e-12);
    EXPECT_GT(island["area_mm2"].get<double>(), 0.0);
}

TEST(Printability, ABallOnThePlateHasNoIsland)
{
    const auto report = check(20, [](int i, int j, int k) { return inBall(i, j, k, 24, 24, 8, 8.2); });
    EXPECT_EQ(report["island_count"], 0);
    EXPECT_EQ(report["resin_trap_count"], 0);
}

TEST(Printability, AClosedHollowSphereIsOneTrapOfItsVolume)
{
    // A 40 x 40 x 40 block with a spherical cavity of radius 12 in its middle.
    const double r = 12.0;
    auto solid = [&](int i, int j, int k) {
        const bool block = i >= 4 && i < 44 && j >= 4 && j < 44;
        return block && !inBall(i, j, k, 24, 24, 20, r);
    };
    const auto report = check(40, solid);
    ASSERT_EQ(report["resin_trap_count"], 1);
    const auto& trap = report["resin_traps"][0];
    const double exact = 4.0 / 3.0 * std::numbers::pi * r * r * r;
    EXPECT_NEAR(trap["volume_mm3"].get<double>(), exact, 0.03 * exact);
    // The drain point is a void pixel of the cavity, as close to a side of the part as any.
    EXPECT_TRUE(inBall(int(trap["x"].get<double>()), int(trap["y"].get<double>()), int(trap["z"].get<double>()), 24, 24,
                       20, r));
    EXPECT_NEAR(trap["drain_mm"].get<double>(), 24 - r - 0.5, 1.0);
    EXPECT_EQ(report["island_count"], 0);

    // The same sphere with a drain hole (a 3 x 3 channel from the cavity to the side): no trap.
    const auto drained = check(40, [&](int i, int j, int k) {
        const bool hole = j >= 23 && j < 26 && k >= 19 && k < 22 && i < 24;
        return solid(i, j, k) && !hole;
    });
    EXPECT_EQ(drained["resin_trap_count"], 0);
    // And with the cavity open to the last layer (the vat): no trap either.
    const auto open = check(26, solid);
    EXPECT_EQ(open["resin_trap_count"], 0);
}

TEST(Printability, ACavityAgainstThePlateIsATrap)
{
    // A cup upside down on the plate: its inside touches layer 0 and nothing else.
    const auto report = check(10, [](int i, int j, int k) {
        const bool cup = i >= 10 && i < 30 && j >= 10 && j < 30;
        const bool inside = i >= 14 && i < 26 && j >= 14 && j < 26 && k < 6;
        return cup && !inside;
    });
    ASSERT_EQ(report["resin_trap_count"], 1);
    EXPECT_DOUBLE_EQ(report["resin_traps"][0]["volume_mm3"].get<double>(), 12.0 * 12.0 * 6.0);
}

TEST(Printability, FeaturesLessThanTwoPixelsAcrossAreThin)
{
    // Layer k: a wall of width 1 (columns 10) and one of width 2 (columns 20-21), rows 5-34.
    const auto report = check(3, [](int i, int j, int) { return j >= 5 && j < 35 && (i == 10 || i == 20 || i == 21); });
    EXPECT_EQ(report["thin"]["pixels"], 3 * 30);
    EXPECT_EQ(report["thin"]["layers"], 3);
    EXPECT_NEAR(report["thin"]["first"][0]["x"].get<double>(), 10.5, 1e-12);
    EXPECT_NEAR(report["thin"]["first"][0]["y"].get<double>(), 20.0, 1e-12);  // the wall's centre
    EXPECT_EQ(report["thin"]["features"], 3);
    // A diagonal line of single pixels is thin everywhere; a 2 x 2 checker block is not.
    const auto diagonal = check(1, [](int i, int j, int) { return i == j && i > 3 && i < 40; });
    EXPECT_EQ(diagonal["thin"]["pixels"], 36);
    const auto block = check(1, [](int i, int j, int) { return i >= 7 && i < 9 && j >= 7 && j < 9; });
    EXPECT_EQ(block["thin"]["pixels"], 0);
    // A strut cross-section of one pixel is a whole region, so a thin feature however small.
    const auto dot = check(1, [](int i, int j, int) { return (i == 7 && j == 7) || (i > 20 && j > 20); });
    EXPECT_EQ(dot["thin"]["pixels"], 1);
    // The tip of an acute wedge (a wall meeting the box at a slant) is not a feature: the
    // triangle below has thin pixels only at its sharp corner.
    const auto wedge = check(1, [](int i, int j, int) { return j >= 5 && j < 40 && i >= 5 && i - 5 <= (j - 5) / 3; });
    EXPECT_EQ(wedge["thin"]["pixels"], 0);
}

TEST(Printability, DiagonalContactJoinsSolidsButNotVoids)
{
    // Two squares touching at a corner are one region (8-connected): the upper one is supported
    // through the lower one only if it overlaps it in the layer below; here layer 1 has both.
    const auto report = check(2, [](int i, int j, int k) {
        const bool a = i >= 5 && i < 10 && j >= 5 && j < 10;
        const bool b = i >= 10 && i < 15 && j >= 10 && j < 15;
        return k == 0 ? a : (a || b);
    });
    EXPECT_EQ(report["island_count"], 0);  // b joins a diagonally within layer 1
}

TEST(Printability, PeriodicReplayMatchesAnalysingEveryLayer)
{
    // Columns that wander with period 7 in z, a floating blob each period and a cavity spanning
    // the period boundary: the replayed report must equal the full one.
    auto stack = [](int i, int j, int k) {
        const int phase = k % 7;
        const bool column = std::abs(i - (10 + phase)) < 3 && j >= 5 && j < 40;
        const bool blob = phase >= 3 && phase <= 4 && std::abs(i - 35) < 3 && std::abs(j - 20) < 3;
        const bool shellOut = i >= 26 && i < 44 && j >= 30 && j < 46;
        const bool shellIn = i >= 30 && i < 40 && j >= 34 && j < 42 && phase != 2;  // void, closed at phase 2
        return column || blob || (shellOut && !shellIn);
    };
    auto full = check(40, stack, 0), replayed = check(40, stack, 7);
    EXPECT_EQ(replayed["layers_analysed"], 7);
    EXPECT_EQ(replayed["layers_replayed"], 33);
    for (const char* volatileKey : {"layers_analysed", "layers_replayed"}) {
        full.erase(volatileKey);
        replayed.erase(volatileKey);
    }
    EXPECT_GT(full["island_count"].get<int>(), 0);
    EXPECT_GT(full["resin_trap_count"].get<int>(), 0);
    EXPECT_EQ(full.dump(), replayed.dump());
}

TEST(Printability, RunsAreTheExposedPixelsOfWideLayersPixelByPixel)
{
    // Layers wider than a word of bits (the rows packed sixteen or eight pixels at a time, then one
    // by one), greys on both sides of 128 in random runs: every row's solid and void runs against
    // the row walked pixel by pixel (exposed = grey >= 128).
    std::mt19937 rng(5);
    const std::uint8_t greys[] = {0, 127, 128, 129, 255, 1, 200};
    for (const int nx : {63, 64, 65, 131, 200, 257}) {
        LayerImage image;
        image.nx = nx;
        image.ny = 6;
        while (image.pixels.size() < std::size_t(nx) * image.ny)
            image.pixels.insert(image.pixels.end(), 1 + rng() % 30, greys[rng() % std::size(greys)]);
        image.pixels.resize(std::size_t(nx) * image.ny);
        const LayerFeatures f = analyseLayer(image);
        std::vector<std::tuple<int, int, int>> solid, hole, expectedSolid, expectedHole;
        for (const auto& r : f.solidRuns) solid.emplace_back(r.row, r.begin, r.end);
        for (const auto& r : f.voidRuns) hole.emplace_back(r.row, r.begin, r.end);
        for (int j = 0; j < image.ny; ++j)
            for (int i = 0; i < nx;) {
                const bool exposed = image.pixels[std::size_t(j) * nx + i] >= 128;
                int end = i + 1;
                while (end < nx && (image.pixels[std::size_t(j) * nx + end] >= 128) == exposed) ++end;
                (exposed ? expectedSolid : expectedHole).emplace_back(j, i, end);
                i = end;
            }
        EXPECT_EQ(solid, expectedSolid) << "nx " << nx;
        EXPECT_EQ(hole, expectedHole) << "nx " << nx;
    }
}
