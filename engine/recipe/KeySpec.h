/// @file KeySpec.h
/// @brief One key of the recipe language: its value's JSON Schema, default and one-line meaning.
/// Node types, outputs and the top level list their keys as KeySpecs; the key check, the JSON
/// Schema (`voxlat schema`) and the docs' key reference (`voxlat schema --markdown`) all come
/// from these lists, so a key is written once.
#pragma once

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace voxlat {

struct KeySpec {
    std::string name;
    nlohmann::json schema;     ///< the value's JSON Schema (refs into recipeSchema()'s $defs)
    std::string meaning;       ///< one line, for the schema's description and the docs
    std::string defaultValue;  ///< as the docs show it; "required" or "—" (none) where there is none
};

/// The names of @a keys, for RecipeNode::checkKeys().
inline std::vector<std::string> keyNames(const std::vector<KeySpec>& keys)
{
    std::vector<std::string> names;
    names.reserve(keys.size());
    for (const KeySpec& k : keys) names.push_back(k.name);
    return names;
}

/// Value schemas shared by the key lists (the $defs they refer to are defined by recipeSchema()).
namespace valueSchema {
using json = nlohmann::json;
inline json ref(const std::string& def)
{
    return {{"$ref", "#/$defs/" + def}};
}
inline json number()
{
    return ref("number");
}
inline json vec3()
{
    return ref("vec3");
}
inline json box()
{
    return ref("box");
}
inline json density()
{
    return ref("density");
}
inline json field()
{
    return ref("field");
}
inline json numberOrVec3()
{
    return {{"anyOf", {ref("number"), ref("vec3")}}};
}
inline json string()
{
    return {{"type", "string"}};
}
inline json boolean()
{
    return {{"type", "boolean"}};
}
inline json anyMap()
{
    return {{"type", "object"}};
}
inline json anything()
{
    return json::object();
}
inline json oneOfWords(const std::vector<std::string>& words)
{
    return {{"enum", words}};
}
inline json stringOrList()
{
    return {{"anyOf", {string(), {{"type", "array"}, {"items", string()}}}}};
}
inline json fieldList()
{
    return {{"type", "array"}, {"items", ref("field")}, {"minItems", 1}};
}
/// A map with exactly @a keys (each described by its meaning), @a required among them.
inline json object(const std::vector<KeySpec>& keys, const std::vector<std::string>& required = {})
{
    json properties = json::object();
    for (const KeySpec& k : keys) {
        json s = k.schema;
        if (!k.meaning.empty()) s["description"] = k.meaning;
        properties[k.name] = std::move(s);
    }
    json o = {{"type", "object"}, {"properties", std::move(properties)}, {"additionalProperties", false}};
    if (!required.empty()) o["required"] = required;
    return o;
}
}  // namespace valueSchema

}  // namespace voxlat
