// The recipe language: parameters and --set, includes, equations and vector fields in recipes,
// the canonical hashed copy, the JSON Schema against the node table and docs/recipes.md, and
// every ```yaml example of the docs run as a recipe (blocks tagged ```yaml <kind>, such as
// `printer-profile`, show other file formats and are left out).
#include "RecipeErrors.h"
#include "TestUtil.h"
#include "engine/jobs/Job.h"
#include "engine/recipe/ExprNodes.h"
#include "engine/recipe/FieldBuilder.h"
#include "engine/recipe/Recipe.h"
#include "engine/recipe/RecipeParams.h"
#include "engine/recipe/Schema.h"
#include "engine/recipe/Sha256.h"
#include "fields/maps/VectorField.h"
#include "fields/tpms/TpmsField.h"

#include <gtest/gtest.h>

#include <regex>
#include <set>

using namespace voxlat;
using namespace voxlat::test;

namespace {

const char* kParams = R"(# a parameterised gyroid
params:
  cell: 5
  t: {default: 0.4, min: 0.05, max: 1.2, doc: sheet half-thickness}
  name: part
voxel: 0.5
domain: {box: [[0, 0, 0], [10, 10, 10]]}
fields:
  lattice: {tpms: gyroid, cell: $cell, solid: sheet, level: $t}
  ball: {sphere: {center: [5, 5, 5], radius: 4}}
  shaped: {expr: "max(lattice, ball) + 0 * $cell"}
result: shaped
outputs: {mesh: "${name}_${cell}.stl"}
allow: [pieces]
)";

std::string recipeWith(const std::string& fields, const std::string& result = "f")
{
    return "voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n" + fields + "result: " + result + "\n";
}

#define EXPECT_HAS(text, part) EXPECT_NE(std::string(text).find(part), std::string::npos) << (text)

}  // namespace

TEST(RecipeLanguage, ParamsAreSubstitutedEverywhere)
{
    const Recipe r = parseRecipe(kParams, "p.yaml", ".");
    EXPECT_EQ(r.fieldSpec("lattice")["cell"].number(), 5.0);
    EXPECT_EQ(r.fieldSpec("lattice")["level"].number(), 0.4);
    ASSERT_EQ(r.outputs.size(), 1u);
    EXPECT_EQ(r.outputs[0].file, "part_5.stl");
    Job job(r);
    const auto field = job.field("shaped");
    const TpmsField gyroid(TpmsType::Gyroid, Vec3d(5.0));
    for (const Vec3d& p : {Vec3d(1, 2, 3), Vec3d(5, 5, 5), Vec3d(9.5, 0.2, 4)}) {
        const double ball = (p - Vec3d(5, 5, 5)).length() - 4;
        EXPECT_NEAR(field->value(p), std::max(std::abs(gyroid.value(p)) - 0.4, ball), 1e-12);
    }
}

TEST(RecipeLanguage, SetOverridesParamsAndKeyPaths)
{
    const Recipe r = parseRecipe(kParams, "p.yaml", ".", {"cell=6", "t=0.3", "voxel=0.25"});
    EXPECT_EQ(r.fieldSpec("lattice")["cell"].number(), 6.0);
    EXPECT_EQ(r.fieldSpec("lattice")["level"].number(), 0.3);
    EXPECT_EQ(r.voxel, 0.25);
    EXPECT_EQ(r.outputs[0].file, "part_6.stl");
    EXPECT_EQ(parseRecipe(kParams, "p.yaml", ".", {"params.cell=7"}).fieldSpec("lattice")["cell"].number(), 7.0);
    // A key path still wins over the parameter where it is used.
    EXPECT_EQ(
        parseRecipe(kParams, "p.yaml", ".", {"fields.lattice.cell=[4, 5, 6]"}).fieldSpec("lattice")["cell"].vec3(),
        Vec3d(4, 5, 6));
    // Wrong type, out of range, unknown name.
    const std::string type = errorOf(kParams, {"cell=abc"});
    EXPECT_HAS(type,
               "bad.yaml (from --set): parameter `cell`: expected a number like its default (declared at "
               "bad.yaml:3:9), got `abc`");
    EXPECT_HAS(errorOf(kParams, {"t=5"}), "parameter `t`: must be at most 1.2");
    const std::string unknown = errorOf(kParams, {"cel=6"});
    EXPECT_HAS(unknown, "no parameter or top-level key `cel`; did you mean `cell`?");
    EXPECT_HAS(unknown, "parameters: cell, t, name");
    EXPECT_HAS(errorOf(kParams, {"params.size=3"}), "declares no parameter `size`");
}

