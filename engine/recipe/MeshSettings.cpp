#include "engine/recipe/MeshSettings.h"

#include "engine/recipe/Recipe.h"

#include <cmath>
#include <sstream>

namespace voxlat {

const std::vector<KeySpec>& meshKeys()
{
    using namespace valueSchema;
    static const std::vector<KeySpec> keys{
        {"file", string(), "the mesh file inside the output folder: .stl, .3mf, .ply or .obj", "required"},
        {"project",
         {{"type", {"string", "boolean"}}},
         "vertices moved onto the true surface by Newton steps along the field's gradient (on / off)",
         "on with `tolerance`, else off"},
        {"tolerance", number(),
         "error-bounded decimation: every point of every triangle stays within this of the true surface (mm)",
         "none (no decimation)"},
        {"refine",
         {{"type", {"string", "boolean"}}},
         "with `tolerance`, for a smooth result: on, meshed on a grid up to 5 times coarser than the recipe's and "
         "its triangles bisected where they stray (fast); off, meshed on a grid fine enough for the tolerance and "
         "decimated (slower, about a third fewer triangles)",
         "on"},
        {"strict",
         {{"type", {"string", "boolean"}}},
         "with `tolerance`: on, a mesh that strays beyond the tolerance fails the job (exit 3); off, it is written "
         "with the warning `mesh_tolerance` (its largest stray, and a voxel and a tolerance that meet it)",
         "off"},
        {"extractor", oneOfWords(meshExtractorNames()),
         "how the grid becomes triangles: marching-cubes (the grid's voxels) or bcc (marching tetrahedra on the "
         "body-centred-cubic lattice: the voxels plus the field at the cube centres; more, less regular triangles)",
         "marching-cubes"}};
    return keys;
}

const std::vector<std::string>& meshExtractorNames()
{
    static const std::vector<std::string> names{"marching-cubes", "bcc"};
    return names;
}

const std::string& meshExtractorName(MeshExtractor extractor)
{
    return meshExtractorNames()[std::size_t(extractor)];
}

std::optional<MeshExtractor> meshExtractorFromName(const std::string& word)
{
    const std::vector<std::string>& names = meshExtractorNames();
    for (std::size_t i = 0; i < names.size(); ++i)
        if (names[i] == word) return MeshExtractor(i);
    return std::nullopt;
}

double checkMeshTolerance(double tolerance, const std::string& where)
{
    if (!(tolerance > 0.0) || !std::isfinite(tolerance)) {
        std::ostringstream msg;
        msg << where << ": the mesh tolerance must be a positive distance in mm, like 0.01; " << tolerance << " is not";
        throw InputError(msg.str());
    }
    return tolerance;
}

namespace {
/// The value of an on/off key (`true` and `false` too); @a meaning says what each word does.
bool onOff(const RecipeNode& node, const std::string& meaning)
{
    const std::string word = node.yaml().Scalar();
    if (word == "on" || word == "true") return true;
    if (word == "off" || word == "false") return false;
    node.fail("expected " + meaning);
}
}  // namespace

MeshSettings parseMeshSettings(const RecipeNode& spec)
{
    MeshSettings s;
    if (spec.isScalar()) {
        checkOutputName(spec, "mesh");
        s.file = spec.string();
        return s;
    }
    if (!spec.isMap())
        spec.fail("expected a file name like `part.stl` or a map like `{file: part.stl, tolerance: 0.01}`");
    spec.checkKeys(keyNames(meshKeys()));
    if (!spec.has("file")) spec.fail("missing key `file`: the mesh file, like `{file: part.stl, tolerance: 0.01}`");
    checkOutputName(spec["file"], "mesh");
    s.file = spec["file"].string();
    if (spec.has("tolerance")) {
        const RecipeNode t = spec["tolerance"];
        const double value = t.number();
        if (!(value > 0.0))
            t.fail(
                "the tolerance is how far (mm) any point of the mesh may stray from the true surface: a "
                "positive number like 0.01; " +
                t.yaml().Scalar() + " is not");
        s.options.tolerance = value;
        s.options.toleranceWhere = t.where();
        s.options.project = true;
    }
    if (spec.has("extractor")) {
        const RecipeNode e = spec["extractor"];
        const std::string word = e.isScalar() ? e.yaml().Scalar() : "";
        const std::optional<MeshExtractor> extractor = meshExtractorFromName(word);
        if (!extractor) {
            const std::string close = closestMatch(word, meshExtractorNames());
            e.fail("unknown extractor `" + word + "`: expected one of " + joinWords(meshExtractorNames()) +
                   (close.empty() ? "" : "; did you mean `" + close + "`?"));
        }
        s.options.extractor = *extractor;
    }
    if (spec.has("refine")) {
        s.options.refine =
            onOff(spec["refine"], "`on` (a coarse grid refined where it strays) or `off` (a finer grid, decimated)");
        if (!s.options.tolerance)
            spec["refine"].fail(
                "`refine` applies to a mesh with a `tolerance`, like `{file: part.stl, tolerance: 0.01, refine: off}`");
    }
    if (spec.has("strict")) {
        s.options.strict =
            onOff(spec["strict"], "`on` (a mesh beyond its tolerance fails the job) or `off` (a warning)");
        if (!s.options.tolerance)
            spec["strict"].fail(
                "`strict` applies to a mesh with a `tolerance`, like `{file: part.stl, tolerance: 0.01, "
                "strict: on}`");
    }
    if (spec.has("project"))
        s.options.project =
            onOff(spec["project"], "`on` (vertices on the true surface) or `off` (marching cubes' vertices)");
    // Refinement starts from a projected marching-cubes mesh on a coarse grid.
    if (spec.has("refine") && (!s.options.project || s.options.extractor != MeshExtractor::MarchingCubes))
        spec["refine"].fail("`refine` applies to a projected marching-cubes mesh: drop `project: off` or `extractor: " +
                            meshExtractorName(s.options.extractor) + "`, or `refine`");
    return s;
}

}  // namespace voxlat
