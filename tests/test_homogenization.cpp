// engine/properties/Homogenization: effective stiffness and conductivity of periodic voxel cells,
// against closed forms (solid, columns, laminates), symmetry, bounds, the thread count and the
// published example of Dong, Tang & Zhao (2019).
#include "engine/core/Errors.h"
#include "engine/properties/Homogenization.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <cstring>
#include <functional>

using namespace voxlat;

namespace {

VoxelCell makeCell(int nx, int ny, int nz, const std::function<bool(int, int, int)>& solid, double h = 1.0)
{
    VoxelCell cell;
    cell.nx = nx, cell.ny = ny, cell.nz = nz;
    cell.hx = cell.hy = cell.hz = h;
    cell.solid.resize(std::size_t(nx) * ny * nz);
    for (int z = 0; z < nz; ++z)
        for (int y = 0; y < ny; ++y)
            for (int x = 0; x < nx; ++x) cell.solid[x + std::size_t(nx) * (y + std::size_t(ny) * z)] = solid(x, y, z);
    return cell;
}

/// Solid gyroid network of n^3 voxels: sin x cos y + sin y cos z + sin z cos x > t.
VoxelCell gyroid(int n, double t)
{
    return makeCell(n, n, n, [&](int x, int y, int z) {
        const double s = 2.0 * M_PI / n;
        const double X = (x + 0.5) * s, Y = (y + 0.5) * s, Z = (z + 0.5) * s;
        return std::sin(X) * std::cos(Y) + std::sin(Y) * std::cos(Z) + std::sin(Z) * std::cos(X) > t;
    });
}

/// Dong et al.'s "grid" cell: struts of radius r along the 12 edges of the unit cell (three
/// periodic struts through the corner), a voxel solid when its centre is within r of an edge.
VoxelCell gridCell(int n, double r)
{
    return makeCell(n, n, n, [&](int x, int y, int z) {
        auto d = [&](int i) {
            const double c = (i + 0.5) / n;
            return std::min(c, 1.0 - c);
        };
        const double dx = d(x), dy = d(y), dz = d(z);
        return dy * dy + dz * dz < r * r || dx * dx + dz * dz < r * r || dx * dx + dy * dy < r * r;
    });
}

double relDiff(double a, double b)
{
    return std::abs(a - b) / std::max(std::abs(b), 1e-300);
}

}  // namespace

TEST(Homogenization, FullySolidCellIsTheMaterial)
{
    const double E = 210.0, nu = 0.3;
    const double c11 = E * (1 - nu) / ((1 + nu) * (1 - 2 * nu)), c12 = E * nu / ((1 + nu) * (1 - 2 * nu)),
                 c44 = E / (2 * (1 + nu));
    for (const auto& [n, h] : {std::pair{4, 1.0}, std::pair{7, 0.25}}) {
        VoxelCell cell = makeCell(
            n, n + 1, n + 2, [](int, int, int) { return true; }, h);
        cell.hy = 2.0 * h;  // a non-cubic voxel is still the same material
        const ElasticityResult r = homogenizeElasticity(cell, {E, nu});
        for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 6; ++j) {
                const double expected = i < 3 && j < 3 ? (i == j ? c11 : c12) : (i == j ? c44 : 0.0);
                EXPECT_NEAR(r.C[i][j], expected, 1e-8 * c11) << i << "," << j;
            }
        EXPECT_EQ(r.relativeDensity, 1.0);
        EXPECT_EQ(r.percolates, (std::array<bool, 3>{true, true, true}));
        const ConductivityResult t = homogenizeConductivity(cell, 3.0);
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) EXPECT_NEAR(t.K[i][j], i == j ? 3.0 : 0.0, 3e-8);
        const EngineeringConstants e = engineeringConstants(r.C);
        EXPECT_LT(relDiff(e.Ex, E), 1e-8);
        EXPECT_LT(relDiff(e.Gxy, c44), 1e-8);
        EXPECT_LT(relDiff(e.nu[0][1], nu), 1e-8);
        EXPECT_LT(relDiff(e.bulkModulus, E / (3 * (1 - 2 * nu))), 1e-8);
        EXPECT_LT(relDiff(e.zenerRatio, 1.0), 1e-8);
        EXPECT_LT(relDiff(directionalYoungsModulus(r.C, {1, 2, -3}), E), 1e-8);
    }
}

