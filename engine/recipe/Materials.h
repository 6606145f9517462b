/// @file Materials.h
/// @brief The `material:` and `properties:` keys of a recipe: what a lattice is made of and which
/// periodic cell of it is homogenized (engine/properties). Named materials are a table with sources.
#pragma once

#include "engine/recipe/KeySpec.h"
#include "engine/recipe/RecipeNode.h"

#include <array>
#include <optional>
#include <string>
#include <vector>

namespace voxlat {

/// An isotropic solid: Young's modulus, Poisson's ratio and (optionally) thermal conductivity.
struct Material {
    std::string name;                    ///< preset name, or "custom"
    double modulusMPa = 0.0;             ///< Young's modulus E_s
    double poisson = 0.0;                ///< nu_s
    std::optional<double> conductivity;  ///< k_s in W/(m K)
    std::string source;                  ///< where the values come from
    std::string where;                   ///< file:line:col of `material:`
};

/// The named materials (`material: ti6al4v`), each with its source.
const std::vector<Material>& materialPresets();

/// Reads `material:`: a preset name, or `{E: 1.6 GPa, nu: 0.38, k: 0.2}` (E with a unit: Pa, kPa,
/// MPa or GPa), or a preset with some values replaced (`{preset: pa12, E: 1.5 GPa}`).
Material parseMaterial(const RecipeNode& node);

/// A modulus with its unit (`1.6 GPa`, `1600 MPa`, `1.6e9 Pa`, `40 kPa`) in MPa; fails at @a node
/// without a unit or for a value that is not positive.
double parseModulusMPa(const RecipeNode& node);

/// The keys of a `material:` map.
const std::vector<KeySpec>& materialKeys();

/// The periodic cell that `voxlat properties` homogenizes (`properties:` top-level key).
struct PropertiesSettings {
    std::optional<std::array<double, 3>> cell;    ///< cell size (mm); default: the result's periods
    std::optional<std::array<double, 3>> origin;  ///< cell's minimum corner; default: the domain's
    /// Voxels along the cell's longest side; default: chosen by a convergence check.
    std::optional<int> resolution;
    double tolerance = 1e-6;    ///< relative residual of each load case
    double convergence = 0.02;  ///< the default resolution's estimated relative error in E
    int maxResolution = 136;    ///< the finest resolution the convergence check may reach
    /// `export: FILE.inp`: the cell's anisotropic elastic constants as a CalculiX/Abaqus material
    /// card, written by `voxlat run` into its output folder.
    std::optional<std::string> exportFile;
    /// Also solve the conductivity (not a key: property searches, which need only the stiffness, turn it off).
    bool conductivity = true;
    std::string where;  ///< file:line:col of `properties:` (or the recipe)
};

/// The keys of a `properties:` map.
const std::vector<KeySpec>& propertiesKeys();

/// Reads `properties:` (absent: the defaults, located at @a fallbackWhere).
PropertiesSettings parseProperties(const RecipeNode* node, const std::string& fallbackWhere);

}  // namespace voxlat
