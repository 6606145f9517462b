/// @file PiecesAdvice.h
/// @brief Numbers for the fix when a result falls apart: for a Gaussian-convolution strut
/// lattice at a fixed density, the largest sigma at which its cells stay in one piece.
#pragma once

#include "engine/core/JobContext.h"
#include "engine/recipe/Recipe.h"

#include <optional>
#include <string>

namespace voxlat {

/// The largest sigma (mm, rounded down to 0.01 mm) below the node's own at which the strut
/// lattice @a name of @a recipe stays in one piece at its `density:` on the recipe's voxels. Each
/// trial is a job over 2 x 2 x 2 of its box cells with only the sigma changed, whose pieces are
/// counted on the grid (crumbs the trial box cuts off do not count); the sigma is bisected between
/// a quarter of the node's and the node's own. nullopt unless the node is `struts:` with only
/// `cell`, `size` and `origin` in a box domain, a `kernel: {gaussian: {sigma: S}}` and a number as
/// `density:`, or when no sigma in that range keeps it whole.
std::optional<double> sigmaKeepingOnePiece(const Recipe& recipe, const std::string& name, JobContext* context);

}  // namespace voxlat
