/// @file DrainSpec.h
/// @brief `drain: {diameter: D, build: [x, y, z]}` parsed once, at load, for `infill`, `shell` and
/// `slices:` alike.
#pragma once

#include "engine/recipe/KeySpec.h"
#include "engine/recipe/RecipeNode.h"
#include "fields/core/FieldNode.h"

#include <string>

namespace voxlat {

/// The drain holes a recipe asks for.
struct DrainSpec {
    double diameter = 0.0;      ///< the channels' diameter (mm)
    Vec3d up{0.0, 0.0, 1.0};    ///< the build direction, a unit vector (the plate is below)
    std::string where;          ///< file:line:col of `drain:`
    std::string diameterWhere;  ///< file:line:col of `diameter:`
};

/// Parses the `drain:` node @a d. @a allowBuild: whether `build:` is accepted (not under `slices:`,
/// which a printer builds along +z). Refuses (InputError with file:line) a missing or non-positive
/// diameter, a zero build direction and any other key.
DrainSpec parseDrain(const RecipeNode& d, bool allowBuild);

/// The schema of `drain:` (with `build:` when @a allowBuild).
nlohmann::json drainSchema(bool allowBuild);

}  // namespace voxlat
