#include "engine/properties/Homogenization.h"

#include "engine/core/Errors.h"
#include "engine/properties/CellTopology.h"
#include "engine/properties/HexElement.h"
#include "engine/properties/Multigrid.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace voxlat {

namespace {

using namespace homogenization;

void validateCell(const VoxelCell& cell)
{
    if (cell.nx < 1 || cell.ny < 1 || cell.nz < 1)
        throw std::invalid_argument("homogenization: the cell needs at least one voxel along each axis");
    const double points = double(cell.nx) * cell.ny * cell.nz;
    // Node and voxel indices are int32 (memory per voxel stays small).
    if (points > double(std::numeric_limits<std::int32_t>::max()))
        throw std::invalid_argument("homogenization: the cell has more than 2^31 voxels");
    if (double(cell.solid.size()) != points)
        throw std::invalid_argument("homogenization: solid has " + std::to_string(cell.solid.size()) +
                                    " entries, the cell " + std::to_string(std::int64_t(points)) + " voxels");
    for (double h : {cell.hx, cell.hy, cell.hz})
        if (!(h > 0.0) || !std::isfinite(h))
            throw std::invalid_argument("homogenization: voxel sizes must be positive and finite");
}

/// What both problems report besides the tensor.
struct Bookkeeping {
    double relativeDensity = 0.0;
    std::int64_t solidVoxels = 0, islandVoxelsRemoved = 0;
    int islandsRemoved = 0;
    std::array<bool, 3> percolates{};
};

template <class Result>
void copyBookkeeping(const Bookkeeping& b, Result& r)
{
    r.relativeDensity = b.relativeDensity;
    r.solidVoxels = b.solidVoxels;
    r.islandVoxelsRemoved = b.islandVoxelsRemoved;
    r.islandsRemoved = b.islandsRemoved;
    r.percolates = b.percolates;
}

/// The effective N x N tensor of the problem with D unknowns per node. Load case v is solved only
/// when every axis in caseAxes[v] percolates: otherwise its total field can be made rigid on every
/// component (the component is bounded along that axis in the tiling, so the macroscopic field's
/// dependence on that coordinate is itself periodic on it), its energy is zero, and its row and
/// column of the tensor are exactly zero.
template <int D, int N>
void homogenize(const VoxelCell& cell, const std::vector<double>& ke, const std::array<std::array<double, N>, N>& C0,
                const std::array<std::array<bool, 3>, N>& caseAxes, const HomogenizationSettings& settings,
                std::array<std::array<double, N>, N>& C, std::array<int, N>& iterations,
                std::array<double, N>& residual, Bookkeeping& book)
{
    const std::array<int, 3> n{cell.nx, cell.ny, cell.nz};
    const CellTopology topology = analyzeCell(n, cell.solid);
    const double voxels = double(cell.nx) * cell.ny * cell.nz;
    book.solidVoxels = topology.keptVoxels;
    book.islandVoxelsRemoved = topology.islandVoxels;
    book.islandsRemoved = topology.islands;
    book.percolates = topology.percolates;
    book.relativeDensity = double(topology.keptVoxels) / voxels;
    C = {};
    iterations = {};
    residual = {};

    std::array<bool, N> solved{};
    int cases = 0;
    for (int v = 0; v < N; ++v) {
        solved[v] = topology.keptVoxels > 0;
        for (int k = 0; k < 3; ++k)
            if (caseAxes[v][k] && !topology.percolates[k]) solved[v] = false;
        cases += solved[v] ? 1 : 0;
    }
    if (cases == 0) return;

    const PeriodicSolver<D> solver(n, topology.label, topology.components, ke);
    constexpr int kE = 8 * D;
    auto elementLoad = [&](int v) {
        // fe = ke * u0: the element's nodal forces under the unit macroscopic field.
        const std::vector<double> u0 = unitLoadField(D, v, cell.hx, cell.hy, cell.hz);
        std::vector<double> fe(kE, 0.0);
        for (int i = 0; i < kE; ++i)
            for (int j = 0; j < kE; ++j) fe[i] += ke[i * kE + j] * u0[j];
        return fe;
    };
    auto load = [&](int v, std::vector<double>& F, double& scale) {
        const std::vector<double> fe = elementLoad(v);
        solver.assemble(fe, F);
        solver.removeTranslations(F);
        double fe2 = 0.0;
        for (double x : fe) fe2 += x * x;
        scale = std::sqrt(fe2 * double(topology.keptVoxels));
    };

    // The load cases' systems in batches (one V-cycle serves a batch, each case the bits it gets
    // alone). In a fully solid cell the nodal loads cancel: what is left is rounding, and the
    // fluctuation is zero.
    std::array<std::vector<double>, N> chi;
    // Every case in one batch: the fastest (W8's 64^3 gyroid, one thread: 0.60 s of CPU against
    // 0.64 s in batches of 3 and 0.70 s of 2), at about twice the memory of one case at a time.
    const int batch = N;
    int done = 0;
    for (int v0 = 0; v0 < N;) {
        std::vector<std::vector<double>> loads, fluctuations;
        std::vector<int> system;
        int v = v0;
        for (; v < N && int(system.size()) < batch; ++v) {
            if (!solved[v]) continue;
            std::vector<double> F;
            double scale = 0.0;
            load(v, F, scale);
            ++done;
            if (std::sqrt(solver.dot(F, F)) <= 1e-12 * scale) {
                chi[v].assign(solver.dofs(), 0.0);
                continue;
            }
            loads.push_back(std::move(F));
            system.push_back(v);
        }
        v0 = v;
        if (system.empty()) continue;
        std::function<bool(double)> progress;
        if (settings.progress)
            progress = [&](double f) {
                return settings.progress((double(done) - double(system.size()) * (1.0 - f)) / cases);
            };
        const auto stats = solver.solve(loads, fluctuations, settings.tolerance, settings.maxIterations, progress);
        for (std::size_t k = 0; k < system.size(); ++k) {
            iterations[system[k]] = stats[k].iterations;
            chi[system[k]] = std::move(fluctuations[k]);
            solver.removeTranslations(chi[system[k]]);
        }
    }
    if (settings.progress && !settings.progress(1.0)) throw Cancelled("homogenization cancelled");

    // C_ij |Y| = sum_e (u0_i - chi_i)^T ke (u0_j - chi_j)
    //          = Ns Ve C0_ij - chi_i.F_j - chi_j.F_i + chi_i.K chi_j,
    // the energy form, symmetric in i and j and stationary in chi (errors enter squared).
    std::array<std::array<double, N>, N> chiF{}, chiKchi{};
    for (int j = 0; j < N; ++j) {
        if (!solved[j]) continue;
        std::vector<double> F, Kchi;
        double scale = 0.0;
        load(j, F, scale);
        solver.apply(chi[j], Kchi);
        const double fnorm = std::sqrt(solver.dot(F, F));
        if (fnorm > 1e-12 * scale) {
            std::vector<double> r(F.size());
            for (std::size_t i = 0; i < r.size(); ++i) r[i] = F[i] - Kchi[i];
            residual[j] = std::sqrt(solver.dot(r, r)) / fnorm;
        }
        std::vector<std::pair<const std::vector<double>*, const std::vector<double>*>> pairs;
        for (int i = 0; i < N; ++i)
            if (solved[i]) {
                pairs.push_back({&chi[i], &F});
                pairs.push_back({&chi[i], &Kchi});
            }
        const std::vector<double> sums = solver.dots(pairs);
        for (int i = 0, k = 0; i < N; ++i) {
            if (!solved[i]) continue;
            chiF[i][j] = sums[k++];
            chiKchi[i][j] = sums[k++];
        }
    }
    const double cellVolume = voxels * cell.hx * cell.hy * cell.hz;
    const double solidVolume = double(topology.keptVoxels) * cell.hx * cell.hy * cell.hz;
    for (int i = 0; i < N; ++i)
        for (int j = 0; j < N; ++j) {
            if (!solved[i] || !solved[j]) continue;
            const double e = solidVolume * C0[i][j] - chiF[i][j] - chiF[j][i] + 0.5 * (chiKchi[i][j] + chiKchi[j][i]);
            C[i][j] = e / cellVolume;
        }
}

/// Eigen-decomposition of a symmetric 6x6 matrix (cyclic Jacobi): A = V diag(w) V^T, V's columns
/// the eigenvectors.
void symmetricEigen(Matrix6 A, std::array<double, 6>& w, Matrix6& V)
{
    V = {};
    for (int i = 0; i < 6; ++i) V[i][i] = 1.0;
    for (int sweep = 0; sweep < 100; ++sweep) {
        double off = 0.0, total = 0.0;
        for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 6; ++j) (i == j ? total : off) += A[i][j] * A[i][j];
        if (off <= 1e-32 * (total + off) || off == 0.0) break;
        for (int p = 0; p < 5; ++p)
            for (int q = p + 1; q < 6; ++q) {
                if (A[p][q] == 0.0) continue;
                const double theta = (A[q][q] - A[p][p]) / (2.0 * A[p][q]);
                const double t = (theta >= 0 ? 1.0 : -1.0) / (std::abs(theta) + std::sqrt(theta * theta + 1.0));
                const double c = 1.0 / std::sqrt(t * t + 1.0), s = t * c;
                for (int k = 0; k < 6; ++k) {  // A = A J
                    const double akp = A[k][p], akq = A[k][q];
                    A[k][p] = c * akp - s * akq;
                    A[k][q] = s * akp + c * akq;
                }
                for (int k = 0; k < 6; ++k) {  // A = J^T A
                    const double apk = A[p][k], aqk = A[q][k];
                    A[p][k] = c * apk - s * aqk;
                    A[q][k] = s * apk + c * aqk;
                }
                for (int k = 0; k < 6; ++k) {
                    const double vkp = V[k][p], vkq = V[k][q];
                    V[k][p] = c * vkp - s * vkq;
                    V[k][q] = s * vkp + c * vkq;
                }
            }
    }
    for (int i = 0; i < 6; ++i) w[i] = A[i][i];
}

