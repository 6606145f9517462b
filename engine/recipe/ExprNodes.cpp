// Recipe node types for user equations (`expr`) and direction fields (`vector`).
#include "engine/recipe/ExprNodes.h"

#include "fields/core/Constant.h"
#include "fields/expr/ExprField.h"
#include "fields/frames/ParametricSurface.h"
#include "fields/levels/LevelSolid.h"
#include "fields/maps/Ramp.h"

#include <algorithm>
#include <cctype>
#include <map>

namespace voxlat {

namespace {

/// `$name` in an equation: the recipe's parameter as a constant, or no symbol when there is none.
ExprSymbol parameterSymbol(const Recipe& recipe, const std::string& name)
{
    const auto it = recipe.params.find(name);
    if (it == recipe.params.end()) return {};
    try {
        return {ExprSymbol::Kind::Constant, it->second.as<double>(), -1};
    } catch (const YAML::Exception&) {
        throw ExprError("parameter `$" + name + "` is `" + (it->second.IsScalar() ? it->second.Scalar() : "a list") +
                            "`, not a number",
                        std::string::npos);
    }
}

/// Answers the names in one equation: parameters become constants, fields become inputs.
class EquationNames {
public:
    explicit EquationNames(FieldBuilder& builder) : mBuilder(builder) {}

    ExprSymbol operator()(const std::string& name, bool isParam)
    {
        const Recipe& recipe = mBuilder.recipe();
        if (isParam) return parameterSymbol(recipe, name);
        const auto dot = name.find('.');
        const std::string base = name.substr(0, dot);
        if (std::find(recipe.fieldNames.begin(), recipe.fieldNames.end(), base) == recipe.fieldNames.end()) {
            if (recipe.params.count(name))
                throw ExprError("`" + name + "` is a parameter: write `$" + name + "`", std::string::npos);
            if (name == "u" || name == "v" || name == "w") return unitCoordinate(name);
            return {};
        }
        FieldPtr f = mBuilder.field(base);  // detects cycles through equations too
        if (dot != std::string::npos) {
            const std::string axis = name.substr(dot + 1);
            const auto* vec = dynamic_cast<const VectorField*>(f.get());
            if (!vec)
                throw ExprError(
                    "`" + base + "` is not a vector field: `." + axis + "` reads a component of a `vector:` node",
                    std::string::npos);
            if (axis != "x" && axis != "y" && axis != "z")
                throw ExprError("a vector field has components `.x`, `.y` and `.z`, not `." + axis + "`",
                                std::string::npos);
            f = vec->component(axis[0] - 'x');
        }
        if (auto it = mIndex.find(name); it != mIndex.end()) return {ExprSymbol::Kind::Input, 0.0, it->second};
        mInputs.push_back(f);
        mIndex[name] = int(mInputs.size()) - 1;
        return {ExprSymbol::Kind::Input, 0.0, mIndex[name]};
    }

    std::vector<FieldPtr> inputs() const { return mInputs; }
    /// Whether compiling failed at u, v or w with no frame's box to give them.
    bool neededUnitBox() const { return mNeededUnitBox; }

private:
    /// IntraLattice's unit-box coordinate @a name (u, v or w): x, y or z scaled to [0, 1] over
    /// the box of the strut frame whose `radius:` is being built (0 along a flat axis).
    ExprSymbol unitCoordinate(const std::string& name)
    {
        const auto& box = mBuilder.unitBox();
        if (!box) {
            mNeededUnitBox = true;
            throw ExprError("`" + name +
                                "` is IntraLattice's unit-box coordinate (u, v, w from 0 to 1 over a strut frame's "
                                "box): it can be used in a field that is a strut `radius:`, and this one is not",
                            std::string::npos);
        }
        mBuilder.noteUnitBoxUse();
        if (auto it = mIndex.find(name); it != mIndex.end()) return {ExprSymbol::Kind::Input, 0.0, it->second};
        const int axis = name[0] - 'u';
        const double lo = box->min[axis], hi = box->max[axis];
        if (hi > lo)
            mInputs.push_back(std::make_shared<RampField>(axis, lo, hi, 0.0, 1.0));
        else
            mInputs.push_back(std::make_shared<ConstantField>(0.0));
        mIndex[name] = int(mInputs.size()) - 1;
        return {ExprSymbol::Kind::Input, 0.0, mIndex[name]};
    }

