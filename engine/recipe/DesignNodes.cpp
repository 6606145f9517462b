// Recipe node types for design spaces from meshes, shells, infill, and the conformal frames of
// lattices (issue 6).
#include "engine/core/Format.h"
#include "engine/parts/MeshDesignSpace.h"
#include "engine/recipe/DrainSpec.h"
#include "engine/recipe/FieldBuilder.h"
#include "fields/frames/CoordinateMap.h"
#include "fields/shapes/Boolean.h"
#include "fields/shapes/Unary.h"

#include <cmath>
#include <iostream>
#include <numbers>

namespace voxlat {

namespace {

/// Millimetres per unit for a mesh's `units:`.
double unitScale(const RecipeNode& node)
{
    const std::string u = node.string();
    if (u == "mm") return 1.0;
    if (u == "um" || u == "micron") return 0.001;
    if (u == "cm") return 10.0;
    if (u == "m") return 1000.0;
    if (u == "in" || u == "inch") return 25.4;
    if (u == "ft") return 304.8;
    const std::string guess = closestMatch(u, {"mm", "um", "cm", "m", "in", "inch", "ft"});
    node.fail("unknown unit `" + u + "`" + (guess.empty() ? "" : "; did you mean `" + guess + "`?") +
              " (units: um, mm, cm, m, in, ft)");
}

void passWarnings(JobContext& context, const MeshDesignSpace& space, const RecipeNode& spec, std::size_t from)
{
    for (std::size_t i = from; i < space.warnings().size(); ++i)
        context.warn("design_space", spec.where() + ": " + spec.context() + ": " + space.warnings()[i]);
}

FieldPtr buildMesh(FieldBuilder& builder, const RecipeNode& spec, const std::string& name)
{
    const Recipe& recipe = builder.recipe();
    const RecipeNode file = spec["mesh"];
    MeshSpaceOptions options;
    options.voxel = recipe.voxel;
    // Grid samples on the domain's voxel centres: the recipe's domain, or the lattice
    // (k + 1/2) * voxel the Job puts an automatic domain's centres on.
    options.sampleOrigin = (recipe.domainBox ? recipe.domainBox->min : Vec3d(0.0)) + Vec3d(0.5 * recipe.voxel);
    options.repair = spec.has("repair") && spec["repair"].boolean();
    if (spec.has("units")) options.unitMm = unitScale(spec["units"]);
    options.domain = recipe.domainBox;
    std::shared_ptr<MeshDesignSpace> space;
    try {
        space = std::make_shared<MeshDesignSpace>(readPartMesh(recipe.resolve(file.string()), file.string()),
                                                  file.string(), options);
    } catch (const InputError& e) {
        file.fail(e.what());
    }
    passWarnings(builder.context(), *space, spec, 0);
    const std::size_t printed = space->warnings().size();
    JobContext* context = &builder.context();
    builder.addPreparation({"design space " + name, [context, space, spec, printed] {
                                try {
                                    space->build();
                                } catch (const InputError& e) {
                                    spec["mesh"].fail(e.what());
                                }
                                passWarnings(*context, *space, spec, printed);
                            }});
    builder.addReporter([space, name](nlohmann::json& report) { report["parts"][name] = space->report(); });
    return std::make_shared<PartField>(space);
}

/// The design space behind a part field, if it is a mesh (to ask for a deeper band).
MeshDesignSpace* meshSpaceOf(const FieldPtr& part)
{
    const auto* p = dynamic_cast<const PartField*>(part.get());
    return p ? p->space().get() : nullptr;
}

}  // namespace

std::function<double()> partMeshVolume(const FieldPtr& part)
{
    MeshDesignSpace* space = meshSpaceOf(part);
    return [space] { return space ? space->meshVolume() : 0.0; };
}

namespace {

double wallThickness(const RecipeNode& node, double voxel, const std::string& what)
{
    const double t = node.number();
    if (!(t >= voxel))
        node.fail(what + " must be at least one voxel (" + std::to_string(voxel) + " mm) to show in the result; got " +
                  node.yaml().Scalar());
    return t;
}

/// @a solid with drain channels through @a part when @a s has `drain: {diameter: D}` (planned by
/// the job once the levels are solved), else @a solid.
FieldPtr withDrains(FieldBuilder& builder, const RecipeNode& s, const std::string& name, FieldPtr solid,
                    const FieldPtr& part, double wall)
{
    if (!s.has("drain")) return solid;
    const RecipeNode d = s["drain"];
    const DrainSpec spec = parseDrain(d, true);
    const double diameter = spec.diameter;
    const double voxel = builder.recipe().voxel;
    if (diameter < 2.0 * voxel)
        d["diameter"].fail("a drain channel of " + formatNumber(diameter) + " mm is less than two voxels (" +
                           formatNumber(2.0 * voxel) +
                           " mm) across: it would not show on the grid; use 1.5 mm or more "
                           "(resin drains through 1.5-3 mm holes)");
    auto drained = std::make_shared<DrainedSolid>(std::move(solid));
    builder.addDrain({name, d.where(), drained, part, diameter, wall, spec.up});
    return drained;
}

FieldPtr buildShell(FieldBuilder& builder, const RecipeNode& spec, const std::string& name)
{
    const RecipeNode s = spec["shell"];
    s.checkKeys({"part", "thickness", "drain"});
    const FieldPtr part = builder.operand(s["part"], name + "/part");
    const double t = wallThickness(s["thickness"], builder.recipe().voxel, "the shell's thickness");
    if (MeshDesignSpace* space = meshSpaceOf(part)) space->requireInteriorBand(t + 2 * builder.recipe().voxel);
    // The wall: inside the part, outside the part shrunk by t: max(d, -(d + t)).
    const FieldPtr inner = std::make_shared<UnaryField>(part, UnaryOp::Offset, t);
    return withDrains(builder, s, name,
                      std::make_shared<BooleanField>(BooleanOp::Difference, std::vector<FieldPtr>{part, inner}), part,
                      t);
}

FieldPtr buildInfill(FieldBuilder& builder, const RecipeNode& spec, const std::string& name)
{
    const RecipeNode s = spec["infill"];
    s.checkKeys({"part", "lattice", "skin", "density", "blend", "material_density", "drain"});
    const double voxel = builder.recipe().voxel;
    const std::string partName = s["part"].isScalar() ? s["part"].string() : name + "/part";
    const FieldPtr part = builder.operand(s["part"], partName);
    const std::string latticeName = s["lattice"].isScalar() ? s["lattice"].string() : name + "/lattice";
    const FieldPtr lattice = builder.operand(s["lattice"], latticeName);
    const double skin = s.has("skin") ? s["skin"].number() : 0.0;
    if (skin != 0.0) wallThickness(s["skin"], voxel, "the skin");
    if (skin < 0.0) s["skin"].fail("the skin is a thickness in millimetres, zero or more");
    const double blend = s.has("blend") ? s["blend"].number() : 0.0;
    if (blend < 0.0) s["blend"].fail("the blend radius must be zero or positive (millimetres)");
    if (blend > 0.0 && skin == 0.0)
        s["blend"].fail("a blend rounds the joint between lattice and skin: give `skin:` too");
    std::optional<double> materialDensity;
    if (s.has("material_density")) materialDensity = s["material_density"].positiveNumber();
    if (MeshDesignSpace* space = meshSpaceOf(part)) space->requireInteriorBand(skin + blend + 2 * voxel);

    // The core: the part shrunk by the skin (negative inside).
    const FieldPtr core = skin > 0.0 ? std::make_shared<UnaryField>(part, UnaryOp::Offset, skin) : part;
    const FieldPtr latticeInCore =
        std::make_shared<BooleanField>(BooleanOp::Intersection, std::vector<FieldPtr>{lattice, core});
    FieldPtr result = latticeInCore;
    if (skin > 0.0) {
        const FieldPtr skinSolid =
            std::make_shared<BooleanField>(BooleanOp::Difference, std::vector<FieldPtr>{part, core});
        // The smooth union fillets the joint; the final intersection keeps the fillet inside the part.
        const FieldPtr joined =
            std::make_shared<BooleanField>(BooleanOp::Union, std::vector<FieldPtr>{skinSolid, latticeInCore}, blend);
        result = blend > 0.0
                     ? std::make_shared<BooleanField>(BooleanOp::Intersection, std::vector<FieldPtr>{joined, part})
                     : joined;
    }

    std::optional<double> density;
    if (s.has("density")) {
        const RecipeNode d = s["density"];
        density = d.number();
        if (!(*density > 0.0 && *density < 1.0))
            d.fail("density is the lattice's share of the space inside the skin, between 0 and 1 (exclusive), got " +
                   d.yaml().Scalar() + "; for 25 % write 0.25");
        LevelNode* node = builder.findLevelNode(latticeName);
        if (!node)
            d.fail("density solves the level of a lattice node (a `tpms`), but `" + latticeName +
                   "` is not one: give the lattice a `level:` instead, or name a tpms node");
        const RecipeNode latticeSpec = s["lattice"].isScalar() ? builder.recipe().fieldSpec(latticeName) : s["lattice"];
        for (const char* key : {"level", "density"})
            if (latticeSpec.has(key))
                latticeSpec[key].fail(std::string("the infill `") + name +
                                      "` solves this lattice's level for its density: remove `" + key + ":` here");
        if (node->solid->isSolved())
            d.fail("the lattice `" + latticeName +
                   "` sets its own size (a fixed level or a thickness in millimetres), so the infill cannot solve it "
                   "for a density: remove `density:` here, or the lattice's size keys there");
        if (node->densityMask && node->densityMask != node->region)
            d.fail("the lattice `" + latticeName +
                   "` already fills another infill; give each infill its own lattice node");
        node->density = density;
        node->densityMask = core;
        node->densityOf = skin > 0.0 ? "the space inside the " + formatNumber(skin) + " mm skin of `" + partName + "`"
                                     : "the inside of `" + partName + "`";
        if (node->region) {
            // A skin frame's lattice fills only its cells: its share of the core within them.
            node->densityMask =
                std::make_shared<BooleanField>(BooleanOp::Intersection, std::vector<FieldPtr>{core, node->region});
            node->densityOf += " within the cells of its skin frame";
        } else if (blend == 0.0) {
            // Skin plus lattice in the core: the mesh's share is read back by the job.
            node->meshShare = LevelNode::MeshShare{name, partMeshVolume(part), skin > 0.0};
        }
    }

    const std::string result0 = builder.recipe().result;
    builder.addReporter([=](nlohmann::json& report) {
        nlohmann::json r{{"part", partName}, {"lattice", latticeName}, {"skin_mm", skin}, {"blend_mm", blend}};
        if (report.contains("parts") && report["parts"].contains(partName)) {
            const auto& p = report["parts"][partName];
            r["part_volume_mm3"] = p["mesh_volume_mm3"];
            if (p.contains("grid_volume_mm3")) r["part_volume_grid_mm3"] = p["grid_volume_mm3"];
        }
        if (density) r["lattice_density_target"] = *density;
        if (report.contains("fields") && report["fields"].contains(latticeName) &&
            report["fields"][latticeName].contains("achieved_density"))
            r["lattice_density"] = report["fields"][latticeName]["achieved_density"];
        if (result0 == name) {
            // The printed solid: skin plus lattice, from the mesh when there is one.
            double solid = -1.0;
            if (report.contains("mesh"))
                solid = report["mesh"]["volume_mm3"].get<double>();
            else if (report.contains("result"))
                solid = report["result"]["volume_mm3"].get<double>();
            if (solid >= 0.0) {
                r["solid_volume_mm3"] = solid;
                if (r.contains("part_volume_mm3"))
                    r["solid_share_of_part"] = solid / r["part_volume_mm3"].get<double>();
                if (materialDensity) {
                    r["material_density_g_cm3"] = *materialDensity;
                    r["mass_g"] = solid * *materialDensity / 1000.0;
                }
            }
        }
        report["infill"][name] = r;
    });
    return withDrains(builder, s, name, result, part, skin > 0.0 ? skin : 2.0 * voxel);
}

}  // namespace

bool levelSolvedByInfill(const Recipe& recipe, const std::string& name)
{
    const YAML::Node fields = recipe.root["fields"];
    if (!fields.IsMap()) return false;
    for (auto it = fields.begin(); it != fields.end(); ++it) {
        if (!it->second.IsMap()) continue;
        // A copy, not a reference: the iterator's value is a temporary (ASan: stack-use-after-scope).
        const YAML::Node spec = it->second;
        const YAML::Node infill = spec["infill"];
        if (!infill.IsDefined() || !infill.IsMap() || !infill["density"] || !infill["lattice"]) continue;
        const YAML::Node lattice = infill["lattice"];
        if (lattice.IsScalar() ? lattice.Scalar() == name : it->first.Scalar() + "/lattice" == name) return true;
    }
    return false;
}

std::optional<Box3> infillPartBox(FieldBuilder& builder, const std::string& name)
{
    const YAML::Node fields = builder.recipe().root["fields"];
    if (!fields.IsMap()) return std::nullopt;
    for (auto it = fields.begin(); it != fields.end(); ++it) {
        if (!it->second.IsMap()) continue;
        const YAML::Node spec = it->second;  // a copy (see levelSolvedByInfill)
        const YAML::Node infill = spec["infill"];
        if (!infill.IsDefined() || !infill.IsMap() || !infill["lattice"] || !infill["part"]) continue;
        const YAML::Node lattice = infill["lattice"];
        const bool fills = lattice.IsScalar() ? lattice.Scalar() == name : it->first.Scalar() + "/lattice" == name;
        // A part given by name is built once, whoever asks first; an inline one is the infill's own.
        if (fills && infill["part"].IsScalar()) return builder.field(infill["part"].Scalar())->support();
    }
    return std::nullopt;
}

FieldPtr applyFrame(const RecipeNode& frame, FieldPtr raw, const Vec3d& cell)
{
    constexpr double pi = std::numbers::pi;
    frame.checkKeys({"cylinder", "sphere", "skin"});
    if (frame.has("cylinder") == frame.has("sphere"))
        frame.fail(
            "a frame is one of `{cylinder: {center, axis, around}}`, `{sphere: {center, axis, around, "
            "pole_to_pole}}` or `{skin: {part, depth, layers}}`");
    auto count = [](const RecipeNode& n) {
        const double v = n.number();
        if (!(v >= 1.0) || v != std::floor(v))
            n.fail("a whole number of cells (1 or more) fits around, so the lattice closes on itself; got " +
                   n.yaml().Scalar());
        return v;
    };
    const bool cylinder = frame.has("cylinder");
    const RecipeNode f = frame[cylinder ? "cylinder" : "sphere"];
    f.checkKeys(cylinder ? std::vector<std::string>{"center", "axis", "around"}
                         : std::vector<std::string>{"center", "axis", "around", "pole_to_pole"});
    const Vec3d center = f.has("center") ? f["center"].vec3() : Vec3d(0.0);
    const Vec3d axis = f.has("axis") ? f["axis"].vec3() : Vec3d(0, 0, 1);
    if (axis.length() <= 0.0) f["axis"].fail("the axis must not be the zero vector");
    Vec3d scale(1.0);
    scale[1] = count(f["around"]) * cell[1] / (2 * pi);
    if (!cylinder) scale[2] = count(f["pole_to_pole"]) * cell[2] / pi;
    return std::make_shared<CoordinateMapField>(std::move(raw), cylinder ? FrameKind::Cylinder : FrameKind::Sphere,
                                                center, axis, scale);
}

void addDesignNodeTypes(std::vector<NodeType>& types)
{
    using namespace valueSchema;
    const auto drainSchema = [] { return voxlat::drainSchema(true); };
    types.push_back({"mesh",
                     {{"mesh", string(), "mesh file (.stl, .obj, .ply, .3mf), relative to the recipe", "required"},
                      {"repair", boolean(), "fill small holes", "false"},
                      {"units", oneOfWords({"um", "mm", "cm", "m", "in", "ft"}), "the file's length unit",
                       "the file's own (3MF), else mm"}},
                     buildMesh});
    types.push_back(
        {"shell",
         {{"shell",
           object({{"part", field(), "the part", "required"},
                   {"thickness", number(), "wall thickness inside the surface (mm)", "required"},
                   {"drain", drainSchema(), "drain holes: every resin trap opened by a channel of D mm", "—"}},
                  {"part", "thickness"}),
           "a solid wall inside a part's surface: {part, thickness, drain}", "required"}},
         buildShell});
    types.push_back(
        {"infill",
         {{"infill",
           object({{"part", field(), "the part (a mesh or any closed field)", "required"},
                   {"lattice", field(), "the lattice filling the core", "required"},
                   {"skin", number(), "skin thickness inside the part's surface (mm)", "0"},
                   {"density", density(), "the lattice's share of the space inside the skin", "—"},
                   {"blend", number(), "smooth-union radius where lattice meets skin (mm)", "0"},
                   {"material_density", number(), "material density (g/cm^3) for the part's mass", "—"},
                   {"drain", drainSchema(), "drain holes: every resin trap opened by a channel of D mm", "—"}},
                  {"part", "lattice"}),
           "skin plus a lattice filling the rest: {part, lattice, skin, density, blend, material_density, "
           "drain}",
           "required"}},
         buildInfill});
}

}  // namespace voxlat
