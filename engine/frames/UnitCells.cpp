#include "engine/frames/UnitCells.h"

#include "engine/core/InputFiles.h"

#include "engine/core/Errors.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>

namespace voxlat {

namespace {

constexpr double kTol = 1e-7;  // relative to the unit cell

using Lines = std::vector<std::pair<Vec3d, Vec3d>>;

/// Corners 0-7 in IntraLattice's order: 000, 100, 110, 010, 001, 101, 111, 011.
Vec3d corner(int i)
{
    static const int c[8][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}};
    return Vec3d(c[i][0], c[i][1], c[i][2]);
}

Lines cubeEdges(const Vec3d& lo, const Vec3d& hi)
{
    Lines l;
    auto p = [&](int i) {
        const Vec3d c = corner(i);
        return Vec3d(c[0] ? hi[0] : lo[0], c[1] ? hi[1] : lo[1], c[2] ? hi[2] : lo[2]);
    };
    const int e[12][2] = {{0, 1}, {1, 2}, {2, 3}, {3, 0}, {4, 5}, {5, 6},
                          {6, 7}, {7, 4}, {0, 4}, {1, 5}, {2, 6}, {3, 7}};
    for (const auto& ij : e) l.emplace_back(p(ij[0]), p(ij[1]));
    return l;
}

Lines bodyDiagonals()
{
    return {{corner(0), corner(6)}, {corner(1), corner(7)}, {corner(3), corner(5)}, {corner(2), corner(4)}};
}

Lines faceDiagonals()
{
    Lines l;
    for (int a = 0; a < 3; ++a)
        for (int side = 0; side < 2; ++side) {
            const int b = (a + 1) % 3, c = (a + 2) % 3;
            Vec3d p0(0.0), p1(0.0), q0(0.0), q1(0.0);
            p0[a] = p1[a] = q0[a] = q1[a] = side;
            p1[b] = p1[c] = 1;
            q0[b] = 1;
            q1[c] = 1;
            l.emplace_back(p0, p1);
            l.emplace_back(q0, q1);
        }
    return l;
}

/// Nodes joined when their distance equals the shortest distance between any two of them.
Lines nearestNeighbours(const std::vector<Vec3d>& nodes)
{
    double best = 1e300;
    for (std::size_t i = 0; i < nodes.size(); ++i)
        for (std::size_t j = i + 1; j < nodes.size(); ++j) best = std::min(best, (nodes[i] - nodes[j]).length());
    Lines l;
    for (std::size_t i = 0; i < nodes.size(); ++i)
        for (std::size_t j = i + 1; j < nodes.size(); ++j)
            if ((nodes[i] - nodes[j]).length() < best * (1 + 1e-9)) l.emplace_back(nodes[i], nodes[j]);
    return l;
}

Lines presetLines(const std::string& name)
{
    const double q = 0.25, h = 0.5, t = 0.75;
    Lines l;
    auto add = [&](const Lines& more) { l.insert(l.end(), more.begin(), more.end()); };
    if (name == "grid") return cubeEdges(Vec3d(0.0), Vec3d(1.0));
    if (name == "x") return bodyDiagonals();
    if (name == "star") {
        add(bodyDiagonals());
        add(cubeEdges(Vec3d(0.0), Vec3d(1.0)));
        return l;
    }
    if (name == "cross" || name == "fcc") return faceDiagonals();
    if (name == "bcc") {
        for (int i = 0; i < 8; ++i) l.emplace_back(Vec3d(h), corner(i));
        return l;
    }
    if (name == "tesseract") {
        add(cubeEdges(Vec3d(0.0), Vec3d(1.0)));
        add(cubeEdges(Vec3d(q), Vec3d(t)));
        for (int i = 0; i < 8; ++i) l.emplace_back(corner(i), Vec3d(q) + h * corner(i));
        return l;
    }
    if (name == "vintiles") {
        // IntraLattice's node numbering: 0-15 quarter points on the bottom and top edges,
        // 16-23 side-face centres at z = 1/4 and 3/4, 24-27 the inner square.
        std::vector<Vec3d> n;
        for (double z : {0.0, 1.0})
            for (const Vec3d& p : {Vec3d(0, q, z), Vec3d(0, t, z), Vec3d(q, 1, z), Vec3d(t, 1, z), Vec3d(1, t, z),
                                   Vec3d(1, q, z), Vec3d(t, 0, z), Vec3d(q, 0, z)})
                n.push_back(p);
        for (double z : {q, t})
            for (const Vec3d& p : {Vec3d(0, h, z), Vec3d(h, 1, z), Vec3d(1, h, z), Vec3d(h, 0, z)}) n.push_back(p);
        for (double y : {q, t}) n.emplace_back(h, y, h);
        for (double x : {q, t}) n.emplace_back(x, h, h);
        const int fans[8][4] = {{16, 0, 1, 26}, {17, 2, 3, 25},   {18, 4, 5, 27},   {19, 6, 7, 24},
                                {20, 8, 9, 26}, {21, 10, 11, 25}, {22, 12, 13, 27}, {23, 14, 15, 24}};
        for (const auto& f : fans)
            for (int k = 1; k < 4; ++k) l.emplace_back(n[f[0]], n[f[k]]);
        for (int i : {1, 3, 5, 9, 11, 13}) l.emplace_back(n[i], n[i + 1]);
        for (int i : {24, 25}) {
            l.emplace_back(n[26], n[i]);
            l.emplace_back(n[27], n[i]);
        }
        l.emplace_back(n[0], n[7]);
        l.emplace_back(n[8], n[15]);
        return l;
    }
    if (name == "octet") {
        add(faceDiagonals());
        const Vec3d f[6] = {{1, h, h}, {h, 1, h}, {0, h, h}, {h, 0, h}, {h, h, 0}, {h, h, 1}};
        for (int i = 0; i < 6; ++i)
            for (int j = i + 1; j < 6; ++j)
                if (std::abs((f[i] - f[j]).length() - std::sqrt(0.5)) < 1e-9) l.emplace_back(f[i], f[j]);
        return l;
    }
    if (name == "diamond") {
        // Diamond cubic with its origin shifted by (1/4, 1/4, 1/4) so that opposite faces mirror
        // each other: the four tetrahedral nodes join the body centre and the 12 edge midpoints.
        for (const Vec3d& p : {Vec3d(q, q, q), Vec3d(t, t, q), Vec3d(t, q, t), Vec3d(q, t, t)}) {
            const double sx = p[0] < h ? 1 : -1, sy = p[1] < h ? 1 : -1, sz = p[2] < h ? 1 : -1;
            for (const Vec3d& d : {Vec3d(q, q, q), Vec3d(-q, -q, q), Vec3d(-q, q, -q), Vec3d(q, -q, -q)})
                l.emplace_back(p, p + Vec3d(sx * d[0], sy * d[1], sz * d[2]));
        }
        return l;
    }
    if (name == "honeycomb") {
        // Hexagonal prism: a honeycomb in the xy plane (regular for cell sizes sqrt(3) : 3),
        // extruded along z with struts along z at every node.
        const std::vector<Vec3d> hex = {{h, 0, 0},       {h, 1.0 / 3, 0}, {0, h, 0}, {1, h, 0},
                                        {0, 5.0 / 6, 0}, {1, 5.0 / 6, 0}, {h, 1, 0}};
        const int e[7][2] = {{0, 1}, {1, 2}, {1, 3}, {2, 4}, {3, 5}, {4, 6}, {5, 6}};
        for (double z : {0.0, 1.0})
            for (const auto& ij : e) l.emplace_back(hex[ij[0]] + Vec3d(0, 0, z), hex[ij[1]] + Vec3d(0, 0, z));
        for (const Vec3d& p : hex) l.emplace_back(p, p + Vec3d(0, 0, 1));
        return l;
    }
    if (name == "honeycomb-auxetic") {
        // Re-entrant (bow-tie) hexagons in the xy plane, extruded along z: a vertical strut on
        // x = 1/2 from y = 1/4 to 3/4 whose ends send two arms outwards and back towards it
        // (down from the top end, up from the bottom end: the hexagons' re-entrant corners) to
        // vertical struts on the side faces x = 0 and x = 1, which run through the faces y = 0, 1.
        // Arms rise 1/6 over 1/2: 30 degrees for cell sizes x : y = 1 : 1.732 (that is, 2 : 3.46).
        const std::vector<Vec3d> hex = {{h, q, 0},        {h, t, 0},        {0, 5.0 / 12, 0}, {1, 5.0 / 12, 0},
                                        {0, 7.0 / 12, 0}, {1, 7.0 / 12, 0}, {0, 0, 0},        {1, 0, 0},
                                        {0, 1, 0},        {1, 1, 0}};
        const int e[9][2] = {{0, 1}, {1, 4}, {1, 5}, {0, 2}, {0, 3}, {4, 8}, {5, 9}, {6, 2}, {7, 3}};
        for (double z : {0.0, 1.0})
            for (const auto& ij : e) l.emplace_back(hex[ij[0]] + Vec3d(0, 0, z), hex[ij[1]] + Vec3d(0, 0, z));
        // Struts along z at the hexagons' corners (the first six nodes), not where the side
        // struts merely pass through the y faces.
        for (int i = 0; i < 6; ++i) l.emplace_back(hex[i], hex[i] + Vec3d(0, 0, 1));
        return l;
    }
    if (name == "kelvin") {
        // Truncated octahedron centred in the cell: vertices at the permutations of
        // (0, +-1/4, +-1/2) around the centre, edges between nearest vertices (36).
        std::vector<Vec3d> v;
        for (int perm = 0; perm < 3; ++perm)
            for (double s1 : {-q, q})
                for (double s2 : {-h, h}) {
                    Vec3d a(0.0), b(0.0);
                    a[(perm + 1) % 3] = s1;
                    a[(perm + 2) % 3] = s2;
                    b[(perm + 1) % 3] = s2;
                    b[(perm + 2) % 3] = s1;
                    v.push_back(Vec3d(h) + a);
                    v.push_back(Vec3d(h) + b);
                }
        return nearestNeighbours(v);
    }
    throw std::invalid_argument("unknown unit cell `" + name + "`");
}

/// Index of @a p in @a nodes within tolerance, appending it if new.
int nodeIndex(std::vector<Vec3d>& nodes, const Vec3d& p, double tol)
{
    for (std::size_t i = 0; i < nodes.size(); ++i)
        if ((nodes[i] - p).lengthSqr() <= tol * tol) return int(i);
    nodes.push_back(p);
    return int(nodes.size() - 1);
}

/// Splits crossing lines into nodes, merges equal nodes, drops duplicate struts.
UnitCell buildCell(const Lines& lines, const std::string& name, double tol)
{
    std::vector<std::vector<double>> cuts(lines.size());
    for (std::size_t i = 0; i < lines.size(); ++i) {
        const Vec3d p = lines[i].first, d = lines[i].second - p;
        const double dd = d.lengthSqr();
        for (std::size_t j = 0; j < lines.size(); ++j) {
            if (i == j) continue;
            const Vec3d q = lines[j].first, e = lines[j].second - q;
            // Closest points of the two segments' lines.
            const Vec3d r = p - q;
            const double a = dd, b = d.dot(e), c = e.lengthSqr(), dr = d.dot(r), er = e.dot(r);
            const double den = a * c - b * b;
            std::vector<std::pair<double, double>> st;
            if (den > 1e-14 * a * c) st.emplace_back((b * er - c * dr) / den, (a * er - b * dr) / den);
            // Endpoints of j touching line i (also covers parallel overlaps).
            for (const Vec3d& end : {lines[j].first, lines[j].second}) st.emplace_back((end - p).dot(d) / dd, -1.0);
            for (auto [s, u] : st) {
                if (s <= kTol || s >= 1 - kTol) continue;
                const Vec3d x = p + s * d;
                Vec3d y;
                if (u < 0) {
                    // x must be one of j's endpoints
                    y = (x - lines[j].first).lengthSqr() < (x - lines[j].second).lengthSqr() ? lines[j].first
                                                                                             : lines[j].second;
                } else {
                    if (u < -kTol || u > 1 + kTol) continue;
                    y = q + u * e;
                }
                if ((x - y).length() <= tol) cuts[i].push_back(s);
            }
        }
    }
    UnitCell cell;
    cell.name = name;
    std::map<std::pair<int, int>, bool> seen;
    for (std::size_t i = 0; i < lines.size(); ++i) {
        auto& c = cuts[i];
        c.push_back(0.0);
        c.push_back(1.0);
        std::sort(c.begin(), c.end());
        const Vec3d p = lines[i].first, d = lines[i].second - p;
        for (std::size_t k = 0; k + 1 < c.size(); ++k) {
            const int a = nodeIndex(cell.nodes, p + c[k] * d, tol), b = nodeIndex(cell.nodes, p + c[k + 1] * d, tol);
            if (a == b) continue;
            const auto key = std::minmax(a, b);
            if (seen.emplace(std::pair<int, int>(key.first, key.second), true).second)
                cell.struts.push_back({key.first, key.second});
        }
    }
    return cell;
}

std::string fmt(const Vec3d& p)
{
    std::ostringstream s;
    s << "(" << p[0] << ", " << p[1] << ", " << p[2] << ")";
    return s.str();
}

}  // namespace

