// The error a recipe gives when it is loaded and built (shared by the recipe tests).
#pragma once

#include "engine/jobs/Job.h"
#include "engine/recipe/Recipe.h"

#include <filesystem>
#include <string>
#include <vector>

namespace voxlat::test {

/// The InputError message of loading and building the recipe @a text with the `--set` values
/// @a sets, its includes read from @a folder ("" if it loads and builds).
inline std::string errorOf(const std::string& text, const std::vector<std::string>& sets = {},
                           const std::filesystem::path& folder = ".")
{
    try {
        Job job(parseRecipe(text, "bad.yaml", folder, sets));
        return "";
    } catch (const InputError& e) {
        return e.what();
    }
}

}  // namespace voxlat::test
