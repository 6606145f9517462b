/// @file TrialRecipe.h
/// @brief Trial jobs (PropertyDesign's density and sigma searches, PiecesAdvice's sigma, a frame's
/// repeated cell, a graded lattice's slabs): their recipes are made by trialRecipe
/// (engine/recipe/Recipe.h) from a typed FieldEdit; here, how a trial hears its parent's cancel.
#pragma once

#include "engine/core/JobContext.h"
#include "engine/recipe/Recipe.h"

#include <string>

namespace voxlat {

/// Makes a trial job's own context (its warnings kept apart) stop when @a parent is cancelled:
/// its stages' progress checks look at the parent too, ten times a second. Without it a
/// SIGTERM during `optimize:` went unheard until every trial had run.
inline void followCancel(JobContext& trial, const JobContext* parent)
{
    if (!parent) return;
    trial.setProgressCallback([&trial, parent](const std::string&, std::uint64_t, std::uint64_t) {
        if (parent->cancelled()) trial.cancel();
    });
    if (parent->cancelled()) trial.cancel();
}

}  // namespace voxlat
