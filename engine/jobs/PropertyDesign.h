/// @file PropertyDesign.h
/// @brief Lattices designed from their properties: `stiffness:` solves the density whose
/// homogenized modulus meets a target, `optimize:` picks the Gaussian joint sigma with the highest
/// modulus at a fixed density (with the capsule, Boolean-joint, lattice at that density as the
/// baseline). Both run before the job builds its fields: each trial is a job of its own on a copy
/// of the recipe that holds only that node, with `density:` or `sigma:` written in, homogenized
/// like `voxlat properties` (engine/jobs/PropertiesJob) but without conductivity.
#pragma once

#include "engine/core/JobContext.h"
#include "engine/recipe/Recipe.h"

#include <nlohmann/json.hpp>

namespace voxlat {

/// Resolves every `stiffness:` and `optimize:` key of @a recipe's fields, in file order: the spec
/// of such a node is replaced in recipe.fieldIndex by one with the key removed and the solved
/// `density:` (stiffness) or `kernel: {gaussian: {sigma}}` (optimize) written in. Returns the
/// report entries by field name ({"stiffness": {...}} or {"optimize": {...}}); empty when no node
/// has either key. Throws InputError (with the recipe line) for bad or contradictory keys and for a
/// target the lattice cannot reach, Cancelled when @a context is cancelled.
nlohmann::json resolvePropertyTargets(Recipe& recipe, JobContext* context);

}  // namespace voxlat