std::vector<std::string> unitCellPresetNames()
{
    return {"grid",     "x",     "star",    "cross",     "tesseract",
            "vintiles", "octet", "diamond", "honeycomb", "honeycomb-auxetic",
            "bcc",      "fcc",   "kelvin"};
}

UnitCell presetUnitCell(const std::string& name)
{
    return buildCell(presetLines(name), name, kTol);
}

UnitCell unitCellFromLines(const std::vector<CellLine>& lines, const std::string& name)
{
    if (lines.empty()) throw InputError(name + ": the cell has no lines");
    Vec3d lo(1e300), hi(-1e300);
    for (const CellLine& l : lines)
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min({lo[a], l.a[a], l.b[a]});
            hi[a] = std::max({hi[a], l.a[a], l.b[a]});
        }
    const double size = (hi - lo).length();
    for (const CellLine& l : lines)
        if ((l.b - l.a).length() <= kTol * size)
            throw InputError(l.where + ": zero-length line from " + fmt(l.a) + " to " + fmt(l.b) +
                             ": a strut needs two distinct end points; remove it");
    for (int a = 0; a < 3; ++a)
        if (hi[a] - lo[a] <= kTol * size)
            throw InputError(lines.front().where + ": the cell is flat along " + std::string(1, "xyz"[a]) +
                             ": a unit cell must span all three axes (all lines have " + std::string(1, "xyz"[a]) +
                             " = " + std::to_string(lo[a]) + ")");
    // NormaliseTopology: scale to the unit cube at the origin.
    Lines unit;
    for (const CellLine& l : lines) {
        Vec3d a, b;
        for (int k = 0; k < 3; ++k) {
            a[k] = (l.a[k] - lo[k]) / (hi[k] - lo[k]);
            b[k] = (l.b[k] - lo[k]) / (hi[k] - lo[k]);
        }
        unit.emplace_back(a, b);
    }
    return buildCell(unit, name, 1e-6);
}

