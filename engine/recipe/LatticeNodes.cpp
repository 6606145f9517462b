// Recipe node types for lattices: `tpms`.
#include "engine/core/Format.h"
#include "engine/recipe/DesignTargets.h"
#include "engine/recipe/ExprNodes.h"
#include "engine/recipe/FieldBuilder.h"
#include "engine/recipe/ScalarMaps.h"
#include "engine/recipe/SkinNodes.h"
#include "fields/core/Constant.h"
#include "fields/levels/GradedLevel.h"
#include "fields/levels/GradientShift.h"
#include "fields/maps/VectorField.h"
#include "fields/tpms/TpmsEquations.h"
#include "fields/tpms/TpmsField.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <vector>

namespace voxlat {

namespace {

/// The largest |grad f| over one cell of @a tpms where f is near zero (its mid-surface), from a
/// 32^3 lattice of points: a sheet |f| <= t is thinnest, about 2t / |grad f| across, there.
double steepestMidSurfaceGradient(const FieldNode& tpms, const Vec3d& cell)
{
    constexpr int n = 32;
    std::vector<Vec3d> points;
    points.reserve(n * n * n);
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j)
            for (int k = 0; k < n; ++k)
                points.push_back({(i + 0.5) * cell[0] / n, (j + 0.5) * cell[1] / n, (k + 0.5) * cell[2] / n});
    std::vector<double> values(points.size());
    std::vector<Vec3d> grads(points.size());
    tpms.gradients(points, values, grads);
    // Near the mid-surface: |f| within the distance a sample spacing spans along the gradient.
    const double spacing = std::max({cell[0], cell[1], cell[2]}) / n;
    double steepest = 0.0;
    for (std::size_t i = 0; i < points.size(); ++i) {
        const double g = grads[i].length();
        if (std::abs(values[i]) <= 0.5 * spacing * g) steepest = std::max(steepest, g);
    }
    return steepest > 0.0 ? steepest : 1.0;
}

/// True when the node has one of the gradient-shift keys.
bool hasShiftKeys(const RecipeNode& spec)
{
    return spec.has("thickness") || spec.has("wall") || spec.has("layer") || spec.has("build") || spec.has("rotation");
}

/// Reads `thickness:` or `wall:` + `layer:` (+ `build:`, `rotation:`): total wall thicknesses in
/// millimetres, each a number or a scalar map. @a cell (may be zero) is used for the warning.
/// @a thinnest gets the thinnest wall asked for (mm; a map's lowest value over the domain, or
/// infinity when that is not known before evaluation).
ShiftSpec readShiftSpec(FieldBuilder& builder, const RecipeNode& spec, const std::string& name, double cell,
                        std::string& description, double& thinnest)
{
    thinnest = std::numeric_limits<double>::infinity();
    ShiftSpec shift;
    shift.scale = 0.5;  // recipes give total thicknesses; the shift on each side is half
    shift.label = "field `" + name + "`";
    const bool uniform = spec.has("thickness");
    if (uniform && (spec.has("wall") || spec.has("layer")))
        spec["thickness"].fail(
            "give either `thickness:` (the same in every direction) or `wall:` and `layer:`, not both");
    if (!uniform && !(spec.has("wall") && spec.has("layer")))
        spec[spec.has("wall")    ? "wall"
             : spec.has("layer") ? "layer"
             : spec.has("build") ? "build"
                                 : "rotation"]
            .fail("give `thickness:`, or both `wall:` (in the build plane) and `layer:` (along the build direction)");
    if (uniform && (spec.has("build") || spec.has("rotation")))
        spec[spec.has("build") ? "build" : "rotation"].fail(
            "a build direction only matters with `wall:` and `layer:`; `thickness:` is the same in every direction");
    double largest = 0.0;
    auto readThickness = [&](const std::string& key) {
        const RecipeNode node = spec[key];
        ScalarMap map = readScalarMap(builder, node, name + "/" + key);
        checkScalarRange(builder, map, node, 0.0, 1e300, false, "the " + key + " thickness (mm)",
                         "; thicknesses are zero or more millimetres");
        if (map.constant && !(*map.constant > 0.0))
            node.fail("the " + key + " thickness must be greater than zero (millimetres), got " +
                      formatNumber(*map.constant));
        double top = map.constant ? *map.constant : 0.0;
        if (!map.constant && builder.recipe().domainBox) top = sampleRange(*map.field, *builder.recipe().domainBox).hi;
        largest = std::max(largest, top);
        if (map.constant)
            thinnest = std::min(thinnest, *map.constant);
        else if (builder.recipe().domainBox)
            thinnest = std::min(thinnest, sampleRange(*map.field, *builder.recipe().domainBox).lo);
        description += (description.empty() ? "" : ", ") + key + " " + map.description + (map.constant ? " mm" : "");
        return map.field;
    };
    if (uniform) {
        shift.uniform = readThickness("thickness");
    } else {
        shift.wall = readThickness("wall");
        shift.layer = readThickness("layer");
        if (spec.has("build")) {
            const RecipeNode b = spec["build"];
            bool allNumbers = b.isSequence() && b.size() == 3;
            for (std::size_t i = 0; allNumbers && i < 3; ++i) allNumbers = b.at(i).isNumber();
            if (allNumbers) {
                shift.direction = b.vec3();
                if (!(shift.direction.length() > 0.0))
                    b.fail("the build direction has zero length; give a direction such as [0, 0, 1]");
                description += ", build [" + formatNumber(shift.direction[0]) + ", " +
                               formatNumber(shift.direction[1]) + ", " + formatNumber(shift.direction[2]) + "]";
            } else if (b.isSequence()) {
                if (b.size() != 3) b.fail("expected [x, y, z]: three numbers or fields");
                for (std::size_t i = 0; i < 3; ++i)
                    shift.directionComponents[i] = readScalarMap(builder, b.at(i), name + "/build/" + "xyz"[i]).field;
                description += ", build direction from three fields";
            } else if (auto vector =
                           std::dynamic_pointer_cast<const VectorField>(builder.operand(b, name + "/build"))) {
                // A `vector:` direction field (by name or inline): its components are the direction.
                for (int i = 0; i < 3; ++i) shift.directionComponents[i] = vector->component(i);
                description += ", build direction from the vector field " +
                               (b.isScalar() ? "`" + b.string() + "`" : std::string("given inline"));
            } else {
                shift.directionGradient = builder.operand(b, name + "/build");
                description += ", build direction along the gradient of " +
                               (b.isScalar() ? "`" + b.string() + "`" : std::string("an inline field"));
            }
        }
        if (spec.has("rotation")) {
            const std::string r = spec["rotation"].string();
            if (r == "rodrigues")
                shift.rotation = ShiftRotation::Rodrigues;
            else if (r == "tensor")
                shift.rotation = ShiftRotation::Tensor;
            else
                spec["rotation"].fail(
                    "rotation is `rodrigues` (seed 004: the magnitude vector is rotated) or `tensor` "
                    "(the magnitude ellipsoid is rotated), got `" +
                    r + "`");
        }
    }
    // Seed 004: the shift stays uniform for gyroids while the wall is below ~10 % of the cell.
    if (cell > 0.0 && largest > 0.1 * cell) {
        std::ostringstream msg;
        msg << "field `" << name << "`: walls " << largest << " mm thick are " << std::lround(100.0 * largest / cell)
            << " % of the " << cell << " mm cell; the gradient shift keeps walls uniform only up to about 10 % ("
            << 0.1 * cell << " mm) for gyroids: beyond that the shifted surfaces cross and walls come out uneven";
        builder.warn("thick_walls", msg.str(), {{"field", name}, {"wall_mm", largest}, {"cell_mm", cell}});
    }
    return shift;
}

FieldPtr buildGradientShift(FieldBuilder& builder, const RecipeNode& spec, const std::string& name)
{
    FieldPtr f = builder.operand(spec["gradient-shift"], name + "/field");
    std::string description;
    double thinnest = 0.0;  // a gradient-shift node is no LevelNode: the walls are not checked here
    ShiftSpec shift = readShiftSpec(builder, spec, name, 0.0, description, thinnest);
    return std::make_shared<GradientShift>(std::move(f), std::move(shift));
}

/// `density:` given as a map or a field name: a GradedLevel over one unit cell of the TPMS.
/// @a tableSource, when given, is the unit cell the density table is measured on (the plain
/// TPMS of an oriented one, whose cells are rotated copies of it).
FieldPtr buildGraded(FieldBuilder& builder, const RecipeNode& spec, const std::string& name, const FieldPtr& raw,
                     SolidSide side, const Vec3d& cell, const std::string& description,
                     const FieldPtr& tableSource = nullptr)
{
    if (spec.has("level"))
        spec["level"].fail("give either `level:` or `density:`, not both (density solves the level)");
    const RecipeNode d = spec["density"];
    ScalarMap rho = readScalarMap(builder, d, name + "/density");
    const FieldPtr indicator = LevelSolid(raw, side, 0.0).indicator();
    auto graded = tableSource ? std::make_shared<GradedLevel>(
                                    indicator, rho.field,
                                    std::make_shared<const DensityTable>(
                                        *LevelSolid(tableSource, side, 0.0).indicator(), Box3{Vec3d(0.0), cell}))
                              : std::make_shared<GradedLevel>(indicator, rho.field, Box3{Vec3d(0.0), cell});
    const DensityTable& table = graded->table();
    checkScalarRange(builder, rho, d, 0.0, 1.0, true, "density",
                     "; a relative density is between 0 and 1 (exclusive): for 30 % write 0.30");
    checkScalarRange(builder, rho, d, table.minDensity(), table.maxDensity(), false, "density",
                     " (the range this " + description + " cell can reach, resolved by its density table)");
    const int axis = rho.axis.value_or(2);
    builder.addGradedNode({name, description, rho.description, graded, rho.field, axis, cell[axis]});
    return graded;
}

FieldPtr buildTpms(FieldBuilder& builder, const RecipeNode& spec, const std::string& name)
{
    const RecipeNode typeNode = spec["tpms"];
    TpmsType type;
    if (!parseTpmsType(typeNode.string(), type)) {
        const auto names = tpmsNames();
        const std::string guess = closestMatch(typeNode.string(), names);
        typeNode.fail("unknown TPMS `" + typeNode.string() + "`" +
                      (guess.empty() ? "" : "; did you mean `" + guess + "`?") + " (known: " + joinWords(names) + ")");
    }
    if (spec.has("stiffness")) refuseUnresolvedDesign(spec["stiffness"]);
    const RecipeNode cellNode = spec["cell"];
    const Vec3d cell = cellNode.scalarOrVec3();
    for (int a = 0; a < 3; ++a)
        if (!(cell[a] > 0.0)) cellNode.fail("cell sizes must be greater than zero (millimetres)");
    const SolidSide side = readSolidSide(spec);
    const std::string solidName = side == SolidSide::Band ? "sheet" : "network";

    FieldPtr raw = std::make_shared<TpmsField>(type, cell);
    const FieldPtr plain = raw;
    if (spec.has("frame"))
        raw = spec["frame"].has("skin") ? applySkinFrame(builder, spec["frame"], raw, cell, name)
                                        : applyFrame(spec["frame"], raw, cell);
    // A skin frame's lattice exists only in its cells: its density is measured there.
    const FieldPtr region = skinRegionOf(raw);
    if (region && spec.has("density") && !spec["density"].isNumber())
        spec["density"].fail(
            "a graded density needs box cells (its table comes from one box cell); on a skin frame "
            "give one number");
    if (spec.has("density_of") && !(spec.has("density") && spec["density"].isNumber()))
        spec["density_of"].fail(
            "`density_of:` says where the node's `density:` (one number) is measured; give `density:`");
    if (spec.has("axes")) raw = orientedField(builder, spec["axes"], raw, name);
    if (hasShiftKeys(spec)) {
        const std::string key = spec.has("thickness") ? "thickness"
                                : spec.has("wall")    ? "wall"
                                : spec.has("layer")   ? "layer"
                                : spec.has("build")   ? "build"
                                                      : "rotation";
        if (side != SolidSide::Band)
            spec[key].fail("a wall thickness makes a sheet: add `solid: sheet` (a network has no walls to thicken)");
        if (spec.has("offset"))
            spec["offset"].fail("`offset` moves a network's surface; a sheet takes `thickness:` (its walls in mm)");
        if (spec.has("level") || spec.has("density"))
            spec[spec.has("level") ? "level" : "density"].fail(
                "give either a thickness in millimetres or `level:`/`density:`, not both");
        std::string walls;
        double thinnestWall = 0.0;
        ShiftSpec shift =
            readShiftSpec(builder, spec, name, std::min({cell[0], cell[1], cell[2]}), walls, thinnestWall);
        auto sheet = std::make_shared<GradientShift>(raw, std::move(shift));
        LevelNode node{name,
                       std::string(tpmsName(type)) + " sheet, " + walls + " (gradient shift)",
                       std::make_shared<LevelSolid>(sheet, SolidSide::Below, 0.0),
                       {},
                       {}};
        // The shift is exact to first order in the curvature: the job measures what it gives.
        if (spec.has("thickness") && spec["thickness"].isNumber())
            node.wallCheck = LevelNode::WallCheck{raw, sheet, Box3{Vec3d(0.0), Vec3d(cell[0], cell[1], cell[2])},
                                                  spec["thickness"].number()};
        else if (spec.has("thickness"))
            node.gradedWalls = walls;
        if (std::isfinite(thinnestWall)) {
            node.thinnest = [thinnestWall](double) { return thinnestWall; };
            node.thinnestKind = "wall";
        }
        FieldPtr result = node.solid;
        builder.addLevelNode(std::move(node));
        return result;
    }
    std::string offsetText;
    if (spec.has("offset"))
        raw = networkOffset(builder, spec, raw, side, name, std::min({cell[0], cell[1], cell[2]}), offsetText);
    if (spec.has("density") && !spec["density"].isNumber())
        return buildGraded(builder, spec, name, raw, side, cell, std::string(tpmsName(type)) + " " + solidName,
                           spec.has("axes") && !spec.has("frame") ? plain : nullptr);
    LevelNode node{name, std::string(tpmsName(type)) + " " + solidName + offsetText, nullptr, {}};
    if (region) {
        node.region = node.densityMask = region;
        node.densityOf = "the cells of the skin frame";
    }
    // An infill's `density:` solves this lattice's level: then it needs none of its own.
    const bool solvedByInfill = levelSolvedByInfill(builder.recipe(), name);
    readLevelKeys(spec, node, raw, side, 0.0,
                  solvedByInfill            ? LevelRule::SolvedElsewhere
                  : side == SolidSide::Band ? LevelRule::Required
                                            : LevelRule::Optional);
    if (side == SolidSide::Band && !spec.has("frame") && !spec.has("offset")) {
        // A sheet |f| <= t is about 2t / |grad f| thick; thinnest where f is steepest on its mid-surface.
        const double steepest = steepestMidSurfaceGradient(*plain, cell);
        node.thinnest = [steepest](double level) { return 2.0 * level / steepest; };
        node.thinnestKind = "wall";
    }
    // A TPMS of cubic cells repeats exactly, everywhere: over a domain box of whole cells the
    // density of the box is that of one period, so the solve samples one period (and a face
    // zone per side), weighted, instead of every voxel of the box: a 50 mm cube of 10 mm cells
    // at 0.1 mm measures 101^3 samples instead of 500^3. periodicPieces() declines (and the
    // solve counts the whole box) when the box is not a whole number of cells.
    const Recipe& recipe = builder.recipe();
    // `density_of: cell`: the density is one period's (the periodic cell `voxlat properties`
    // homogenizes), not the domain box's, which differ when the box is not a whole number of
    // cells. One period, sampled on exactly one period of voxels (cell / n: a uniform rule over a
    // whole period of a smooth periodic field), 1.5 times finer than the job's voxel.
    bool perCell = false;
    if (spec.has("density_of")) {
        const RecipeNode of = spec["density_of"];
        const std::string where = of.string();
        if (where != "cell" && where != "frame")
            of.fail(
                "expected `cell` (one period of the TPMS, the cell `voxlat properties` homogenizes) or `frame` (the "
                "domain box, the default)");
        if (!node.density || solvedByInfill)
            of.fail("`density_of:` says where the node's `density:` (one number) is measured; give `density:`");
        perCell = where == "cell";
        if (perCell && (spec.has("frame") || spec.has("axes") || region))
            of.fail(std::string("`density_of: cell` needs the TPMS in box cells (its period is the cell); with `") +
                    (spec.has("axes") ? "axes:" : "frame:") +
                    "` the cells change shape or direction from place to place: measure the density over the "
                    "domain (remove `density_of`)");
        if (perCell && !recipe.domainBox)
            of.fail("`density_of: cell` measures one period at the domain's corner: give `domain: {box: ...}`");
    }
    if (perCell) {
        const double longest = std::max({cell[0], cell[1], cell[2]});
        const int base = std::max(8, int(std::ceil(longest / (recipe.voxel / 1.5))));
        // The first count from base whose voxel divides every side of the cell (a cubic cell: base).
        int n = base;
        for (int m = base; m < base + 256; ++m) {
            bool whole = true;
            for (int a = 0; a < 3; ++a) {
                const double k = cell[a] / (longest / m);
                whole = whole && std::abs(k - std::round(k)) < 1e-9 * k;
            }
            if (whole) {
                n = m;
                break;
            }
        }
        const Vec3d lo = recipe.domainBox->min;
        node.densityBox = Box3{lo, lo + cell};
        node.densityVoxel = longest / n;
        node.subVoxelDensity = true;
        node.densityOf = "one period of the TPMS (`density_of: cell`)";
    } else if (node.density && raw == plain && !region && recipe.domainBox && cell[0] == cell[1] &&
               cell[1] == cell[2]) {
        node.densityPeriod = cell;
        node.densityReach = 0.0;
        node.densityBox = *recipe.domainBox;
        node.densityVoxel = recipe.voxel;
    }
    const Interval range = tpmsLevelRange(type);
    if (node.solid->isSolved() && side == SolidSide::Below && !range.contains(node.solid->level())) {
        std::ostringstream msg;
        msg << "level " << node.solid->level() << " is outside the range where " << tpmsName(type) << " has a surface ["
            << range.lo << ", " << range.hi << "]: the part would be empty or solid";
        spec["level"].fail(msg.str());
    }
    FieldPtr result = node.solid;
    builder.addLevelNode(std::move(node));
    return result;
}

}  // namespace

