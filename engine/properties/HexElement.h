/// @file HexElement.h
/// @brief Element matrices of the trilinear 8-node voxel (box) element (internal to properties).
#pragma once

#include <array>
#include <vector>

namespace voxlat::homogenization {

/// Local node a of a voxel sits at corner (a & 1, (a >> 1) & 1, (a >> 2) & 1); an element vector
/// holds node a's D values at a*D .. a*D+D-1. Matrices are row-major, (8D) x (8D).

/// The 24x24 stiffness of an isotropic elastic box hx x hy x hz (2x2x2 Gauss, exact here).
std::vector<double> elasticElementMatrix(double hx, double hy, double hz, double E, double nu);

/// The 8x8 conduction matrix of a box of conductivity k.
std::vector<double> conductionElementMatrix(double hx, double hy, double hz, double k);

/// The 6x6 isotropic stiffness (Voigt xx, yy, zz, yz, xz, xy, engineering shear).
std::array<std::array<double, 6>, 6> isotropicStiffness(double E, double nu);

/// Nodal values of the linear field of a unit macroscopic load case, per element (8D values):
/// D = 3: displacement eps * x for Voigt strain @a loadCase (shear cases are engineering strains
/// of 1, so eps_ij = 1/2); D = 1: temperature x_i for the unit gradient along axis @a loadCase.
std::vector<double> unitLoadField(int D, int loadCase, double hx, double hy, double hz);

}  // namespace voxlat::homogenization