TEST(RecipeLanguage, ParamErrorsNameTheUse)
{
    std::string text = kParams;
    text.replace(text.find("cell: $cell"), 11, "cell: $cel");
    const std::string e = errorOf(text);
    EXPECT_HAS(e, "bad.yaml:9:33: parameter reference: unknown parameter `$cel`; did you mean `$cell`?");
    // A parameter used where a number is needed, holding a word: the use site and the declaration.
    const std::string word = errorOf(kParams, {"fields.lattice.cell=$name"});
    EXPECT_HAS(word, "(`$name`, declared at bad.yaml:5:9)");
    EXPECT_HAS(word, "expected a number, got `part`");
    // In an equation the parameter must be a number too.
    std::string eq = kParams;
    eq.replace(eq.find("0 * $cell"), 9, "0 * $name");
    EXPECT_HAS(errorOf(eq), "parameter `$name` is `part`, not a number");
    EXPECT_HAS(errorOf(recipeWith("  f: {expr: \"x - cell\"}\n") + "params: {cell: 3}\n"),
               "`cell` is a parameter: write `$cell`");
}

TEST(RecipeLanguage, IncludesMergeParamsAndFields)
{
    TempDir dir;
    std::filesystem::create_directories(dir.path / "lib");
    dir.write(
        "lib/cells.yaml",
        "params: {cell: 4, wall: 0.3}\nfields:\n  cellwall: {tpms: gyroid, cell: $cell, solid: sheet, level: $wall}\n"
        "  bad: {sphere: {radius: -1}}\n");
    dir.write(
        "lib/good.yaml",
        "params: {cell: 4, wall: 0.3}\nfields:\n  cellwall: {tpms: gyroid, cell: $cell, solid: sheet, level: $wall}\n");
    const std::string main = "include: [lib/good.yaml]\nparams: {cell: 6}\n" +
                             recipeWith("  f: {intersection: [cellwall, {sphere: {center: [5, 5, 5], radius: 4}}]}\n");
    const Recipe r = parseRecipe(main, "main.yaml", dir.path);
    EXPECT_EQ(r.fieldSpec("cellwall")["cell"].number(), 6.0);  // the including recipe's default wins
    EXPECT_EQ(r.fieldSpec("cellwall")["level"].number(), 0.3);
    EXPECT_EQ(errorOf(main, {}, dir.path), "");
    EXPECT_EQ(parseRecipe(main, "main.yaml", dir.path, {"wall=0.2"}).fieldSpec("cellwall")["level"].number(), 0.2);
    // An error inside the included file names that file and line.
    std::string withBad = main;
    withBad.replace(withBad.find("good.yaml"), 9, "cells.yaml");
    EXPECT_HAS(errorOf(withBad, {}, dir.path), (dir.path / "lib/cells.yaml").string() + ":4:");
    EXPECT_HAS(errorOf("include: [nothere.yaml]\n" + recipeWith("  f: {sphere: {radius: 1}}\n"), {}, dir.path),
               "bad.yaml:1:11: `include` item 1: cannot find");
    EXPECT_HAS(errorOf("include: [/etc/passwd]\n" + recipeWith("  f: {sphere: {radius: 1}}\n"), {}, dir.path),
               "ending in .yaml or .yml");
    dir.write("lib/a.yaml", "include: [b.yaml]\nfields: {fa: {sphere: {radius: 1}}}\n");
    dir.write("lib/b.yaml", "include: [a.yaml]\nfields: {fb: {sphere: {radius: 1}}}\n");
    EXPECT_HAS(errorOf("include: lib/a.yaml\n" + recipeWith("  f: {sphere: {radius: 1}}\n"), {}, dir.path),
               "includes form a cycle: ");
    EXPECT_HAS(errorOf("include: lib/good.yaml\n" + recipeWith("  cellwall: {sphere: {radius: 1}}\n", "cellwall"), {},
                       dir.path),
               "field `cellwall` is also defined by the recipe that includes this file");
    EXPECT_HAS(errorOf("include: lib/good.yaml\nfields: {}\nresult: x\n", {}, dir.path), "no field named `x`");
}

