#include "engine/recipe/Materials.h"

#include <cmath>
#include <sstream>

namespace voxlat {

const std::vector<Material>& materialPresets()
{
    static const std::vector<Material> presets{
        {"form2", 1600.0, 0.38, std::nullopt,
         "Formlabs Form 2 resin as modelled in the convolution-lattice paper (shared/seeds/002): E 1.6 GPa, nu 0.38",
         ""},
        {"ti6al4v", 113800.0, 0.342, 6.7,
         "ASM Aerospace Specification Metals, Titanium Ti-6Al-4V (Grade 5), annealed: E 113.8 GPa, nu 0.342, "
         "k 6.7 W/(m K)",
         ""},
        {"316l", 193000.0, 0.27, 16.3,
         "ASM / MatWeb, AISI Type 316L stainless steel: E 193 GPa, nu 0.27, k 16.3 W/(m K)", ""},
        {"17-4ph", 196500.0, 0.272, 17.9,
         "AK Steel 17-4 PH product data bulletin (condition H900): E 28.5e6 psi = 196.5 GPa, nu 0.272, "
         "k 17.9 W/(m K) at 100 C",
         ""},
        {"pa12", 1700.0, 0.39, 0.22,
         "EOS PA 2200 (PA12) material data sheet: tensile modulus 1700 MPa; nu 0.39 and k 0.22 W/(m K) are typical "
         "polyamide 12 values, not from the data sheet",
         ""}};
    return presets;
}

const std::vector<KeySpec>& materialKeys()
{
    using namespace valueSchema;
    static const std::vector<KeySpec> keys{
        {"preset", oneOfWords({"form2", "ti6al4v", "316l", "17-4ph", "pa12"}), "a named material to start from",
         "none"},
        {"E",
         {{"type", {"string", "number"}}},
         "Young's modulus with a unit: `1.6 GPa`, `1600 MPa`, `1.6e9 Pa`",
         "the preset's; required without one"},
        {"nu", number(), "Poisson's ratio, between -1 and 0.5", "the preset's; required without one"},
        {"k", number(), "thermal conductivity, W/(m K) (the conductivity tensor is also reported relative to it)",
         "the preset's; none"}};
    return keys;
}

double parseModulusMPa(const RecipeNode& node)
{
    const std::string text = node.yaml().Scalar();
    std::istringstream in(text);
    double value = 0.0;
    std::string unit;
    if (!(in >> value)) node.fail("expected a modulus with a unit, like `1.6 GPa`, got `" + text + "`");
    in >> unit;
    std::string rest;
    if (in >> rest) node.fail("expected a modulus with a unit, like `1.6 GPa`, got `" + text + "`");
    double scale = 0.0;
    if (unit == "Pa") scale = 1e-6;
    if (unit == "kPa") scale = 1e-3;
    if (unit == "MPa") scale = 1.0;
    if (unit == "GPa") scale = 1e3;
    if (scale == 0.0)
        node.fail("a modulus needs its unit (Pa, kPa, MPa or GPa), like `" + text + " GPa` or `" + text +
                  " MPa`; got `" + text + "`");
    if (!(value > 0.0) || !std::isfinite(value)) node.fail("expected a positive modulus, got `" + text + "`");
    // Diamond, the stiffest solid, is about 1.2 TPa; rubber about 1 MPa. Far outside, the
    // solver's numbers overflow (1e308 GPa) or vanish.
    const double mpa = value * scale;
    if (mpa > 1e7 || mpa < 1e-6)
        node.fail("a modulus of " + text +
                  " is outside any material's (1 Pa to 10 000 GPa): check the number and its unit");
    return mpa;
}

namespace {

std::vector<std::string> presetNames()
{
    std::vector<std::string> names;
    for (const Material& m : materialPresets()) names.push_back(m.name);
    return names;
}

const Material* findPreset(const RecipeNode& node)
{
    const std::string name = node.string();
    for (const Material& m : materialPresets())
        if (m.name == name) return &m;
    std::string message = "unknown material `" + name + "`";
    const std::string guess = closestMatch(name, presetNames());
    if (!guess.empty()) message += "; did you mean `" + guess + "`?";
    node.fail(message + " (materials: " + joinWords(presetNames()) + ", or a map {E: 1.6 GPa, nu: 0.38})");
    return nullptr;
}

std::array<double, 3> triple(const RecipeNode& n, const char* what)
{
    if (!n.isSequence() || n.size() != 3) n.fail(std::string("expected [x, y, z]: ") + what);
    return {n.at(0).number(), n.at(1).number(), n.at(2).number()};
}

}  // namespace

Material parseMaterial(const RecipeNode& node)
{
    Material m;
    if (node.isScalar()) {
        m = *findPreset(node);
        m.where = node.where();
        return m;
    }
    if (!node.isMap())
        node.fail("expected a material name (" + joinWords(presetNames()) + ") or {E: 1.6 GPa, nu: 0.38}");
    node.checkKeys(keyNames(materialKeys()));
    if (node.has("preset")) {
        m = *findPreset(node["preset"]);
    } else {
        if (!node.has("E") || !node.has("nu"))
            node.fail("a material needs `E` (with a unit) and `nu`, e.g. {E: 1.6 GPa, nu: 0.38}, or `preset:`");
        m.name = "custom";
        m.source = "given in the recipe";
    }
    if (node.has("E")) m.modulusMPa = parseModulusMPa(node["E"]);
    if (node.has("nu")) {
        m.poisson = node["nu"].number();
        if (!(m.poisson > -1.0 && m.poisson < 0.5)) node["nu"].fail("Poisson's ratio must lie between -1 and 0.5");
    }
    if (node.has("k")) m.conductivity = node["k"].positiveNumber();
    if (node.has("preset") && (node.has("E") || node.has("nu") || node.has("k")))
        m.source += " (values changed in the recipe)";
    m.where = node.where();
    return m;
}

const std::vector<KeySpec>& propertiesKeys()
{
    using namespace valueSchema;
    static const std::vector<KeySpec> keys{
        {"cell", vec3(), "the periodic cell's size [a, b, c] (mm)", "the result's periods"},
        {"origin", vec3(), "the cell's minimum corner (mm)", "the domain's minimum corner"},
        {"resolution", number(), "voxels along the cell's longest side",
         "chosen by a convergence check (24, 34, 48, ... voxels)"},
        {"convergence", number(), "the relative error in E the default resolution is chosen for", "0.02"},
        {"max_resolution", number(), "the finest resolution the convergence check may reach", "136"},
        {"tolerance", number(), "relative residual each load case is solved to", "1e-6"},
        {"export", string(), "FILE.inp: the cell's elastic constants as a CalculiX/Abaqus *MATERIAL card", "—"}};
    return keys;
}

PropertiesSettings parseProperties(const RecipeNode* node, const std::string& fallbackWhere)
{
    PropertiesSettings s;
    s.where = fallbackWhere;
    if (!node) return s;
    if (!node->isMap()) node->fail("expected a map like {cell: [10, 10, 10], resolution: 40}");
    node->checkKeys(keyNames(propertiesKeys()));
    s.where = node->where();
    if (node->has("cell")) {
        s.cell = triple((*node)["cell"], "the cell's size (mm)");
        for (double v : *s.cell)
            if (!(v > 0.0)) (*node)["cell"].fail("cell sides must be positive (mm)");
    }
    if (node->has("origin")) s.origin = triple((*node)["origin"], "the cell's minimum corner (mm)");
    if (node->has("resolution")) {
        const double v = (*node)["resolution"].number();
        if (v != std::floor(v) || v < 4 || v > 512)
            (*node)["resolution"].fail("expected a whole number of voxels from 4 to 512 along the cell's longest side");
        s.resolution = int(v);
    }
    if (node->has("convergence")) {
        s.convergence = (*node)["convergence"].positiveNumber();
        if (s.convergence >= 0.5)
            (*node)["convergence"].fail("expected a relative error in E below 0.5, like 0.02 (2 %)");
    }
    if (node->has("max_resolution")) {
        const double v = (*node)["max_resolution"].number();
        if (v != std::floor(v) || v < 48 || v > 512)
            (*node)["max_resolution"].fail(
                "expected a whole number of voxels from 48 to 512 (the convergence check needs 24, 34 and 48)");
        s.maxResolution = int(v);
    }
    if (node->has("export")) {
        const std::string file = (*node)["export"].string();
        if (file.size() < 5 || file.substr(file.size() - 4) != ".inp")
            (*node)["export"].fail("expected a file name ending in .inp (a CalculiX/Abaqus input deck), like cell.inp");
        s.exportFile = file;
    }
    if (node->has("tolerance")) {
        s.tolerance = (*node)["tolerance"].positiveNumber();
        // Double-precision CG on a voxel model reaches about 1e-12 at best: a smaller tolerance
        // could never be met (at 1e-15 the conductivity solve diverged).
        if (s.tolerance >= 0.1 || s.tolerance < 1e-10)
            (*node)["tolerance"].fail(
                "expected a relative residual from 1e-10 to 0.1, like 1e-6 (double precision "
                "cannot meet a smaller one)");
    }
    return s;
}

}  // namespace voxlat
