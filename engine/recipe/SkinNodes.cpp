// Recipe glue for skin-following frames (issue 6): cells between two offset surfaces of a part,
// for strut frames (`struts: {skin: ...}`) and TPMS (`frame: {skin: ...}`).
#include "engine/recipe/SkinNodes.h"

#include "engine/core/Errors.h"
#include "engine/frames/SkinFrame.h"
#include "engine/parts/MeshDesignSpace.h"
#include "engine/parts/MeshSdf.h"
#include "fields/frames/SkinMap.h"

#include <cmath>
#include <iostream>
#include <sstream>

namespace voxlat {

namespace {

struct SkinSetup {
    std::shared_ptr<const SkinCells> cells;
    SkinCellStats stats;
    SkinLayout layout;
    std::string partName;
};

/// Reads `skin: {part, depth, layers}` and builds the cells. @a size: the cell size along the
/// surface; @a layerDepth: the depth of a layer when `depth:` gives only the outer depth.
SkinSetup readSkin(FieldBuilder& builder, const RecipeNode& s, const std::string& name, double size, double layerDepth,
                   double extension)
{
    s.checkKeys({"part", "depth", "layers"});
    if (!s.has("part")) s.fail("give `part:` (the part whose surface the cells follow: a mesh or any closed field)");
    if (!s.has("depth"))
        s.fail(
            "give `depth:` in mm below the part's surface: [outer, inner], or the outer depth alone (the inner "
            "one is then outer + layers x the cell's depth)");
    SkinSetup setup;
    SkinLayout& layout = setup.layout;
    layout.size = size;
    layout.extension = extension;
    if (s.has("layers")) {
        const RecipeNode l = s["layers"];
        const double v = l.number();
        if (!(v >= 1 && v == std::floor(v) && v <= 1000)) l.fail("layers is a whole number of cells, 1 or more");
        layout.layers = int(v);
    }
    const RecipeNode d = s["depth"];
    if (d.isSequence()) {
        if (d.size() != 2) d.fail("depth is [outer, inner] in mm below the part's surface, or one number (the outer)");
        layout.outer = d.at(0).number();
        layout.inner = d.at(1).number();
    } else {
        layout.outer = d.number();
        layout.inner = layout.outer + layout.layers * layerDepth;
    }
    if (!(layout.outer >= 0.0)) d.fail("the outer depth is zero or more (mm below the part's surface)");
    if (!(layout.inner > layout.outer))
        d.fail("the inner depth must be greater than the outer one: depth: [outer, inner] with outer < inner (got [" +
               std::to_string(layout.outer) + ", " + std::to_string(layout.inner) + "])");

    setup.partName = s["part"].isScalar() ? s["part"].string() : name + "/part";
    const FieldPtr part = builder.operand(s["part"], setup.partName);
    const double voxel = builder.recipe().voxel;
    FieldPtr distance = part;
    std::optional<Box3> region;
    if (const auto* mesh = dynamic_cast<const PartField*>(part.get())) {
        // The part's own grid is built later, once every user has asked for its band; the cells
        // are needed now, so they get a grid of their own, exact to the inner depth and a cell.
        const auto& space = mesh->space();
        auto xform = openvdb::math::Transform::createLinearTransform(voxel);
        // Contour vertices start up to a cell diagonal off the outer surface: exact that far out too.
        const float interior = float(std::ceil((layout.inner + 1.5 * size) / voxel) + 3.0);
        const float exterior = float(std::ceil(std::max(0.0, 2.0 * size - layout.outer) / voxel) + 3.0);
        try {
            auto grid = meshToSdf(space->mesh(), *xform, exterior, interior);
            Box3 support = space->bounds();
            support.min -= Vec3d(voxel);
            support.max += Vec3d(voxel);
            distance = std::make_shared<MeshDistance>(grid, support);
        } catch (const InputError& e) {
            s["part"].fail(e.what());
        }
        region = space->bounds();
    } else {
        region = part->support();
        if (!region) region = builder.recipe().domainBox;
        if (!region)
            s["part"].fail(
                "the part has no bounds to search for its surface (an unbounded field): give a closed part "
                "or a `domain:`");
    }
    try {
        setup.cells = buildSkinCells(distance, *region, layout, setup.stats);
    } catch (const InputError& e) {
        d.fail(std::string(e.what()) + " (part `" + setup.partName + "`)");
    }
    const SkinCellStats stats = setup.stats;
    const SkinLayout lay = layout;
    const std::string partName = setup.partName;
    builder.addReporter([=](nlohmann::json& report) {
        nlohmann::json j = stats.json();
        j["part"] = partName;
        j["depth_mm"] = {lay.outer, lay.inner};
        j["layers"] = lay.layers;
        j["cell_mm"] = lay.size;
        report["skin_frames"][name] = j;
    });
    if (stats.dropped > 0) {
        std::ostringstream msg;
        msg << "field `" << name << "`: " << stats.dropped << " of " << stats.dropped + stats.hexes
            << " skin cells were left out: the part is thinner there than twice the inner depth (" << lay.inner
            << " mm), or the cells fold (corners turned inside out)";
        builder.warn("skin_cells_dropped", msg.str());
    }
    return setup;
}

}  // namespace

Frame buildSkinStrutFrame(FieldBuilder& builder, const RecipeNode& struts, const UnitCell& cell,
                          const std::string& name, FieldPtr& region)
{
    for (const char* k : {"count", "origin", "cylinder", "sphere", "within", "min_length"})
        if (struts.has(k))
            struts[k].fail("a skin frame places its cells along the part's surface; remove `" + std::string(k) + "`");
    if (!struts.has("size")) struts.fail("give the cell size along the surface `size:` (mm)");
    const RecipeNode sizeNode = struts["size"];
    if (!sizeNode.isNumber()) sizeNode.fail("a skin frame's cell size is one number (mm along the surface)");
    const double size = sizeNode.positiveNumber();
    const SkinSetup setup = readSkin(builder, struts["skin"], name, size, size, 0.0);
    if (setup.stats.seamEdges > 0 && !quarterTurnSymmetric(cell)) {
        std::ostringstream msg;
        msg << "field `" << name << "`: cell `" << cell.name << "` is not the same after a quarter turn about its z "
            << "axis, and " << setup.stats.seamEdges << " quad edges of the skin are seams where neighbouring cells "
            << "are turned: struts may not meet there (cells such as grid, bcc, fcc, octet meet everywhere)";
        builder.warn("skin_cell_not_symmetric", msg.str());
    }
    region = std::make_shared<SkinRegionField>(setup.cells);
    return skinFrame(cell, *setup.cells);
}

FieldPtr applySkinFrame(FieldBuilder& builder, const RecipeNode& frame, FieldPtr raw, const Vec3d& cell,
                        const std::string& name)
{
    frame.checkKeys({"skin"});
    // One period per cell: quads about as wide as the cell's x and y, layers as deep as its z.
    const double size = 0.5 * (cell[0] + cell[1]);
    // Outer cells reach half a layer past their chord faces to the outer surface itself.
    const SkinSetup setup = readSkin(builder, frame["skin"], name, size, cell[2], 0.5);
    const Interval range = raw->bound(Box3{Vec3d(0.0), cell});
    const double outside = std::max(std::abs(range.lo), std::abs(range.hi)) + 1.0;
    if (setup.stats.seamEdges > 0) {
        // Seams are continuous only for a lattice the same after a quarter turn about z.
        double worst = 0.0;
        std::vector<Vec3d> p, q;
        for (int i = 0; i <= 8; ++i)
            for (int k = 0; k <= 8; ++k) {
                const double t = i / 8.0, w = k / 8.0;
                for (const Vec3d& u : {Vec3d(0, t, w), Vec3d(1, t, w), Vec3d(t, 0, w), Vec3d(t, 1, w)}) {
                    p.emplace_back(u[0] * cell[0], u[1] * cell[1], u[2] * cell[2]);
                    q.emplace_back((1 - u[1]) * cell[0], u[0] * cell[1], u[2] * cell[2]);
                }
            }
        std::vector<double> vp(p.size()), vq(q.size());
        raw->values(p, vp);
        raw->values(q, vq);
        for (std::size_t i = 0; i < p.size(); ++i) worst = std::max(worst, std::abs(vp[i] - vq[i]));
        if (worst > 1e-6 * (range.hi - range.lo)) {
            std::ostringstream msg;
            msg << "field `" << name << "`: " << setup.stats.seamEdges << " quad edges of the skin are seams where "
                << "neighbouring cells are turned by a quarter turn, and this lattice is not the same after one (its "
                << "values differ by up to " << worst << " across a seam face): the surface has a step there";
            builder.warn("skin_seams", msg.str());
        }
    }
    return std::make_shared<SkinMapField>(std::move(raw), setup.cells, cell, outside);
}

FieldPtr skinRegionOf(const FieldPtr& raw)
{
    if (const auto* m = dynamic_cast<const SkinMapField*>(raw.get()))
        return std::make_shared<SkinRegionField>(m->cells());
    return nullptr;
}

}  // namespace voxlat
