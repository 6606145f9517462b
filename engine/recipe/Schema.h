/// @file Schema.h
/// @brief The recipe language as a JSON Schema, generated from the node-type table the loader
/// validates with, so the two cannot drift.
#pragma once

#include <nlohmann/json.hpp>

namespace voxlat {

/// JSON Schema (draft 2020-12) of a recipe: top-level keys, one definition per node type with
/// exactly the keys the loader accepts. Numbers may also be written as `$param` references.
nlohmann::json recipeSchema();

}  // namespace voxlat
