/// @file Schema.h
/// @brief The recipe language as a JSON Schema, generated from the node-type table the loader
/// validates with, so the two cannot drift.
#pragma once

#include <nlohmann/json.hpp>

#include <string>

namespace voxlat {

/// JSON Schema (draft 2020-12) of a recipe: top-level keys, one definition per node type with
/// exactly the keys the loader accepts. Numbers may also be written as `$param` references.
nlohmann::json recipeSchema();

/// Every key of the language as Markdown tables (key, meaning, default): the key reference at the
/// end of docs/recipes.md is this text (`voxlat schema --markdown`; a test keeps them equal).
std::string recipeKeysMarkdown();

}  // namespace voxlat