TEST(RecipeLanguage, EquationErrorsShowACaret)
{
    const std::string syntax = errorOf(recipeWith("  f: {expr: \"sin(x) * (y + 2\"}\n"));
    EXPECT_HAS(
        syntax,
        "bad.yaml:4:13: field `f` `expr`: equation: expected `)` to close the `(` at character 10 (character 16)\n"
        "    sin(x) * (y + 2\n                   ^");
    const std::string unknown = errorOf(recipeWith("  ball: {sphere: {radius: 3}}\n  f: {expr: \"min(bal, x)\"}\n"));
    EXPECT_HAS(unknown,
               "unknown name `bal`; did you mean `ball`? (fields: ball, f; coordinates x, y, z; constants pi, tau, e)");
    EXPECT_HAS(unknown, "    min(bal, x)\n        ^");
    const std::string cycle = errorOf(recipeWith("  f: {expr: \"g + 1\"}\n  g: {expr: \"2 * f\"}\n"));
    EXPECT_HAS(cycle, "fields refer to each other in a cycle: f -> g -> f");
    EXPECT_HAS(errorOf(recipeWith("  f: {expr: \"f + 1\"}\n")), "cycle: f -> f");
    EXPECT_HAS(errorOf(recipeWith("  f: {expr: 3, solid: sheet}\n")), "give `level:`");
    EXPECT_HAS(errorOf(recipeWith("  f: {expr: \"x\", solid: web, level: 1}\n")), "solid is `network`");
    EXPECT_HAS(errorOf(recipeWith("  f: {expr: [x]}\n")), "expected an equation in x, y, z");
    EXPECT_HAS(errorOf(recipeWith("  d: {vector: [1, 0]}\n  f: {expr: \"d.x\"}\n")), "expected three components");
    EXPECT_HAS(errorOf(recipeWith("  d: {sphere: {radius: 1}}\n  f: {expr: \"d.x\"}\n")), "`d` is not a vector field");
    EXPECT_HAS(errorOf(recipeWith("  d: {vector: [1, 0, y]}\n  f: {expr: \"d.w\"}\n")),
               "components `.x`, `.y` and `.z`");
}