TEST(Homogenization, SquareColumnsAlongX)
{
    // Columns of a x a voxels along x in an L x L cell: uniaxial stress in the columns, which are
    // free to contract sideways (they do not touch): E_x = (a/L)^2 E exactly, nothing else.
    const int L = 8, a = 3;
    const double E = 70.0;
    VoxelCell cell = makeCell(5, L, L, [&](int, int y, int z) { return y < a && z < a; });
    cell.hy = 0.7, cell.hz = 1.3;  // the area fraction does not depend on the voxel's shape
    const ElasticityResult r = homogenizeElasticity(cell, {E, 0.33});
    EXPECT_EQ(r.percolates, (std::array<bool, 3>{true, false, false}));
    const double expected = double(a * a) / (L * L) * E;
    EXPECT_LT(relDiff(r.C[0][0], expected), 1e-8);
    for (int i = 0; i < 6; ++i)
        for (int j = 0; j < 6; ++j) {
            if (i != 0 || j != 0) {
                EXPECT_EQ(r.C[i][j], 0.0) << i << "," << j;
            }
        }
    EXPECT_EQ(r.iterations[1], 0);  // not solved: y does not percolate
    const EngineeringConstants e = engineeringConstants(r.C);
    EXPECT_LT(relDiff(e.Ex, expected), 1e-8);
    EXPECT_EQ(e.Ey, 0.0);
    EXPECT_EQ(e.Ez, 0.0);
    EXPECT_EQ(e.Gxy, 0.0);
    EXPECT_EQ(e.bulkModulus, 0.0);
    EXPECT_EQ(directionalYoungsModulus(r.C, {1, 1, 0}), 0.0);  // the stress has a part no column carries
    EXPECT_LT(relDiff(directionalYoungsModulus(r.C, {1, 0, 0}), expected), 1e-8);

    const ConductivityResult t = homogenizeConductivity(cell, 2.0);
    EXPECT_LT(relDiff(t.K[0][0], double(a * a) / (L * L) * 2.0), 1e-8);
    EXPECT_EQ(t.K[1][1], 0.0);
    EXPECT_EQ(t.K[2][2], 0.0);
}

TEST(Homogenization, SymmetricAndWithinBounds)
{
    const VoxelCell cell = makeCell(9, 10, 11, [](int x, int y, int z) {
        return std::sin(0.9 * x + 0.3) * std::cos(0.7 * y) + std::sin(0.6 * z + 0.2 * x) > -0.2;
    });
    const double E = 100.0, nu = 0.25;
    const ElasticityResult r = homogenizeElasticity(cell, {E, nu});
    double top = 0.0;
    for (int i = 0; i < 6; ++i) top = std::max(top, std::abs(r.C[i][i]));
    for (int i = 0; i < 6; ++i)
        for (int j = 0; j < 6; ++j) EXPECT_LE(std::abs(r.C[i][j] - r.C[j][i]), 1e-12 * top);
    // Voigt bound: no stiffer than the solid fraction times the material; positive diagonal.
    const double c11 = E * (1 - nu) / ((1 + nu) * (1 - 2 * nu)), c44 = E / (2 * (1 + nu));
    for (int i = 0; i < 3; ++i) {
        EXPECT_GT(r.C[i][i], 0.0);
        EXPECT_LT(r.C[i][i], r.relativeDensity * c11);
        EXPECT_GT(r.C[i + 3][i + 3], 0.0);
        EXPECT_LT(r.C[i + 3][i + 3], r.relativeDensity * c44);
    }
    for (int v = 0; v < 6; ++v) EXPECT_LT(r.residual[v], 1e-8);
    const ConductivityResult t = homogenizeConductivity(cell, 1.0);
    for (int i = 0; i < 3; ++i) {
        EXPECT_GT(t.K[i][i], 0.0);
        EXPECT_LT(t.K[i][i], t.relativeDensity);
        for (int j = 0; j < 3; ++j) EXPECT_LE(std::abs(t.K[i][j] - t.K[j][i]), 1e-12);
    }
}

