#include "engine/recipe/ScalarMaps.h"

#include "engine/core/Format.h"
#include "engine/core/InputFiles.h"

#include "fields/core/Constant.h"
#include "fields/maps/Ramp.h"
#include "fields/maps/SampledGrid.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>

namespace voxlat {

namespace {

}  // namespace

ScalarMap readRamp(FieldBuilder& builder, const RecipeNode& r)
{
    ScalarMap map;
    r.checkKeys({"axis", "from", "to", "range"});
    const int axis = r["axis"].axis();
    const double from = r["from"].number(), to = r["to"].number();
    double start = 0.0, end = 0.0;
    if (r.has("range")) {
        const RecipeNode range = r["range"];
        if (!range.isSequence() || range.size() != 2) range.fail("expected [start, end] in millimetres");
        start = range.at(0).number();
        end = range.at(1).number();
        if (!(end > start)) range.fail("the range's end must be above its start");
    } else {
        const auto& box = builder.recipe().domainBox;
        if (!box) r.fail("give `range: [start, end]` (there is no domain to take it from)");
        start = box->min[axis];
        end = box->max[axis];
    }
    map.field = std::make_shared<RampField>(axis, start, end, from, to);
    map.axis = axis;
    map.description = "ramp along " + std::string(1, "xyz"[axis]) + " from " + formatNumber(from) + " at " +
                      formatNumber(start) + " mm to " + formatNumber(to) + " at " + formatNumber(end) + " mm";
    return map;
}

ScalarMap readDistanceRamp(FieldBuilder& builder, const RecipeNode& r, const std::string& name)
{
    ScalarMap map;
    r.checkKeys({"field", "from", "to", "over"});
    const FieldPtr source = builder.operand(r["field"], name + "/distance");
    const double from = r["from"].number(), to = r["to"].number(), over = r["over"].positiveNumber();
    map.field = std::make_shared<RampField>(source, 0.0, over, from, to);
    map.description =
        "from " + formatNumber(from) + " at the surface to " + formatNumber(to) + " at " + formatNumber(over) + " mm";
    return map;
}

ScalarMap readScalarMap(FieldBuilder& builder, const RecipeNode& node, const std::string& name)
{
    ScalarMap map;
    if (node.isNumber()) {
        map.constant = node.number();
        map.field = std::make_shared<ConstantField>(*map.constant);
        map.description = formatNumber(*map.constant);
        return map;
    }
    if (node.isScalar()) {
        map.field = builder.field(node.string());
        map.description = "field `" + node.string() + "`";
        return map;
    }
    if (!node.isMap()) node.fail("expected a number, a field name, or a map with one of ramp, distance, field, file");
    node.checkKeys({"ramp", "distance", "field", "file"});
    if (node.size() != 1) node.fail("give one of ramp, distance, field, file");
    if (node.has("ramp")) return readRamp(builder, node["ramp"]);
    if (node.has("distance")) return readDistanceRamp(builder, node["distance"], name);
    if (node.has("field")) {
        map.field = builder.operand(node["field"], name + "/field");
        map.description = node["field"].isScalar() ? "field `" + node["field"].string() + "`" : "inline field";
        return map;
    }
    const RecipeNode file = node["file"];
    const std::filesystem::path path = builder.recipe().resolve(file.string());
    try {
        map.field = readValueGrid(path, file.string());
    } catch (const InputError& e) {
        file.fail(e.what());
    }
    map.description = "values from " + file.string();
    return map;
}

SampledRange sampleRange(const FieldNode& field, const Box3& box, int n)
{
    SampledRange r{std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity()};
    std::vector<Vec3d> points;
    const Vec3d step = box.extent() / double(n);
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j)
            for (int k = 0; k < n; ++k)
                points.push_back(box.min + Vec3d((i + 0.5) * step.x(), (j + 0.5) * step.y(), (k + 0.5) * step.z()));
    std::vector<double> v(points.size());
    field.values(points, v);
    for (std::size_t i = 0; i < v.size(); ++i) {
        if (!(v[i] >= r.lo)) r.lo = v[i], r.where_lo = points[i];
        if (!(v[i] <= r.hi)) r.hi = v[i], r.where_hi = points[i];
    }
    return r;
}

