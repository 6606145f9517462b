#include "engine/FieldBuilder.h"

#include <algorithm>
#include <iostream>

namespace voxlat {

FieldBuilder::FieldBuilder(const Recipe& recipe) : mRecipe(recipe) {}

const std::vector<NodeType>& FieldBuilder::nodeTypes()
{
    static const std::vector<NodeType> types = [] {
        std::vector<NodeType> t;
        addLatticeNodeTypes(t);
        addStrutNodeTypes(t);
        addDesignNodeTypes(t);
        addExprNodeTypes(t);
        addShapeNodeTypes(t);
        return t;
    }();
    return types;
}

void FieldBuilder::warn(const std::string& message)
{
    std::cerr << "warning: " << message << "\n";
    mWarnings.push_back(message);
}

FieldPtr FieldBuilder::field(const std::string& name)
{
    if (auto it = mBuilt.find(name); it != mBuilt.end()) return it->second;
    const RecipeNode spec = mRecipe.fieldSpec(name);
    if (std::find(mInProgress.begin(), mInProgress.end(), name) != mInProgress.end()) {
        std::string cycle;
        for (auto it = std::find(mInProgress.begin(), mInProgress.end(), name); it != mInProgress.end(); ++it)
            cycle += *it + " -> ";
        spec.fail("fields refer to each other in a cycle: " + cycle + name);
    }
    mInProgress.push_back(name);
    FieldPtr f = buildSpec(spec, name);
    mInProgress.pop_back();
    mBuilt[name] = f;
    return f;
}

FieldPtr FieldBuilder::operand(const RecipeNode& spec, const std::string& name)
{
    if (spec.isScalar()) return field(spec.string());
    return buildSpec(spec, name);
}

FieldPtr FieldBuilder::buildSpec(const RecipeNode& spec, const std::string& name)
{
    const auto& types = nodeTypes();
    std::vector<std::string> typeKeys;
    for (const NodeType& t : types) typeKeys.push_back(t.key);
    if (!spec.isMap()) spec.fail("expected a map naming the node type, one of: " + [&] {
        std::string s;
        for (const auto& k : typeKeys) s += (s.empty() ? "" : ", ") + k;
        return s;
    }());
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
        std::string valid;
        for (const auto& k : typeKeys) valid += (valid.empty() ? "" : ", ") + k;
        spec.fail(message + " (types: " + valid + ")");
    }
    spec.checkKeys(found->keys);
    return found->build(*this, spec, name);
}

}  // namespace voxlat
