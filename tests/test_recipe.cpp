// Recipe loading: every bad input gives one message naming the file, the line and the fix.
#include "RecipeErrors.h"
#include "TestUtil.h"
#include "engine/jobs/Job.h"
#include "engine/recipe/FieldBuilder.h"
#include "engine/recipe/Recipe.h"
#include "engine/recipe/RecipeParams.h"

#include <gtest/gtest.h>

using namespace voxlat;
using voxlat::test::errorOf;

namespace {

const char* kGood = R"(# a small gyroid
voxel: 0.5
domain: {box: [[0, 0, 0], [10, 10, 10]]}
fields:
  lattice: {tpms: gyroid, cell: 5, solid: network, density: 0.30}
result: lattice
outputs: {mesh: part.stl}
)";

std::string replace(std::string text, const std::string& from, const std::string& to)
{
    text.replace(text.find(from), from.size(), to);
    return text;
}

}  // namespace

TEST(Recipe, GoodRecipeLoads)
{
    EXPECT_EQ(errorOf(kGood), "");
    const Recipe r = parseRecipe(kGood, "good.yaml", ".");
    EXPECT_EQ(r.voxel, 0.5);
    EXPECT_EQ(r.result, "lattice");
    ASSERT_EQ(r.outputs.size(), 1u);
    EXPECT_EQ(r.outputs[0].file, "part.stl");
}

TEST(Recipe, UnknownKeySuggestsTheClosest)
{
    const std::string e = errorOf(replace(kGood, "cell: 5", "cel: 5"));
    EXPECT_NE(e.find("bad.yaml:5:"), std::string::npos) << e;
    EXPECT_NE(e.find("unknown key `cel`"), std::string::npos) << e;
    EXPECT_NE(e.find("did you mean `cell`?"), std::string::npos) << e;
    const std::string top = errorOf(replace(kGood, "voxel:", "voxle:"));
    EXPECT_NE(top.find("bad.yaml:2:1"), std::string::npos) << top;
    EXPECT_NE(top.find("`voxel`"), std::string::npos) << top;
}

TEST(Recipe, WrongTypesAndRanges)
{
    EXPECT_NE(errorOf(replace(kGood, "cell: 5", "cell: five")).find("expected a number, got `five`"),
              std::string::npos);
    const std::string density = errorOf(replace(kGood, "density: 0.30", "density: 30"));
    EXPECT_NE(density.find("between 0 and 1"), std::string::npos) << density;
    EXPECT_NE(density.find("bad.yaml:5:"), std::string::npos) << density;
    EXPECT_NE(errorOf(replace(kGood, "density: 0.30", "density: 0")).find("between 0 and 1"), std::string::npos);
    const std::string voxel = errorOf(replace(kGood, "voxel: 0.5", "voxel: 20"));
    EXPECT_NE(voxel.find("larger than the domain"), std::string::npos) << voxel;
    EXPECT_NE(voxel.find("bad.yaml:2:"), std::string::npos) << voxel;
    EXPECT_NE(errorOf(replace(kGood, "gyroid,", "gyriod,")).find("did you mean `gyroid`?"), std::string::npos);
    EXPECT_NE(errorOf(replace(kGood, "network", "solid")).find("`network`"), std::string::npos);
    EXPECT_NE(errorOf(replace(kGood, "[10, 10, 10]", "[10, -1, 10]")).find("above the first"), std::string::npos);
    EXPECT_NE(errorOf(replace(kGood, "density: 0.30", "density: 0.3, level: 0.1")).find("not both"), std::string::npos);
    EXPECT_NE(errorOf(replace(kGood, "network, density: 0.30", "sheet")).find("give `level:`"), std::string::npos);
    EXPECT_NE(errorOf(replace(kGood, "density: 0.30", "level: 7")).find("outside the range"), std::string::npos);
}

TEST(Recipe, FieldReferences)
{
    EXPECT_NE(errorOf(replace(kGood, "result: lattice", "result: latice")).find("did you mean `lattice`?"),
              std::string::npos);
    const std::string cyclic = R"(voxel: 0.5
domain: {box: [[0, 0, 0], [10, 10, 10]]}
fields:
  a: {union: [b]}
  b: {intersection: [a]}
result: a
)";
    EXPECT_NE(errorOf(cyclic).find("cycle"), std::string::npos) << errorOf(cyclic);
    const std::string unknownType = R"(voxel: 0.5
domain: {box: [[0, 0, 0], [10, 10, 10]]}
fields:
  a: {sphre: {radius: 2}}
result: a
)";
    EXPECT_NE(errorOf(unknownType).find("did you mean `sphere`?"), std::string::npos) << errorOf(unknownType);
}

TEST(Recipe, SyntaxErrorsAndMissingFiles)
{
    const std::string e = errorOf("voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]\n");
    EXPECT_NE(e.find("not valid YAML"), std::string::npos) << e;
    EXPECT_NE(e.find("bad.yaml:"), std::string::npos) << e;
    try {
        loadRecipe("/no/such/recipe.yaml");
        FAIL();
    } catch (const InputError& err) {
        EXPECT_NE(std::string(err.what()).find("/no/such/recipe.yaml"), std::string::npos);
    }
}