TEST(Homogenization, LaminateIsSeriesAndParallel)
{
    // Plates normal to z, 3 of every 8 layers: in plane the parallel (Voigt) value f k, across
    // them the series value, zero since the gaps are void.
    const VoxelCell cell = makeCell(6, 6, 8, [](int, int, int z) { return z % 8 < 3; });
    const ConductivityResult t = homogenizeConductivity(cell, 5.0);
    EXPECT_LT(relDiff(t.K[0][0], 3.0 / 8.0 * 5.0), 1e-8);
    EXPECT_LT(relDiff(t.K[1][1], 3.0 / 8.0 * 5.0), 1e-8);
    EXPECT_EQ(t.K[2][2], 0.0);
    EXPECT_EQ(t.percolates, (std::array<bool, 3>{true, true, false}));
    // Elastic plates: in-plane plane-stress stiffness f E / (1 - nu^2), nothing involving z.
    const double E = 10.0, nu = 0.3;
    const ElasticityResult r = homogenizeElasticity(cell, {E, nu});
    EXPECT_LT(relDiff(r.C[0][0], 3.0 / 8.0 * E / (1 - nu * nu)), 1e-8);
    EXPECT_LT(relDiff(r.C[0][1], 3.0 / 8.0 * E * nu / (1 - nu * nu)), 1e-8);
    EXPECT_LT(relDiff(r.C[5][5], 3.0 / 8.0 * E / (2 * (1 + nu))), 1e-8);
    for (int i : {2, 3, 4})
        for (int j = 0; j < 6; ++j) EXPECT_EQ(r.C[i][j], 0.0);
}

TEST(Homogenization, CubicCellIsCubic)
{
    const ElasticityResult r = homogenizeElasticity(gridCell(16, 0.2), {1.0, 0.3});
    EXPECT_LT(relDiff(r.C[1][1], r.C[0][0]), 1e-7);
    EXPECT_LT(relDiff(r.C[2][2], r.C[0][0]), 1e-7);
    EXPECT_LT(relDiff(r.C[0][2], r.C[0][1]), 1e-7);
    EXPECT_LT(relDiff(r.C[1][2], r.C[0][1]), 1e-7);
    EXPECT_LT(relDiff(r.C[4][4], r.C[3][3]), 1e-7);
    EXPECT_LT(relDiff(r.C[5][5], r.C[3][3]), 1e-7);
    EXPECT_LT(std::abs(r.C[0][3]), 1e-7 * r.C[0][0]);
}

TEST(Homogenization, SameBitsForAnyThreadCount)
{
    const VoxelCell cell = gyroid(20, 0.6);
    ElasticityResult one, three;
    ConductivityResult tOne, tThree;
    {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
        one = homogenizeElasticity(cell, {1.0, 0.3});
        tOne = homogenizeConductivity(cell, 1.0);
    }
    {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 3);
        three = homogenizeElasticity(cell, {1.0, 0.3});
        tThree = homogenizeConductivity(cell, 1.0);
    }
    EXPECT_EQ(std::memcmp(&one.C, &three.C, sizeof one.C), 0);
    EXPECT_EQ(one.iterations, three.iterations);
    EXPECT_EQ(std::memcmp(&one.residual, &three.residual, sizeof one.residual), 0);
    EXPECT_EQ(std::memcmp(&tOne.K, &tThree.K, sizeof tOne.K), 0);
    EXPECT_GT(one.C[0][0], 0.0);
}

