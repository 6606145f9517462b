#include "engine/recipe/DesignTargets.h"

#include "engine/core/Format.h"
#include "engine/recipe/Materials.h"

#include <cmath>

namespace voxlat {

namespace {

std::optional<int> readResolution(const RecipeNode& node)
{
    const double v = node.number();
    if (v != std::floor(v) || v < 8 || v > 256)
        node.fail("expected a whole number of voxels from 8 to 256 along the cell's longest side");
    return int(v);
}

}  // namespace

const std::vector<KeySpec>& stiffnessKeys()
{
    using namespace valueSchema;
    static const std::vector<KeySpec> keys{
        {"E", {{"type", {"string", "number"}}}, "target Young's modulus with a unit: `40 MPa`, `1.2 GPa`", "—"},
        {"E_ratio", number(), "target E / E_s of the material, in (0, 1)", "—"},
        {"axis", oneOfWords({"x", "y", "z"}), "the axis the modulus is measured along", "z"},
        {"resolution", number(), "voxels along the cell's longest side while solving (8 to 256)",
         "`properties: resolution`, else 32"},
        {"tolerance", number(), "relative error of the achieved modulus, in (0, 0.2)", "0.01"}};
    return keys;
}

const std::vector<KeySpec>& optimizeKeys()
{
    using namespace valueSchema;
    static const std::vector<KeySpec> keys{
        {"sigma",
         {{"type", "array"}, {"items", number()}, {"minItems", 2}, {"maxItems", 2}},
         "[lo, hi]: the range of the Gaussian kernel's sigma searched (mm)",
         "required"},
        {"axis", oneOfWords({"x", "y", "z"}), "the axis whose modulus is maximised", "z"},
        {"resolution", number(), "voxels along the cell's longest side while searching (8 to 256)",
         "`properties: resolution`, else 32"},
        {"tolerance", number(), "sigma is found to this (mm)", "(hi - lo) / 100"},
        {"samples", number(), "points of the coarse sweep before the golden-section refinement (3 to 20)", "5"},
        {"baseline", boolean(), "also homogenize the capsule (Boolean-joint) lattice at the same density", "true"}};
    return keys;
}

StiffnessTarget parseStiffness(const RecipeNode& node)
{
    if (!node.isMap()) node.fail("expected a map like {E: 40 MPa, axis: z} or {E_ratio: 0.05}");
    node.checkKeys(keyNames(stiffnessKeys()));
    StiffnessTarget t;
    t.where = node.where();
    t.context = node.context();
    if (node.has("E") == node.has("E_ratio"))
        node.fail("give the target modulus either as `E: 40 MPa` or as `E_ratio: 0.05` (E / E_s), one of them");
    if (node.has("E")) t.modulusMPa = parseModulusMPa(node["E"]);
    if (node.has("E_ratio")) {
        const double r = node["E_ratio"].number();
        if (!(r > 0.0 && r < 1.0))
            node["E_ratio"].fail("E_ratio is the lattice's modulus over the solid's, between 0 and 1 (exclusive)");
        t.ratio = r;
    }
    if (node.has("axis")) t.axis = node["axis"].axis();
    if (node.has("resolution")) t.resolution = readResolution(node["resolution"]);
    if (node.has("tolerance")) {
        t.tolerance = node["tolerance"].positiveNumber();
        if (t.tolerance >= 0.2) node["tolerance"].fail("expected a relative error below 0.2, like 0.01");
    }
    return t;
}

SigmaOptimization parseOptimize(const RecipeNode& node)
{
    if (!node.isMap()) node.fail("expected a map like {sigma: [0.4, 1.6], axis: z}");
    node.checkKeys(keyNames(optimizeKeys()));
    SigmaOptimization o;
    o.where = node.where();
    o.context = node.context();
    if (!node.has("sigma")) node.fail("give the range searched: `sigma: [0.4, 1.6]` (mm)");
    const RecipeNode s = node["sigma"];
    if (!s.isSequence() || s.size() != 2) s.fail("expected [lo, hi]: the sigma range searched (mm)");
    o.lo = s.at(0).number();
    o.hi = s.at(1).number();
    if (!(o.lo > 0.0 && o.hi > o.lo)) s.fail("expected 0 < lo < hi (mm)");
    o.tolerance = (o.hi - o.lo) / 100.0;
    if (node.has("axis")) o.axis = node["axis"].axis();
    if (node.has("resolution")) o.resolution = readResolution(node["resolution"]);
    if (node.has("tolerance")) {
        o.tolerance = node["tolerance"].positiveNumber();
        if (o.tolerance >= o.hi - o.lo) node["tolerance"].fail("expected a tolerance smaller than the range (mm)");
    }
    if (node.has("samples")) {
        const double v = node["samples"].number();
        if (v != std::floor(v) || v < 3 || v > 20) node["samples"].fail("expected a whole number from 3 to 20");
        o.samples = int(v);
    }
    if (node.has("baseline")) o.baseline = node["baseline"].boolean();
    return o;
}

void StiffnessTarget::fail(const std::string& message) const
{
    throw InputError(where + ": " + context + ": " + message);
}

void SigmaOptimization::fail(const std::string& message) const
{
    throw InputError(where + ": " + context + ": " + message);
}

namespace {

void requireMaterial(const std::optional<Material>& material, const RecipeNode& key, const std::string& what)
{
    if (!material)
        key.fail(what +
                 " needs the material the lattice is made of: add `material: form2` (or ti6al4v, 316l, 17-4ph, "
                 "pa12) or `material: {E: 1.6 GPa, nu: 0.38}` at the top of the recipe");
}

}  // namespace

std::optional<FieldDesign> parseFieldDesign(const RecipeNode& spec, const std::string& name,
                                            const std::optional<Material>& material)
{
    if (!spec.isMap()) return std::nullopt;
    FieldDesign d;
    d.field = name;
    if (spec.has("stiffness")) {
        if (!spec.has("tpms") && !spec.has("struts"))
            spec["stiffness"].fail("`stiffness:` is a key of `tpms` and `struts` nodes");
        const RecipeNode key = spec["stiffness"];
        StiffnessTarget target = parseStiffness(key);
        for (const char* other : {"density", "level", "radius", "thickness", "wall", "layer"})
            if (spec.has(other))
                key.fail(std::string("give either `stiffness:` or `") + other +
                         ":`, not both (the stiffness solves the density, which sets the " +
                         (std::string(other) == "density" ? "level" : "size") + ")");
        if (spec.has("optimize")) key.fail("`optimize:` needs a fixed `density:`; give it instead of `stiffness:`");
        requireMaterial(material, key, "a stiffness target");
        const double Es = material->modulusMPa;
        target.goalMPa = target.modulusMPa ? *target.modulusMPa : *target.ratio * Es;
        if (target.goalMPa >= Es)
            key.fail("the target modulus " + formatNumber(target.goalMPa) + " MPa along " +
                     std::string(1, "xyz"[target.axis]) + " is not below the solid's own (" + formatNumber(Es) +
                     " MPa, " + material->name + "): no lattice of it reaches that");
        d.stiffness = std::move(target);
        return d;
    }
    if (!spec.has("optimize")) return std::nullopt;
    if (spec["optimize"].isScalar() && spec["optimize"].string() == "off") {
        d.optimizeOff = true;
        return d;
    }
    if (!spec.has("struts")) spec["optimize"].fail("`optimize:` is a key of `struts` nodes");
    const RecipeNode key = spec["optimize"];
    SigmaOptimization o = parseOptimize(key);
    if (!spec.has("density") || !spec["density"].isNumber())
        key.fail("`optimize:` compares joints at a fixed density: give the node `density:` (one number)");
    if (!spec.has("kernel") || !spec["kernel"].has("gaussian"))
        key.fail("`optimize:` picks the Gaussian kernel's sigma: give `kernel: {gaussian: {sigma: S}}`");
    requireMaterial(material, key, "`optimize:`");
    o.density = spec["density"].number();
    d.optimize = std::move(o);
    return d;
}

}  // namespace voxlat
