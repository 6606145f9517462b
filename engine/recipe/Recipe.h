/// @file Recipe.h
/// @brief A YAML recipe, loaded and checked: domain, named fields, result, outputs.
#pragma once

#include "engine/recipe/DesignTargets.h"
#include "engine/recipe/FieldEdits.h"
#include "engine/recipe/KeySpec.h"
#include "engine/recipe/Materials.h"
#include "engine/recipe/MeshSettings.h"
#include "engine/recipe/RecipeNode.h"
#include "engine/recipe/SliceSettings.h"

#include <algorithm>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace voxlat {

/// One entry of `outputs:`.
struct OutputSpec {
    std::string kind;   ///< "mesh", "vdb" or "slices"
    std::string file;   ///< relative to the output folder
    YAML::Node spec;    ///< the entry as written (for the canonical recipe; jobs read the settings below)
    std::string where;  ///< file:line:col of the entry, for messages
    /// A `mesh:` entry's settings, parsed and checked when the recipe loads.
    std::optional<MeshSettings> mesh{};
    /// A `slices:` entry's settings, parsed and checked when the recipe loads.
    std::optional<SliceSettings> slices{};
    /// The other files the output writes, relative to the output folder and named after its whole
    /// file name: a slices output's contact sheet (`FILE.preview.png` or its `preview:`), a
    /// properties output's picture, the first mesh's preview picture (`FILE.preview.png`, written
    /// by `voxlat run` unless --no-preview). No two outputs of a recipe share any of these names.
    std::vector<std::string> sideFiles{};
};

struct Recipe {
    std::shared_ptr<RecipeSource> source;
    std::filesystem::path folder;  ///< paths inside the recipe are relative to this
    YAML::Node root;

    double voxel = 0.1;
    std::optional<Box3> domainBox;
    /// Where `voxel:` and `domain:` are written ("file:line", or the file when the recipe does not
    /// give them), for the messages a job places there after it has built the fields.
    std::string voxelWhere, domainWhere;
    std::string result;
    std::vector<std::string> fieldNames;  ///< in file order
    std::vector<OutputSpec> outputs;
    /// `material:` (needed by properties) and the `properties:` cell settings.
    std::optional<Material> material;
    PropertiesSettings properties;
    /// Checks the recipe turns from errors into warnings (`allow: [pieces]`).
    std::vector<std::string> allow;
    bool allows(const std::string& check) const { return std::find(allow.begin(), allow.end(), check) != allow.end(); }
    /// The first output of @a kind ("mesh", "vdb", "slices", ...) in file order; null when none.
    const OutputSpec* firstOutput(const std::string& kind) const
    {
        const auto it =
            std::find_if(outputs.begin(), outputs.end(), [&](const OutputSpec& o) { return o.kind == kind; });
        return it == outputs.end() ? nullptr : &*it;
    }
    /// Effective parameter values (`params:` defaults after --set), by name.
    std::map<std::string, YAML::Node> params;
    /// The nodes of `fields:` by name (yaml-cpp looks map keys up linearly, converting each).
    std::map<std::string, YAML::Node> fieldIndex;
    /// The fields' design keys (`stiffness:`, `optimize:`), parsed and checked at load, in file
    /// order; a job resolves them (engine/jobs/PropertyDesign) and editField removes them.
    std::vector<FieldDesign> designs;
    /// What trial jobs need to know of each field's spec (PiecesAdvice, a frame's repeated cell,
    /// graded material cards), read at load and kept in step by editField.
    std::map<std::string, FieldFacts> fieldFacts;

    /// The spec of field @a name (throws InputError naming the valid names if absent).
    RecipeNode fieldSpec(const std::string& name) const;
    RecipeNode node(const std::string& key) const;
    /// A path written in the recipe, resolved against the recipe's folder.
    std::filesystem::path resolve(const std::string& path) const;
};

/// Replaces field @a name of @a recipe by its spec with @a edit applied (editedSpec), with its
/// facts read again and its design keys gone from Recipe::designs. The one place after load where
/// a spec changes: solved design targets are written in through it.
void editField(Recipe& recipe, const std::string& name, const FieldEdit& edit);

/// A copy of @a base whose only field (with the fields it reads) and result is @a name, edited by
/// @a edit, with no outputs and no design keys: the job of one trial (a density or sigma search,
/// a frame's repeated cell, a slab of a graded lattice).
Recipe trialRecipe(const Recipe& base, const std::string& name, const FieldEdit& edit);

/// The recipe's top-level keys, with their schemas, defaults and meanings.
const std::vector<KeySpec>& topLevelKeys();
/// The output kinds of `outputs:` (mesh, vdb, slices), each a key with its value's schema.
const std::vector<KeySpec>& outputKinds();

/// Checks an output name of kind @a kind (`mesh`, `vdb`, `slices`): a relative path that stays
/// inside the output folder (no `..`, not absolute) with the kind's extension. Fails at @a node.
void checkOutputName(const RecipeNode& node, const std::string& kind);

/// Reads and validates a recipe file. @a overrides are "key.path=value" strings from --set;
/// values are parsed as YAML (numbers, words, [lists]).
Recipe loadRecipe(const std::string& path, const std::vector<std::string>& overrides = {});

/// Parses recipe text (for tests and for scripting); @a name stands in for the file name.
Recipe parseRecipe(const std::string& text, const std::string& name, const std::filesystem::path& folder,
                   const std::vector<std::string>& overrides = {});

}  // namespace voxlat
