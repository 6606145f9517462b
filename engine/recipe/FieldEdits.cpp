#include "engine/recipe/FieldEdits.h"

#include "engine/recipe/Recipe.h"

#include <algorithm>
#include <cstdio>
#include <vector>

namespace voxlat {

namespace {

/// A copy of the map @a map without @a drop. Children are shared, not copied (they keep their
/// recipe lines); only the maps on a path that is edited are new, so the recipe is never changed.
YAML::Node mapWithout(const YAML::Node& map, const std::vector<std::string>& drop)
{
    YAML::Node out(YAML::NodeType::Map);
    for (auto it = map.begin(); it != map.end(); ++it) {
        const std::string key = it->first.Scalar();
        if (std::find(drop.begin(), drop.end(), key) == drop.end()) out[key] = it->second;
    }
    return out;
}

std::optional<Vec3d> readVec3(const YAML::Node& node, bool scalarToo)
{
    try {
        if (scalarToo && node.IsScalar()) return Vec3d(node.as<double>());
        if (node.IsSequence() && node.size() == 3)
            return Vec3d(node[0].as<double>(), node[1].as<double>(), node[2].as<double>());
    } catch (const YAML::Exception&) {
    }
    return std::nullopt;
}

}  // namespace

YAML::Node exactNumber(double v)
{
    char text[40];
    std::snprintf(text, sizeof text, "%.17g", v);
    return YAML::Node(std::string(text));
}

FieldFacts readFieldFacts(const YAML::Node& spec)
{
    FieldFacts f;
    if (!spec.IsMap()) return f;
    const YAML::Node density = spec["density"];
    f.hasDensity = bool(density);
    f.densityScalar = density && density.IsScalar();
    const YAML::Node kernel = spec["kernel"];
    if (kernel && kernel.IsMap()) {
        const YAML::Node gaussian = kernel["gaussian"];
        if (gaussian && gaussian.IsMap()) {
            const YAML::Node sigma = gaussian["sigma"];
            if (sigma && sigma.IsScalar()) try {
                    f.sigma = sigma.as<double>();
                } catch (const YAML::Exception&) {
                }
        }
    }
    const YAML::Node struts = spec["struts"];
    if (!struts || !struts.IsMap()) return f;
    f.boxFrame = struts["cell"] && struts["size"];
    for (const char* other : {"within", "skin", "between", "cylinder", "sphere", "wireframe"})
        if (struts[other]) f.boxFrame = false;
    bool plain = bool(struts["size"]);
    for (auto it = struts.begin(); it != struts.end(); ++it) {
        const std::string key = it->first.Scalar();
        if (key != "cell" && key != "size" && key != "origin") plain = false;
    }
    if (!plain) return f;
    const std::optional<Vec3d> cell = readVec3(struts["size"], true);
    if (!cell) return f;
    if (struts["origin"]) {
        // Three numbers or nothing: an origin that does not read leaves no plain box.
        try {
            const YAML::Node o = struts["origin"];
            f.plainBoxOrigin = Vec3d(o[0].as<double>(), o[1].as<double>(), o[2].as<double>());
        } catch (const YAML::Exception&) {
            return f;
        }
    }
    f.plainBoxCell = cell;
    return f;
}

YAML::Node editedSpec(const YAML::Node& spec, const FieldEdit& edit)
{
    std::vector<std::string> drop{"stiffness", "optimize"};
    if (edit.capsule) drop.insert(drop.end(), {"radius", "kernel"});
    YAML::Node s = mapWithout(spec, drop);
    if (edit.density) s["density"] = exactNumber(*edit.density);
    if (edit.sigma) {
        const YAML::Node kernelIn = spec["kernel"];
        YAML::Node kernel = mapWithout(kernelIn, {});
        YAML::Node gaussian = mapWithout(kernelIn["gaussian"], {});
        gaussian["sigma"] = exactNumber(*edit.sigma);
        kernel["gaussian"] = gaussian;
        s["kernel"] = kernel;
    }
    if (edit.capsule) s["kernel"] = YAML::Node(std::string("capsule"));
    if (edit.count || edit.origin) {
        YAML::Node struts = mapWithout(spec["struts"], {});
        if (edit.count) {
            YAML::Node count(YAML::NodeType::Sequence);
            for (int c : *edit.count) count.push_back(c);
            struts["count"] = count;
        }
        if (edit.origin) {
            YAML::Node origin(YAML::NodeType::Sequence);
            for (double o : *edit.origin) origin.push_back(exactNumber(o));
            struts["origin"] = origin;
        }
        s["struts"] = struts;
    }
    return s;
}

void editField(Recipe& recipe, const std::string& name, const FieldEdit& edit)
{
    const YAML::Node spec = editedSpec(recipe.fieldIndex.at(name), edit);
    // An assignment to the handle writes through to the node it shares with `root`: the canonical
    // recipe (report.json `recipe_canonical`, the hash) shows the solved value.
    recipe.fieldIndex[name] = spec;
    recipe.fieldFacts[name] = readFieldFacts(spec);
    recipe.designs.erase(std::remove_if(recipe.designs.begin(), recipe.designs.end(),
                                        [&](const FieldDesign& d) { return d.field == name; }),
                         recipe.designs.end());
}

Recipe trialRecipe(const Recipe& base, const std::string& name, const FieldEdit& edit)
{
    Recipe r = base;
    // A new handle, not an assignment: the copy's handles share their nodes with @a base's (and
    // its `root`), and an assignment would write the trial's spec into the parent recipe.
    const YAML::Node spec = editedSpec(base.fieldIndex.at(name), edit);
    r.fieldIndex.erase(name);
    r.fieldIndex.emplace(name, spec);
    r.fieldFacts[name] = readFieldFacts(spec);
    r.designs.clear();  // the trial builds only @a name, whose targets the edit resolved
    r.fieldNames = {name};
    r.result = name;
    r.outputs.clear();
    return r;
}

}  // namespace voxlat
