// Recipe node types for Aether's point and curve fields (issue 19): `points` and `curves`,
// F = sum_i w_i k(d_i) with an inverse, inverse-square or Gaussian falloff; the solid F >= level.
#include "engine/core/InputFiles.h"
#include "engine/frames/UnitCells.h"
#include "engine/recipe/FieldBuilder.h"
#include "fields/struts/DistanceFalloff.h"

#include <cmath>
#include <sstream>

namespace voxlat {

namespace {

/// `file:` of a point field: rows `x,y,z` or `x,y,z,w` (a weight per point); blank lines, `#`
/// comments and a header row (first line) are skipped.
std::vector<FalloffSource> readPointFile(const std::string& path, bool& weighted)
{
    const std::string text = readInputFile(path, kMaxDataFileBytes, "point file");
    std::istringstream in(text);
    std::vector<FalloffSource> sources;
    std::string line;
    int lineNo = 0, columns = 0;
    while (std::getline(in, line)) {
        ++lineNo;
        const auto first = line.find_first_not_of(" \t\r");
        if (first == std::string::npos || line[first] == '#') continue;
        std::vector<double> v;
        std::stringstream row(line);
        std::string cell;
        bool numbers = true;
        while (std::getline(row, cell, ',')) {
            try {
                std::size_t used = 0;
                const auto b = cell.find_first_not_of(" \t\r"), e = cell.find_last_not_of(" \t\r");
                const std::string c = b == std::string::npos ? "" : cell.substr(b, e - b + 1);
                v.push_back(std::stod(c, &used));
                if (used != c.size()) numbers = false;
            } catch (const std::exception&) {
                numbers = false;
            }
        }
        const std::string where = path + ":" + std::to_string(lineNo);
        if (!numbers && sources.empty() && columns == 0) {
            columns = -1;  // a header row
            continue;
        }
        if (!numbers || (v.size() != 3 && v.size() != 4))
            throw InputError(where + ": expected a point `x,y,z` or `x,y,z,w` (w: its weight)");
        if (columns > 0 && int(v.size()) != columns)
            throw InputError(where + ": every row has the same columns (" + std::to_string(columns) + " above, " +
                             std::to_string(v.size()) + " here)");
        columns = int(v.size());
        for (double x : v)
            if (!std::isfinite(x)) throw InputError(where + ": numbers must be finite");
        sources.push_back({{Vec3d(v[0], v[1], v[2])}, v.size() == 4 ? v[3] : 1.0});
    }
    if (sources.empty()) throw InputError(path + ": no points in the file (rows `x,y,z` or `x,y,z,w`)");
    weighted = columns == 4;
    return sources;
}

/// The most sources an inverse or inverse-square falloff may sum at every voxel.
constexpr std::size_t kMaxReachingSources = 100000;

/// A node's map of sources (`points:` or `curves:`) into the field; @a label is "point" or "curve".
FieldPtr buildFalloff(FieldBuilder& builder, const RecipeNode& spec, const std::string& name, const std::string& key)
{
    const bool points = key == "points";
    const RecipeNode m = spec[key];
    const std::string list = points ? "at" : "polylines";
    const std::string what = points ? "point" : "curve";
    if (!m.isMap())
        m.fail(points ? "expected {at: [[x, y, z], ...] or file: points.csv, weight, falloff, sigma}"
                      : "expected {polylines: [[[x, y, z], ...], ...] or file: curves.obj, weight, falloff, sigma}");
    m.checkKeys({list, "file", "weight", "falloff", "sigma"});
    if (m.has(list) == m.has("file"))
        m.fail("give the " + what + "s either inline (`" + list + ":`) or from a file (`file:`), one of the two");
    std::vector<FalloffSource> sources;
    bool fileWeights = false;
    if (m.has("file")) {
        const std::string path = builder.recipe().resolve(m["file"].string()).string();
        if (points) {
            sources = readPointFile(path, fileWeights);
        } else {
            for (ObjPolyline& p : readObjPolylines(path)) sources.push_back({std::move(p.points), 1.0});
        }
    } else {
        const RecipeNode l = m[list];
        if (!l.isSequence() || l.size() == 0)
            l.fail(points ? "expected a list of points [[x, y, z], ...]"
                          : "expected a list of polylines, each a list of points [[x, y, z], [x, y, z], ...]");
        for (std::size_t i = 0; i < l.size(); ++i) {
            const RecipeNode e = l.at(i);
            if (points) {
                sources.push_back({{e.vec3()}, 1.0});
                continue;
            }
            if (!e.isSequence() || e.size() < 2)
                e.fail("a polyline is a list of at least two points [[x, y, z], [x, y, z], ...]");
            FalloffSource s;
            for (std::size_t k = 0; k < e.size(); ++k) s.vertices.push_back(e.at(k).vec3());
            sources.push_back(std::move(s));
        }
    }
    if (m.has("weight")) {
        const RecipeNode w = m["weight"];
        if (fileWeights) w.fail("the point file gives a weight per point (fourth column); remove `weight:`");
        if (w.isSequence()) {
            if (w.size() != sources.size())
                w.fail("the weight list has " + std::to_string(w.size()) + " entries but there are " +
                       std::to_string(sources.size()) + " " + what + "s (one weight each, or a single number)");
            for (std::size_t i = 0; i < sources.size(); ++i) sources[i].weight = w.at(i).number();
        } else {
            const double v = w.number();
            for (FalloffSource& s : sources) s.weight = v;
        }
    }
    Falloff falloff = Falloff::Inverse;
    if (m.has("falloff")) {
        const std::string f = m["falloff"].string();
        if (f == "inverse")
            falloff = Falloff::Inverse;
        else if (f == "inverse-square")
            falloff = Falloff::InverseSquare;
        else if (f == "gaussian")
            falloff = Falloff::Gaussian;
        else
            m["falloff"].fail(
                "falloff is `inverse` (1/d), `inverse-square` (1/d^2) or `gaussian` "
                "(exp(-d^2 / 2 sigma^2)), got `" +
                f + "`");
    }
    double sigma = 0.0;
    if (falloff == Falloff::Gaussian) {
        if (!m.has("sigma")) m.fail("a gaussian falloff needs `sigma:` (mm, the kernel's width)");
        sigma = m["sigma"].positiveNumber();
    } else if (m.has("sigma")) {
        m["sigma"].fail("`sigma` is the width of a gaussian falloff; with `falloff: " +
                        std::string(falloff == Falloff::Inverse ? "inverse" : "inverse-square") + "` remove it");
    }
    // 1/d and 1/d^2 reach everywhere: every voxel sums every source (no cut-off to gather by), so
    // the time grows as sources x voxels (10^6 points still ran after two minutes on a small
    // domain). Past kMaxReachingSources the job is refused before any work.
    if (falloff != Falloff::Gaussian && sources.size() > kMaxReachingSources)
        throw JobError(m.where() + ": " + std::to_string(sources.size()) + " " + what +
                       "s with `falloff: " + (falloff == Falloff::Inverse ? "inverse" : "inverse-square") +
                       "` make every voxel sum all of them (about " + std::to_string(sources.size()) +
                       " terms a voxel, more than the " + std::to_string(kMaxReachingSources) +
                       " a job can run in reasonable time): use `falloff: gaussian` with a `sigma:` (cut off at "
                       "7.4 sigma), or fewer " +
                       what + "s");
    bool anyPositive = false;
    for (const FalloffSource& s : sources) anyPositive = anyPositive || s.weight > 0.0;
    if (!anyPositive)
        m[m.has("weight") ? "weight" : key].fail("no " + what +
                                                 " has a positive weight: F would never reach a positive level");
    auto raw = std::make_shared<DistanceFalloff>(std::move(sources), falloff, sigma);
    const char* kind = falloff == Falloff::Inverse         ? "inverse"
                       : falloff == Falloff::InverseSquare ? "inverse-square"
                                                           : "gaussian";
    LevelNode node{name, std::string(what) + " field (" + kind + " falloff), solid F >= level", nullptr};
    readLevelKeys(spec, node, raw, SolidSide::Above, 1.0,
                  levelSolvedByInfill(builder.recipe(), name) ? LevelRule::SolvedElsewhere : LevelRule::Optional);
    if (node.solid->isSolved() && !(node.solid->level() > 0.0))
        spec["level"].fail("the level must be greater than zero: F >= " + spec["level"].yaml().Scalar() +
                           " holds far from every " + what + " (F tends to 0 there), so the solid would fill space");
    FieldPtr result = node.solid;
    builder.addLevelNode(std::move(node));
    return result;
}

FieldPtr buildPoints(FieldBuilder& builder, const RecipeNode& spec, const std::string& name)
{
    return buildFalloff(builder, spec, name, "points");
}

FieldPtr buildCurves(FieldBuilder& builder, const RecipeNode& spec, const std::string& name)
{
    return buildFalloff(builder, spec, name, "curves");
}

}  // namespace

void addFalloffNodeTypes(std::vector<NodeType>& types)
{
    using namespace valueSchema;
    const KeySpec weight{"weight",
                         {{"anyOf", {number(), {{"type", "array"}, {"items", number()}}}}},
                         "w_i: one number for all, or one per source",
                         "1"};
    const KeySpec falloff{"falloff", oneOfWords({"inverse", "inverse-square", "gaussian"}),
                          "k(d): 1/d, 1/d^2 or exp(-d^2 / 2 sigma^2)", "inverse"};
    const KeySpec sigma{"sigma", number(), "the gaussian falloff's width (mm)", "—"};
    const KeySpec level{"level", number(), "t in F >= t (the field's units); value t - F, negative inside", "1"};
    const KeySpec density = densityKey();
    types.push_back({"points",
                     {{"points",
                       object({{"at", {{"type", "array"}, {"items", vec3()}, {"minItems", 1}}, "the points (mm)", "—"},
                               {"file", string(), "CSV of rows x,y,z or x,y,z,w", "—"},
                               weight,
                               falloff,
                               sigma}),
                       "F = sum_i w_i k(|p - p_i|) over points p_i", "required"},
                      level,
                      density},
                     buildPoints});
    types.push_back({"curves",
                     {{"curves",
                       object({{"polylines",
                                {{"type", "array"}, {"items", {{"type", "array"}, {"items", vec3()}, {"minItems", 2}}}},
                                "the curves, each a list of points (mm)",
                                "—"},
                               {"file", string(), "OBJ file: each `l` element (over `v` vertices) is one curve", "—"},
                               weight,
                               falloff,
                               sigma}),
                       "F = sum_i w_i k(d_i), d_i the distance to curve i", "required"},
                      level,
                      density},
                     buildCurves});
}

}  // namespace voxlat