TEST(RecipeLanguage, EquationLatticeSolvesLikeTheBuiltIn)
{
    const std::string builtin = recipeWith("  f: {tpms: gyroid, cell: 5, solid: network, density: 0.3}\n");
    const std::string user = recipeWith(
        "  f: {expr: \"sin(2*pi*x/5)*cos(2*pi*y/5) + sin(2*pi*y/5)*cos(2*pi*z/5) + sin(2*pi*z/5)*cos(2*pi*x/5)\", "
        "solid: network, density: 0.3}\n");
    Job a(parseRecipe(builtin, "a.yaml", ".")), b(parseRecipe(user, "b.yaml", "."));
    a.solveLevels();
    b.solveLevels();
    const auto ra = a.report(), rb = b.report();
    EXPECT_NEAR(ra["fields"]["f"]["level"].get<double>(), rb["fields"]["f"]["level"].get<double>(), 1e-12);
    EXPECT_EQ(ra["fields"]["f"]["achieved_density"], rb["fields"]["f"]["achieved_density"]);
    EXPECT_EQ(a.mesh().triangles.size(), b.mesh().triangles.size());
    EXPECT_EQ(b.report()["fields"]["f"]["type"], "expr network");
    // Interval bounds as tight as the built-in's: culling skips exactly the same leaves.
    EXPECT_EQ(a.report()["result"]["evaluated_leaves"], b.report()["result"]["evaluated_leaves"]);
    EXPECT_EQ(a.report()["result"]["inside_tiles"], b.report()["result"]["inside_tiles"]);
}

TEST(RecipeLanguage, VectorFieldsGiveDirections)
{
    const std::string text =
        recipeWith("  swirl: {vector: [\"-y\", \"x\", 1]}\n  f: {expr: \"swirl.x * swirl.y + swirl.z\"}\n");
    Job job(parseRecipe(text, "v.yaml", "."));
    const FieldPtr f = job.field("f");
    const auto [v, g] = f->valueAndGradient(Vec3d(2, 3, 4));
    EXPECT_DOUBLE_EQ(v, -3.0 * 2.0 + 1.0);  // -y*x + 1
    EXPECT_NEAR((g - Vec3d(-3, -2, 0)).length(), 0.0, 1e-15);
    const auto swirl = std::dynamic_pointer_cast<const VectorField>(job.field("swirl"));
    ASSERT_TRUE(swirl);
    std::vector<Vec3d> pts{Vec3d(2, 3, 4)}, dirs(1);
    swirl->directions(pts, dirs);
    EXPECT_EQ(dirs[0], Vec3d(-3, 2, 1));
    EXPECT_NEAR(swirl->value(Vec3d(2, 3, 4)), std::sqrt(14.0), 1e-15);
    // Where a node expects a direction: a vector field's name, an inline vector, or a constant.
    const Recipe r = parseRecipe(text, "v.yaml", ".");
    FieldBuilder builder(r, JobContext::silent());
    const YAML::Node extra = YAML::Load("[[0.1, 0.2, 3], swirl, {vector: [z, 0, 0]}]");
    const auto source = r.source;
    const Vec3d expected[3] = {Vec3d(0.1, 0.2, 3), Vec3d(-3, 2, 1), Vec3d(4, 0, 0)};
    for (int i = 0; i < 3; ++i) {
        const auto dir = directionField(builder, RecipeNode(extra[i], source, "direction"), "d");
        dir->directions(pts, dirs);
        EXPECT_EQ(dirs[0], expected[i]) << i;
    }
    EXPECT_THROW(directionField(builder, RecipeNode(YAML::Load("f"), source, "direction"), "d"), InputError);
}

