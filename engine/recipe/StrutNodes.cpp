// Recipe node types for strut lattices (issue 3): `struts`, a frame of unit cells (or a
// wireframe file) solidified by Gaussian convolution or by round capsules.
#include "engine/core/Errors.h"
#include "engine/core/Format.h"
#include "engine/frames/StrutFrames.h"
#include "engine/recipe/DesignTargets.h"
#include "engine/recipe/FieldBuilder.h"
#include "engine/recipe/ScalarMaps.h"
#include "engine/recipe/SkinNodes.h"
#include "fields/core/GridValueMemo.h"
#include "fields/core/Supported.h"
#include "fields/frames/ParametricSurface.h"
#include "fields/levels/GradedLevel.h"
#include "fields/maps/PeriodicTiling.h"
#include "fields/shapes/Boolean.h"
#include "fields/struts/IsoRadius.h"
#include "fields/struts/StrutCapsules.h"
#include "fields/struts/StrutConvolution.h"
#include "fields/struts/TiledInterior.h"

#include <algorithm>
#include <cmath>
#include <iostream>
#include <limits>
#include <map>
#include <numbers>
#include <sstream>

namespace voxlat {

namespace {

/// A Gaussian lattice's density is solved on the job's own voxels where they are at most this
/// share of its smallest sigma (else on a lattice 1.16 times finer than the voxel).
constexpr double kJobVoxelsPerSigma = 0.25;

/// The job's cancel check, as the interrupter frames and strut tables call.
FrameInterrupt cancelCheck(const FieldBuilder& builder)
{
    return [&builder] { builder.context().checkCancelled(); };
}

/// The unit cell of `cell:` (a preset name, `{lines: [...]}` or `{obj: file}`), checked.
UnitCell readCell(const FieldBuilder& builder, const RecipeNode& c)
{
    UnitCell cell;
    if (c.isScalar()) {
        const auto names = unitCellPresetNames();
        const std::string name = c.string();
        if (std::find(names.begin(), names.end(), name) == names.end()) {
            const std::string guess = closestMatch(name, names);
            c.fail("unknown unit cell `" + name + "`" + (guess.empty() ? "" : "; did you mean `" + guess + "`?") +
                   " (presets: " + joinWords(names) +
                   "; or {lines: [[[x, y, z], [x, y, z]], ...]} or {obj: cell.obj})");
        }
        return presetUnitCell(name);
    }
    c.checkKeys({"lines", "obj"});
    if (c.has("lines") == c.has("obj")) c.fail("a custom cell is either {lines: [...]} or {obj: file.obj}");
    std::string label;
    if (c.has("obj")) {
        const std::string path = builder.recipe().resolve(c["obj"].string()).string();
        cell = unitCellFromLines(readObjLines(path), path);
        label = path;
    } else {
        const RecipeNode list = c["lines"];
        if (!list.isSequence() || list.size() == 0) list.fail("expected a list of lines, each [[x, y, z], [x, y, z]]");
        std::vector<CellLine> lines;
        for (std::size_t i = 0; i < list.size(); ++i) {
            const RecipeNode l = list.at(i);
            if (!l.isSequence() || l.size() != 2) l.fail("a line is two points: [[x, y, z], [x, y, z]]");
            lines.push_back({l.at(0).vec3(), l.at(1).vec3(), l.where() + ": line " + std::to_string(i + 1)});
        }
        cell = unitCellFromLines(lines, c.where());
        label = c.where();
    }
    const auto problems = unitCellProblems(cell);
    if (!problems.empty()) {
        std::string msg = "the cell cannot tile space (each face needs a node and opposite faces mirror nodes):";
        for (const auto& p : problems) msg += "\n  " + p;
        c.fail(msg);
    }
    return cell;
}

/// Whether every strut of @a f has a strut of @a f as its @a image (end points equal within 1e-9
/// of the box's size). A point near the rounding boundary of the comparison can only make a
/// symmetric frame look asymmetric, which costs time, never accuracy.
/// @a interrupt is called every 2^16 struts (a plate's frame holds 10^5-10^6).
template <class Image>
bool mapsOntoItself(const Frame& f, const Box3& box, const FrameInterrupt& interrupt, Image&& image)
{
    const double quantum = 1e-9 * std::max(1.0, box.extent().length());
    using Key = std::array<long long, 6>;
    auto point = [&](const Vec3d& p) {
        std::array<long long, 3> k;
        for (int a = 0; a < 3; ++a) k[a] = std::llround((p[a] - box.min[a]) / quantum);
        return k;
    };
    auto key = [&](const Vec3d& p, const Vec3d& q) {
        auto a = point(p), b = point(q);
        if (b < a) std::swap(a, b);
        return Key{a[0], a[1], a[2], b[0], b[1], b[2]};
    };
    std::vector<Key> keys;
    keys.reserve(f.struts.size());
    for (const auto& s : f.struts) {
        if ((keys.size() & 0xffff) == 0) interrupt();
        keys.push_back(key(f.nodes[s[0]], f.nodes[s[1]]));
    }
    std::sort(keys.begin(), keys.end());
    interrupt();
    for (std::size_t j = 0; j < f.struts.size(); ++j) {
        if ((j & 0xffff) == 0) interrupt();
        const auto& s = f.struts[j];
        if (!std::binary_search(keys.begin(), keys.end(), key(image(f.nodes[s[0]]), image(f.nodes[s[1]]))))
            return false;
    }
    return true;
}

/// Whether @a f is its own mirror image about the middle of @a box along @a axis.
bool mirrorSymmetric(const Frame& f, const Box3& box, int axis, const FrameInterrupt& interrupt)
{
    const double mid = box.min[axis] + box.max[axis];
    return mapsOntoItself(f, box, interrupt, [&](Vec3d p) {
        p[axis] = mid - p[axis];
        return p;
    });
}

/// Whether @a f is its own image when x and y are swapped about the corner of @a box.
bool swapSymmetric(const Frame& f, const Box3& box, const FrameInterrupt& interrupt)
{
    const Vec3d& o = box.min;
    return mapsOntoItself(f, box, interrupt,
                          [&](const Vec3d& p) { return Vec3d(o.x() + p.y() - o.y(), o.y() + p.x() - o.x(), p.z()); });
}

std::array<int, 3> readCounts(const RecipeNode& n)
{
    const Vec3d v = n.scalarOrVec3();
    std::array<int, 3> counts;
    for (int a = 0; a < 3; ++a) {
        if (!(v[a] >= 1 && v[a] == std::floor(v[a]) && v[a] < 1e5))
            n.fail("cell counts are whole numbers of at least 1");
        counts[a] = int(v[a]);
    }
    return counts;
}

/// The repeating cell of a frame of uniform cells (a box, or `within:` a solid).
struct UniformCells {
    UnitCell cell;
    Vec3d size{0.0};
    /// A frame trimmed `within:` a solid: the box its cells fill from its minimum corner (the
    /// untrimmed frame's cells), before the trim.
    std::optional<Box3> fill{};
};

/// The ways a frame is laid out: the key that selects each and the keys it uses. Any other key
/// of `struts:` is refused, naming itself.
struct FrameLayout {
    const char* key;   ///< the key that selects it ("" for the box of uniform cells)
    const char* what;  ///< for messages
    std::vector<std::string> keys;
};
const std::vector<FrameLayout>& frameLayouts()
{
    static const std::vector<FrameLayout> kinds = {
        {"wireframe", "a wireframe (used as the frame as it is)", {"wireframe"}},
        {"between", "a frame between two surfaces", {"cell", "between", "cells"}},
        {"skin", "a skin frame (cells along the part's surface)", {"cell", "size", "skin"}},
        {"cylinder",
         "a cylinder frame (cells from `cylinder: {radius, inner, height, base, cells}`)",
         {"cell", "cylinder"}},
        {"sphere", "a sphere frame (cells from `sphere: {radius, inner, center, cells}`)", {"cell", "sphere"}},
        {"within",
         "a frame `within:` a solid (uniform cells over the domain, trimmed)",
         {"cell", "size", "within", "min_length", "trim"}},
        {"", "a box frame", {"cell", "size", "count", "origin", "edges"}},
    };
    return kinds;
}

/// The kind of frame @a s lays out, its keys checked: no key the kind does not use (another
/// kind's key included).
const FrameLayout& readFrameLayout(const RecipeNode& s)
{
    std::vector<std::string> all;
    for (const FrameLayout& k : frameLayouts())
        for (const std::string& key : k.keys)
            if (std::find(all.begin(), all.end(), key) == all.end()) all.push_back(key);
    s.checkKeys(all);
    // The first kind named decides; another kind's key then has no use in it.
    const FrameLayout* kind = &frameLayouts().back();
    for (const FrameLayout& k : frameLayouts())
        if (*k.key != '\0' && s.has(k.key)) {
            kind = &k;
            break;
        }
    for (const std::string& key : all)
        if (s.has(key) && std::find(kind->keys.begin(), kind->keys.end(), key) == kind->keys.end()) {
            std::string hint;
            if (key == "min_length" || key == "trim")
                hint = " (`" + key + "` applies to frames trimmed `within:` a solid)";
            if (*kind->key == '\0' && key == "cells")
                hint = " (`cells:` counts the cells of a frame `between:` two surfaces; a box frame takes `count:`)";
            s[key].fail("`" + key + "` has no use in " + kind->what + ", which takes " + joinWords(kind->keys) + hint +
                        "; remove `" + key + "`");
        }
    return *kind;
}

/// A point on the second surface of a `between:` frame for the point @a p of the first one.
using SecondSurface = std::function<Vec3d(double u, double v, const Vec3d& p)>;

/// The second entry of `between:`: a surface, `{axis: [[x, y, z], [x, y, z]]}` (the nearest point
/// of the line through the two points) or `{point: [x, y, z]}`.
SecondSurface readSecondSurface(FieldBuilder& builder, const RecipeNode& n, const std::string& name)
{
    if (n.isMap() && (n.has("axis") || n.has("point"))) {
        n.checkKeys({"axis", "point"});
        if (n.has("axis") && n.has("point")) n.fail("the second surface is an `axis:` or a `point:`, not both");
        if (n.has("point")) {
            const Vec3d q = n["point"].vec3();
            return [q](double, double, const Vec3d&) { return q; };
        }
        const RecipeNode axis = n["axis"];
        if (!axis.isSequence() || axis.size() != 2) axis.fail("an axis is two points on it: [[x, y, z], [x, y, z]]");
        const Vec3d a = axis.at(0).vec3(), b = axis.at(1).vec3();
        const Vec3d d = b - a;
        if (!(d.lengthSqr() > 0.0)) axis.fail("the axis' two points are the same point: it has no direction");
        return [a, d](double, double, const Vec3d& p) { return a + ((p - a).dot(d) / d.lengthSqr()) * d; };
    }
    auto surface = builder.surface(n, name);
    return [surface](double u, double v, const Vec3d&) { return surface->point(u, v); };
}

/// `struts: {cell, between: [S1, S2], cells: [nu, nv, nw]}`: node (i, j, k) of the grid at
/// (1 - w) S1(u, v) + w S2(u, v), u = i / nu, v = j / nv, w = k / nw; cells mapped trilinearly.
Frame buildBetweenFrame(FieldBuilder& builder, const RecipeNode& s, const UnitCell& cell, const std::string& name)
{
    const RecipeNode between = s["between"];
    if (!between.isSequence() || between.size() != 2)
        between.fail(
            "`between:` is two surfaces [S1, S2]: S1 a `surface` node (its name or {surface: {x, y, z}}), S2 one "
            "too, or {axis: [[x, y, z], [x, y, z]]} or {point: [x, y, z]}");
    if (!s.has("cells")) s.fail("give `cells: [nu, nv, nw]` (cells along u and v, and from S1 to S2)");
    const std::array<int, 3> counts = readCounts(s["cells"]);
    const auto first = builder.surface(between.at(0), name + "/between/0");
    const SecondSurface second = readSecondSurface(builder, between.at(1), name + "/between/1");
    checkStrutCount(cell, counts);  // before the grid's nodes are allocated
    const int nu = counts[0], nv = counts[1], nw = counts[2];
    std::vector<Vec3d> grid(std::size_t(nu + 1) * (nv + 1) * (nw + 1));
    for (int i = 0; i <= nu; ++i)
        for (int j = 0; j <= nv; ++j) {
            const double u = double(i) / nu, v = double(j) / nv;
            const Vec3d p = first->point(u, v), q = second(u, v, p);
            for (int a = 0; a < 3; ++a)
                if (!std::isfinite(p[a]) || !std::isfinite(q[a]))
                    between.fail("a surface has no finite point at u = " + formatNumber(u) +
                                 ", v = " + formatNumber(v) + " (check its equations)");
            for (int k = 0; k <= nw; ++k) {
                const double w = double(k) / nw;
                grid[(std::size_t(i) * (nv + 1) + j) * (nw + 1) + k] = (1.0 - w) * p + w * q;
            }
        }
    return hexGridFrame(cell, grid, counts, cancelCheck(builder));
}

/// @a uniform receives the cell and its size when the frame is made of uniform cells.
/// @a region receives the cells' space for a skin frame (its density is measured there).
/// @a within receives the solid a `within:` frame is trimmed to.
Frame buildFrame(FieldBuilder& builder, const RecipeNode& s, const std::string& name,
                 std::optional<UniformCells>& uniform, FieldPtr& region, FieldPtr& within)
{
    const std::string kind = readFrameLayout(s).key;
    const FrameInterrupt interrupt = cancelCheck(builder);
    if (kind == "wireframe") return readWireframe(builder.recipe().resolve(s["wireframe"].string()).string());
    if (!s.has("cell")) s.fail("give `cell:` (a preset such as bcc, or custom lines) or `wireframe:` (a file)");
    const UnitCell cell = readCell(builder, s["cell"]);
    if (kind == "skin") return buildSkinStrutFrame(builder, s, cell, name, region);
    if (kind == "between") return buildBetweenFrame(builder, s, cell, name);
    // The box a frame fills: the domain, else the part an infill fills with this lattice.
    std::optional<Box3> domainBox = builder.recipe().domainBox;
    if (!domainBox && kind != "within") domainBox = infillPartBox(builder, name);
    if (kind == "cylinder") {
        const RecipeNode c = s["cylinder"];
        c.checkKeys({"radius", "inner", "height", "base", "cells"});
        const double outer = c["radius"].positiveNumber(), height = c["height"].positiveNumber();
        const double inner = c.has("inner") ? c["inner"].number() : 0.0;
        if (!(inner >= 0.0 && inner < outer)) c["inner"].fail("the inner radius is at least 0 and below the radius");
        Vec3d base = c.has("base") ? c["base"].vec3() : Vec3d(0.0);
        if (!c.has("base") && domainBox) {
            const Vec3d centre = domainBox->center();
            base = Vec3d(centre[0], centre[1], domainBox->min[2]);
        }
        if (!c.has("cells")) c.fail("give `cells: [axial, angular, radial]` (cell counts)");
        return cylinderFrame(cell, base, inner, outer, height, readCounts(c["cells"]), interrupt);
    }
    if (kind == "sphere") {
        const RecipeNode c = s["sphere"];
        c.checkKeys({"radius", "inner", "center", "cells"});
        const double outer = c["radius"].positiveNumber();
        const double inner = c.has("inner") ? c["inner"].number() : 0.0;
        if (!(inner >= 0.0 && inner < outer)) c["inner"].fail("the inner radius is at least 0 and below the radius");
        Vec3d centre = c.has("center") ? c["center"].vec3() : (domainBox ? domainBox->center() : Vec3d(0.0));
        if (!c.has("cells")) c.fail("give `cells: [polar, azimuthal, radial]` (cell counts)");
        const std::array<int, 3> counts = readCounts(c["cells"]);
        if (counts[0] < 2 || counts[1] < 3)
            c["cells"].fail(
                "a sphere needs at least 2 cells from pole to pole (polar) and 3 around the axis "
                "(azimuthal), or the shell folds flat");
        return sphereFrame(cell, centre, inner, outer, counts, interrupt);
    }
    if (!s.has("size")) s.fail("give the cell size `size:` in mm (a number or [x, y, z])");
    const Vec3d size = s["size"].scalarOrVec3();
    for (int a = 0; a < 3; ++a)
        if (!(size[a] > 0.0)) s["size"].fail("cell sizes must be greater than zero (millimetres)");
    if (kind == "within") {
        const FieldPtr solid = within = builder.operand(s["within"], name + "/within");
        // The cells fill the domain, or without one the solid's own box (a bounded part).
        const std::optional<Box3> fill = domainBox ? domainBox : solid->support();
        if (!fill)
            s["within"].fail(
                "a frame `within:` a solid fills the domain box, and this solid is unbounded: give `domain:` or a "
                "bounded solid (a part or a shape)");
        const double minLength =
            s.has("min_length") ? s["min_length"].number() : 0.1 * std::min({size[0], size[1], size[2]});
        uniform = UniformCells{cell, size, *fill};
        return clippedFrame(
            cell, *fill, size, [&](const Vec3d& p) { return solid->value(p); }, minLength);
    }
    // A box frame filling the domain runs one cell past it on every side and is cut by the domain
    // box, as a TPMS is (`edges: cut`): the struts at the faces are whole there, neither thinned
    // into spikes (a convolution strut with no neighbour beyond) nor left as loose ends.
    // `edges: frame`, `origin:` or `count:` lay the frame as written.
    const std::string edges = s.has("edges") ? s["edges"].string() : "cut";
    if (edges != "cut" && edges != "frame")
        s["edges"].fail(
            "`edges:` is `cut` (the frame runs a cell past the domain and the domain box cuts it) or "
            "`frame` (the cells that fit, struts ending at their nodes); got `" +
            edges + "`");
    if (edges == "cut" && domainBox && !s.has("origin") && !s.has("count")) {
        std::array<int, 3> counts;
        for (int a = 0; a < 3; ++a)
            counts[a] = int(std::clamp(std::ceil(domainBox->extent()[a] / size[a] - 1e-9), 1.0, 2e9)) + 2;
        uniform = UniformCells{cell, size};
        Frame f = boxFrame(cell, domainBox->min - size, size, counts, interrupt);
        f.layoutBox = *domainBox;
        return f;
    }
    if (s.has("edges") && edges == "cut")
        s["edges"].fail(std::string("`edges: cut` lays a frame that fills the domain; ") +
                        (domainBox ? "`origin:` and `count:` lay it as written" : "this recipe has no `domain:`") +
                        ": remove `edges:`");
    Vec3d origin = s.has("origin") ? s["origin"].vec3() : (domainBox ? domainBox->min : Vec3d(0.0));
    std::array<int, 3> counts;
    if (s.has("count")) {
        counts = readCounts(s["count"]);
    } else {
        if (!domainBox) s.fail("give `count:` or a `domain:` to fill");
        for (int a = 0; a < 3; ++a) {
            counts[a] = int(std::min(std::floor((domainBox->max[a] - origin[a]) / size[a] + 1e-9), 2e9));
            if (counts[a] < 1)
                s["size"].fail("a cell of " + std::to_string(size[a]) + " mm does not fit in the domain along " +
                               std::string(1, "xyz"[a]) + "; give a smaller size or `count:`");
        }
    }
    uniform = UniformCells{cell, size};
    return boxFrame(cell, origin, size, counts, interrupt);
}

/// A frame of (2 margin + 1)^3 of the cells and its middle cell: the middle cell sees every strut
/// within margin cells, as a cell deep inside a large frame does, so its density table is the
/// periodic lattice's.
std::pair<Frame, Box3> tableFrame(const UniformCells& cells, int margin)
{
    const int n = 2 * margin + 1;
    const Frame frame = boxFrame(cells.cell, Vec3d(0.0), cells.size, {n, n, n});
    return {frame, Box3{double(margin) * cells.size, double(margin + 1) * cells.size}};
}

/// `density:` as a map (a ramp, a field, a file): the level follows the target density point by
/// point through the density table of one interior cell (@a tableIndicator over @a tableCell).
FieldPtr buildGradedStruts(FieldBuilder& builder, const RecipeNode& spec, const std::string& name,
                           const FieldPtr& indicator, const FieldNode& tableIndicator, const Box3& tableCell,
                           const std::string& description)
{
    const RecipeNode d = spec["density"];
    ScalarMap rho = readScalarMap(builder, d, name + "/density");
    checkScalarRange(builder, rho, d, 0.0, 1.0, true, "density",
                     "; a relative density is between 0 and 1 (exclusive): for 20 % write 0.20");
    auto table = std::make_shared<const DensityTable>(tableIndicator, tableCell);
    checkScalarRange(builder, rho, d, table->minDensity(), table->maxDensity(), false, "density",
                     " (the range this strut cell can reach, resolved by its density table)");
    auto graded = std::make_shared<GradedLevel>(indicator, rho.field, table);
    const int axis = rho.axis.value_or(2);
    builder.addGradedNode({name, description, rho.description, graded, rho.field, axis, tableCell.extent()[axis]});
    return graded;
}

/// A `radius: {gradient: ...}` preset, read once.
struct RadiusGradient {
    std::string preset;
    double lo = 0.0, hi = 0.0;
    int axis = 0;
};

RadiusGradient readRadiusGradient(const RecipeNode& r)
{
    r.checkKeys({"gradient", "min", "max", "axis"});
    RadiusGradient g;
    g.preset = r["gradient"].string();
    const std::vector<std::string> presets = {"linear", "centred", "cylindrical", "spherical"};
    if (std::find(presets.begin(), presets.end(), g.preset) == presets.end())
        r["gradient"].fail("unknown gradient `" + g.preset + "` (presets: " + joinWords(presets) +
                           "); for radii from an equation give `radius: {expr: \"" + g.preset +
                           "\"}` in mm, with u, v, w in [0, 1] over the frame's box as IntraLattice has them");
    auto positive = [](const RecipeNode& node) {
        const double v = node.number();
        if (!(v > 0.0)) node.fail("a radius must be greater than zero (millimetres)");
        return v;
    };
    g.lo = positive(r["min"]);
    g.hi = positive(r["max"]);
    if (r.has("axis")) g.axis = r["axis"].axis();
    return g;
}

/// The radii of @a frame's strut ends from the gradient @a g, with u, v, w over @a box.
std::vector<std::array<double, 2>> gradientRadii(const RadiusGradient& grad, const Frame& frame, const Box3& box)
{
    const std::string& preset = grad.preset;
    const int axis = grad.axis;
    // u, v, w over the frame's box, held to [0, 1]: the nodes of cells laid past the domain (a
    // domain thinner than a cell) take the radius of the nearest point of the box, so every
    // radius lies within [min, max] (unclamped, a 0.2 mm domain of 2 mm cells gave ends 10 times
    // past the box radii of 1.7 mm, and nothing was exposed).
    auto g = [&](const Vec3d& p) {
        Vec3d u;
        for (int a = 0; a < 3; ++a)
            u[a] = box.extent()[a] > 0 ? std::clamp((p[a] - box.min[a]) / box.extent()[a], 0.0, 1.0) : 0.0;
        if (preset == "linear") return std::abs(u[axis]);
        if (preset == "centred") return std::abs(2 * u[axis] - 1);
        if (preset == "cylindrical") {
            const int b = (axis + 1) % 3, c = (axis + 2) % 3;
            return std::sqrt(sqr(2 * u[b] - 1) + sqr(2 * u[c] - 1)) / std::sqrt(2.0);
        }
        return std::sqrt(sqr(2 * u[0] - 1) + sqr(2 * u[1] - 1) + sqr(2 * u[2] - 1)) / std::sqrt(3.0);
    };
    std::vector<std::array<double, 2>> radii(frame.struts.size());
    for (std::size_t j = 0; j < frame.struts.size(); ++j)
        for (int e = 0; e < 2; ++e) radii[j][e] = grad.lo + g(frame.nodes[frame.struts[j][e]]) * (grad.hi - grad.lo);
    return radii;
}

/// Radius at each end of each strut from `radius:` (a number, a list, a gradient preset, or any
/// field: a name or an inline node, evaluated at the strut ends with u, v, w over the frame's box).
std::vector<std::array<double, 2>> readRadii(FieldBuilder& builder, const RecipeNode& r, const Frame& frame,
                                             const std::string& name)
{
    const std::size_t n = frame.struts.size();
    std::vector<std::array<double, 2>> radii(n);
    auto positive = [](const RecipeNode& node) {
        const double v = node.number();
        if (!(v > 0.0)) node.fail("a radius must be greater than zero (millimetres)");
        return v;
    };
    if (r.isNumber()) {
        const double v = positive(r);
        for (auto& e : radii) e = {v, v};
        return radii;
    }
    if (r.isScalar() || (r.isMap() && !r.has("gradient"))) {
        FieldPtr field;
        {
            FieldBuilder::UnitBoxScope unitBox(builder, frame.box());
            field = builder.operand(r, name + "/radius");
        }
        std::vector<Vec3d> ends(2 * n);
        for (std::size_t j = 0; j < n; ++j)
            for (int e = 0; e < 2; ++e) ends[2 * j + e] = frame.nodes[frame.struts[j][e]];
        std::vector<double> values(ends.size());
        field->values(ends, values);
        for (std::size_t i = 0; i < ends.size(); ++i) {
            if (!(values[i] > 0.0) || !std::isfinite(values[i]))
                r.fail("the radius field is " + formatNumber(values[i]) + " mm at the strut end (" +
                       formatNumber(ends[i][0]) + ", " + formatNumber(ends[i][1]) + ", " + formatNumber(ends[i][2]) +
                       "): a radius must be greater than zero (millimetres)");
            radii[i / 2][i % 2] = values[i];
        }
        return radii;
    }
    if (r.isSequence()) {
        if (r.size() != n)
            r.fail("the radius list has " + std::to_string(r.size()) + " entries but the frame has " +
                   std::to_string(n) + " struts (one entry per strut: r or [r_start, r_end])");
        for (std::size_t j = 0; j < n; ++j) {
            const RecipeNode e = r.at(j);
            if (e.isSequence()) {
                if (e.size() != 2) e.fail("a strut's radii are [r_start, r_end]");
                radii[j] = {positive(e.at(0)), positive(e.at(1))};
            } else {
                radii[j] = {positive(e), positive(e)};
            }
        }
        return radii;
    }
    return gradientRadii(readRadiusGradient(r), frame, frame.box());
}

/// Records @a frame for frame outputs (`outputs: {frame: F}`): @a endRadius(j, e, level) is
/// strut j's radius at end e for the level there, @a levelAt(p) the solved level at a point.
void recordFrame(FieldBuilder& builder, const std::string& name, const Frame& frame,
                 std::function<double(std::size_t, int, double)> endRadius, std::function<double(const Vec3d&)> levelAt)
{
    if (frame.layoutBox) {
        // A frame laid past the domain is written as the domain cuts it: each strut's piece inside
        // the box, its radius at a cut end interpolated along the strut.
        const Box3 box = *frame.layoutBox;
        Frame inside;
        std::vector<std::size_t> source;
        std::vector<std::array<double, 2>> at;
        std::map<std::array<double, 3>, int> index;
        auto node = [&](const Vec3d& p) {
            const auto [it, fresh] = index.emplace(std::array<double, 3>{p[0], p[1], p[2]}, int(inside.nodes.size()));
            if (fresh) inside.nodes.push_back(p);
            return it->second;
        };
        for (std::size_t j = 0; j < frame.struts.size(); ++j) {
            if ((j & 0xffff) == 0) builder.context().checkCancelled();
            const Vec3d a = frame.nodes[frame.struts[j][0]], b = frame.nodes[frame.struts[j][1]];
            // Liang-Barsky: the parameters of the segment inside the box.
            double t0 = 0.0, t1 = 1.0;
            for (int ax = 0; ax < 3 && t0 <= t1; ++ax) {
                const double d = b[ax] - a[ax];
                if (d == 0.0) {
                    if (a[ax] < box.min[ax] || a[ax] > box.max[ax]) t1 = -1.0;
                    continue;
                }
                double lo = (box.min[ax] - a[ax]) / d, hi = (box.max[ax] - a[ax]) / d;
                if (lo > hi) std::swap(lo, hi);
                t0 = std::max(t0, lo);
                t1 = std::min(t1, hi);
            }
            if (!(t1 - t0 > 1e-9)) continue;  // outside, or touching a face or an edge only
            inside.struts.push_back({node(a + t0 * (b - a)), node(a + t1 * (b - a))});
            source.push_back(j);
            at.push_back({t0, t1});
        }
        StrutFrameRecord record{name, inside.nodes, inside.struts, {}};
        record.radii = [frame, source, at, endRadius = std::move(endRadius), levelAt = std::move(levelAt)] {
            std::vector<std::array<double, 2>> r(source.size());
            for (std::size_t k = 0; k < source.size(); ++k) {
                const std::size_t j = source[k];
                const double r0 = endRadius(j, 0, levelAt(frame.nodes[frame.struts[j][0]]));
                const double r1 = endRadius(j, 1, levelAt(frame.nodes[frame.struts[j][1]]));
                for (int e = 0; e < 2; ++e) r[k][e] = r0 + at[k][e] * (r1 - r0);
            }
            return r;
        };
        builder.addStrutFrame(std::move(record));
        return;
    }
    StrutFrameRecord record{name, frame.nodes, frame.struts, {}};
    record.radii = [frame, endRadius = std::move(endRadius), levelAt = std::move(levelAt)] {
        std::vector<std::array<double, 2>> r(frame.struts.size());
        for (std::size_t j = 0; j < frame.struts.size(); ++j)
            for (int e = 0; e < 2; ++e) r[j][e] = endRadius(j, e, levelAt(frame.nodes[frame.struts[j][e]]));
        return r;
    };
    builder.addStrutFrame(std::move(record));
}

/// The level of a graded lattice at a point: value = indicator - level.
std::function<double(const Vec3d&)> gradedLevelAt(const FieldPtr& graded)
{
    return [graded](const Vec3d& p) {
        return static_cast<const GradedLevel&>(*graded).indicator()->value(p) - graded->value(p);
    };
}

/// The axis of a `radius: {gradient: linear, axis: A}` or `{gradient: centred, axis: A}` (the
/// radii depend on that coordinate only), or -1 for any other radius.
int radiusGradientAxis(const RecipeNode& spec)
{
    if (!spec.has("radius") || !spec["radius"].isMap()) return -1;
    const RecipeNode r = spec["radius"];
    // Linear and centred (|2u - 1|) radii depend on the one coordinate; the others' on two or three.
    if (!r.has("gradient") || (r["gradient"].string() != "linear" && r["gradient"].string() != "centred")) return -1;
    return r.has("axis") ? r["axis"].string()[0] - 'x' : 0;
}

/// Strut @a j of @a f as a convolution strut of @a sigma, its end weights from its radii @a r
/// (w = exp(R^2 / 2 sigma^2) / (sigma sqrt(2 pi)): radius R at level 1), or 1 without.
ConvolutionStrut convolutionStrut(const Frame& f, std::size_t j, double sigma, const std::array<double, 2>* r)
{
    ConvolutionStrut s;
    s.a = f.nodes[f.struts[j][0]];
    s.b = f.nodes[f.struts[j][1]];
    s.sigma = sigma;
    if (r) {
        s.w0 = gaussianStrutWeight((*r)[0], sigma, 1.0);
        s.w1 = gaussianStrutWeight((*r)[1], sigma, 1.0);
    }
    return s;
}

/// The period of a box frame of cells of @a size: none along @a gradedAxis (radii graded along it;
/// -1 for none).
Vec3d framePeriod(Vec3d size, int gradedAxis)
{
    if (gradedAxis >= 0) size[gradedAxis] = 0.0;
    return size;
}

/// Per axis, whether @a f is its own mirror image about the middle of @a box; never along
/// @a gradedAxis (radii graded along it; -1 for none).
std::array<bool, 3> frameMirrors(const Frame& f, const Box3& box, int gradedAxis, const FrameInterrupt& interrupt)
{
    std::array<bool, 3> mirror{};
    for (int a = 0; a < 3; ++a) mirror[a] = a != gradedAxis && mirrorSymmetric(f, box, a, interrupt);
    return mirror;
}

/// The struts one of two frames holds and the other does not, by their ends (either order) and
/// their radii (@a ra and @a rb: per strut, or null for none), as segments; none when fewer than
/// a quarter of @a b's struts are also @a a's as they are (little for a table to serve).
std::optional<std::vector<std::array<Vec3d, 2>>> differingStruts(const Frame& a,
                                                                 const std::vector<std::array<double, 2>>* ra,
                                                                 const Frame& b,
                                                                 const std::vector<std::array<double, 2>>* rb)
{
    // A strut as its ends (the lesser first) and its radii in that order, and its frame.
    using Key = std::array<double, 8>;
    std::vector<std::pair<Key, int>> all;
    all.reserve(a.struts.size() + b.struts.size());
    auto add = [&all](const Frame& f, const std::vector<std::array<double, 2>>* r, int which) {
        for (std::size_t j = 0; j < f.struts.size(); ++j) {
            Vec3d p = f.nodes[f.struts[j][0]], q = f.nodes[f.struts[j][1]];
            std::array<double, 2> e = r ? (*r)[j] : std::array<double, 2>{0.0, 0.0};
            if (std::lexicographical_compare(q.asPointer(), q.asPointer() + 3, p.asPointer(), p.asPointer() + 3)) {
                std::swap(p, q);
                std::swap(e[0], e[1]);
            }
            all.push_back({Key{p[0], p[1], p[2], q[0], q[1], q[2], e[0], e[1]}, which});
        }
    };
    add(a, ra, 0);
    add(b, rb, 1);
    std::sort(all.begin(), all.end());
    std::vector<std::array<Vec3d, 2>> differing;
    std::size_t same = 0;
    for (std::size_t i = 0; i < all.size();) {
        std::size_t e = i + 1;
        while (e < all.size() && all[e].first == all[i].first) ++e;
        const bool both = all[i].second == 0 && all[e - 1].second == 1;
        if (both) {
            ++same;
        } else {
            const Key& k = all[i].first;
            differing.push_back({Vec3d(k[0], k[1], k[2]), Vec3d(k[3], k[4], k[5])});
        }
        i = e;
    }
    if (4 * same < b.struts.size()) return std::nullopt;
    return differing;
}

/// A strut lattice as its frame lays it out; @a within receives the solid a `within:` frame is
/// trimmed to (its struts' axes end at its surface, their solid does not yet).
FieldPtr buildStrutLattice(FieldBuilder& builder, const RecipeNode& spec, const std::string& name, FieldPtr& within)
{
    const FrameInterrupt interrupt = cancelCheck(builder);
    std::optional<UniformCells> uniform;
    FieldPtr region;
    const std::string withinName = spec["struts"].has("within") && spec["struts"]["within"].isScalar()
                                       ? spec["struts"]["within"].string()
                                       : name + "/within";
    for (const char* key : {"stiffness", "optimize"})
        if (spec.has(key)) refuseUnresolvedDesign(spec[key]);
    const Frame frame = [&] {
        try {
            return buildFrame(builder, spec["struts"], name, uniform, region, within);
        } catch (const JobError& e) {
            throw JobError(spec["struts"].where() + ": " + e.what());  // the line of the frame
        }
    }();
    if (frame.struts.empty()) spec["struts"].fail("the frame has no struts (is the design space empty?)");
    if (spec.has("level") && spec.has("density"))
        spec.fail("give either `level:` or `density:`, not both (density solves the level)");
    // A density map (ramp, field, file) sets the level point by point from one cell's table.
    const bool graded = spec.has("density") && !spec["density"].isNumber();
    if (graded) {
        if (!uniform)
            spec["density"].fail(
                "a graded density needs uniform cells (`cell:` with `size:`, in a box or `within:` a "
                "solid): the level comes from one cell's density table; a cylinder frame or a "
                "wireframe takes a single density (a number)");
        if (spec.has("radius") && !spec["radius"].isNumber())
            spec["radius"].fail(
                "with a graded density the radius is one number: the density sets the strut "
                "thickness point by point");
    }
    if (!spec.has("kernel"))
        spec.fail("give `kernel:`: {gaussian: {sigma: 0.5}} (convolution joints) or capsule / {capsule: {blend: 0.3}}");
    const RecipeNode kernel = spec["kernel"];
    const bool capsule = (kernel.isScalar() && kernel.string() == "capsule") || kernel.has("capsule");
    if (!capsule && !kernel.has("gaussian"))
        kernel.fail("the kernel is {gaussian: {sigma: S}} or capsule / {capsule: {blend: B}}");
    if (kernel.isMap()) {
        kernel.checkKeys({"gaussian", "capsule"});
        if (kernel.has("gaussian") && kernel.has("capsule"))
            kernel["gaussian"].fail("a lattice has one kernel: give `gaussian` or `capsule`, not both; remove one");
        if (kernel.has("capsule") && !kernel["capsule"].isMap() && !kernel["capsule"].yaml().IsNull())
            kernel["capsule"].fail("capsule takes {blend: B} or nothing (`kernel: capsule`)");
    }
    const std::size_t n = frame.struts.size();
    std::optional<std::vector<std::array<double, 2>>> radii;
    if (spec.has("radius"))
        radii = readRadii(builder, spec["radius"], frame, name);
    else if (!frame.radii.empty())
        radii = frame.radii;  // a wireframe CSV with r1,r2 columns (a frame output read back)
    const Box3 box = frame.box();
    // A frame is finite: its solid lies within its box grown by the struts' reach, which gives
    // the domain when the recipe has none (as a shape's box does).
    // A box of identical cells with identical struts repeats cell by cell deeper inside its box
    // than the struts' reach: lattice properties take their cell from there (RepeatZone).
    const bool identicalBoxCells =
        uniform && !spec["struts"].has("within") && (!radii || spec["radius"].isNumber()) && !graded;
    // @a solidReach (when given) is how far the solid reaches from the struts once its level is
    // known: deeper inside the box than that, a box of identical cells repeats (RepeatZone).
    const Box3 extent = frame.bounds();  // where the struts are (past the box for a cut frame)
    auto withinReach = [&box, &extent, &uniform](FieldPtr solid, double reach,
                                                 std::function<double()> solidReach = {}) -> FieldPtr {
        std::function<std::optional<RepeatZone>()> zone;
        if (solidReach)
            zone = [box, size = uniform->size, solidReach]() -> std::optional<RepeatZone> {
                const double r = solidReach();
                return RepeatZone{size, Box3{box.min + Vec3d(r), box.max - Vec3d(r)}, box.min};
            };
        return std::make_shared<SupportedField>(
            std::move(solid), Box3{extent.min - Vec3d(reach), extent.max + Vec3d(reach)}, std::move(zone));
    };
    // `density_of: cell`: the density is the periodic cell's (the middle cell of the frame, which
    // sees all its neighbours), as `voxlat properties` homogenizes it, not the frame box's.
    bool perCell = false;
    Box3 middleCell;
    double neighbourDepth = 0.0;  // how far the middle cell's neighbours reach on its thinnest side (mm)
    if (spec.has("density_of")) {
        const RecipeNode of = spec["density_of"];
        const std::string where = of.string();
        if (where != "cell" && where != "frame")
            of.fail(
                "expected `cell` (the periodic cell, as `voxlat properties` homogenizes it) or `frame` (the "
                "frame's bounding box, the default)");
        if (!spec.has("density") || graded)
            of.fail("`density_of:` says where the node's `density:` (one number) is measured; give `density:`");
        perCell = where == "cell";
        if (perCell && !identicalBoxCells)
            of.fail(
                "`density_of: cell` needs a box of identical cells (`struts: {cell, size}` with one radius, no "
                "`within:`): only there is the cell known");
        if (perCell) {
            Vec3d lo, hi;
            for (int a = 0; a < 3; ++a) {
                const int count = int(std::lround(box.extent()[a] / uniform->size[a]));
                if (count < 3)
                    of.fail(
                        "`density_of: cell` measures the frame's middle cell, which needs a neighbour on each "
                        "side: give at least 3 cells along " +
                        std::string(1, "xyz"[a]) + " (`count:` or a larger domain)");
                lo[a] = box.min[a] + (count / 2) * uniform->size[a];
                hi[a] = lo[a] + uniform->size[a];
                const double depth = std::min(count / 2, count - count / 2 - 1) * uniform->size[a];
                neighbourDepth = a == 0 ? depth : std::min(neighbourDepth, depth);
            }
            middleCell = Box3{lo, hi};
        }
    }
    LevelNode node;
    node.name = name;
    node.region = region;
    // An infill's `density:` solves this lattice's level over the part's core: a `radius:` then
    // only shapes the struts relative to each other (a common shift), as with `density:`.
    const bool solvedByInfill = levelSolvedByInfill(builder.recipe(), name);
    if (solvedByInfill) {
        if (graded) spec["density"].fail("the infill's `density:` sets this lattice's density: remove it here");
        node.subVoxelDensity = true;  // struts line up with the voxels: coverage, not a count
    }
    if (spec.has("density") && !graded) {
        const RecipeNode d = spec["density"];
        const double rho = d.number();
        if (!(rho > 0.0 && rho < 1.0))
            d.fail("density is a relative density between 0 and 1 (exclusive), got " + d.yaml().Scalar() +
                   "; for 20 % write 0.20");
        node.density = rho;
        if (region) {
            // A skin frame: the density is the lattice's share of its cells' space.
            node.densityMask = region;
            node.densityOf = "the cells of the skin frame";
            node.subVoxelDensity = true;
        }
        for (int a = 0; a < 3 && !region; ++a)
            if (!(box.extent()[a] > 0.0))
                d.fail("the frame is flat along " + std::string(1, "xyz"[a]) +
                       ": its bounding box has no volume to measure a density in; give `level:` or `radius:`");
        if (within) {
            // `within:` a part: the share of the part's interior (the struts are trimmed to it).
            node.densityMask = within;
            node.densityOf = "the inside of `" + withinName + "`";
            node.meshShare = LevelNode::MeshShare{name, partMeshVolume(within), false};
        } else if (!region) {
            node.densityBox = perCell ? middleCell : box;
            node.densityOf = perCell           ? "one cell of the periodic lattice (`density_of: cell`)"
                             : frame.layoutBox ? "the domain box"
                                               : "the frame's bounding box";
        }
        // Cells of a whole number of voxels line struts up with the voxel lattice, and counting
        // voxel centres then aliases (about 2 % for BCC at 0.1 mm); coverage does not.
        node.subVoxelDensity = true;
        // ... and a measuring voxel of 1 / (1 + 1/(2 pi)) of the job's samples every phase.
        node.densityVoxel = builder.recipe().voxel / (1.0 + 1.0 / (2.0 * std::numbers::pi));
    }

    if (capsule && perCell) node.densityVoxel = *node.densityVoxel / 1.5;  // one cell at a fixed phase
    if (capsule) {
        double blend = 0.0;
        if (kernel.isMap()) {
            const RecipeNode c = kernel["capsule"];
            if (c.isMap()) {
                c.checkKeys({"blend"});
                if (c.has("blend")) {
                    blend = c["blend"].number();
                    if (blend < 0.0) c["blend"].fail("the blend radius is zero or positive (millimetres)");
                }
            }
        }
        if (!radii && !node.density && !graded && !spec.has("level") && !solvedByInfill)
            spec.fail(
                "capsules need `radius:` (or `density:`, which solves a uniform radius, or `level:`, the radius "
                "offset, which alone is the radius)");
        auto capsuleStruts = [](const Frame& f, const std::optional<std::vector<std::array<double, 2>>>& r) {
            std::vector<CapsuleStrut> struts;
            for (std::size_t j = 0; j < f.struts.size(); ++j)
                struts.push_back(
                    {f.nodes[f.struts[j][0]], f.nodes[f.struts[j][1]], r ? (*r)[j][0] : 0.0, r ? (*r)[j][1] : 0.0});
            return struts;
        };
        const std::vector<CapsuleStrut> struts = capsuleStruts(frame, radii);
        double rMax = 0.0, longest = 0.0;
        for (const CapsuleStrut& c : struts) {
            rMax = std::max({rMax, c.ra, c.rb});
            longest = std::max(longest, (c.b - c.a).length());
        }
        // The cap must exceed any level the density solve can reach (a radius offset).
        const double cap = rMax + blend + longest;
        auto raw = std::make_shared<StrutCapsules>(struts, blend, cap);
        // A capsule's radius at the level c (the distance offset): its own radius plus c.
        auto capsuleRadius = [struts](std::size_t j, int e, double level) {
            return std::max(0.0, (e == 0 ? struts[j].ra : struts[j].rb) + level);
        };
        node.description = std::string("strut capsules") + (blend > 0 ? " (blended)" : "");
        if (graded) {
            // Struts reach into the next cell only by their radius and blend: one cell of margin.
            const auto [cells, cellBox] = tableFrame(*uniform, 1);
            std::optional<std::vector<std::array<double, 2>>> cellRadii;
            if (radii) cellRadii = readRadii(builder, spec["radius"], cells, name);
            const StrutCapsules cellField(capsuleStruts(cells, cellRadii), blend, cap);
            FieldPtr result = buildGradedStruts(builder, spec, name, raw, cellField, cellBox, node.description);
            recordFrame(builder, name, frame, capsuleRadius, gradedLevelAt(result));
            // The table's levels stay below the cap, so the solid is within rMax + blend + cap.
            return withinReach(result, rMax + blend + cap);
        }
        const bool solved = node.density || solvedByInfill;
        // The job's aim may move a solved level: the raw values are kept between its evaluations.
        // A level given is read through a memo too (never keeping), which rounds the grid's values
        // as a solved one's: the reported level pasted back gives the same grid.
        const auto memo = std::make_shared<GridValueMemo>(raw);
        node.solid = solved ? LevelSolid::unsolved(memo, SolidSide::Below)
                            : std::make_shared<LevelSolid>(memo, SolidSide::Below,
                                                           spec.has("level") ? spec["level"].number() : 0.0);
        // A capsule's level is an offset of every radius.
        double rMin = std::numeric_limits<double>::infinity();
        for (const CapsuleStrut& c : struts) rMin = std::min({rMin, c.ra, c.rb});
        node.thinnest = [rMin](double level) { return std::max(0.0, 2.0 * (rMin + level)); };
        recordFrame(builder, name, frame, capsuleRadius, [solid = node.solid](const Vec3d&) { return solid->level(); });
        // A capsule reaches its radius plus the level (an offset) plus the blend; a solved level
        // stays below the cap.
        const double reach = rMax + blend + (solved ? cap : std::max(0.0, node.solid->level()));
        std::function<double()> solidReach;
        if (identicalBoxCells)
            solidReach = [solid = node.solid, rMax, blend] { return rMax + blend + std::max(0.0, solid->level()); };
        FieldPtr result = withinReach(node.solid, reach, solidReach);
        builder.addLevelNode(std::move(node));
        return result;
    }

    const RecipeNode g = kernel["gaussian"];
    g.checkKeys({"sigma", "cutoff"});
    std::vector<double> sigma(n);
    const RecipeNode sn = g["sigma"];
    // A kernel wider than the frame's longest strut flattens the field over the whole cell (no
    // struts left to see), and its reach (7.4 sigma) gathers the struts of ever more cells per
    // point: `optimize: {sigma: [0.3, 1e6]}` ran for minutes on its first trial. Refused.
    double longest = 0.0;
    for (const auto& st : frame.struts) longest = std::max(longest, (frame.nodes[st[1]] - frame.nodes[st[0]]).length());
    auto positiveSigma = [longest](const RecipeNode& s) {
        const double v = s.number();
        if (!(v > 0.0)) s.fail("sigma must be greater than zero (millimetres; it sets the joint size)");
        if (longest > 0.0 && v > longest)
            s.fail("a sigma of " + formatNumber(v) + " mm is wider than the frame's longest strut (" +
                   formatNumber(longest) +
                   " mm): the kernel would blur the struts into a flat field; use a sigma of a fraction of the "
                   "strut, like " +
                   formatNumber(0.1 * longest) + " mm");
        return v;
    };
    if (sn.isSequence()) {
        if (graded) sn.fail("with a graded density sigma is one number (the table is computed for one cell)");
        if (sn.size() != n)
            sn.fail("the sigma list has " + std::to_string(sn.size()) + " entries but the frame has " +
                    std::to_string(n) + " struts (one per strut, or a single number)");
        for (std::size_t j = 0; j < n; ++j) sigma[j] = positiveSigma(sn.at(j));
    } else {
        std::fill(sigma.begin(), sigma.end(), positiveSigma(sn));
    }
    double eps = 1e-4;
    if (g.has("cutoff")) {
        eps = g["cutoff"].number();
        if (!(eps > 0.0 && eps < 0.1))
            g["cutoff"].fail("the cut-off is a small fraction of a strut's peak, in (0, 0.1); default 1e-4");
    }
    if (!radii && !node.density && !spec.has("level") && !graded && !solvedByInfill)
        spec.fail("give `density:` (solves the iso-value), `level:` (the iso-value t in F >= t) or `radius:`");
    // Weights: with radii, w = t0 exp(R^2 / (2 sigma^2)) / (sigma sqrt(2 pi)) at t0 = 1, so an
    // isolated long strut has radius R at level 1 (and radius sqrt(R^2 + 2 sigma^2 ln(1 / t))
    // at level t). Without radii every weight is 1.
    auto convolutionStruts = [&](const Frame& f, const std::optional<std::vector<std::array<double, 2>>>& r) {
        std::vector<ConvolutionStrut> struts;
        for (std::size_t j = 0; j < f.struts.size(); ++j) {
            const ConvolutionStrut s =
                convolutionStrut(f, j, graded ? sigma.front() : sigma[j], r ? &(*r)[j] : nullptr);
            if (!std::isfinite(s.w0) || !std::isfinite(s.w1))  // weights of 1 without radii
                spec["radius"].fail("radius " + std::to_string(std::max((*r)[j][0], (*r)[j][1])) +
                                    " is too large for sigma " + std::to_string(s.sigma) +
                                    " (the weight exp(R^2 / 2 sigma^2) overflows): raise sigma");
            struts.push_back(s);
        }
        return struts;
    };
    auto raw = std::make_shared<StrutConvolution>(convolutionStruts(frame, radii), eps, interrupt);
    // The solid F >= t is evaluated as IsoRadius(F) <= rho(t) (same solid, same density; a
    // field marching cubes interpolates without bias). P: the largest strut peak.
    double peak = 0.0, sigmaMax = 0.0, rcMax = 0.0;
    for (std::size_t j = 0; j < n; ++j) {
        peak = std::max(peak, raw->peak(j));
        sigmaMax = std::max(sigmaMax, sigma[j]);
        rcMax = std::max(rcMax, raw->cutoffRadius(j));
    }
    auto iso = std::make_shared<IsoRadius>(raw, peak, sigmaMax, 2.0 * rcMax);
    // The radius of an isolated strut end of weight w at the iso-value t the level stands for:
    // w sigma sqrt(2 pi) exp(-r^2 / 2 sigma^2) = t.
    auto convolutionRadius = [iso, weights = convolutionStruts(frame, radii)](std::size_t j, int e, double level) {
        const ConvolutionStrut& s = weights[j];
        const double t = iso->valueOf(level);
        const double ratio = (e == 0 ? s.w0 : s.w1) * s.sigma * kSqrtTwoPi / t;
        return ratio > 1.0 ? s.sigma * std::sqrt(2.0 * std::log(ratio)) : 0.0;
    };
    // A box of identical cells with identical struts repeats cell by cell wherever the box's
    // faces are beyond the cut-off: evaluate one cell of the interior and tile it.
    const bool sameStruts = (!radii || spec["radius"].isNumber()) && !g["sigma"].isSequence();
    const bool periodic = uniform && !spec["struts"].has("within") && sameStruts && !graded;
    // Radii graded along one axis (linear or centred) depend on that coordinate only: the box's cells still
    // repeat along the other two axes, so the field is tabled one period deep across them and
    // as it is along the graded axis (period 0 there).
    const int gradedAxis = radiusGradientAxis(spec);
    const bool partlyPeriodic = uniform && !spec["struts"].has("within") && !graded && !sameStruts &&
                                !g["sigma"].isSequence() && gradedAxis >= 0;
    const Vec3d period = uniform ? framePeriod(uniform->size, gradedAxis) : Vec3d(0.0);
    // Identical struts (same sigma and radius) whose frame is its own mirror image: the field is
    // too (radii graded along an axis: mirror images across the other axes keep their radii).
    std::array<bool, 3> mirror{};
    if (periodic || partlyPeriodic) mirror = frameMirrors(frame, box, gradedAxis, interrupt);
    FieldPtr evaluated = iso;
    if (periodic || partlyPeriodic) evaluated = std::make_shared<PeriodicTiling>(iso, box, period, rcMax, mirror);
    // A frame trimmed `within:` a solid is, deeper inside the solid than the kernel's reach from
    // every strut the trim removed or cut, the untrimmed box frame: its values there come from
    // that frame's tabled period (the same struts and weights, the same peak and cap), the rest
    // strut by strut (TiledInterior).
    bool tiledInterior = false;
    if (uniform && uniform->fill && !graded && !sn.isSequence() && (sameStruts || gradedAxis >= 0)) {
        // The untrimmed frame's radii: the one radius, or the gradient over the trimmed frame's
        // box (so a strut both frames hold has the same radii in both).
        std::optional<double> oneRadius;
        std::optional<RadiusGradient> gradient;
        if (radii && spec["radius"].isNumber())
            oneRadius = spec["radius"].number();
        else if (radii)
            gradient = readRadiusGradient(spec["radius"]);
        using Radii = std::vector<std::array<double, 2>>;
        // Made on the first grid batch (TiledInterior): slices and point queries never pay.
        auto parts = [trimmed = std::make_shared<const Frame>(frame),
                      trimmedRadii = radii ? std::make_shared<const Radii>(*radii) : nullptr, cells = *uniform,
                      oneRadius, gradient, sigma0 = sigma.front(), eps, peak, sigmaMax, rcMax, gradedAxis, interrupt] {
            TiledInterior::Parts parts;
            const Frame untrimmed = clippedFrame(
                cells.cell, *cells.fill, cells.size, [](const Vec3d&) { return -1.0; }, 0.0);
            std::optional<Radii> untrimmedRadii;
            if (oneRadius)
                untrimmedRadii.emplace(untrimmed.struts.size(), std::array<double, 2>{*oneRadius, *oneRadius});
            if (gradient) untrimmedRadii = gradientRadii(*gradient, untrimmed, trimmed->box());
            auto differing =
                differingStruts(*trimmed, trimmedRadii.get(), untrimmed, untrimmedRadii ? &*untrimmedRadii : nullptr);
            if (!differing) return parts;
            std::vector<ConvolutionStrut> struts(untrimmed.struts.size());
            for (std::size_t j = 0; j < struts.size(); ++j)
                struts[j] = convolutionStrut(untrimmed, j, sigma0, untrimmedRadii ? &(*untrimmedRadii)[j] : nullptr);
            auto raw = std::make_shared<StrutConvolution>(struts, eps, interrupt);
            parts.reach = rcMax;
            for (std::size_t j = 0; j < struts.size(); ++j) parts.reach = std::max(parts.reach, raw->cutoffRadius(j));
            // The trimmed frame's peak and cap: both measure levels alike.
            const auto same = std::make_shared<IsoRadius>(raw, peak, sigmaMax, 2.0 * rcMax);
            const Box3 box = untrimmed.box();
            parts.same = std::make_shared<PeriodicTiling>(same, box, framePeriod(cells.size, gradedAxis), parts.reach,
                                                          frameMirrors(untrimmed, box, gradedAxis, interrupt));
            parts.differing = std::move(*differing);
            return parts;
        };
        evaluated = std::make_shared<TiledInterior>(iso, std::move(parts));
        tiledInterior = true;
    }
    // Evaluated strut by strut: in stacks of up to sixteen leaves along z (rows of 128 points: a
    // strut row's set-up, its table and the struts' gather shared by the stack's leaves), fewer
    // where the domain is not tall enough to repay them (stackLeavesFor). W2g's frames at 25 mm,
    // user + sys CPU, stacks of 4, 8 and 16 leaves: the wireframe 10.4, 9.3 and 8.4 s (16.3 s one
    // leaf at a time), the cylinder frame 3.6, 3.2 and 3.3 s (5.4 s); at 50 mm, 8 against 16
    // leaves: the wireframe 21.6-22.5 against 19.8-20.7 s, the cylinder frame's user CPU 6.6-6.8
    // against 6.1-6.6 s, the same bytes. A trimmed frame stays at eight: its TiledInterior decides
    // leaf by leaf within a stack which leaves read the tiling, and sixteen cost it 15 %.
    if (!(periodic || partlyPeriodic)) node.stackLeaves = tiledInterior ? 8 : 16;
    // Grids evaluated strut by strut (not tabled) take their values from nodes every second
    // voxel where the struts are smooth at the voxel (CoarseNodes.h); the report says so.
    if (!(periodic || partlyPeriodic)) node.gridNodesBound = [raw](double voxel) { return raw->servedBound(voxel); };
    const double t = spec.has("level") ? spec["level"].positiveNumber() : 1.0;
    {
        std::ostringstream d;
        d << "strut convolution (gaussian); level: the iso-value t in F >= t; level_radius_mm = sigma sqrt(2 ln(P / "
             "t)), the radius of an isolated strut at iso-value t, with P = "
          << peak << ", sigma = " << sigmaMax;
        node.description = d.str();
    }
    if (graded) {
        // Every strut within the cut-off of the middle cell must be in the table's frame.
        const double smallest = std::min({uniform->size[0], uniform->size[1], uniform->size[2]});
        const int margin = std::max(1, int(std::ceil(rcMax / smallest)));
        const auto [cells, cellBox] = tableFrame(*uniform, margin);
        std::optional<std::vector<std::array<double, 2>>> cellRadii;
        if (radii) cellRadii = readRadii(builder, spec["radius"], cells, name);
        auto cellRaw = std::make_shared<StrutConvolution>(convolutionStruts(cells, cellRadii), eps);
        // The same peak and sigma as the frame's, so that both measure levels alike.
        const IsoRadius cellField(cellRaw, peak, sigmaMax, 2.0 * rcMax);
        // Whether it holds together is checked on the grid (Job: pieces), not at strut middles.
        FieldPtr result = buildGradedStruts(builder, spec, name, iso, cellField, cellBox, node.description);
        recordFrame(builder, name, frame, convolutionRadius, gradedLevelAt(result));
        // Beyond the cut-off radius F = 0, below every iso-value.
        return withinReach(result, rcMax);
    }
    const bool solved = node.density || solvedByInfill;
    // A solved level may be moved by the job's aim at the mesh's share: the grid's values below
    // the level are kept between those evaluations (GridValueMemo), where they are costly to make
    // again. A tiled field's values are copies of its table's (a tabled period, made once): kept
    // again, they cost more than they save, and most aims keep the solved level (W2g's graded
    // 50 mm frame: 0.6 GB of kept doubles, a fifth of the run zeroing their fresh pages, read by
    // no second evaluation).
    const bool tiled = periodic || partlyPeriodic;
    // A level given is read through a memo too (never keeping), which rounds the grid's values as
    // a solved one's: the reported level pasted back gives the same grid.
    const FieldPtr values = tiled ? evaluated : std::make_shared<GridValueMemo>(evaluated);
    node.solid = solved ? LevelSolid::unsolved(values, SolidSide::Below)
                        : std::make_shared<LevelSolid>(values, SolidSide::Below, iso->radiusOf(t));
    // The recipe's `level:` is t: the double t whose radiusOf() gives back this level exactly (a
    // neighbour of valueOf()'s when rounding moves it), so the reported t pasted into the recipe
    // builds the same solid, bit for bit.
    node.recipeLevel = [iso](double level) {
        const double t = iso->valueOf(level);
        double best = t, bestError = std::abs(iso->radiusOf(t) - level);
        for (const double direction : {-1.0, 1.0}) {
            double u = t;
            for (int k = 0; k < 64 && bestError > 0.0; ++k) {
                u = std::nextafter(u, direction * std::numeric_limits<double>::infinity());
                const double error = std::abs(iso->radiusOf(u) - level);
                if (error < bestError) best = u, bestError = error;
            }
        }
        return best;
    };
    // Mid-strut, away from joints, a strut of peak p is a cylinder of radius sigma sqrt(2 ln(p / t))
    // at iso-value t (none where p <= t: the strut vanishes).
    node.thinnest = [raw, iso, n, sigma](double level) {
        const double value = iso->valueOf(level);
        double thinnest = std::numeric_limits<double>::infinity();
        for (std::size_t j = 0; j < n; ++j) {
            const double p = raw->peak(j);
            thinnest = std::min(thinnest, p > value ? 2.0 * sigma[j] * std::sqrt(2.0 * std::log(p / value)) : 0.0);
        }
        return thinnest;
    };
    recordFrame(builder, name, frame, convolutionRadius, [solid = node.solid](const Vec3d&) { return solid->level(); });
    if (perCell) {
        // One cell: its lattice sampled at a fixed phase, finer (as one period below) and fine
        // enough for the kernel.
        node.densityVoxel = std::min(*node.densityVoxel / 1.5, *std::min_element(sigma.begin(), sigma.end()) / 8.0);
        if (rcMax > neighbourDepth)
            spec["density_of"].fail("the Gaussian kernel reaches " + formatNumber(rcMax) + " mm, beyond the " +
                                    formatNumber(neighbourDepth) +
                                    " mm of cells around the frame's middle cell: give the frame more cells (or a "
                                    "smaller sigma) for `density_of: cell`");
    } else if ((periodic || partlyPeriodic) && node.density) {
        node.densityPeriod = period;
        node.densityReach = rcMax;
        // The density pieces measure one face zone for both faces of a mirror axis, and one of
        // each piece and its transpose where swapping x and y keeps the frame (and the radii:
        // graded along z or not at all).
        node.densityMirror = mirror;
        node.densitySwapXY = (gradedAxis < 0 || gradedAxis == 2) && swapSymmetric(frame, box, interrupt);
        node.densityIndicator = iso;
        // One period is sampled at a fixed phase, so its lattice does not average over phases
        // as the whole box's incommensurate one does: sample it 1.5 times finer (level within
        // 0.0002 mm of the converged one for BCC at 0.1 mm, against 0.001 mm at the same spacing).
        // The coverage resolves the kernel, whatever the job's voxel: at most sigma / 8 a step
        // (one period costs little). BCC, sigma 0.5, 5 mm: at a 0.2 mm job the level is 0.39812 mm
        // instead of 0.40231 (1.0 % more material on the mesh); converged 0.39770; 0.1 mm jobs
        // already sample finer (0.39780).
        node.densityVoxel = std::min(*node.densityVoxel / 1.5, *std::min_element(sigma.begin(), sigma.end()) / 8.0);
    } else if (node.density && node.densityBox &&
               builder.recipe().voxel <= kJobVoxelsPerSigma * *std::min_element(sigma.begin(), sigma.end())) {
        // A frame nothing folds (a cylinder frame, a wireframe, graded radii) is measured on the
        // job's own voxels: the solve's band leaves are the grid's (GridValueMemo), not a second
        // lattice 1.16 times finer. Where the voxel is at most sigma / 4 the coverage measure
        // holds the density there too, cells of whole voxels included (test
        // StrutLattice.DensityOnTheJobsVoxelsHoldsByBruteForce).
        node.densityOnJobVoxels = true;
    }
    const double sigmaShown = sigma.front();
    if (solved) {
        JobContext* context = &builder.context();
        if (radii)
            // t as report.json's `level` gives it (the double whose radius is rho exactly).
            node.onSolved = [context, name, recipeLevel = node.recipeLevel, sigmaShown](double rho) {
                const double t = recipeLevel(rho);
                std::ostringstream msg;
                msg << "field `" << name << "`: the density sets the iso-value to t = " << t
                    << ", so the radii R hold up to a common shift: r^2 = R^2 + 2 sigma^2 ln(1/t) = R^2 "
                    << (t < 1 ? "+ " : "- ") << std::abs(2 * sigmaShown * sigmaShown * std::log(1 / t))
                    << " mm^2 (for sigma = " << sigmaShown << ")";
                context->warnAgain({"radii_shifted", msg.str(), {{"field", name}, {"iso_value", t}}});
            };
    }
    // Beyond the cut-off radius F = 0, below every iso-value (the value there is the cap 2 rcMax,
    // above any level a density solve or a positive iso-value gives).
    FieldPtr result = node.solid;
    if (solved || iso->radiusOf(t) < 2.0 * rcMax) {
        std::function<double()> solidReach;
        if (identicalBoxCells && !g["sigma"].isSequence()) solidReach = [rcMax] { return rcMax; };
        result = withinReach(node.solid, rcMax, solidReach);
    }
    builder.addLevelNode(std::move(node));
    return result;
}

FieldPtr buildStruts(FieldBuilder& builder, const RecipeNode& spec, const std::string& name)
{
    FieldPtr within;
    FieldPtr lattice = buildStrutLattice(builder, spec, name, within);
    if (!within) return lattice;
    // A lattice `within:` a part stays inside it: the struts' solid ends at the surface (`trim:
    // solid`, the default), or only their axes do and the solid stands out by a radius (`trim:
    // axis`, the frame as trimmed).
    const RecipeNode s = spec["struts"];
    const std::string trim = s.has("trim") ? s["trim"].string() : "solid";
    if (trim == "axis") return lattice;
    if (trim != "solid")
        s["trim"].fail(
            "`trim:` is `solid` (the struts' solid ends at the surface, the default) or `axis` (only "
            "their axes do); got `" +
            trim + "`");
    return std::make_shared<BooleanField>(BooleanOp::Intersection, std::vector<FieldPtr>{lattice, within});
}

}  // namespace

void addStrutNodeTypes(std::vector<NodeType>& types)
{
    using namespace valueSchema;
    const json frame =
        object({{"cell", anything(), "a preset name, {lines: [...]} or {obj: file}", "required"},
                {"size", numberOrVec3(), "cell size in mm, or [x, y, z]", "required"},
                {"count", anything(), "cells per axis: a number or [x, y, z]", "—"},
                {"origin", vec3(), "the frame's corner (mm)", "[0, 0, 0]"},
                {"edges", oneOfWords({"cut", "frame"}),
                 "a box frame filling the domain: laid a cell past it and cut by the domain box, or as written", "cut"},
                {"cylinder", anyMap(), "{radius, inner, height, base, cells}: a cylinder frame", "—"},
                {"sphere", anyMap(), "{radius, inner, center, cells}: a spherical frame", "—"},
                {"within", field(), "a solid the uniform frame is trimmed to", "—"},
                {"min_length", number(), "trimmed pieces shorter than this are dropped (mm)", "—"},
                {"trim", oneOfWords({"solid", "axis"}),
                 "with `within:`, where the struts end: their solid at the surface, or only their axes", "solid"},
                {"wireframe", string(), "OBJ or CSV file used directly as the frame", "—"},
                {"between", anything(),
                 "[S1, S2]: cells between two surfaces (S1 a `surface` node; S2 one too, {axis: [[x, y, z], [x, y, "
                 "z]]} or {point: [x, y, z]})",
                 "—"},
                {"cells", anything(), "cells of a `between:` frame: [nu, nv, nw] (along u, v, and S1 to S2)", "—"},
                {"skin",
                 object({{"part", field(), "the part whose skin the cells follow", "required"},
                         {"depth", anything(), "[outer, inner] mm below the surface, or the outer alone", "required"},
                         {"layers", number(), "cells across, from the outer to the inner depth", "1"}},
                        {"part", "depth"}),
                 "cells between two offset surfaces of a part", "—"}});
    types.push_back(
        {"struts",
         {{"struts", frame, "the frame: unit cell and how it is laid out", "required"},
          {"kernel", anything(), "{gaussian: {sigma, cutoff}} (convolution joints), capsule or {capsule: {blend}}",
           "required"},
          {"radius", anything(),
           "strut radius (mm): a number, a list, {gradient, min, max, axis}, or a field (a name or an inline node, "
           "e.g. {expr: \"0.3 + 0.01*z\"}; u, v, w run 0 to 1 over the frame's box) evaluated at each strut end",
           "—"},
          {"density", gradedDensitySchema(),
           "target relative density over the frame's bounding box, or a map grading it point by point", "—"},
          {"stiffness", object(stiffnessKeys()),
           "instead of `density:`: {E: 40 MPa, axis: z} or {E_ratio: 0.05}, the density whose homogenized "
           "modulus meets it is solved (needs `material:`)",
           "—"},
          {"optimize",
           {{"anyOf", {object(optimizeKeys(), {"sigma"}), oneOfWords({"off"})}}},
           "{sigma: [lo, hi], axis: z}: the Gaussian sigma with the highest modulus at the node's `density:` is "
           "chosen, the capsule kernel at that density reported next to it (needs `material:`); `off`: the sigma "
           "as written",
           "—"},
          {"density_of", oneOfWords({"cell", "frame"}),
           "where `density:` is measured: `frame` (its bounding box) or `cell` (the periodic cell, the middle one "
           "of the frame, as `voxlat properties` homogenizes it)",
           "frame"},
          levelKey()},
         buildStruts});
}

}  // namespace voxlat