TEST(Homogenization, FloatingCubeIsRemoved)
{
    // A frame of 2x2 struts along the cell edges and a 3^3 cube floating in the middle.
    const int n = 12;
    auto frame = [](int x, int y, int z) {
        const int s = (x < 2) + (y < 2) + (z < 2);
        return s >= 2;
    };
    auto cube = [](int x, int y, int z) { return x >= 5 && x < 8 && y >= 5 && y < 8 && z >= 5 && z < 8; };
    const VoxelCell withCube = makeCell(n, n, n, [&](int x, int y, int z) { return frame(x, y, z) || cube(x, y, z); });
    const VoxelCell without = makeCell(n, n, n, frame);
    const ElasticityResult a = homogenizeElasticity(withCube, {1.0, 0.3});
    const ElasticityResult b = homogenizeElasticity(without, {1.0, 0.3});
    EXPECT_EQ(a.islandsRemoved, 1);
    EXPECT_EQ(a.islandVoxelsRemoved, 27);
    EXPECT_EQ(b.islandsRemoved, 0);
    EXPECT_EQ(a.solidVoxels, b.solidVoxels);
    EXPECT_EQ(std::memcmp(&a.C, &b.C, sizeof a.C), 0);
    EXPECT_EQ(a.percolates, (std::array<bool, 3>{true, true, true}));
    // A cell of islands only carries nothing.
    const ElasticityResult c = homogenizeElasticity(makeCell(n, n, n, cube), {1.0, 0.3});
    EXPECT_EQ(c.islandsRemoved, 1);
    EXPECT_EQ(c.solidVoxels, 0);
    EXPECT_EQ(c.C[0][0], 0.0);
    EXPECT_EQ(c.percolates, (std::array<bool, 3>{false, false, false}));
}

TEST(Homogenization, DongTangZhaoGridExample)
{
    // Dong, Tang & Zhao (2019), the "grid" cell: 40^3 voxels, struts of radius 0.1 along the edges,
    // lambda 115.4, mu 79.6. Published: density 0.0855, C11 7.1876, C12 0.3875, C44 0.1489.
    const double lambda = 115.4, mu = 79.6;
    const double E = mu * (3 * lambda + 2 * mu) / (lambda + mu), nu = lambda / (2 * (lambda + mu));
    const ElasticityResult r = homogenizeElasticity(gridCell(40, 0.1), {E, nu});
    std::printf("Dong grid 40^3: density %.6f C11 %.6f C12 %.6f C44 %.6f, iterations %d %d %d %d %d %d\n",
                r.relativeDensity, r.C[0][0], r.C[0][1], r.C[3][3], r.iterations[0], r.iterations[1], r.iterations[2],
                r.iterations[3], r.iterations[4], r.iterations[5]);
    EXPECT_LT(relDiff(r.relativeDensity, 0.0855), 1e-3);
    EXPECT_LT(relDiff(r.C[0][0], 7.1876), 1e-3);
    EXPECT_LT(relDiff(r.C[0][1], 0.3875), 1e-3);
    EXPECT_LT(relDiff(r.C[3][3], 0.1489), 1e-3);
}

TEST(Homogenization, MultigridIterationsDoNotGrowWithResolution)
{
    int worst[2] = {0, 0};
    const int sizes[2] = {16, 48};
    for (int k = 0; k < 2; ++k) {
        const ConductivityResult t = homogenizeConductivity(gyroid(sizes[k], 0.5), 1.0);
        for (int it : t.iterations) worst[k] = std::max(worst[k], it);
    }
    std::printf("gyroid conductivity PCG iterations: %d at 16^3, %d at 48^3\n", worst[0], worst[1]);
    EXPECT_LE(worst[1], 1.5 * worst[0] + 5);
}

TEST(Homogenization, CancelsAndRejectsBadInput)
{
    HomogenizationSettings settings;
    settings.progress = [](double) { return false; };
    EXPECT_THROW(homogenizeElasticity(gyroid(8, 0.3), {1.0, 0.3}, settings), Cancelled);
    VoxelCell bad = gyroid(4, 0.0);
    bad.solid.pop_back();
    EXPECT_THROW(homogenizeElasticity(bad, {1.0, 0.3}), std::invalid_argument);
    EXPECT_THROW(homogenizeElasticity(gyroid(4, 0.0), {1.0, 0.5}), std::invalid_argument);
    EXPECT_THROW(homogenizeConductivity(gyroid(4, 0.0), 0.0), std::invalid_argument);
}