void addScalarMapNodeTypes(std::vector<NodeType>& types)
{
    using valueSchema::anyMap;
    types.push_back(
        {"ramp",
         {{"ramp", anyMap(), "{axis, from, to, range}: linear along x, y or z", "required"}},
         [](FieldBuilder& b, const RecipeNode& spec, const std::string&) { return readRamp(b, spec["ramp"]).field; }});
    types.push_back({"distance-ramp",
                     {{"distance-ramp", anyMap(),
                       "{field, from, to, over}: linear in the distance from a field's surface", "required"}},
                     [](FieldBuilder& b, const RecipeNode& spec, const std::string& name) {
                         return readDistanceRamp(b, spec["distance-ramp"], name).field;
                     }});
    types.push_back({"value-grid",
                     {{"value-grid", valueSchema::string(),
                       "a text file of values on a regular grid, interpolated linearly", "required"}},
                     [](FieldBuilder& b, const RecipeNode& spec, const std::string&) -> FieldPtr {
                         const RecipeNode file = spec["value-grid"];
                         try {
                             return readValueGrid(b.recipe().resolve(file.string()), file.string());
                         } catch (const InputError& e) {
                             file.fail(e.what());
                         }
                     }});
}

void checkScalarRange(const FieldBuilder& builder, const ScalarMap& map, const RecipeNode& node, double lo, double hi,
                      bool open, const std::string& what, const std::string& fix)
{
    auto outside = [&](double v) { return open ? !(v > lo && v < hi) : !(v >= lo && v <= hi); };
    std::ostringstream rangeText;  // a stream: GCC 12 flags `const char* + std::string` here (-Wrestrict)
    rangeText << (open ? "(" : "[") << formatNumber(lo) << ", " << formatNumber(hi) << (open ? ")" : "]");
    const std::string range = rangeText.str();
    if (map.constant) {
        if (outside(*map.constant))
            node.fail(what + " must lie in " + range + ", got " + formatNumber(*map.constant) + fix);
        return;
    }
    const auto& box = builder.recipe().domainBox;
    if (!box) return;
    // A ramp is checked exactly by its bound; other fields by sampling the domain.
    const Interval b = map.field->bound(*box);
    if (map.axis && (outside(b.lo) || outside(b.hi)))
        node.fail(what + " must lie in " + range + " over the domain, but the ramp reaches " +
                  formatNumber(outside(b.lo) ? b.lo : b.hi) + fix);
    const SampledRange s = sampleRange(*map.field, *box);
    auto at = [](const Vec3d& p) {
        return " at (" + formatNumber(p[0]) + ", " + formatNumber(p[1]) + ", " + formatNumber(p[2]) + ")";
    };
    if (outside(s.lo))
        node.fail(what + " must lie in " + range + " over the domain, but it reaches " + formatNumber(s.lo) +
                  at(s.where_lo) + fix);
    if (outside(s.hi))
        node.fail(what + " must lie in " + range + " over the domain, but it reaches " + formatNumber(s.hi) +
                  at(s.where_hi) + fix);
}