/// Pseudo-inverse of C and the projector onto its null space.
struct PseudoInverse {
    Matrix6 S{}, null{};

    explicit PseudoInverse(const Matrix6& C)
    {
        Matrix6 sym;
        for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 6; ++j) sym[i][j] = 0.5 * (C[i][j] + C[j][i]);
        std::array<double, 6> w;
        Matrix6 V;
        symmetricEigen(sym, w, V);
        const double top = *std::max_element(w.begin(), w.end());
        for (int k = 0; k < 6; ++k) {
            const bool kept = top > 0.0 && w[k] > 1e-12 * top;
            for (int i = 0; i < 6; ++i)
                for (int j = 0; j < 6; ++j) {
                    if (kept)
                        S[i][j] += V[i][k] * V[j][k] / w[k];
                    else
                        null[i][j] += V[i][k] * V[j][k];
                }
        }
    }

    /// Whether the stress s lies (to 1e-8) in the range of C, i.e. can be carried.
    bool carries(const std::array<double, 6>& s) const
    {
        double n2 = 0.0, s2 = 0.0;
        for (int i = 0; i < 6; ++i) {
            double p = 0.0;
            for (int j = 0; j < 6; ++j) p += null[i][j] * s[j];
            n2 += p * p;
            s2 += s[i] * s[i];
        }
        return n2 <= 1e-16 * s2;
    }

    /// 1 / (s^T S s) for a carried stress s, else 0.
    double modulus(const std::array<double, 6>& s) const
    {
        if (!carries(s)) return 0.0;
        double q = 0.0;
        for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 6; ++j) q += s[i] * S[i][j] * s[j];
        return q > 0.0 ? 1.0 / q : 0.0;
    }
};

