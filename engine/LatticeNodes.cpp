// Recipe node types for lattices: `tpms`.
#include "engine/FieldBuilder.h"
#include "fields/TpmsField.h"

#include <sstream>

namespace voxlat {

namespace {

/// Reads `level:` / `density:` of a lattice node into a LevelNode (density in (0, 1)).
void readLevelKeys(const RecipeNode& spec, LevelNode& node, double defaultLevel, bool levelRequired)
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
    } else if (spec.has("level")) {
        node.solid->setLevel(spec["level"].number());
    } else if (levelRequired) {
        spec.fail("give `level:` (for a sheet, the half-thickness t in |f| <= t) or `density:`");
    } else {
        node.solid->setLevel(defaultLevel);
    }
}

FieldPtr buildTpms(FieldBuilder& builder, const RecipeNode& spec, const std::string& name)
{
    const RecipeNode typeNode = spec["tpms"];
    TpmsType type;
    if (!parseTpmsType(typeNode.string(), type)) {
        const auto names = tpmsNames();
        std::string valid;
        for (const auto& n : names) valid += (valid.empty() ? "" : ", ") + n;
        const std::string guess = closestMatch(typeNode.string(), names);
        typeNode.fail("unknown TPMS `" + typeNode.string() + "`" + (guess.empty() ? "" : "; did you mean `" + guess + "`?") +
                      " (known: " + valid + ")");
    }
    const RecipeNode cellNode = spec["cell"];
    const Vec3d cell = cellNode.scalarOrVec3();
    for (int a = 0; a < 3; ++a)
        if (!(cell[a] > 0.0)) cellNode.fail("cell sizes must be greater than zero (millimetres)");
    std::string solidName = spec.has("solid") ? spec["solid"].string() : "network";
    SolidSide side;
    if (solidName == "network") side = SolidSide::Below;
    else if (solidName == "sheet") side = SolidSide::Band;
    else spec["solid"].fail("solid is `network` (f <= level) or `sheet` (|f| <= level), got `" + solidName + "`");

    FieldPtr raw = std::make_shared<TpmsField>(type, cell);
    if (spec.has("frame")) raw = applyFrame(spec["frame"], raw, cell);
    LevelNode node{name, std::string(tpmsName(type)) + " " + solidName, std::make_shared<LevelSolid>(raw, side, 0.0), {}};
    // An infill's `density:` solves this lattice's level: then it needs none of its own.
    const bool solvedByInfill = levelSolvedByInfill(builder.recipe(), name);
    readLevelKeys(spec, node, 0.0, side == SolidSide::Band && !solvedByInfill);
    if (side == SolidSide::Band && !node.density && !solvedByInfill && !(node.solid->level() > 0.0))
        spec["level"].fail("a sheet's level is its half-thickness t in |f| <= t and must be greater than zero");
    const Interval range = tpmsLevelRange(type);
    if (!node.density && side == SolidSide::Below && !range.contains(node.solid->level())) {
        std::ostringstream msg;
        msg << "level " << node.solid->level() << " is outside the range where " << tpmsName(type)
            << " has a surface [" << range.lo << ", " << range.hi << "]: the part would be empty or solid";
        spec["level"].fail(msg.str());
    }
    FieldPtr result = node.solid;
    builder.addLevelNode(std::move(node));
    return result;
}

}  // namespace

void addLatticeNodeTypes(std::vector<NodeType>& types)
{
    types.push_back({"tpms", {"tpms", "cell", "solid", "level", "density", "frame"}, buildTpms});
}

}  // namespace voxlat
