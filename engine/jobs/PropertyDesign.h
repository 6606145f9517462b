/// @file PropertyDesign.h
/// @brief Lattices designed from their properties: `stiffness:` solves the density whose
/// homogenized modulus meets a target, `optimize:` picks the Gaussian joint sigma with the highest
/// modulus at a fixed density (with the capsule, Boolean-joint, lattice at that density as the
/// baseline). Both run before the job builds its fields: each trial is a job of its own on a copy
/// of the recipe that holds only that node (trialRecipe, from a typed FieldEdit: `density:` or
/// `sigma:` written in), homogenized
/// like `voxlat properties` (engine/jobs/PropertiesJob) but without conductivity.
#pragma once

#include "engine/core/JobContext.h"
#include "engine/recipe/Recipe.h"

#include <nlohmann/json.hpp>

namespace voxlat {

/// Resolves every `stiffness:` and `optimize:` key of @a recipe's fields (Recipe::designs, parsed
/// and checked at load), in file order: each node is edited (editField) with the key removed and
/// the solved `density:` (stiffness) or `kernel: {gaussian: {sigma}}` (optimize) written in. Returns
/// the report entries by field name ({"stiffness": {...}} or {"optimize": {...}}); empty when no
/// node has either key. Throws InputError (with the key's recipe line) for a target the lattice
/// cannot reach, Cancelled when @a context is cancelled.
nlohmann::json resolvePropertyTargets(Recipe& recipe, JobContext* context);

}  // namespace voxlat