TEST(Recipe, SetOverridesKeys)
{
    const Recipe r = parseRecipe(kGood, "good.yaml", ".", {"voxel=0.25", "fields.lattice.cell=[4, 5, 6]"});
    EXPECT_EQ(r.voxel, 0.25);
    EXPECT_EQ(r.fieldSpec("lattice")["cell"].vec3(), Vec3d(4, 5, 6));
    const std::string e = errorOf(kGood, {"fields.lattice.density=2"});
    EXPECT_NE(e.find("(from --set)"), std::string::npos) << e;
    EXPECT_NE(errorOf(kGood, {"novalue"}).find("KEY=VALUE"), std::string::npos);
}

TEST(Recipe, EveryNodeTypeBuilds)
{
    const std::string text = R"(voxel: 0.5
domain: {box: [[0, 0, 0], [10, 10, 10]]}
fields:
  g: {tpms: schwarz-p, cell: [4, 5, 6], solid: sheet, level: 0.4}
  s: {sphere: {center: [5, 5, 5], radius: 4}}
  b: {box: [[1, 1, 1], [9, 9, 9]]}
  c: {cylinder: {center: [5, 5, 5], axis: [0, 1, 0], radius: 2, height: 8}}
  u: {union: [s, c], blend: 0.5}
  i: {intersection: [g, b, {sphere: {radius: 9}}]}
  d: {difference: [u, g]}
  t: {translate: [1, 0, 0], field: d}
  r: {rotate: {axis: [0, 0, 1], degrees: 30}, field: t}
  k: {scale: 1.5, field: r}
result: k
)";
    EXPECT_EQ(errorOf(text), "");
}

TEST(Recipe, DesignTargetsAndTrialEditsAreTypedAtLoad)
{
    const std::string text = R"(material: form2
voxel: 0.5
domain: {box: [[0, 0, 0], [10, 10, 10]]}
fields:
  lattice:
    struts: {cell: x, size: 5}
    kernel: {gaussian: {sigma: 0.5}}
    density: 0.2
    optimize: {sigma: [0.4, 1.2], samples: 4}
  sheet: {tpms: gyroid, cell: 5, solid: sheet, stiffness: {E_ratio: 0.05, axis: x}}
result: lattice
)";
    Recipe r = parseRecipe(text, "t.yaml", ".");
    // Both design keys read at load, in file order, with their lines; the ratio is taken of the
    // material's own modulus.
    ASSERT_EQ(r.designs.size(), 2u);
    EXPECT_EQ(r.designs[0].field, "lattice");
    ASSERT_TRUE(r.designs[0].optimize);
    EXPECT_EQ(r.designs[0].optimize->lo, 0.4);
    EXPECT_EQ(r.designs[0].optimize->hi, 1.2);
    EXPECT_EQ(r.designs[0].optimize->samples, 4);
    EXPECT_EQ(r.designs[0].optimize->density, 0.2);
    EXPECT_EQ(r.designs[0].optimize->where.rfind("t.yaml:9:", 0), 0u) << r.designs[0].optimize->where;
    ASSERT_TRUE(r.designs[1].stiffness);
    EXPECT_EQ(r.designs[1].stiffness->axis, 0);
    EXPECT_DOUBLE_EQ(r.designs[1].stiffness->goalMPa, 0.05 * r.material->modulusMPa);
    // What the pieces advice reads of the lattice, read at load.
    const FieldFacts& facts = r.fieldFacts.at("lattice");
    EXPECT_TRUE(facts.densityScalar);
    ASSERT_TRUE(facts.sigma);
    EXPECT_EQ(*facts.sigma, 0.5);
    ASSERT_TRUE(facts.plainBoxCell);
    EXPECT_EQ(*facts.plainBoxCell, Vec3d(5.0));
    EXPECT_TRUE(facts.boxFrame);

    // A trial changes its own copy only: the parent's canonical recipe is as loaded, untouched
    // nodes keep their lines, the design key is gone from the trial.
    const nlohmann::json before = canonicalRecipe(r);
    FieldEdit sigma;
    sigma.sigma = 0.7;
    const Recipe trial = trialRecipe(r, "lattice", sigma);
    EXPECT_EQ(canonicalRecipe(r), before);
    EXPECT_EQ(trial.fieldSpec("lattice")["kernel"]["gaussian"]["sigma"].number(), 0.7);
    EXPECT_FALSE(trial.fieldSpec("lattice").has("optimize"));
    EXPECT_TRUE(trial.designs.empty());
    EXPECT_EQ(*trial.fieldFacts.at("lattice").sigma, 0.7);
    EXPECT_EQ(trial.fieldSpec("lattice")["density"].where(), r.fieldSpec("lattice")["density"].where());
    EXPECT_EQ(r.fieldSpec("lattice")["density"].where().rfind("t.yaml:8:", 0), 0u);

    // A solved target is written into the recipe itself (and its canonical form).
    FieldEdit solved;
    solved.density = 0.25;
    editField(r, "sheet", solved);
    EXPECT_EQ(canonicalRecipe(r)["fields"]["sheet"]["density"], 0.25);
    EXPECT_FALSE(canonicalRecipe(r)["fields"]["sheet"].contains("stiffness"));
    ASSERT_EQ(r.designs.size(), 1u);
    EXPECT_EQ(r.designs[0].field, "lattice");

    // Bad design keys fail at load, at their line, before any job.
    try {
        parseRecipe(replace(text, "material: form2\n", ""), "t.yaml", ".");
        ADD_FAILURE() << "a design target without a material loaded";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("t.yaml:8:"), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find("needs the material"), std::string::npos) << e.what();
    }
}
