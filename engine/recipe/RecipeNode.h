/// @file RecipeNode.h
/// @brief Typed access to a recipe's YAML nodes with errors that name file, line and fix.
#pragma once

#include "engine/core/Errors.h"
#include "fields/core/FieldNode.h"

#include <yaml-cpp/yaml.h>

#include <initializer_list>
#include <memory>
#include <string>
#include <vector>

namespace voxlat {

/// Where a recipe came from: used in every message about it.
struct RecipeSource {
    std::string path;                   ///< as the user gave it
    std::vector<YAML::Node> overrides;  ///< nodes set from the command line (--set), with their children
    /// Nodes merged from `include:` files, with the file each came from.
    std::vector<std::pair<YAML::Node, std::string>> included;
    /// Nodes that replaced a `$name` reference, with "file:line:col (`$name`, declared at ...)".
    std::vector<std::pair<YAML::Node, std::string>> substituted;
};

/// A YAML node plus the file it came from and a human description of where it sits
/// ("field `lattice`"). All getters throw InputError with "file:line:col: ..." messages.
class RecipeNode {
public:
    RecipeNode(YAML::Node node, std::shared_ptr<const RecipeSource> source, std::string context);

    const YAML::Node& yaml() const { return mNode; }
    const std::string& context() const { return mContext; }
    bool isMap() const { return mNode.IsMap(); }
    bool isSequence() const { return mNode.IsSequence(); }
    bool isScalar() const { return mNode.IsScalar(); }
    /// A scalar that reads as a number (so a key may take a number or something richer).
    bool isNumber() const;
    bool has(const std::string& key) const { return mNode.IsMap() && mNode[key]; }

    /// The child at @a key (must exist unless optional; check has() first for optional keys).
    RecipeNode operator[](const std::string& key) const;
    RecipeNode at(std::size_t index) const;
    std::size_t size() const { return mNode.size(); }

    double number() const;
    double positiveNumber() const;
    /// `x`, `y` or `z` as 0, 1 or 2.
    int axis() const;
    std::string string() const;
    bool boolean() const;
    Vec3d vec3() const;
    /// A number (the same on every axis) or a list of three.
    Vec3d scalarOrVec3() const;
    Box3 box() const;  ///< [[x0, y0, z0], [x1, y1, z1]] with min < max on every axis

    /// Rejects any key not in @a allowed, suggesting the closest valid one.
    void checkKeys(const std::vector<std::string>& allowed) const;
    /// "file:line:col" of this node ("file (from --set)" for overrides).
    std::string where() const;
    [[noreturn]] void fail(const std::string& message) const;

private:
    YAML::Node mNode;
    std::shared_ptr<const RecipeSource> mSource;
    std::string mContext;
};

/// "a, b, c": for lists of valid names in messages.
std::string joinWords(const std::vector<std::string>& words);

/// The valid word closest to @a word by edit distance, or "" if none is close.
std::string closestMatch(const std::string& word, const std::vector<std::string>& candidates);

/// Refuses YAML that expands past kMaxYamlNodes nodes (aliases counted each time they are used: a
/// few hundred bytes of nested aliases can stand for billions of nodes) or nests deeper than
/// kMaxYamlDepth. Stops counting at the limit, so the check itself stays cheap.
inline constexpr std::size_t kMaxYamlNodes = 1'000'000;
inline constexpr int kMaxYamlDepth = 64;
void checkYamlSize(const YAML::Node& root, const std::string& name);

/// Parses one YAML document of a user's file @a name (a recipe, an include, a printer profile):
/// InputError with name:line:col for bad YAML, a second document, a key given twice in one map,
/// or a tree past checkYamlSize's limits.
YAML::Node loadYaml(const std::string& text, const std::string& name);

}  // namespace voxlat
