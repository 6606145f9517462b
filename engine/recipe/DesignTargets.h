/// @file DesignTargets.h
/// @brief Lattice keys that ask for a property rather than a geometry: `stiffness:` (the density
/// whose homogenized modulus meets a target) and `optimize:` (the Gaussian joint sigma with the
/// highest modulus at a fixed density). The job resolves them (engine/jobs/PropertyDesign) before
/// the fields are built; this file only reads and checks them.
#pragma once

#include "engine/recipe/KeySpec.h"
#include "engine/recipe/Materials.h"
#include "engine/recipe/RecipeNode.h"

#include <optional>
#include <string>
#include <vector>

namespace voxlat {

/// `stiffness: {E: 40 MPa, axis: z}` or `{E_ratio: 0.05}`: the modulus along one axis that the
/// solved density gives.
struct StiffnessTarget {
    std::optional<double> modulusMPa;  ///< E, absolute
    std::optional<double> ratio;       ///< E / E_s
    int axis = 2;                      ///< 0, 1, 2: x, y, z
    std::optional<int> resolution;     ///< voxels along the cell's longest side during the solve
    double tolerance = 0.01;           ///< relative error of the achieved modulus
    std::string where;                 ///< file:line:col of `stiffness:`
    std::string context;               ///< the key's description in messages (RecipeNode::context)
    /// The target modulus in MPa (E, or E_ratio times the material's E_s), set by parseFieldDesign.
    double goalMPa = 0.0;
    /// Throws InputError at `stiffness:`, as RecipeNode::fail does.
    [[noreturn]] void fail(const std::string& message) const;
};

/// `optimize: {sigma: [0.4, 1.6], axis: z}`: the Gaussian kernel's sigma in that range with the
/// highest modulus along the axis, at the node's fixed `density:`.
struct SigmaOptimization {
    double lo = 0.0, hi = 0.0;      ///< the sigma range searched (mm)
    int axis = 2;                   ///< 0, 1, 2: x, y, z
    std::optional<int> resolution;  ///< voxels along the cell's longest side during the search
    double tolerance = 0.0;         ///< the search stops when sigma is known to this (mm)
    int samples = 5;                ///< the coarse sweep's points before the golden-section refinement
    bool baseline = true;           ///< also homogenize the capsule (Boolean-joint) lattice at the density
    std::string where;              ///< file:line:col of `optimize:`
    std::string context;            ///< the key's description in messages (RecipeNode::context)
    double density = 0.0;           ///< the node's fixed `density:`, set by parseFieldDesign
    /// Throws InputError at `optimize:`, as RecipeNode::fail does.
    [[noreturn]] void fail(const std::string& message) const;
};

/// A field's design key, parsed and checked when the recipe loads (Recipe::designs): the job
/// resolves it (engine/jobs/PropertyDesign) from this, reading no YAML.
struct FieldDesign {
    std::string field;                          ///< the field's name
    std::optional<StiffnessTarget> stiffness;   ///< `stiffness:`
    std::optional<SigmaOptimization> optimize;  ///< `optimize:` as a map
    bool optimizeOff = false;                   ///< `optimize: off` (from --set): the sigma as written
};

/// The keys of a `stiffness:` map.
const std::vector<KeySpec>& stiffnessKeys();
/// The keys of an `optimize:` map.
const std::vector<KeySpec>& optimizeKeys();

/// Reads `stiffness:` (exactly one of E, E_ratio).
StiffnessTarget parseStiffness(const RecipeNode& node);
/// Reads `optimize:`.
SigmaOptimization parseOptimize(const RecipeNode& node);

/// Reads and checks the design key of the field @a spec (`stiffness:` on a tpms or struts node,
/// with no density, level or size key beside it and a material below the target; `optimize:` on a
/// struts node with a fixed density and a Gaussian kernel, or `optimize: off`), with @a material
/// the recipe's. Empty when the node has neither key. Throws InputError at the key's line.
std::optional<FieldDesign> parseFieldDesign(const RecipeNode& spec, const std::string& name,
                                            const std::optional<Material>& material);

}  // namespace voxlat
