#include "engine/recipe/Schema.h"

#include "engine/recipe/FieldBuilder.h"
#include "engine/recipe/MeshSettings.h"
#include "engine/recipe/SliceSettings.h"

#include <sstream>

namespace voxlat {

namespace {

using json = nlohmann::json;

/// A KeySpec's schema with its meaning as the description.
json describedKey(const KeySpec& k)
{
    json s = k.schema;
    s["description"] = k.meaning + (k.defaultValue.empty() || k.defaultValue == "—" || k.defaultValue == "required"
                                        ? ""
                                        : " (default: " + k.defaultValue + ")");
    return s;
}

json keysObject(const std::vector<KeySpec>& keys, const std::vector<std::string>& required)
{
    json properties = json::object();
    for (const KeySpec& k : keys) properties[k.name] = describedKey(k);
    json o = {{"type", "object"}, {"properties", std::move(properties)}, {"additionalProperties", false}};
    if (!required.empty()) o["required"] = required;
    return o;
}

std::vector<std::string> requiredOf(const std::vector<KeySpec>& keys)
{
    std::vector<std::string> names;
    for (const KeySpec& k : keys)
        if (k.defaultValue == "required") names.push_back(k.name);
    return names;
}

/// A table cell: pipes escaped.
std::string cell(const std::string& text)
{
    std::string out;
    for (char c : text) out += c == '|' ? std::string("\\|") : std::string(1, c);
    return out;
}

void markdownTable(std::ostringstream& md, const std::vector<KeySpec>& keys)
{
    md << "| key | meaning | default |\n| --- | --- | --- |\n";
    for (const KeySpec& k : keys)
        md << "| `" << k.name << "` | " << cell(k.meaning) << " | " << cell(k.defaultValue) << " |\n";
}

}  // namespace

nlohmann::json recipeSchema()
{
    using valueSchema::ref;
    json defs;
    defs["param"] = {{"type", "string"},
                     {"pattern", "^\\$\\{?[A-Za-z_][A-Za-z0-9_]*\\}?$"},
                     {"description", "a reference to a parameter declared under params:"}};
    defs["number"] = {{"anyOf", {{{"type", "number"}}, ref("param")}}};
    defs["vec3"] = {
        {"anyOf", {{{"type", "array"}, {"items", ref("number")}, {"minItems", 3}, {"maxItems", 3}}, ref("param")}}};
    defs["box"] = {{"type", "array"}, {"items", ref("vec3")}, {"minItems", 2}, {"maxItems", 2}};
    defs["density"] = {
        {"anyOf", {{{"type", "number"}, {"exclusiveMinimum", 0}, {"exclusiveMaximum", 1}}, ref("param")}}};
    defs["field"] = {{"anyOf", {{{"type", "string"}, {"description", "the name of a field"}}, ref("node")}}};
    defs["slices"] = keysObject(sliceKeys(), requiredOf(sliceKeys()));
    defs["mesh"] = keysObject(meshKeys(), requiredOf(meshKeys()));
    defs["params"] = {{"type", "object"},
                      {"propertyNames", {{"pattern", "^[A-Za-z_][A-Za-z0-9_]*$"}}},
                      {"additionalProperties",
                       {{"anyOf",
                         {{{"type", {"number", "string", "boolean", "array"}}},
                          {{"type", "object"},
                           {"properties",
                            {{"default", json::object()},
                             {"min", {{"type", "number"}}},
                             {"max", {{"type", "number"}}},
                             {"doc", {{"type", "string"}}}}},
                           {"required", {"default"}},
                           {"additionalProperties", false}}}}}}};

    json nodes = json::array();
    for (const NodeType& type : FieldBuilder::nodeTypes()) {
        defs["node_" + type.key] = keysObject(type.keys, {type.key});
        nodes.push_back(valueSchema::ref("node_" + type.key));
    }
    defs["node"] = {{"oneOf", nodes}, {"description", "a field node: exactly one node-type key"}};

    // `result:` is required of a recipe that runs; a file of fields alone is a library for include:.
    json top = keysObject(topLevelKeys(), {});
    top["$schema"] = "https://json-schema.org/draft/2020-12/schema";
    top["$id"] = "https://voxlat.example/recipe.schema.json";
    top["title"] = "voxlat recipe";
    top["$defs"] = defs;
    return top;
}

std::string recipeKeysMarkdown()
{
    std::ostringstream md;
    md << "### Top level\n\n";
    markdownTable(md, topLevelKeys());
    md << "\n### `outputs`\n\n";
    markdownTable(md, outputKinds());
    md << "\n### `outputs: {mesh: {...}}`\n\n";
    markdownTable(md, meshKeys());
    md << "\n### `outputs: {slices: ...}`\n\n";
    markdownTable(md, sliceKeys());
    for (const NodeType& type : FieldBuilder::nodeTypes()) {
        md << "\n### `" << type.key << "`\n\n";
        markdownTable(md, type.keys);
    }
    return md.str();
}

}  // namespace voxlat