FieldPtr networkOffset(FieldBuilder& builder, const RecipeNode& spec, FieldPtr raw, SolidSide side,
                       const std::string& name, double cell, std::string& description)
{
    // The network's surface moved m mm along its unit gradient: f(x - m n(x)) <= c, the
    // one-sided form of the sheet's gradient shift.
    const RecipeNode o = spec["offset"];
    if (side != SolidSide::Below)
        o.fail("`offset` moves a network's surface; a sheet takes `thickness:` (its walls in mm)");
    if (spec.has("density"))
        o.fail("give either `offset:` or `density:`, not both: the density solve would move the surface back");
    const double m = o.number();
    if (!std::isfinite(m)) o.fail("the offset is a number of millimetres");
    if (cell > 0.0 && std::abs(m) > 0.1 * cell) {
        std::ostringstream msg;
        msg << "field `" << name << "`: an offset of " << m << " mm is more than 10 % of the " << cell
            << " mm cell; the gradient shift moves the surface by the offset only while it is small against "
               "the surface's curvature radius";
        builder.warn("large_offset", msg.str(), {{"field", name}, {"offset_mm", m}});
    }
    ShiftSpec shift;
    shift.uniform = std::make_shared<ConstantField>(m);
    shift.oneSided = true;
    shift.label = "field `" + name + "`";
    description = ", offset " + formatNumber(m) + " mm (gradient shift)";
    return std::make_shared<GradientShift>(std::move(raw), std::move(shift));
}

