/// @file RecipeParams.h
/// @brief The parts of the recipe language applied before a recipe is checked: `include:`,
/// `params:` with `$name` references and --set, and the canonical, hashed form of a recipe.
#pragma once

#include "engine/recipe/RecipeNode.h"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <map>
#include <string>

namespace voxlat {

struct Recipe;

/// What a parameter holds; an override must hold the same.
enum class ParamKind { Number, Boolean, Text, List };

/// A declared parameter: its kind, optional range and where it was declared.
struct ParamDecl {
    ParamKind kind = ParamKind::Number;
    std::optional<double> min, max;
    std::string where;  ///< "file:line:col" of the default
};

/// Merges the files named in `include:` (recursively, relative to @a folder) into @a root:
/// their `params:` become defaults (the including recipe's own values win) and their `fields:`
/// are added (a name defined twice is an error). Only the named files are read; a cycle of
/// includes is an error. Nodes merged are recorded in @a source for error messages.
void mergeIncludes(YAML::Node root, const std::string& path, const std::filesystem::path& folder, RecipeSource& source);

/// Reads the `params:` block: names, kinds, ranges. Throws InputError for a malformed block.
std::map<std::string, ParamDecl> declaredParams(const YAML::Node& root, const std::shared_ptr<RecipeSource>& source);

/// Turns `--set NAME=VALUE` for a declared parameter into its key path (`params.NAME=VALUE`);
/// dotted paths and top-level keys pass through unchanged. An undotted name that is neither is
/// an error suggesting the closest parameter.
std::string routeAssignment(const YAML::Node& root, const std::string& assignment, const std::string& path,
                            const std::vector<std::string>& topKeys);

/// Checks every parameter against its declaration, then replaces each scalar `$name` (or
/// `${name}`) anywhere in the recipe by the parameter's value and `${name}` inside other text by
/// its text (equations, which read `$name` themselves, are left as written). Returns the
/// effective values by name.
std::map<std::string, YAML::Node> substituteParams(YAML::Node root, const std::shared_ptr<RecipeSource>& source,
                                                   const std::map<std::string, ParamDecl>& declared);

/// The recipe as run: includes merged, overrides and parameters applied, keys sorted, numbers
/// normalised, as JSON. Running it as a recipe gives the same part.
nlohmann::json canonicalRecipe(const Recipe& recipe);
/// SHA-256 of the compact text of canonicalRecipe().
std::string recipeHash(const Recipe& recipe);

}  // namespace voxlat