    bool mNeededUnitBox = false;
    FieldBuilder& mBuilder;
    std::vector<FieldPtr> mInputs;
    std::map<std::string, int> mIndex;
};

FieldPtr buildExpr(FieldBuilder& builder, const RecipeNode& spec, const std::string& name)
{
    FieldPtr raw = equationField(builder, spec["expr"]);
    // An infill's `density:` solves this equation's level (a network f <= c unless `solid:` says).
    const bool solvedByInfill = levelSolvedByInfill(builder.recipe(), name);
    if (!solvedByInfill && !spec.has("solid") && !spec.has("level") && !spec.has("density") && !spec.has("offset"))
        return raw;
    const SolidSide side = readSolidSide(spec);
    std::string offset;
    if (spec.has("offset")) raw = networkOffset(builder, spec, raw, side, name, 0.0, offset);
    LevelNode node{name, (side == SolidSide::Band ? "expr sheet" : "expr network") + offset, nullptr};
    readLevelKeys(spec, node, raw, side, 0.0,
                  solvedByInfill            ? LevelRule::SolvedElsewhere
                  : side == SolidSide::Band ? LevelRule::Required
                                            : LevelRule::Optional);
    FieldPtr result = node.solid;
    builder.addLevelNode(std::move(node));
    return result;
}

FieldPtr buildVector(FieldBuilder& builder, const RecipeNode& spec, const std::string&)
{
    const RecipeNode list = spec["vector"];
    if (!list.isSequence() || list.size() != 3)
        list.fail("expected three components (numbers or equations), like [0, 0, 1] or [\"-y\", \"x\", 0]");
    std::array<FieldPtr, 3> components;
    for (int a = 0; a < 3; ++a) components[a] = equationField(builder, list.at(a));
    return std::make_shared<VectorField>(components);
}

/// A direction field that is @a v everywhere.
std::shared_ptr<const VectorField> constantDirection(const Vec3d& v)
{
    return std::make_shared<VectorField>(std::array<FieldPtr, 3>{std::make_shared<ConstantField>(v[0]),
                                                                 std::make_shared<ConstantField>(v[1]),
                                                                 std::make_shared<ConstantField>(v[2])});
}

FieldPtr buildOrient(FieldBuilder& builder, const RecipeNode& spec, const std::string& name)
{
    return orientedField(builder, spec["orient"], builder.operand(spec["field"], name + "/field"), name);
}

/// One coordinate of a `surface` node: an equation in u, v (0 to 1) and $params.
std::shared_ptr<const ExprProgram> surfaceCoordinate(FieldBuilder& builder, const RecipeNode& textNode)
{
    if (!textNode.isScalar()) textNode.fail("expected an equation in u and v, like \"10*u\" or \"5*cos(tau*u)\"");
    const std::string text = textNode.string();
    // x, y and z are built into equations as the point's coordinates, which a surface has none of.
    for (std::size_t i = 0; i < text.size(); ++i) {
        const auto word = [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '.'; };
        if (!word(text[i]) || (i > 0 && (word(text[i - 1]) || text[i - 1] == '$'))) continue;
        std::size_t end = i;
        while (end < text.size() && word(text[end])) ++end;
        const std::string name = text.substr(i, end - i);
        if (name == "x" || name == "y" || name == "z")
            textNode.fail("equation: a surface's coordinates are equations in u and v (0 to 1), not in `" + name +
                          "` (character " + std::to_string(i + 1) + ")\n" + exprCaret(text, i));
    }
    const Recipe& recipe = builder.recipe();
    auto resolve = [&](const std::string& name, bool isParam) -> ExprSymbol {
        if (isParam) return parameterSymbol(recipe, name);
        if (name == "u") return {ExprSymbol::Kind::Input, 0.0, 0};
        if (name == "v") return {ExprSymbol::Kind::Input, 0.0, 1};
        throw ExprError("a surface's coordinates are equations in u and v (0 to 1), constants and $params; `" + name +
                            "` is none of them",
                        std::string::npos);
    };
    try {
        return std::make_shared<const ExprProgram>(ExprProgram::compile(text, resolve));
    } catch (const ExprError& e) {
        textNode.fail("equation: " + std::string(e.what()) + " (character " + std::to_string(e.position() + 1) + ")\n" +
                      exprCaret(text, e.position()));
    }
}

FieldPtr buildSurface(FieldBuilder& builder, const RecipeNode& spec, const std::string&)
{
    const RecipeNode s = spec["surface"];
    if (!s.isMap())
        s.fail("a surface is {x: \"...\", y: \"...\", z: \"...\"}: its coordinates as equations in u and v");
    s.checkKeys({"x", "y", "z"});
    std::array<std::shared_ptr<const ExprProgram>, 3> coordinates;
    for (int a = 0; a < 3; ++a) {
        const std::string key(1, "xyz"[a]);
        if (!s.has(key)) s.fail("give `" + key + ":` (the " + key + " coordinate as an equation in u and v)");
        coordinates[a] = surfaceCoordinate(builder, s[key]);
    }
    return std::make_shared<ParametricSurface>(coordinates);
}

}  // namespace

FieldPtr equationField(FieldBuilder& builder, const RecipeNode& textNode)
{
    if (!textNode.isScalar()) textNode.fail("expected an equation in x, y, z, like \"sin(x) + cos(y)\"");
    const std::string text = textNode.string();
    EquationNames names(builder);
    try {
        auto program = std::make_shared<const ExprProgram>(
            ExprProgram::compile(text, [&](const std::string& n, bool isParam) { return names(n, isParam); }));
        return std::make_shared<ExprField>(program, names.inputs());
    } catch (const ExprError& e) {
        std::string message = e.what();
        if (names.neededUnitBox())
            throw UnitBoxNeeded(textNode.where() + ": equation: " + message + " (character " +
                                std::to_string(e.position() + 1) + ")\n" + exprCaret(text, e.position()));
        if (!e.unknownName().empty()) {
            const Recipe& recipe = builder.recipe();
            std::vector<std::string> candidates;
            std::string known;
            if (e.unknownName()[0] == '$') {
                for (const auto& [p, v] : recipe.params) candidates.push_back("$" + p);
                known =
                    candidates.empty() ? "the recipe declares no `params:`" : "parameters: " + joinWords(candidates);
            } else {
                candidates = recipe.fieldNames;
                for (const auto& c : exprConstantNames()) candidates.push_back(c);
                known = "fields: " + joinWords(recipe.fieldNames) + "; coordinates x, y, z; constants pi, tau, e";
            }
            const std::string guess = closestMatch(e.unknownName(), candidates);
            if (!guess.empty()) message += "; did you mean `" + guess + "`?";
            message += " (" + known + ")";
        }
        textNode.fail("equation: " + message + " (character " + std::to_string(e.position() + 1) + ")\n" +
                      exprCaret(text, e.position()));
    }
}

std::shared_ptr<const VectorField> directionField(FieldBuilder& builder, const RecipeNode& spec,
                                                  const std::string& name)
{
    if (spec.isSequence()) return constantDirection(spec.vec3());
    if (spec.isScalar()) {
        // An unknown name is reported here, at its use, rather than at the recipe's `fields:`.
        const std::vector<std::string>& names = builder.recipe().fieldNames;
        if (std::find(names.begin(), names.end(), spec.string()) == names.end()) {
            const std::string guess = closestMatch(spec.string(), names);
            spec.fail("no field named `" + spec.string() + "`" +
                      (guess.empty() ? "" : "; did you mean `" + guess + "`?") + " (fields: " + joinWords(names) + ")");
        }
    }
    auto f = std::dynamic_pointer_cast<const VectorField>(builder.operand(spec, name));
    if (!f) spec.fail("expected a direction: the name of a `vector:` field, {vector: [...]} or [x, y, z]");
    return f;
}

FieldPtr orientedField(FieldBuilder& builder, const RecipeNode& spec, FieldPtr child, const std::string& name)
{
    if (spec.isMap()) spec.checkKeys({"along", "x", "origin"});
    if (!spec.isMap() || !(spec.has("along") || spec.has("x")))
        spec.fail(
            "expected an orientation {along: DIRECTION, x: DIRECTION, origin: [x, y, z]} with `along` (the "
            "cells' z axis) or `x` (their x axis) or both; a direction is the name of a `vector` field, "
            "{vector: [...]} or [x, y, z]");
    // Constant directions are checked here, where the recipe line is known; fields at run time.
    for (const char* key : {"along", "x"})
        if (spec.has(key) && spec[key].isSequence() && spec[key].size() == 3 && spec[key].vec3().length() <= 0.0)
            spec[key].fail(std::string("the `") + key + "` direction must not be the zero vector");
    if (spec.has("along") && spec.has("x") && spec["along"].isSequence() && spec["x"].isSequence()) {
        const Vec3d z = spec["along"].vec3(), x = spec["x"].vec3();
        if (z.cross(x).length() <= 1e-6 * z.length() * x.length())
            spec["x"].fail("`x` is parallel to `along`: the x axis needs a reference that is not along z");
    }
    auto z = spec.has("along") ? directionField(builder, spec["along"], name + "/along") : constantDirection({0, 0, 1});
    auto x = spec.has("x") ? directionField(builder, spec["x"], name + "/x") : nullptr;
    auto frame = std::make_shared<const FrameField>(std::move(z), std::move(x), "field `" + name + "`");
    const Vec3d origin = spec.has("origin") ? spec["origin"].vec3() : Vec3d(0.0);
    return std::make_shared<OrientField>(std::move(child), std::move(frame), origin);
}

void addExprNodeTypes(std::vector<NodeType>& types)
{
    using namespace valueSchema;
    types.push_back(
        {"expr",
         {{"expr", string(), "an equation in x, y, z, $params and field names", "required"},
          solidKey(),
          levelKey(),
          densityKey(),
          {"offset", number(), "moves a network's surface m mm along its unit gradient (outwards for m > 0)", "—"}},
         buildExpr});
    types.push_back({"vector",
                     {{"vector",
                       {{"type", "array"},
                        {"items", {{"anyOf", {{{"type", "number"}}, {{"type", "string"}}}}}},
                        {"minItems", 3},
                        {"maxItems", 3}},
                       "three components: numbers or equations",
                       "required"}},
                     buildVector});
    types.push_back(
        {"surface",
         {{"surface",
           object({{"x", string(), "x (mm) as an equation in u and v (each 0 to 1) and $params", "required"},
                   {"y", string(), "y (mm), likewise", "required"},
                   {"z", string(), "z (mm), likewise", "required"}},
                  {"x", "y", "z"}),
           "a parametric surface for a strut frame's `between:` (not a field)", "required"}},
         buildSurface});
    types.push_back(
        {"orient",
         {{"orient", orientationSchema(), "a frame field: the field's axes follow it point by point", "required"},
          {"field", field(), "the field turned", "required"}},
         buildOrient});
}

}  // namespace voxlat
