#include "engine/recipe/Schema.h"

#include "engine/recipe/FieldBuilder.h"
#include "fields/TpmsEquations.h"

#include <map>

namespace voxlat {

namespace {

using json = nlohmann::json;

json defRef(const std::string& def)
{
    return {{"$ref", "#/$defs/" + def}};
}
json described(json schema, const std::string& text)
{
    schema["description"] = text;
    return schema;
}
json number(const std::string& text)
{
    return described(defRef("number"), text);
}
json vec3(const std::string& text)
{
    return described(defRef("vec3"), text);
}
json numberOrVec3(const std::string& text)
{
    return described({{"anyOf", {defRef("number"), defRef("vec3")}}}, text);
}
json object(json properties, json required = json::array())
{
    json o = {{"type", "object"}, {"properties", std::move(properties)}, {"additionalProperties", false}};
    if (!required.empty()) o["required"] = std::move(required);
    return o;
}
json fieldList(const std::string& text)
{
    return described({{"type", "array"}, {"items", defRef("field")}, {"minItems", 1}}, text);
}

/// The value schema of each key, by "type.key" (falls back to the bare key). Keys of node types
/// not listed here (added by other families) still appear in the schema, described generically.
const std::map<std::string, json>& keySchemas()
{
    static const std::map<std::string, json> table = [] {
        std::map<std::string, json> t;
        json level = number("c for a network (f <= c), t for a sheet (|f| <= t), in f's units");
        json density = described(defRef("density"), "target relative density in (0, 1); the level is solved");
        json solid = described({{"enum", {"network", "sheet"}}}, "network (f <= level) or sheet (|f| <= level)");
        t["tpms.tpms"] = described({{"enum", tpmsNames()}}, "the surface");
        t["tpms.cell"] = numberOrVec3("cell size in mm, or [x, y, z]");
        t["solid"] = solid;
        t["level"] = level;
        t["density"] = density;
        t["sphere.sphere"] = object(
            {{"center", vec3("centre (mm), default the origin")}, {"radius", number("radius (mm)")}}, {"radius"});
        t["box.box"] = described(defRef("box"), "[[x0, y0, z0], [x1, y1, z1]] (mm)");
        t["cylinder.cylinder"] = object({{"center", vec3("centre (mm)")},
                                         {"axis", vec3("axis direction, default [0, 0, 1]")},
                                         {"radius", number("radius (mm)")},
                                         {"height", number("length along the axis (mm)")}},
                                        {"radius", "height"});
        t["union.union"] = fieldList("fields joined (min)");
        t["intersection.intersection"] = fieldList("fields intersected (max)");
        t["difference.difference"] = fieldList("the first field minus all the others");
        t["blend"] = number("smooth blend radius (mm), 0 = sharp");
        t["translate.translate"] = vec3("offset (mm)");
        t["rotate.rotate"] =
            object({{"axis", vec3("rotation axis")}, {"degrees", number("angle (degrees)")}}, {"axis", "degrees"});
        t["scale.scale"] = numberOrVec3("factor, or [x, y, z]");
        t["field"] = described(defRef("field"), "the field transformed");
        t["mesh.mesh"] = described({{"type", "string"}}, "mesh file (.stl, .obj, .ply, .3mf), relative to the recipe");
        t["mesh.units"] = described({{"enum", {"um", "mm", "cm", "m", "in", "ft"}}}, "the file's length unit");
        t["mesh.repair"] = described({{"type", "boolean"}}, "fill small holes");
        t["shell.shell"] = object({{"part", described(defRef("field"), "the part")},
                                   {"thickness", number("wall thickness inside the surface (mm)")}},
                                  {"part", "thickness"});
        t["infill.infill"] =
            object({{"part", described(defRef("field"), "the part (a mesh or any closed field)")},
                    {"lattice", described(defRef("field"), "the lattice filling the core")},
                    {"skin", number("skin thickness inside the part's surface (mm)")},
                    {"density", described(defRef("density"), "the lattice's share of the space inside the skin")},
                    {"blend", number("smooth-union radius where lattice meets skin (mm)")},
                    {"material_density", number("material density (g/cm^3) for the part's mass")}},
                   {"part", "lattice"});
        t["struts.struts"] = object(
            {{"cell", described(json::object(), "a preset name, {lines: [...]} or {obj: file}")},
             {"size", numberOrVec3("cell size in mm, or [x, y, z]")},
             {"count", described(json::object(), "cells per axis: a number or [x, y, z]")},
             {"origin", vec3("the frame's corner (mm)")},
             {"cylinder", described(json::object(), "{radius, inner, height, base, cells}: a cylinder frame")},
             {"sphere", described(json::object(), "{radius, inner, center, cells}: a spherical frame")},
             {"within", described(defRef("field"), "a solid the uniform frame is trimmed to")},
             {"min_length", number("trimmed pieces shorter than this are dropped (mm)")},
             {"wireframe", described({{"type", "string"}}, "OBJ or CSV file used directly as the frame")},
             {"skin", described(object({{"part", described(defRef("field"), "the part whose skin the cells follow")},
                                        {"depth", described(json::object(),
                                                            "[outer, inner] mm below the surface, or the outer alone")},
                                        {"layers", number("cells across, from the outer to the inner depth")}},
                                       {"part", "depth"}),
                                "cells between two offset surfaces of a part")}});
        t["struts.kernel"] = described(json::object(), "{gaussian: {sigma, cutoff}}, capsule or {capsule: {blend}}");
        // A density may also be a map (ramp, distance, field, file) that grades it point by point.
        const json gradedDensity = described(
            {{"anyOf", {defRef("density"), {{"type", "object"}}, {{"type", "string"}}}}},
            "target relative density in (0, 1): a number (the level is solved) or a map setting it point by point");
        t["tpms.density"] = gradedDensity;
        t["struts.density"] = gradedDensity;
        t["struts.radius"] = described(json::object(), "strut radius (mm): a number, a list or {gradient, min, max, axis}");
        t["expr.expr"] = described({{"type", "string"}}, "an equation in x, y, z, $params and field names");
        t["vector.vector"] = described({{"type", "array"},
                                        {"items", {{"anyOf", {{{"type", "number"}}, {{"type", "string"}}}}}},
                                        {"minItems", 3},
                                        {"maxItems", 3}},
                                       "three components: numbers or equations");
        const json direction = described(json::object(), "a direction: a vector field's name, {vector: [...]} or [x, y, z]");
        const json orientation =
            object({{"along", described(direction, "the cells' z axis, default [0, 0, 1]")},
                    {"x", described(direction, "reference for the cells' x axis (made orthogonal to z)")},
                    {"origin", vec3("the point the cells are rotated about (mm), default the origin")}});
        t["orient.orient"] = described(orientation, "a frame field: the field's axes follow it point by point");
        t["tpms.axes"] = described(orientation, "the cells' axes follow a frame field (as the orient node)");
        return t;
    }();
    return table;
}

}  // namespace

nlohmann::json recipeSchema()
{
    json defs;
    defs["param"] = {{"type", "string"},
                     {"pattern", "^\\$\\{?[A-Za-z_][A-Za-z0-9_]*\\}?$"},
                     {"description", "a reference to a parameter declared under params:"}};
    defs["number"] = {{"anyOf", {{{"type", "number"}}, defRef("param")}}};
    defs["vec3"] = {
        {"anyOf",
         {{{"type", "array"}, {"items", defRef("number")}, {"minItems", 3}, {"maxItems", 3}}, defRef("param")}}};
    defs["box"] = {{"type", "array"}, {"items", defRef("vec3")}, {"minItems", 2}, {"maxItems", 2}};
    defs["density"] = {
        {"anyOf", {{{"type", "number"}, {"exclusiveMinimum", 0}, {"exclusiveMaximum", 1}}, defRef("param")}}};
    defs["field"] = {{"anyOf", {{{"type", "string"}, {"description", "the name of a field"}}, defRef("node")}}};

    json nodes = json::array();
    for (const NodeType& type : FieldBuilder::nodeTypes()) {
        json properties = json::object();
        for (const std::string& key : type.keys) {
            const auto& table = keySchemas();
            auto it = table.find(type.key + "." + key);
            if (it == table.end()) it = table.find(key);
            properties[key] = it != table.end() ? it->second : json{{"description", "see docs/recipes.md"}};
        }
        defs["node_" + type.key] = object(properties, {type.key});
        nodes.push_back(defRef("node_" + type.key));
    }
    defs["node"] = {{"oneOf", nodes}, {"description", "a field node: exactly one node-type key"}};

    json params = {{"type", "object"},
                   {"propertyNames", {{"pattern", "^[A-Za-z_][A-Za-z0-9_]*$"}}},
                   {"additionalProperties",
                    {{"anyOf",
                      {{{"type", {"number", "string", "boolean", "array"}}},
                       object({{"default", json::object()},
                               {"min", {{"type", "number"}}},
                               {"max", {{"type", "number"}}},
                               {"doc", {{"type", "string"}}}},
                              {"default"})}}}}};
    json stringOrList = {{"anyOf", {{{"type", "string"}}, {{"type", "array"}, {"items", {{"type", "string"}}}}}}};
    json top = object({{"voxel", number("voxel size (mm), default 0.1")},
                       {"domain", object({{"box", defRef("box")}}, {"box"})},
                       {"fields", {{"type", "object"}, {"additionalProperties", defRef("node")}}},
                       {"result", {{"type", "string"}, {"description", "the field meshed and measured"}}},
                       {"outputs", object({{"mesh", stringOrList}, {"vdb", {{"type", "string"}}}})},
                       {"params", described(params, "parameters with defaults, referenced as $name")},
                       {"include", described(stringOrList, "recipe libraries whose params and fields are merged")}},
                      {"result"});
    top["$schema"] = "https://json-schema.org/draft/2020-12/schema";
    top["$id"] = "https://voxlat.example/recipe.schema.json";
    top["title"] = "voxlat recipe";
    top["$defs"] = defs;
    return top;
}

}  // namespace voxlat
