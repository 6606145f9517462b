/// @file TrialRecipe.h
/// @brief Recipes for trial jobs: the searches that run a node again with one value changed
/// (PropertyDesign's density and sigma, PiecesAdvice's sigma) build their copies here.
#pragma once

#include "engine/core/JobContext.h"
#include "engine/recipe/Recipe.h"

#include <yaml-cpp/yaml.h>

#include <cstdio>
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

/// A number as YAML text that reads back to the same double.
inline YAML::Node exactNumber(double v)
{
    char text[40];
    std::snprintf(text, sizeof text, "%.17g", v);
    return YAML::Node(std::string(text));
}

/// A copy of @a base whose only field (with the fields it reads) and result is @a name, given
/// @a spec, with no outputs: the job of one trial.
inline Recipe trialRecipe(const Recipe& base, const std::string& name, const YAML::Node& spec)
{
    Recipe r = base;
    r.fieldIndex[name] = spec;
    r.fieldNames = {name};
    r.result = name;
    r.outputs.clear();
    return r;
}

}  // namespace voxlat
