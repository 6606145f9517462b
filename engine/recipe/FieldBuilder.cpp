#include "engine/recipe/FieldBuilder.h"

#include "fields/frames/ParametricSurface.h"

#include <algorithm>
#include <iostream>

namespace voxlat {

FieldBuilder::FieldBuilder(const Recipe& recipe, JobContext& context) : mRecipe(recipe), mContext(context) {}

const std::vector<NodeType>& FieldBuilder::nodeTypes()
{
    static const std::vector<NodeType> types = [] {
        std::vector<NodeType> t;
        addLatticeNodeTypes(t);
        addStrutNodeTypes(t);
        addDesignNodeTypes(t);
        addExprNodeTypes(t);
        addFalloffNodeTypes(t);
        addShapeNodeTypes(t);
        return t;
    }();
    return types;
}

FieldPtr FieldBuilder::field(const std::string& name)
{
    FieldPtr f = anyField(name);
    if (dynamic_cast<const ParametricSurface*>(f.get()))
        mRecipe.fieldSpec(name).fail("`" + name +
                                     "` is a surface (x, y, z as equations in u and v): it serves in a strut "
                                     "frame's `between:`, not as a field");
    return f;
}

FieldPtr FieldBuilder::anyField(const std::string& name)
{
    if (auto it = mBuilt.find(name); it != mBuilt.end()) {
        const auto box = mUnitBoxOf.find(name);
        if (box == mUnitBoxOf.end()) return it->second;
        // Built with u, v, w over a frame's box: the same box reuses it, another builds it again.
        if (mUnitBox && mUnitBox->min == box->second.min && mUnitBox->max == box->second.max) {
            noteUnitBoxUse();
            return it->second;
        }
    }
    const RecipeNode spec = mRecipe.fieldSpec(name);
    if (std::find(mInProgress.begin(), mInProgress.end(), name) != mInProgress.end()) {
        std::string cycle;
        for (auto it = std::find(mInProgress.begin(), mInProgress.end(), name); it != mInProgress.end(); ++it)
            cycle += *it + " -> ";
        spec.fail("fields refer to each other in a cycle: " + cycle + name);
    }
    // Popped on errors too: buildAll() goes on after a field that waits for a frame's box.
    struct InProgress {
        std::vector<std::string>& names;
        ~InProgress() { names.pop_back(); }
    } inProgress{mInProgress};
    mInProgress.push_back(name);
    const std::size_t usesBefore = mUnitBoxUses;
    FieldPtr f = buildSpec(spec, name);
    mBuilt[name] = f;
    if (mUnitBoxUses != usesBefore)
        mUnitBoxOf[name] = *mUnitBox;
    else
        mUnitBoxOf.erase(name);
    return f;
}

FieldPtr FieldBuilder::buildAll()
{
    std::vector<std::pair<std::string, std::string>> waiting;  // field, its error without a box
    for (const std::string& name : mRecipe.fieldNames) {
        try {
            anyField(name);
        } catch (const UnitBoxNeeded& e) {
            waiting.emplace_back(name, e.what());
        }
    }
    FieldPtr result = field(mRecipe.result);
    for (const auto& [name, message] : waiting)
        if (!mUnitBoxOf.count(name)) throw InputError(message);
    return result;
}

std::shared_ptr<const ParametricSurface> FieldBuilder::surface(const RecipeNode& spec, const std::string& name)
{
    const FieldPtr f = spec.isScalar() ? anyField(spec.string()) : buildSpec(spec, name);
    auto s = std::dynamic_pointer_cast<const ParametricSurface>(f);
    if (!s)
        spec.fail(
            "expected a surface: the name of a `surface` node or {surface: {x: \"...\", y: \"...\", z: \"...\"}} "
            "(equations in u and v from 0 to 1)");
    return s;
}

FieldBuilder::UnitBoxScope::UnitBoxScope(FieldBuilder& builder, const Box3& box)
    : mBuilder(builder), mPrevious(builder.mUnitBox)
{
    builder.mUnitBox = box;
}

FieldBuilder::UnitBoxScope::~UnitBoxScope()
{
    mBuilder.mUnitBox = mPrevious;
}

FieldPtr FieldBuilder::operand(const RecipeNode& spec, const std::string& name)
{
    if (spec.isScalar()) return field(spec.string());
    FieldPtr f = buildSpec(spec, name);
    if (dynamic_cast<const ParametricSurface*>(f.get()))
        spec.fail("a surface (x, y, z as equations in u and v) serves in a strut frame's `between:`, not as a field");
    return f;
}

FieldPtr FieldBuilder::buildSpec(const RecipeNode& spec, const std::string& name)
{
    const auto& types = nodeTypes();
    std::vector<std::string> typeKeys;
    for (const NodeType& t : types) typeKeys.push_back(t.key);
    if (!spec.isMap()) spec.fail("expected a map naming the node type, one of: " + joinWords(typeKeys));
    const NodeType* found = nullptr;
    for (const NodeType& t : types) {
        if (!spec.has(t.key)) continue;
        if (found) spec.fail("a field has one type, but this one has both `" + found->key + "` and `" + t.key + "`");
        found = &t;
    }
    if (!found) {
        std::string message = "no node type given";
        for (auto it = spec.yaml().begin(); it != spec.yaml().end(); ++it) {
            const std::string guess = closestMatch(it->first.Scalar(), typeKeys);
            if (!guess.empty()) {
                message = "unknown node type `" + it->first.Scalar() + "`; did you mean `" + guess + "`?";
                break;
            }
        }
        spec.fail(message + " (types: " + joinWords(typeKeys) + ")");
    }
    spec.checkKeys(keyNames(found->keys));
    return found->build(*this, spec, name);
}

KeySpec solidKey()
{
    return {"solid", valueSchema::oneOfWords({"network", "sheet"}), "network (f <= level) or sheet (|f| <= level)",
            "network"};
}

KeySpec levelKey()
{
    return {"level", valueSchema::number(), "c for a network (f <= c), t for a sheet (|f| <= t), in f's units",
            "network: 0"};
}

KeySpec densityKey()
{
    return {"density", valueSchema::density(), "target relative density in (0, 1); the level is solved", "—"};
}

nlohmann::json gradedDensitySchema()
{
    using namespace valueSchema;
    return {{"anyOf", {density(), anyMap(), string()}}};
}

nlohmann::json orientationSchema()
{
    using namespace valueSchema;
    const char* direction = "a direction: a vector field's name, {vector: [...]} or [x, y, z]";
    return object({{"along", anything(), std::string("the cells' z axis; ") + direction, "[0, 0, 1]"},
                   {"x", anything(),
                    std::string("reference for the cells' x axis (made orthogonal to z); ") + direction, "[1, 0, 0]"},
                   {"origin", vec3(), "the point the cells are rotated about (mm)", "[0, 0, 0]"}});
}

SolidSide readSolidSide(const RecipeNode& spec)
{
    const std::string solid = spec.has("solid") ? spec["solid"].string() : "network";
    if (solid == "network") return SolidSide::Below;
    if (solid == "sheet") return SolidSide::Band;
    spec["solid"].fail("solid is `network` (f <= level) or `sheet` (|f| <= level), got `" + solid + "`");
}

std::shared_ptr<LevelSolid> readLevelKeys(const RecipeNode& spec, LevelNode& node, FieldPtr raw, SolidSide side,
                                          double defaultLevel, LevelRule rule)
{
    if (spec.has("level") && spec.has("density"))
        spec.fail("give either `level:` or `density:`, not both (density solves the level)");
    if (spec.has("density")) {
        const RecipeNode d = spec["density"];
        const double rho = d.number();
        if (!(rho > 0.0 && rho < 1.0))
            d.fail("density is a relative density between 0 and 1 (exclusive), got " + d.yaml().Scalar() +
                   "; for 30 % write 0.30");
        node.density = rho;
        node.solid = LevelSolid::unsolved(std::move(raw), side);
    } else if (rule == LevelRule::SolvedElsewhere) {
        node.solid = LevelSolid::unsolved(std::move(raw), side);
    } else if (spec.has("level")) {
        const double level = spec["level"].number();
        if (side == SolidSide::Band && !(level > 0.0))
            spec["level"].fail("a sheet's level is its half-thickness t in |f| <= t and must be greater than zero");
        node.solid = std::make_shared<LevelSolid>(std::move(raw), side, level);
    } else if (rule == LevelRule::Required) {
        spec.fail("give `level:` (for a sheet, the half-thickness t in |f| <= t) or `density:`");
    } else {
        node.solid = std::make_shared<LevelSolid>(std::move(raw), side, defaultLevel);
    }
    return node.solid;
}

void refuseUnresolvedDesign(const RecipeNode& key)
{
    key.fail(
        "this key asks for a property (a homogenized modulus), which a job resolves before it builds the "
        "fields (voxlat run / properties, Python voxlat.Job); this builder cannot");
}

}  // namespace voxlat
