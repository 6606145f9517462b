#include "engine/recipe/Recipe.h"

#include "engine/core/InputFiles.h"

#include "engine/recipe/MeshSettings.h"
#include "engine/recipe/RecipeParams.h"
#include "engine/recipe/SliceSettings.h"

#include <algorithm>
#include <fstream>
#include <map>
#include <sstream>

namespace voxlat {

namespace {

/// A recipe is text of a few kilobytes; 16 MB leaves room for long value lists.
constexpr std::uintmax_t kMaxRecipeBytes = std::uintmax_t(16) << 20;

const std::vector<std::string> kTopKeys = keyNames(topLevelKeys());
const std::vector<std::string> kOutputKeys = keyNames(outputKinds());

/// Records @a node and everything below it as set from the command line.
void collectNodes(const YAML::Node& node, std::vector<YAML::Node>& out)
{
    out.push_back(node);
    if (node.IsSequence() || node.IsMap())
        for (auto it = node.begin(); it != node.end(); ++it) {
            if (node.IsMap()) {
                out.push_back(it->first);
                collectNodes(it->second, out);
            } else {
                collectNodes(*it, out);
            }
        }
}

/// Applies one --set override "a.b.c=value" to the YAML tree.
void applyOverride(YAML::Node root, const std::string& assignment, const std::string& path,
                   std::vector<YAML::Node>& overrides)
{
    const auto eq = assignment.find('=');
    if (eq == std::string::npos || eq == 0)
        throw InputError(path + ": --set " + assignment + ": expected KEY=VALUE, for example --set voxel=0.2");
    const std::string key = assignment.substr(0, eq), value = assignment.substr(eq + 1);
    std::vector<std::string> parts;
    std::stringstream ss(key);
    for (std::string part; std::getline(ss, part, '.');) parts.push_back(part);
    YAML::Node parsed;
    try {
        parsed = YAML::Load(value);
    } catch (const YAML::Exception& e) {
        throw InputError(path + ": --set " + assignment + ": cannot read the value: " + e.msg);
    }
    // Walk with copies of the handles (yaml-cpp nodes are references into one tree).
    std::vector<YAML::Node> chain{root};
    for (std::size_t i = 0; i + 1 < parts.size(); ++i) {
        YAML::Node next = chain.back()[parts[i]];
        if (!next.IsDefined() || !next.IsMap()) {
            chain.back()[parts[i]] = YAML::Node(YAML::NodeType::Map);
            next = chain.back()[parts[i]];
        }
        chain.push_back(next);
    }
    chain.back()[parts.back()] = parsed;
    collectNodes(chain.back()[parts.back()], overrides);
}

/// Fails at the second of two outputs that would write one file (their own files, their side
/// files or report.json), naming both: a run writes all its outputs or none, so it must not
/// find out half-way.
void refuseCollidingOutputs(const Recipe& r, const RecipeNode& outputs)
{
    std::map<std::string, std::string> writer;  // normal path -> who writes it
    writer["report.json"] = "the run's report";
    writer["report.html"] = "the run's page";
    auto where = [&](const OutputSpec& o) {
        const YAML::Mark m = o.spec.Mark();
        return m.line >= 0 ? r.source->path + ":" + std::to_string(m.line + 1) + ":" + std::to_string(m.column + 1)
                           : r.source->path;
    };
    for (const OutputSpec& o : r.outputs) {
        std::vector<std::pair<std::string, std::string>> files{{o.file, "the " + o.kind + " output `" + o.file + "`"}};
        for (const std::string& side : o.sideFiles)
            files.push_back({side, "the side file `" + side + "` of the " + o.kind + " output `" + o.file + "`"});
        for (const auto& [file, who] : files) {
            const std::string key = std::filesystem::path(file).lexically_normal().string();
            const std::string by = who + " (" + where(o) + ")";
            const auto [it, fresh] = writer.emplace(key, by);
            if (!fresh)
                outputs.fail("two outputs write `" + key + "`: " + it->second + " and " + by +
                             "; give each output its own file name");
        }
    }
}

Recipe build(YAML::Node root, const std::string& name, const std::filesystem::path& folder,
             const std::vector<std::string>& overrides)
{
    Recipe r;
    r.source = std::make_shared<RecipeSource>();
    r.source->path = name;
    r.folder = folder;
    if (!root.IsDefined() || root.IsNull()) throw InputError(name + ": the recipe is empty");
    if (!root.IsMap())
        throw InputError(name + ":1:1: a recipe is a map of keys (voxel, domain, fields, result, outputs)");
    // `--set include=FILE` names what is merged: applied before the merge (after it, the key
    // would be set and never read).
    auto setsInclude = [](const std::string& o) { return o.rfind("include=", 0) == 0 || o.rfind("include.", 0) == 0; };
    for (const std::string& o : overrides)
        if (setsInclude(o)) applyOverride(root, o, name, r.source->overrides);
    mergeIncludes(root, name, folder, *r.source);
    const auto declared = declaredParams(root, r.source);
    for (const std::string& o : overrides)
        if (!setsInclude(o)) applyOverride(root, routeAssignment(root, o, name, kTopKeys), name, r.source->overrides);
    r.params = substituteParams(root, r.source, declared);
    r.root = root;

    const RecipeNode top(root, r.source, "recipe");
    top.checkKeys(kTopKeys);
    if (top.has("voxel")) r.voxel = top["voxel"].positiveNumber();
    r.voxelWhere = top.has("voxel") ? top["voxel"].where() : r.source->path;
    r.domainWhere = top.has("domain") ? top["domain"].where() : r.source->path;
    if (top.has("domain")) {
        const RecipeNode domain = top["domain"];
        domain.checkKeys({"box"});
        r.domainBox = domain["box"].box();
        for (int a = 0; a < 3; ++a)
            if (r.voxel > r.domainBox->extent()[a])
                top["voxel"].fail("the voxel (" + std::to_string(r.voxel) +
                                  ") is larger than the domain; use a voxel well below the smallest domain side (" +
                                  std::to_string(r.domainBox->extent()[a]) + ")");
    }
    const RecipeNode fields = top["fields"];
    if (!fields.isMap() || fields.size() == 0)
        fields.fail("expected a map of named fields, like `lattice: {tpms: gyroid, cell: 10}`");
    for (auto it = root["fields"].begin(); it != root["fields"].end(); ++it) {
        r.fieldNames.push_back(it->first.Scalar());
        r.fieldIndex.emplace(it->first.Scalar(), it->second);
    }

    if (!top.has("result"))
        top.fail(
            "missing key `result`: name the field the recipe makes, like `result: lattice` (a file of "
            "fields without one is a library: `include:` it from a recipe)");
    const RecipeNode result = top["result"];
    r.result = result.string();
    r.fieldSpec(r.result);  // must name a field

    if (top.has("allow")) {
        const RecipeNode allow = top["allow"];
        if (!allow.isSequence()) allow.fail("expected a list of checks, like `allow: [pieces]`");
        for (std::size_t i = 0; i < allow.size(); ++i) {
            const std::string word = allow.at(i).string();
            if (word != "pieces")
                allow.at(i).fail("unknown check `" + word +
                                 "` (pieces: a result in several pieces is a warning instead of an error)");
            r.allow.push_back(word);
        }
    }
    if (top.has("material")) r.material = parseMaterial(top["material"]);
    if (top.has("properties")) {
        const RecipeNode properties = top["properties"];
        r.properties = parseProperties(&properties, name);
    } else {
        r.properties = parseProperties(nullptr, name);
    }
    if (top.has("outputs")) {
        const RecipeNode outputs = top["outputs"];
        outputs.checkKeys(kOutputKeys);
        for (const std::string& kind : kOutputKeys) {
            if (!outputs.has(kind)) continue;
            const RecipeNode entry = outputs[kind];
            if (kind == "slices") {  // a map (or a list of maps) of slice settings
                for (std::size_t i = 0; i < (entry.isSequence() ? entry.size() : 1); ++i) {
                    const RecipeNode one = entry.isSequence() ? entry.at(i) : entry;
                    SliceSettings settings = parseSliceSettings(one);  // parsed and checked once, here
                    checkOutputName(one["file"], kind);
                    OutputSpec out{kind, one["file"].string(), one.yaml(), one.where()};
                    if (settings.preview != "off")
                        out.sideFiles.push_back(
                            settings.preview.empty()
                                ? out.file + ".preview.png"
                                : (std::filesystem::path(out.file).parent_path() / settings.preview).string());
                    out.slices = std::move(settings);
                    r.outputs.push_back(std::move(out));
                }
                continue;
            }
            for (std::size_t i = 0; i < (entry.isSequence() ? entry.size() : 1); ++i) {
                const RecipeNode one = entry.isSequence() ? entry.at(i) : entry;
                if (kind == "mesh") {                                // a file name or a map of mesh settings
                    MeshSettings settings = parseMeshSettings(one);  // parsed and checked once, here
                    OutputSpec out{kind, settings.file, one.yaml(), one.where()};
                    out.mesh = std::move(settings);
                    if (!r.firstOutput("mesh")) out.sideFiles.push_back(out.file + ".preview.png");
                    r.outputs.push_back(std::move(out));
                    continue;
                }
                checkOutputName(one, kind);
                // A frame output keeps its node: without struts the job names its line.
                OutputSpec out{kind, one.string(), one.yaml(), one.where()};
                if (kind == "properties")
                    out.sideFiles.push_back(std::filesystem::path(out.file).replace_extension(".png").string());
                r.outputs.push_back(std::move(out));
            }
        }
        refuseCollidingOutputs(r, outputs);
    }
    // Design keys and the facts trial jobs read, once, here: jobs read no field YAML for them.
    for (const std::string& field : r.fieldNames) {
        const YAML::Node& spec = r.fieldIndex.at(field);
        r.fieldFacts[field] = readFieldFacts(spec);
        const RecipeNode node(spec, r.source, "field `" + field + "`");
        if (std::optional<FieldDesign> design = parseFieldDesign(node, field, r.material))
            r.designs.push_back(std::move(*design));
    }
    return r;
}

}  // namespace

void checkOutputName(const RecipeNode& node, const std::string& kind)
{
    const std::string name = node.string();
    const std::filesystem::path path(name);
    if (name.empty() || path.is_absolute() || name.front() == '~')
        node.fail("an output name is a path inside the output folder (--out), like `part.stl`; `" + name + "` is not");
    for (const auto& part : path)
        if (part == "..")
            node.fail("an output stays inside the output folder (--out): `" + name + "` climbs out of it with `..`");
    const std::string ext = path.extension().string();
    if (kind == "mesh" && ext != ".stl" && ext != ".3mf" && ext != ".ply" && ext != ".obj")
        node.fail("a mesh file ends in .stl, .3mf, .ply or .obj; `" + name + "` does not");
    if (kind == "vdb" && ext != ".vdb") node.fail("a vdb output ends in .vdb; `" + name + "` does not");
    if (kind == "frame" && ext != ".csv" && ext != ".obj" && ext != ".3mf")
        node.fail("a frame file ends in .csv (x1,y1,z1,x2,y2,z2,r1,r2), .obj (v / l) or .3mf (beam lattice); `" + name +
                  "` does not");
    if (kind == "properties" && ext != ".json")
        node.fail("a properties output ends in .json (the numbers; a picture NAME.png is written next to it); `" +
                  name + "` does not");
}

const std::vector<KeySpec>& topLevelKeys()
{
    using namespace valueSchema;
    static const std::vector<KeySpec> keys{
        {"voxel", number(), "voxel size (mm); must be below the smallest domain side", "0.1"},
        {"domain", object({{"box", box(), "[[x0, y0, z0], [x1, y1, z1]] (mm)", "required"}}, {"box"}),
         "{box: [[x0, y0, z0], [x1, y1, z1]]}; snapped to a whole number of voxels",
         "the result's bounding box plus 3 voxels"},
        {"fields",
         {{"type", "object"}, {"additionalProperties", ref("node")}},
         "map of name -> node; names are referred to by other nodes",
         "required"},
        {"result", string(), "the name of the field that is meshed and measured", "required"},
        {"outputs", object(outputKinds()), "what to write: mesh, vdb, slices, properties", "none (report only)"},
        {"params", ref("params"), "named parameters with defaults, used anywhere as $name", "none"},
        {"include", stringOrList(), "recipe libraries whose params: and fields: are merged in", "none"},
        {"material",
         {{"anyOf", {oneOfWords({"form2", "ti6al4v", "316l", "17-4ph", "pa12"}), object(materialKeys())}}},
         "what the part is made of: a named material or {E: 1.6 GPa, nu: 0.38, k: 0.2}; needed by properties",
         "none"},
        {"properties", object(propertiesKeys()),
         "the periodic cell that `voxlat properties` and a `properties:` output homogenize",
         "one period of the result"},
        {"allow",
         {{"type", "array"}, {"items", oneOfWords({"pieces"})}},
         "checks that warn instead of failing: pieces (a result with pieces floating free, e.g. a plate of "
         "separate parts)",
         "none"}};
    return keys;
}

const std::vector<KeySpec>& outputKinds()
{
    using namespace valueSchema;
    static const std::vector<KeySpec> kinds{
        {"mesh",
         {{"anyOf", {string(), ref("mesh"), {{"type", "array"}, {"items", {{"anyOf", {string(), ref("mesh")}}}}}}}},
         "mesh file(s): .stl, .3mf, .ply or .obj, by extension; a map (or a list of names and maps) of mesh "
         "settings for vertices on the true surface and error-bounded decimation",
         "—"},
        {"vdb", string(), "the result's sparse grid as an OpenVDB file (.vdb)", "—"},
        {"slices",
         {{"anyOf", {ref("slices"), {{"type", "array"}, {"items", ref("slices")}}}}},
         "resin-printer slices: a map (or a list of maps) of slice settings",
         "—"},
        {"frame",
         {{"anyOf", {string(), {{"type", "array"}, {"items", string()}}}}},
         "the strut frame (nodes, struts, radii at the solved level): .csv (x1,y1,z1,x2,y2,z2,r1,r2 per strut), "
         ".obj (v / l) or .3mf (Beam Lattice extension)",
         "—"},
        {"properties", string(),
         "effective stiffness and conductivity of one periodic cell (.json, and a picture of the directional Young's "
         "modulus next to it as .png); needs `material:`",
         "—"}};
    return kinds;
}

RecipeNode Recipe::node(const std::string& key) const
{
    return RecipeNode(root, source, "recipe")[key];
}

RecipeNode Recipe::fieldSpec(const std::string& name) const
{
    if (auto it = fieldIndex.find(name); it != fieldIndex.end())
        return RecipeNode(it->second, source, "field `" + name + "`");
    const RecipeNode fields = node("fields");
    if (!fields.has(name)) {
        std::string message = "no field named `" + name + "`";
        const std::string guess = closestMatch(name, fieldNames);
        if (!guess.empty()) message += "; did you mean `" + guess + "`?";
        fields.fail(message + " (fields: " + joinWords(fieldNames) + ")");
    }
    return RecipeNode(root["fields"][name], source, "field `" + name + "`");
}

std::filesystem::path Recipe::resolve(const std::string& path) const
{
    const std::filesystem::path p(path);
    return p.is_absolute() ? p : folder / p;
}

Recipe parseRecipe(const std::string& text, const std::string& name, const std::filesystem::path& folder,
                   const std::vector<std::string>& overrides)
{
    return build(loadYaml(text, name), name, folder, overrides);
}

Recipe loadRecipe(const std::string& path, const std::vector<std::string>& overrides)
{
    const std::string text = readInputFile(path, kMaxRecipeBytes, "recipe file");
    const std::filesystem::path folder = std::filesystem::absolute(path).parent_path();
    return parseRecipe(text, path, folder, overrides);
}

}  // namespace voxlat