void addLatticeNodeTypes(std::vector<NodeType>& types)
{
    using namespace valueSchema;
    const json gradedNumber = {{"anyOf", {number(), anyMap(), string()}}};
    const std::vector<KeySpec> thicknessKeys{
        // A thickness may vary in space: a number, or a map / field as for a graded density.
        {"thickness", gradedNumber, "total wall thickness 2m (mm), the same in every direction", "—"},
        {"wall", gradedNumber, "total wall thickness in the build plane (mm)", "—"},
        {"layer", gradedNumber, "total wall thickness along the build direction (mm)", "—"},
        {"build", anything(), "build direction: [x, y, z], a vector field or any field's unit gradient", "[0, 0, 1]"},
        {"rotation", oneOfWords({"rodrigues", "tensor"}), "how wall / layer follow the build direction", "tensor"}};
    std::vector<KeySpec> tpms{
        {"tpms", oneOfWords(tpmsNames()), "the surface", "required"},
        {"cell", numberOrVec3(), "cell size in mm, or [x, y, z]", "required"},
        solidKey(),
        levelKey(),
        {"density", gradedDensitySchema(),
         "target relative density in (0, 1) (the level is solved), or a map grading it point by point", "—"},
        {"stiffness", object(stiffnessKeys()),
         "instead of `density:`: {E: 40 MPa, axis: z} or {E_ratio: 0.05}, the density whose homogenized modulus "
         "meets it is solved (needs `material:`)",
         "—"},
        {"frame", anyMap(), "conformal cells: {cylinder: ...}, {sphere: ...} or {skin: ...}", "box cells"},
        {"density_of", oneOfWords({"cell", "frame"}),
         "where `density:` is measured: `frame` (the domain box) or `cell` (one period, the cell `voxlat "
         "properties` homogenizes; they differ when the box is not a whole number of cells)",
         "frame"}};
    tpms.insert(tpms.end(), thicknessKeys.begin(), thicknessKeys.end());
    tpms.push_back(
        {"offset", number(), "moves a network's surface m mm along its unit gradient (outwards for m > 0)", "—"});
    tpms.push_back(
        {"axes", orientationSchema(), "the cells' axes follow a frame field (as the orient node)", "world axes"});
    types.push_back({"tpms", tpms, buildTpms});
    addScalarMapNodeTypes(types);
    std::vector<KeySpec> shift{{"gradient-shift", field(), "the raw field whose zero set is thickened", "required"}};
    shift.insert(shift.end(), thicknessKeys.begin(), thicknessKeys.end());
    types.push_back({"gradient-shift", shift, buildGradientShift});
}

}  // namespace voxlat