TEST(RecipeLanguage, CanonicalCopyIsHashedAndReproducible)
{
    const Recipe a = parseRecipe(kParams, "p.yaml", ".");
    // The same recipe written differently: other key order, spacing, numbers spelled 4.0, 0.50.
    std::string other = kParams;
    other.replace(other.find("radius: 4"), 9, "radius: 4.0");
    other.replace(other.find("voxel: 0.5\n"), 11, "");
    other += "voxel:   0.50\n";
    const Recipe b = parseRecipe(other, "q.yaml", ".");
    EXPECT_EQ(recipeHash(a), recipeHash(b));
    EXPECT_NE(recipeHash(a), recipeHash(parseRecipe(kParams, "p.yaml", ".", {"cell=6"})));
    const nlohmann::json canonical = canonicalRecipe(a);
    EXPECT_EQ(canonical["fields"]["lattice"]["cell"], 5);
    EXPECT_EQ(canonical["params"]["t"], 0.4);
    // The canonical copy is itself a recipe that makes the same part.
    const Recipe again = parseRecipe(canonical.dump(), "canonical.json", ".");
    EXPECT_EQ(recipeHash(again), recipeHash(a));
    Job j1(a), j2(again);
    EXPECT_EQ(j1.mesh().points, j2.mesh().points);
    EXPECT_EQ(j1.report()["recipe_sha256"], recipeHash(a));
    EXPECT_EQ(j1.report()["recipe_canonical"], canonical);
    // The hash is SHA-256 (FIPS 180-4 test vectors).
    EXPECT_EQ(sha256Hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
    EXPECT_EQ(sha256Hex(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
    EXPECT_EQ(sha256Hex(std::string(1000, 'a')).substr(0, 16), "41edece42d63e8d9");
}

TEST(RecipeLanguage, BrokenRecipesGiveTheExpectedMessages)
{
    struct Case {
        std::string text;
        std::vector<std::string> expected;
    };
    const std::vector<Case> cases = {
        {recipeWith("  f: {tpms: gyroid, cel: 5}\n"),
         {"bad.yaml:4:21: field `f`: unknown key `cel`; did you mean `cell`?",
          "(valid keys: tpms, cell, solid, level, density"}},
        {recipeWith("  f: {sphere: {radus: 2}}\n"),
         {"bad.yaml:4:16: field `f` `sphere`: unknown key `radus`; did you mean `radius`?"}},
        {recipeWith("  f: {expt: \"x\"}\n"),
         {"bad.yaml:4:6: field `f`: unknown node type `expt`; did you mean `expr`?"}},
        {recipeWith("  f: {expr: \"x\", levle: 1}\n"),
         {"unknown key `levle`; did you mean `level`?", "(valid keys: expr, solid, level, density, offset)"}},
        {recipeWith("  f: {vector: [1, 0, 0], normalize: true}\n"),
         {"unknown key `normalize`", "(valid keys: vector)"}},
        {"parms: {a: 1}\n" + recipeWith("  f: {sphere: {radius: 1}}\n"),
         {"bad.yaml:1:1: recipe: unknown key `parms`; did you mean `params`?"}},
        {"params: [a, b]\n" + recipeWith("  f: {sphere: {radius: 1}}\n"),
         {"bad.yaml:1:9: `params`: expected a map of parameters"}},
        {"params: {2x: 1}\n" + recipeWith("  f: {sphere: {radius: 1}}\n"),
         {"parameter names are letters, digits and _"}},
        {"params: {a: {default: 1, mn: 0}}\n" + recipeWith("  f: {sphere: {radius: $a}}\n"),
         {"unknown key `mn`; did you mean `min`?"}},
        {"params: {a: {min: 0}}\n" + recipeWith("  f: {sphere: {radius: 1}}\n"),
         {"parameter `a`: missing key `default`"}},
        {"params: {a: -1}\n" + recipeWith("  f: {sphere: {radius: $a}}\n"),
         {"bad.yaml:5:24 (`$a`, declared at bad.yaml:1:13): field `f` `sphere` `radius`: must be greater than zero"}},
        {recipeWith("  f: {expr: \"sin(x) +* 2\"}\n"), {"equation: unexpected `*`", "    sin(x) +* 2\n            ^"}},
        {recipeWith("  f: {expr: \"sinn(x)\"}\n"), {"unknown function `sinn`; did you mean `sin`?"}},
        {recipeWith("  f: {expr: \"x + $r\"}\n"), {"unknown parameter `$r` (the recipe declares no `params:`)"}},
        {"fields:\n  f: {sphere: {radius: 1}}\n",
         {"bad.yaml:1:1: recipe: missing key `result`: name the field the recipe makes, like `result: lattice`",
          "`include:` it from a recipe"}},
    };
    for (const Case& c : cases) {
        const std::string e = errorOf(c.text);
        for (const std::string& part : c.expected) EXPECT_HAS(e, part);
    }
}

TEST(RecipeLanguage, SchemaMatchesTheNodeTable)
{
    const nlohmann::json schema = recipeSchema();
    const auto& defs = schema["$defs"];
    std::set<std::string> types;
    for (const NodeType& t : FieldBuilder::nodeTypes()) {
        types.insert(t.key);
        const auto& def = defs.at("node_" + t.key);
        const auto names = keyNames(t.keys);
        std::set<std::string> keys(names.begin(), names.end()), schemaKeys;
        for (const auto& [k, v] : def["properties"].items()) schemaKeys.insert(k);
        EXPECT_EQ(keys, schemaKeys) << t.key;
        EXPECT_EQ(def["required"], nlohmann::json::array({t.key}));
        EXPECT_EQ(def["additionalProperties"], false);
    }
    EXPECT_EQ(defs["node"]["oneOf"].size(), types.size());
    std::set<std::string> top;
    for (const auto& [k, v] : schema["properties"].items()) top.insert(k);
    EXPECT_EQ(top, (std::set<std::string>{"voxel", "domain", "fields", "result", "outputs", "params", "include",
                                          "allow", "material", "properties"}));
    // The command prints the same schema.
    std::string out;
    ASSERT_EQ(runCommand(voxlatBinary() + " schema", &out), 0) << out;
    EXPECT_EQ(nlohmann::json::parse(out), schema);
}

namespace {

/// Sections of docs/recipes.md: heading line -> text up to the next heading.
std::vector<std::pair<std::string, std::string>> docSections(const std::string& doc)
{
    std::vector<std::pair<std::string, std::string>> sections;
    std::istringstream in(doc);
    for (std::string line; std::getline(in, line);) {
        if (line.rfind("## ", 0) == 0 || line.rfind("### ", 0) == 0)
            sections.emplace_back(line, "");
        else if (!sections.empty())
            sections.back().second += line + "\n";
    }
    return sections;
}

/// Property names anywhere below a schema node (nested objects such as sphere: {center, radius}).
void propertyNames(const nlohmann::json& s, std::set<std::string>& out)
{
    if (!s.is_object()) return;
    if (s.contains("properties"))
        for (const auto& [k, v] : s["properties"].items()) {
            out.insert(k);
            propertyNames(v, out);
        }
}

}  // namespace

TEST(RecipeLanguage, EveryNodeKeyIsDocumentedAndEveryDocumentedKeyExists)
{
    const std::string doc = readFile(sourceDir() / "docs/recipes.md");
    ASSERT_FALSE(doc.empty());
    const auto sections = docSections(doc);
    const nlohmann::json schema = recipeSchema();
    for (const NodeType& t : FieldBuilder::nodeTypes()) {
        const auto it = std::find_if(sections.begin(), sections.end(), [&](const auto& s) {
            return s.first.rfind("### ", 0) == 0 && s.first.find("`" + t.key + "`") != std::string::npos;
        });
        ASSERT_NE(it, sections.end()) << "docs/recipes.md has no ### section naming `" << t.key << "`";
        for (const std::string& key : keyNames(t.keys))
            EXPECT_TRUE(it->second.find("`" + key + "`") != std::string::npos ||
                        it->second.find(key + ":") != std::string::npos ||
                        it->first.find("`" + key + "`") != std::string::npos)
                << "key `" << key << "` of `" << t.key << "` is not documented in its section";
    }
    // Every key in a node section's table exists in the schema of the node types it names.
    const std::regex row(R"(^\| `([A-Za-z_]+)`)");
    for (const auto& [heading, body] : sections) {
        if (heading.rfind("### ", 0) != 0) continue;
        std::set<std::string> known;
        bool isNodeSection = false;
        for (const NodeType& t : FieldBuilder::nodeTypes())
            if (heading.find("`" + t.key + "`") != std::string::npos) {
                isNodeSection = true;
                for (const KeySpec& k : t.keys) known.insert(k.name);
                propertyNames(schema["$defs"]["node_" + t.key], known);
            }
        if (!isNodeSection) continue;
        std::istringstream in(body);
        for (std::string line; std::getline(in, line);) {
            std::smatch m;
            if (std::regex_search(line, m, row)) {
                EXPECT_TRUE(known.count(m[1])) << heading << ": documented key `" << m[1] << "` is not in the schema";
            }
        }
    }
    // The top-level table lists exactly the top-level keys.
    const auto top =
        std::find_if(sections.begin(), sections.end(), [](const auto& s) { return s.first == "## Top-level keys"; });
    ASSERT_NE(top, sections.end());
    std::set<std::string> documented, schemaTop;
    std::istringstream in(top->second);
    for (std::string line; std::getline(in, line);) {
        std::smatch m;
        if (std::regex_search(line, m, row)) documented.insert(m[1]);
    }
    for (const auto& [k, v] : schema["properties"].items()) schemaTop.insert(k);
    EXPECT_EQ(documented, schemaTop);
}

TEST(RecipeLanguage, EveryDocExampleRuns)
{
    // Full recipes (with `result:`) run as they are, at a coarse voxel; fragments (field entries)
    // are gathered into one recipe, in order, so later fragments may use earlier names.
    int full = 0, fragments = 0;
    YAML::Node gathered(YAML::NodeType::Map);
    std::string lastName;
    for (const auto& entry : std::filesystem::directory_iterator(sourceDir() / "docs")) {
        if (entry.path().extension() != ".md") continue;
        const std::string doc = readFile(entry.path());
        std::size_t pos = 0;
        int block = 0;
        while ((pos = doc.find("```yaml\n", pos)) != std::string::npos) {
            const std::size_t start = pos + 8, end = doc.find("```", start);
            const std::string text = doc.substr(start, end - start);
            pos = end + 3;
            ++block;
            const std::string name = entry.path().filename().string() + " example " + std::to_string(block);
            YAML::Node y = YAML::Load(text);
            if (y.IsMap() && y["result"]) {
                ++full;
                double extent = 0.0;
                const Recipe probe = parseRecipe(text, name, sourceDir() / "data/recipes");
                if (probe.domainBox)
                    for (int a = 0; a < 3; ++a) extent = std::max(extent, probe.domainBox->extent()[a]);
                const double voxel = std::max(probe.voxel, extent / 40.0);
                try {
                    // At the coarse voxel thin walls break into pieces the example's own voxel keeps
                    // whole: pieces are allowed (warned) here, as they are not what this test checks.
                    Job job(parseRecipe(text, name, sourceDir() / "data/recipes",
                                        {"voxel=" + std::to_string(voxel), "allow=[pieces]"}));
                    job.mesh();
                } catch (const std::exception& e) {
                    ADD_FAILURE() << name << ": " << e.what() << "\n" << text;
                }
                continue;
            }
            const YAML::Node fields = (y.IsMap() && y["fields"]) ? y["fields"] : y;
            if (!fields.IsMap()) continue;
            for (auto it = fields.begin(); it != fields.end(); ++it) {
                gathered[it->first.Scalar()] = it->second;
                lastName = it->first.Scalar();
                ++fragments;
            }
        }
    }
    EXPECT_GE(full, 4);
    EXPECT_GE(fragments, 10);
    YAML::Node recipe(YAML::NodeType::Map);
    recipe["voxel"] = 0.5;
    recipe["domain"]["box"] = YAML::Load("[[0, 0, 0], [10, 10, 10]]");
    recipe["fields"] = gathered;
    recipe["result"] = lastName;
    YAML::Emitter out;
    out << recipe;
    try {
        Job job(parseRecipe(out.c_str(), "doc fragments", sourceDir() / "data/recipes"));
        job.mesh();
    } catch (const std::exception& e) {
        ADD_FAILURE() << e.what() << "\n" << out.c_str();
    }
}

TEST(RecipeLanguage, CheckCommandTimesLoadAndValidation)
{
    TempDir dir;
    const auto path = dir.write("p.yaml", kParams);
    std::string out;
    ASSERT_EQ(runCommand(voxlatBinary() + " check " + path.string() + " --set cell=6 --repeat 3", &out), 0) << out;
    EXPECT_HAS(out, "ok: 3 fields, result `shaped`, recipe sha256 " +
                        recipeHash(parseRecipe(kParams, path.string(), dir.path, {"cell=6"})));
    EXPECT_HAS(out, "median of 3");
    EXPECT_EQ(runCommand(voxlatBinary() + " check " + path.string() + " --set cell=abc", &out), 2) << out;
    EXPECT_HAS(out, "expected a number like its default");
}

TEST(RecipeLanguage, RunRecordsTheRecipeInTheReport)
{
    TempDir dir;
    const auto path = dir.write("p.yaml", kParams);
    std::string out;
    ASSERT_EQ(
        runCommand(voxlatBinary() + " -q run " + path.string() + " --set cell=6 --out " + (dir.path / "out").string(),
                   &out),
        0)
        << out;
    EXPECT_TRUE(std::filesystem::exists(dir.path / "out/part_6.stl"));
    const auto report = nlohmann::json::parse(readFile(dir.path / "out/report.json"));
    EXPECT_EQ(report["recipe_sha256"], sha256Hex(report["recipe_canonical"].dump()));
    EXPECT_EQ(report["recipe_canonical"]["params"]["cell"], 6);
    // Re-made from the report alone: the same mesh, byte for byte.
    const auto again = dir.write("again.json", report["recipe_canonical"].dump());
    ASSERT_EQ(
        runCommand(voxlatBinary() + " -q run " + again.string() + " --out " + (dir.path / "again").string(), &out), 0)
        << out;
    EXPECT_EQ(readFile(dir.path / "out/part_6.stl"), readFile(dir.path / "again/part_6.stl"));
}

TEST(RecipeLanguage, BadEquationOnTheCommandLineWritesNothing)
{
    TempDir dir;
    const auto path = dir.write("bad.yaml", recipeWith("  g: {tpms: gyroid, cell: 5, solid: network, level: 0}\n"
                                                       "  f: {expr: \"max(g, gg - 1)\"}\n") +
                                                "outputs: {mesh: part.stl}\n");
    std::string out;
    EXPECT_EQ(runCommand(voxlatBinary() + " run " + path.string() + " --out " + (dir.path / "out").string(), &out), 2);
    EXPECT_HAS(out,
               "error: " + path.string() + ":5:13: field `f` `expr`: equation: unknown name `gg`; did you mean `g`?");
    EXPECT_HAS(out, "    max(g, gg - 1)\n           ^");
    EXPECT_FALSE(std::filesystem::exists(dir.path / "out" / "part.stl"));
    EXPECT_FALSE(std::filesystem::exists(dir.path / "out" / "report.json"));
    // Sampling an equation from the command line gives its value and exact gradient.
    const auto good = dir.write("good.yaml", recipeWith("  f: {expr: \"x*y + sin(z)\"}\n"));
    ASSERT_EQ(runCommand("echo '2 3 0.5' | " + voxlatBinary() + " sample " + good.string() + " --gradient", &out), 0)
        << out;
    std::istringstream values(out);
    double v, gx, gy, gz;
    values >> v >> gx >> gy >> gz;
    EXPECT_NEAR(v, 6 + std::sin(0.5), 1e-8);
    EXPECT_NEAR(gx, 3, 1e-8);
    EXPECT_NEAR(gy, 2, 1e-8);
    EXPECT_NEAR(gz, std::cos(0.5), 1e-8);
}
