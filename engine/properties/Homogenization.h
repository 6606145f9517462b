/// @file Homogenization.h
/// @brief Effective (homogenized) stiffness and conductivity of a periodic voxel cell.
///
/// The method is the voxel finite-element homogenization of Andreassen & Andreasen (2014) and
/// Dong, Tang & Zhao (2019): one trilinear 8-node hexahedron per solid voxel, void voxels absent
/// (no soft filler material), periodic boundary conditions. For each unit macroscopic strain (or
/// temperature gradient) the periodic fluctuation is solved for, and the effective tensor is the
/// cell-averaged energy of the total field.
///
/// The cell is cleaned first: connected components of solid voxels (two voxels are connected when
/// they share at least one node, as in the element model) are found on the periodic torus, and
/// components that do not connect to their own periodic translate ("islands": a floating cube, a
/// detached strut piece) are removed and counted, since they carry no load and only make the
/// system singular. A direction along which no remaining component connects to its translate
/// cannot carry load: its rows and columns of the tensor are zero and its load cases are not solved.
///
/// The solver is matrix-free (all solid voxels share one element matrix) preconditioned conjugate
/// gradients with a geometric multigrid V-cycle (Galerkin coarse operators, Chebyshev smoothing).
/// Results are bit-identical for any number of threads.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <vector>

namespace voxlat {

/// A periodic cell of voxels. Voxel (x, y, z) is solid[x + nx*(y + ny*z)] != 0; the cell repeats
/// with period (nx*hx, ny*hy, nz*hz).
struct VoxelCell {
    int nx = 0, ny = 0, nz = 0;
    double hx = 1.0, hy = 1.0, hz = 1.0;  ///< voxel size along each axis
    std::vector<std::uint8_t> solid;
};

/// An isotropic linear elastic solid. The effective stiffness is in the unit of E.
struct IsotropicMaterial {
    double E = 1.0;
    double nu = 0.3;
};

/// How hard the solver works, and how it reports.
struct HomogenizationSettings {
    /// Each load case stops when the residual norm falls below tolerance times the load's norm.
    double tolerance = 1e-8;
    /// Per load case; a case that does not converge reports its iterations and final residual.
    int maxIterations = 2000;
    /// Called with the fraction done (0..1) during the solve; returning false cancels, and the
    /// call throws voxlat::Cancelled.
    std::function<bool(double)> progress;
};

/// 6x6 stiffness or compliance in Voigt order xx, yy, zz, yz, xz, xy, with engineering shear
/// strains (gamma = 2 eps), so stress = C * strain.
using Matrix6 = std::array<std::array<double, 6>, 6>;
using Matrix3 = std::array<std::array<double, 3>, 3>;

/// The effective stiffness of a cell and what was done to find it.
struct ElasticityResult {
    Matrix6 C{};                   ///< effective stiffness (symmetric)
    double relativeDensity = 0.0;  ///< solidVoxels / all voxels (islands not counted)
    std::int64_t solidVoxels = 0;  ///< solid voxels that carry load (after island removal)
    std::int64_t islandVoxelsRemoved = 0;
    int islandsRemoved = 0;            ///< components that do not connect to their periodic translates
    std::array<bool, 3> percolates{};  ///< some component connects to its own translate along x, y, z
    std::array<int, 6> iterations{};   ///< PCG iterations per load case (0: not solved, zero by topology)
    std::array<double, 6> residual{};  ///< final true relative residual per load case
};

/// The effective conductivity of a cell and what was done to find it.
struct ConductivityResult {
    Matrix3 K{};  ///< effective conductivity (symmetric), in the unit of k
    double relativeDensity = 0.0;
    std::int64_t solidVoxels = 0;
    std::int64_t islandVoxelsRemoved = 0;
    int islandsRemoved = 0;
    std::array<bool, 3> percolates{};
    std::array<int, 3> iterations{};  ///< per unit temperature gradient along x, y, z
    std::array<double, 3> residual{};
};

/// The effective elastic stiffness of @a cell made of @a material. Throws std::invalid_argument
/// for an inconsistent cell (sizes, non-positive voxel size, E <= 0, nu outside (-1, 0.5)) and
/// voxlat::Cancelled when settings.progress returns false.
ElasticityResult homogenizeElasticity(const VoxelCell& cell, const IsotropicMaterial& material,
                                      const HomogenizationSettings& settings = {});

/// The effective thermal (or electrical, or any Laplace-type) conductivity of @a cell made of a
/// material of conductivity @a k. Throws as homogenizeElasticity.
ConductivityResult homogenizeConductivity(const VoxelCell& cell, double k, const HomogenizationSettings& settings = {});

/// Engineering constants derived from an effective stiffness.
///
/// A stiffness that is singular (a direction that does not percolate, or a shear the structure
/// cannot resist) has no inverse; S is then its Moore-Penrose pseudo-inverse (eigenvalues below
/// 1e-12 of the largest treated as zero), and a modulus whose uniaxial stress (or shear stress)
/// is not fully carried by the stiffness is reported as 0 rather than as the infinite stiffness
/// the pseudo-inverse's zero compliance would suggest.
struct EngineeringConstants {
    Matrix6 S{};                       ///< compliance (pseudo-inverse of C)
    double Ex = 0, Ey = 0, Ez = 0;     ///< Young's moduli along the axes
    double Gyz = 0, Gxz = 0, Gxy = 0;  ///< shear moduli
    Matrix3 nu{};                      ///< nu[i][j] = -S_ji / S_ii: contraction along j under stress along i
    double bulkModulus = 0;  ///< 1 / sum of S_ij over i, j < 3 (hydrostatic stress), 0 if one axis carries nothing
    double zenerRatio = 0;   ///< 2 C44 / (C11 - C12); 0 when C11 == C12
};

/// Compliance and engineering constants of @a C (see EngineeringConstants).
EngineeringConstants engineeringConstants(const Matrix6& C);

/// Young's modulus along the direction @a d (need not be unit length): 1 / (s^T S s) with s the
/// Voigt vector of the uniaxial stress d d^T / |d|^2, S the pseudo-inverse of @a C. 0 when the
/// uniaxial stress along d is not carried by C (it has a part in C's null space).
double directionalYoungsModulus(const Matrix6& C, const std::array<double, 3>& d);

}  // namespace voxlat