FieldPtr readValueGrid(const std::filesystem::path& path, const std::string& shown)
{
    if (!std::filesystem::exists(path))
        throw InputError("cannot read `" + shown + "` (looked for " + path.string() + ")");
    checkInputFile(path, kMaxDataFileBytes, "value file");
    std::ifstream in(path);
    if (!in) throw InputError("cannot read `" + shown + "` (looked for " + path.string() + ")");
    auto split = [](const std::string& line) {
        std::vector<std::string> out;
        std::string cur;
        for (char ch : line) {
            if (ch == ',' || ch == ';' || ch == ' ' || ch == '\t' || ch == '\r') {
                if (!cur.empty()) out.push_back(cur), cur.clear();
            } else {
                cur += ch;
            }
        }
        if (!cur.empty()) out.push_back(cur);
        return out;
    };
    std::vector<std::string> header;
    std::vector<std::vector<double>> rows;
    std::vector<int> rowLine;
    std::string line;
    for (int number = 1; std::getline(in, line); ++number) {
        const auto first = line.find_first_not_of(" \t\r");
        if (first == std::string::npos || line[first] == '#') continue;
        const auto cells = split(line);
        const std::string where = shown + ":" + std::to_string(number) + ": ";
        if (header.empty()) {
            header = cells;
            continue;
        }
        if (cells.size() != header.size())
            throw InputError(where + "expected " + std::to_string(header.size()) + " values (one per column), got " +
                             std::to_string(cells.size()));
        std::vector<double> row;
        for (std::size_t column = 0; column < cells.size(); ++column) {
            const std::string& c = cells[column];
            char* end = nullptr;
            const double v = std::strtod(c.c_str(), &end);
            // The value is not quoted: messages show the recipe's text only, never another file's.
            if (end == c.c_str() || *end != '\0' || !std::isfinite(v))
                throw InputError(where + "column " + std::to_string(column + 1) + " is not a finite number");
            row.push_back(v);
        }
        rows.push_back(std::move(row));
        rowLine.push_back(number);
    }
    int axisColumn[3] = {-1, -1, -1}, valueColumn = -1;
    for (std::size_t c = 0; c < header.size(); ++c) {
        std::string h = header[c];
        std::transform(h.begin(), h.end(), h.begin(), [](unsigned char ch) { return std::tolower(ch); });
        if (h == "x" || h == "y" || h == "z") {
            axisColumn[h[0] - 'x'] = int(c);
        } else if (valueColumn < 0) {
            valueColumn = int(c);
        } else {
            throw InputError(shown + ": the header names two value columns (`" + header[valueColumn] + "` and `" +
                             header[c] + "`); give x, y and/or z and one value column, e.g. `x,y,z,density`");
        }
    }
    if (header.empty() || valueColumn < 0)
        throw InputError(shown + ": expected a header line naming the columns, e.g. `x,y,z,density` or `z,density`");
    if (rows.empty()) throw InputError(shown + ": no rows of values after the header");
    std::array<std::vector<double>, 3> coords;
    for (int a = 0; a < 3; ++a) {
        if (axisColumn[a] < 0) {
            coords[a] = {0.0};
            continue;
        }
        for (const auto& r : rows) coords[a].push_back(r[axisColumn[a]]);
        std::sort(coords[a].begin(), coords[a].end());
        coords[a].erase(std::unique(coords[a].begin(), coords[a].end()), coords[a].end());
    }
    const std::size_t nodes = coords[0].size() * coords[1].size() * coords[2].size();
    if (nodes != rows.size())
        throw InputError(shown + ": the rows do not form a full regular grid: " + std::to_string(rows.size()) +
                         " rows for " + std::to_string(coords[0].size()) + " x " + std::to_string(coords[1].size()) +
                         " x " + std::to_string(coords[2].size()) + " grid nodes");
    std::vector<double> values(nodes, 0.0);
    std::vector<char> seen(nodes, 0);
    for (std::size_t r = 0; r < rows.size(); ++r) {
        std::size_t idx[3] = {0, 0, 0};
        for (int a = 0; a < 3; ++a)
            if (axisColumn[a] >= 0)
                idx[a] = std::size_t(std::lower_bound(coords[a].begin(), coords[a].end(), rows[r][axisColumn[a]]) -
                                     coords[a].begin());
        const std::size_t i = (idx[0] * coords[1].size() + idx[1]) * coords[2].size() + idx[2];
        if (seen[i]) throw InputError(shown + ":" + std::to_string(rowLine[r]) + ": this grid node appears twice");
        seen[i] = 1;
        values[i] = rows[r][valueColumn];
    }
    return std::make_shared<SampledGridField>(std::move(coords), std::move(values));
}

}  // namespace voxlat