std::array<double, 6> unitStress(int i)
{
    std::array<double, 6> s{};
    s[i] = 1.0;
    return s;
}

}  // namespace

ElasticityResult homogenizeElasticity(const VoxelCell& cell, const IsotropicMaterial& material,
                                      const HomogenizationSettings& settings)
{
    validateCell(cell);
    if (!(material.E > 0.0) || !std::isfinite(material.E))
        throw std::invalid_argument("homogenization: Young's modulus must be positive");
    if (!(material.nu > -1.0 && material.nu < 0.5))
        throw std::invalid_argument("homogenization: Poisson's ratio must lie in (-1, 0.5)");
    const std::vector<double> ke = elasticElementMatrix(cell.hx, cell.hy, cell.hz, material.E, material.nu);
    const auto C0 = isotropicStiffness(material.E, material.nu);
    // Axes each Voigt strain involves: xx, yy, zz, yz, xz, xy.
    const std::array<std::array<bool, 3>, 6> axes{{{true, false, false},
                                                   {false, true, false},
                                                   {false, false, true},
                                                   {false, true, true},
                                                   {true, false, true},
                                                   {true, true, false}}};
    ElasticityResult result;
    Bookkeeping book;
    homogenize<3, 6>(cell, ke, C0, axes, settings, result.C, result.iterations, result.residual, book);
    copyBookkeeping(book, result);
    return result;
}