std::vector<ObjPolyline> readObjPolylines(const std::string& path)
{
    if (std::filesystem::exists(path))
        checkInputFile(path, kMaxDataFileBytes, "cell file");  // before open: a FIFO blocks
    std::ifstream in(path);
    if (!in) throw InputError(path + ": cannot open the file (check the path; it is relative to the recipe's folder)");
    std::vector<Vec3d> v;
    std::vector<std::pair<std::vector<long>, int>> polylines;
    std::string text;
    int lineNo = 0;
    while (std::getline(in, text)) {
        ++lineNo;
        std::istringstream s(text);
        std::string tag;
        if (!(s >> tag) || tag[0] == '#') continue;
        if (tag == "v") {
            Vec3d p;
            if (!(s >> p[0] >> p[1] >> p[2]))
                throw InputError(path + ":" + std::to_string(lineNo) + ": a vertex needs three numbers: v x y z");
            v.push_back(p);
        } else if (tag == "l") {
            std::vector<long> idx;
            std::string tok;
            while (s >> tok) {
                try {
                    std::size_t used = 0;
                    idx.push_back(std::stol(tok.substr(0, tok.find('/')), &used));
                } catch (const std::exception&) {
                    throw InputError(path + ":" + std::to_string(lineNo) +
                                     ": an `l` element holds something other than vertex numbers");
                }
            }
            if (idx.size() < 2)
                throw InputError(path + ":" + std::to_string(lineNo) +
                                 ": a line element needs at least two vertex indices: l i j");
            // OBJ indices are 1-based; negative ones count back from the last vertex so far.
            for (long& i : idx) {
                const long resolved = i < 0 ? long(v.size()) + i + 1 : i;
                if (i == 0 || resolved < 1 || resolved > long(v.size()))
                    throw InputError(path + ":" + std::to_string(lineNo) + ": vertex index " + std::to_string(i) +
                                     " does not exist (" + std::to_string(v.size()) +
                                     " vertices are defined before this line; OBJ indices start at 1)");
                i = resolved - 1;
            }
            polylines.emplace_back(idx, lineNo);
        }
    }
    if (polylines.empty()) throw InputError(path + ": no `l` elements (lines) in the file");
    std::vector<ObjPolyline> out;
    for (const auto& [idx, no] : polylines) {
        ObjPolyline p{{}, path + ":" + std::to_string(no)};
        for (const long i : idx) p.points.push_back(v[i]);
        out.push_back(std::move(p));
    }
    return out;
}

