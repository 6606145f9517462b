/// @file PropertiesJob.h
/// @brief What a lattice does: effective stiffness and conductivity of one periodic cell of a
/// recipe's result (engine/properties), in MPa, with the engineering constants users quote and a
/// picture of the directional Young's modulus.
#pragma once

#include "engine/core/JobContext.h"
#include "engine/properties/Homogenization.h"
#include "engine/recipe/Recipe.h"
#include "fields/core/FieldNode.h"
#include "fields/levels/LevelSolid.h"

#include <nlohmann/json.hpp>

#include <array>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace voxlat {

/// The homogenized cell, as report.json's `properties` and `voxlat properties --json`.
struct PropertiesResult {
    nlohmann::json report;
    Matrix6 stiffnessMPa{};
    double relativeDensity = 0.0;
};

/// The relative density a lattice was asked for (`density:`): the homogenized cell's level is
/// solved again on the voxel model that is homogenized, at its resolution, so that the cell holds
/// exactly that density (the job's level is solved over the frame's box, whose edge cells lack
/// their neighbours, and the voxel model aliases with the struts).
struct CellDensityTarget {
    double density = 0.0;               ///< the relative density asked
    double level = 0.0;                 ///< the level the job solved, in the node's own units
    SolidSide side = SolidSide::Below;  ///< which side of the level is solid
    /// The node's level as the recipe's `level:` key means it (a Gaussian lattice's iso-value t);
    /// empty when the two are the same.
    std::function<double(double)> recipeLevel;
};

/// A frame of identical cells (FieldNode::repeatZone()) too small to hold a whole cell deeper
/// than its struts reach (a frame of one or two cells): the zone, whose period is the cell and
/// whose phase is the frame's corner; empty when the cell is given (`properties: {cell}`), when
/// the result is periodic or has a whole repeating cell.
std::optional<RepeatZone> frameWithoutWholeCell(const FieldNode& field, const PropertiesSettings& settings);

/// Homogenizes one periodic cell of @a field (the recipe's result, levels solved): the cell is
/// `properties: {cell, origin}`, or one period of the field along each axis starting at
/// @a domainMin, or (a finite frame of identical cells, FieldNode::repeatZone()) the first whole
/// cell of the frame's repeating interior. Its resolution is `properties: {resolution}`, or the
/// first of 24, 34, 48, 68, ... voxels along its longest side at which Richardson extrapolation
/// of E over the last three says E is within `properties: {convergence}` of its limit (report
/// `convergence`; a `not_converged` warning when `max_resolution` comes first). With @a target
/// the cell's level is solved on its voxel model (CellDensityTarget). Needs `material:`. Throws
/// InputError for a missing material or period (naming the recipe line), JobError for a cell with
/// no solid or one that carries no load along any axis.
PropertiesResult computeProperties(const FieldNode& field, const Recipe& recipe, const Vec3d& domainMin,
                                   const JobContext* context, const CellDensityTarget* target = nullptr);

/// The Gibson–Ashby law E/E_s = C rho^n fitted per axis (least squares on log E/E_s against log
/// rho, over the points that carry load along that axis).
struct GibsonAshbyFit {
    std::array<double, 3> C{};      ///< prefactor per axis (0 with fewer than two points)
    std::array<double, 3> n{};      ///< exponent per axis (about 2 for bending, 1 for stretching)
    double maxRelativeError = 0.0;  ///< largest |C rho^n / (E/E_s) - 1| over the fitted points
};

/// Fits @a modulusRatio (E/E_s per axis) against @a density (relative densities, > 0).
GibsonAshbyFit fitGibsonAshby(const std::vector<double>& density,
                              const std::vector<std::array<double, 3>>& modulusRatio);

/// One point of a density curve (`voxlat properties --curve`) from a properties() report:
/// relative_density (the cell's), relative_density_target, C_MPa, E_MPa, G_MPa, E_ratio, nu,
/// K_ratio, level and the resolution.
nlohmann::json densityCurvePoint(const nlohmann::json& properties);

/// The curve's JSON: {curve: [points], gibson_ashby: {C, n, max_relative_error}}.
nlohmann::json densityCurve(const std::vector<nlohmann::json>& points);

/// The cell's stiffness in @a properties (a properties() report) as a CalculiX/Abaqus material
/// card named @a name: `*MATERIAL, NAME=...` and `*ELASTIC, TYPE=ANISO` with the 21 constants
/// D1111, D1122, D2222, D1133, D2233, D3333, D1112, D2212, D3312, D1212, D1113, D2213, D3313,
/// D1213, D1313, D1123, D2223, D3323, D1223, D1323, D2323 (engineering shear strains, MPa =
/// N/mm^2: a model in mm and N), eight to a line; comment lines (`**`) say where it came from and,
/// with @a region, where in the part the material holds (a slab of a graded lattice).
std::string abaqusMaterialCard(const nlohmann::json& properties, const std::string& name, const std::string& recipe,
                               const std::string& region = {});

/// A shaded picture (PNG, @a size pixels square) of the directional Young's modulus surface
/// E(d) of @a C: the surface r = E(d) / max E over the unit sphere.
std::string directionalModulusPng(const Matrix6& C, int size = 640);

/// The result as a small text table for a terminal (the library never prints; the CLI does).
std::string propertiesTable(const nlohmann::json& properties);

}  // namespace voxlat