ConductivityResult homogenizeConductivity(const VoxelCell& cell, double k, const HomogenizationSettings& settings)
{
    validateCell(cell);
    if (!(k > 0.0) || !std::isfinite(k)) throw std::invalid_argument("homogenization: conductivity must be positive");
    const std::vector<double> ke = conductionElementMatrix(cell.hx, cell.hy, cell.hz, k);
    const std::array<std::array<double, 3>, 3> K0{{{k, 0, 0}, {0, k, 0}, {0, 0, k}}};
    const std::array<std::array<bool, 3>, 3> axes{{{true, false, false}, {false, true, false}, {false, false, true}}};
    ConductivityResult result;
    Bookkeeping book;
    homogenize<1, 3>(cell, ke, K0, axes, settings, result.K, result.iterations, result.residual, book);
    copyBookkeeping(book, result);
    return result;
}

EngineeringConstants engineeringConstants(const Matrix6& C)
{
    EngineeringConstants e;
    const PseudoInverse p(C);
    e.S = p.S;
    e.Ex = p.modulus(unitStress(0));
    e.Ey = p.modulus(unitStress(1));
    e.Ez = p.modulus(unitStress(2));
    e.Gyz = p.modulus(unitStress(3));
    e.Gxz = p.modulus(unitStress(4));
    e.Gxy = p.modulus(unitStress(5));
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            if (i != j && p.carries(unitStress(i)) && p.S[i][i] > 0.0) e.nu[i][j] = -p.S[j][i] / p.S[i][i];
    const std::array<double, 6> hydrostatic{1, 1, 1, 0, 0, 0};
    if (p.carries(hydrostatic)) {
        double sum = 0.0;
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) sum += p.S[i][j];
        e.bulkModulus = sum > 0.0 ? 1.0 / sum : 0.0;
    }
    const double denominator = C[0][0] - C[0][1];
    e.zenerRatio = denominator != 0.0 ? 2.0 * C[3][3] / denominator : 0.0;
    return e;
}

double directionalYoungsModulus(const Matrix6& C, const std::array<double, 3>& d)
{
    const double len2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    if (!(len2 > 0.0)) throw std::invalid_argument("directionalYoungsModulus: zero direction");
    const double x = d[0] / std::sqrt(len2), y = d[1] / std::sqrt(len2), z = d[2] / std::sqrt(len2);
    // Uniaxial unit stress along d: sigma = d d^T, Voigt (xx, yy, zz, yz, xz, xy); the normal strain
    // along d is then s^T S s with engineering shears.
    return PseudoInverse(C).modulus({x * x, y * y, z * z, y * z, x * z, x * y});
}

}  // namespace voxlat