std::vector<CellLine> readObjLines(const std::string& path)
{
    std::vector<CellLine> lines;
    for (const ObjPolyline& p : readObjPolylines(path))
        for (std::size_t k = 0; k + 1 < p.points.size(); ++k) lines.push_back({p.points[k], p.points[k + 1], p.where});
    return lines;
}

std::vector<std::string> unitCellProblems(const UnitCell& cell)
{
    std::vector<std::string> problems;
    const char* axis = "xyz";
    for (int a = 0; a < 3; ++a) {
        for (int side = 0; side < 2; ++side) {
            bool any = false;
            for (const Vec3d& p : cell.nodes) {
                if (std::abs(p[a] - side) > 1e-6) continue;
                any = true;
                Vec3d m = p;
                m[a] = 1 - side;
                const bool mirrored = std::any_of(cell.nodes.begin(), cell.nodes.end(),
                                                  [&](const Vec3d& o) { return (o - m).length() <= 1e-6; });
                if (!mirrored)
                    problems.push_back("node " + fmt(p) + " on face " + axis[a] + "=" + std::to_string(side) +
                                       " has no mirror node " + fmt(m) + " on face " + axis[a] + "=" +
                                       std::to_string(1 - side));
            }
            if (!any) problems.push_back(std::string("face ") + axis[a] + "=" + std::to_string(side) + " has no node");
        }
    }
    return problems;
}

}  // namespace voxlat
