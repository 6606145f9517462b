#include "engine/frames/SkinFrame.h"

#include "fields/core/BlockLattice.h"

#include "engine/core/Errors.h"

#include <openvdb/tools/VolumeToMesh.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <deque>
#include <sstream>

namespace voxlat {

nlohmann::json SkinCellStats::json() const
{
    return {{"quads", quads},           {"vertices", vertices},           {"cells", hexes},
            {"dropped_cells", dropped}, {"dropped_unreached", unreached}, {"seam_edges", seamEdges},
            {"deepest_mm", deepest}};
}

namespace {

std::string mm(double v)
{
    std::ostringstream s;
    s.precision(4);
    s << v;
    return s.str();
}

Vec3d unitGradient(const FieldNode& distance, const Vec3d& p)
{
    const Vec3d g = distance.valueAndGradient(p).second;
    const double l = g.length();
    return l > 0.0 ? g / l : Vec3d(0.0);
}

/// Moves @a p along the gradient flow of the distance (inward or outward) onto the offset
/// surface distance == -depth: steps of at most @a stepMax, each along the current gradient, and
/// bisection on the step that crosses the surface. Following the flow (rather than one straight
/// line) lets a point that meets a crease of the distance (the medial surface behind a convex
/// edge) slide along it, as the offset surfaces themselves do. Where the gradient vanishes (a
/// point of symmetry) @a fallback (an outward unit direction) is used. False when the flow
/// stalls (a ridge shallower than @a depth: the part is too thin here).
bool toDepth(const FieldNode& distance, Vec3d& p, double depth, const Vec3d& fallback, double stepMax, double tol)
{
    double r = distance.value(p) + depth;
    if (std::abs(r) <= tol) return true;
    const double sign = r > 0.0 ? -1.0 : 1.0;  // too shallow: inward, against the gradient
    const double stepMin = 0.02 * stepMax;
    Vec3d dir = fallback;
    int stalled = 0;
    for (int it = 0; it < 4000; ++it) {
        const auto [v, g] = distance.valueAndGradient(p);
        r = v + depth;
        const double gl = g.length();
        if (gl > 0.3) dir = g / gl;
        const double step = std::clamp(std::abs(r), stepMin, stepMax);
        Vec3d q = p + sign * step * dir;
        auto [vq, gq] = distance.valueAndGradient(q);
        double rq = vq + depth;
        if ((rq > 0.0) == (r > 0.0) && std::abs(r) - std::abs(rq) < 0.5 * step && gq.length() > 0.3) {
            // The step crossed a crease (little progress): go along the two sides' mean
            // direction, which runs along the crease, as the flow does.
            const Vec3d mean = dir + gq / gq.length();
            if (mean.length() > 0.2) {
                const Vec3d q2 = p + sign * step * mean.unit();
                const double r2 = distance.value(q2) + depth;
                if (std::abs(r2) < std::abs(rq) || (r2 > 0.0) != (r > 0.0)) {
                    q = q2;
                    rq = r2;
                }
            }
        }
        if (std::abs(rq) <= tol) {
            p = q;
            return true;
        }
        if ((rq > 0.0) != (r > 0.0)) {
            // Bisection on the crossing step.
            Vec3d lo = p, hi = q;
            double rlo = r;
            for (int b = 0; b < 60; ++b) {
                const Vec3d mid = 0.5 * (lo + hi);
                const double rm = distance.value(mid) + depth;
                if (std::abs(rm) <= 1e-3 * tol) {
                    lo = hi = mid;
                    break;
                }
                if ((rm > 0.0) == (rlo > 0.0)) {
                    lo = mid;
                    rlo = rm;
                } else {
                    hi = mid;
                }
            }
            p = 0.5 * (lo + hi);
            return std::abs(distance.value(p) + depth) <= tol;
        }
        stalled = std::abs(r) - std::abs(rq) < 0.05 * step ? stalled + 1 : 0;
        if (stalled > 8) return false;
        p = q;
    }
    return false;
}

/// Quarter turns per quad so that neighbours' (u, v) axes agree: two starts (a breadth-first
/// walk, and a cube map by the quads' dominant normal axis), each improved by local descent; the
/// one with fewer seams wins. Returns the number of edges where neighbours still disagree.
std::size_t alignQuads(const std::vector<openvdb::Vec4I>& quads, const std::vector<openvdb::Vec3s>& points,
                       std::vector<int>& turn)
{
    struct Use {
        std::uint64_t key;
        std::uint32_t quad;
        std::uint8_t pos;
        bool operator<(const Use& o) const
        {
            return key != o.key ? key < o.key : quad != o.quad ? quad < o.quad : pos < o.pos;
        }
    };
    std::vector<Use> uses;
    uses.reserve(4 * quads.size());
    for (std::uint32_t q = 0; q < quads.size(); ++q)
        for (std::uint8_t i = 0; i < 4; ++i) {
            const std::uint64_t a = quads[q][i], b = quads[q][(i + 1) % 4];
            uses.push_back({(std::min(a, b) << 32) | std::max(a, b), q, i});
        }
    std::sort(uses.begin(), uses.end());
    // Neighbour of (quad, pos) across its edge: the other use of a two-quad edge.
    std::vector<std::int64_t> across(4 * quads.size(), -1);
    for (std::size_t s = 0; s < uses.size();) {
        std::size_t e = s;
        while (e < uses.size() && uses[e].key == uses[s].key) ++e;
        if (e - s == 2) {
            across[4 * uses[s].quad + uses[s].pos] = 4 * std::int64_t(uses[s + 1].quad) + uses[s + 1].pos;
            across[4 * uses[s + 1].quad + uses[s + 1].pos] = 4 * std::int64_t(uses[s].quad) + uses[s].pos;
        }
        s = e;
    }
    auto opposite = [&](std::uint32_t a, int i, std::uint32_t b, int j) {
        return quads[a][i] == quads[b][(j + 1) % 4] && quads[a][(i + 1) % 4] == quads[b][j];
    };
    // Consistent: B's local edge index is A's + 2 (A's u = 1 face is B's u = 0 face, and so on).
    auto wanted = [](int i, int rA, int j) { return (((j - i + rA - 2) % 4) + 4) % 4; };
    auto countSeams = [&](const std::vector<int>& t) {
        std::size_t seams = 0;
        for (std::uint32_t a = 0; a < quads.size(); ++a)
            for (int i = 0; i < 4; ++i) {
                const std::int64_t o = across[4 * a + i];
                if (o < 0) {
                    ++seams;  // an edge of one quad or of more than two: counted from each side
                    continue;
                }
                const std::uint32_t b = std::uint32_t(o / 4);
                const int j = int(o % 4);
                if (a < b && (!opposite(a, i, b, j) || t[b] != wanted(i, t[a], j))) ++seams;
            }
        return seams;
    };
    // Local descent: each quad in turn takes the turn that agrees with most neighbours
    // (sequential, in a fixed order, so the result is deterministic), until nothing changes.
    auto descend = [&](std::vector<int>& t) {
        for (int sweep = 0; sweep < 50; ++sweep) {
            bool changed = false;
            for (std::uint32_t a = 0; a < quads.size(); ++a) {
                int best = t[a], bestCount = -1;
                for (int r0 = 0; r0 < 4; ++r0) {
                    const int r = (t[a] + r0) % 4;  // the current turn first: ties keep it
                    int count = 0;
                    for (int i = 0; i < 4; ++i) {
                        const std::int64_t o = across[4 * a + i];
                        if (o < 0) continue;
                        const std::uint32_t b = std::uint32_t(o / 4);
                        const int j = int(o % 4);
                        count += opposite(a, i, b, j) && t[b] == wanted(i, r, j);
                    }
                    if (count > bestCount) {
                        bestCount = count;
                        best = r;
                    }
                }
                changed = changed || best != t[a];
                t[a] = best;
            }
            if (!changed) break;
        }
    };
    // Start 1: a breadth-first walk from each component's first quad.
    std::vector<int> walk(quads.size(), -1);
    std::deque<std::uint32_t> queue;
    for (std::uint32_t q0 = 0; q0 < quads.size(); ++q0) {
        if (walk[q0] >= 0) continue;
        walk[q0] = 0;
        queue.push_back(q0);
        while (!queue.empty()) {
            const std::uint32_t a = queue.front();
            queue.pop_front();
            for (int i = 0; i < 4; ++i) {
                const std::int64_t o = across[4 * a + i];
                if (o < 0) continue;
                const std::uint32_t b = std::uint32_t(o / 4);
                const int j = int(o % 4);
                if (walk[b] >= 0 || !opposite(a, i, b, j)) continue;
                walk[b] = wanted(i, walk[a], j);
                queue.push_back(b);
            }
        }
    }
    descend(walk);
    // Start 2: a cube map. Where the quad faces mostly along axis m, u follows axis m + 1 (so
    // seams gather where the dominant axis changes, like the edges of a cube).
    std::vector<int> cube(quads.size(), 0);
    for (std::size_t q = 0; q < quads.size(); ++q) {
        const Vec3d c0(points[quads[q][0]]), c1(points[quads[q][1]]), c2(points[quads[q][2]]), c3(points[quads[q][3]]);
        const Vec3d n = (c2 - c0).cross(c3 - c1);
        int m = 0;
        for (int k = 1; k < 3; ++k)
            if (std::abs(n[k]) > std::abs(n[m])) m = k;
        const int axis = (m + 1) % 3;
        double best = -1e300;
        for (int r = 0; r < 4; ++r) {
            const double along = Vec3d(points[quads[q][(r + 1) % 4]])[axis] - Vec3d(points[quads[q][r]])[axis];
            if (along > best) {
                best = along;
                cube[q] = r;
            }
        }
    }
    descend(cube);
    const std::size_t seamsWalk = countSeams(walk), seamsCube = countSeams(cube);
    turn = seamsCube < seamsWalk ? cube : walk;
    return std::min(seamsWalk, seamsCube);
}

}  // namespace

std::shared_ptr<const SkinCells> buildSkinCells(const FieldPtr& distance, const Box3& region, const SkinLayout& layout,
                                                SkinCellStats& stats)
{
    const double a = layout.outer, b = layout.inner, h = layout.size;
    const int layers = layout.layers;
    if (!(a >= 0.0)) throw InputError("the outer depth must be zero or more (mm below the part's surface)");
    if (!(b > a))
        throw InputError("the inner depth (" + mm(b) + " mm) must be greater than the outer depth (" + mm(a) +
                         " mm): give depth: [outer, inner]");
    if (!(h > 0.0) || layers < 1) throw InputError("the cell size must be positive and layers at least 1");
    stats = SkinCellStats{};

    // 1. The distance plus the depth on a grid of spacing h (index ijk at world ijk * h), over
    // the region grown by two cells so the surface is closed.
    auto xform = openvdb::math::Transform::createLinearTransform(h);
    openvdb::Coord lo, hi;
    for (int k = 0; k < 3; ++k) {
        lo[k] = int(std::floor(region.min[k] / h)) - 2;
        hi[k] = int(std::ceil(region.max[k] / h)) + 2;
    }
    const openvdb::Coord dims = hi - lo + openvdb::Coord(1);
    const double samples = double(dims[0]) * dims[1] * dims[2];
    if (samples > 2e8)
        throw InputError("the part is " + mm(region.extent()[0]) + " x " + mm(region.extent()[1]) + " x " +
                         mm(region.extent()[2]) + " mm: cells of " + mm(h) +
                         " mm need too many samples; give a larger cell size");
    std::vector<float> values(static_cast<std::size_t>(samples));
    BlockLattice lattice;  // the points (lo + ijk) h
    lattice.step = Vec3d(h);
    lattice.offset = Vec3d(lo[0], lo[1], lo[2]);
    lattice.count = {dims[0], dims[1], dims[2]};
    sampleBlocks(*distance, lattice, [&](std::size_t, const GridBatch& batch, auto first, std::span<const double> v) {
        std::size_t n = 0;
        for (int i = 0; i < batch.nx; ++i)
            for (int j = 0; j < batch.ny; ++j)
                for (int k = 0; k < batch.nz; ++k)
                    values[(std::size_t(first[0] + i) * dims[1] + first[1] + j) * dims[2] + first[2] + k] =
                        float(v[n++] + a);
    });
    float deepest = 0.0f;
    for (float v : values) deepest = std::min(deepest, v);
    stats.deepest = a - double(deepest);
    if (!(deepest < 0.0f))
        throw InputError("the part has no interior " + mm(a) + " mm below its surface (its deepest point on a " +
                         mm(h) + " mm grid is " + mm(stats.deepest) +
                         " mm deep): give a smaller outer depth or a smaller cell size");
    auto grid = openvdb::FloatGrid::create(float(2 * h));
    grid->setTransform(xform);
    {
        auto acc = grid->getAccessor();
        std::size_t n = 0;
        for (int i = 0; i < dims[0]; ++i)
            for (int j = 0; j < dims[1]; ++j)
                for (int k = 0; k < dims[2]; ++k) acc.setValue(lo + openvdb::Coord(i, j, k), values[n++]);
    }

    // 2. Quads of the outer offset surface.
    std::vector<openvdb::Vec3s> points;
    std::vector<openvdb::Vec4I> quads;
    openvdb::tools::volumeToMesh(*grid, points, quads, 0.0);
    if (quads.empty())
        throw InputError("the part has no surface " + mm(a) + " mm below its own at cells of " + mm(h) +
                         " mm (it is at most " + mm(2 * stats.deepest) +
                         " mm thick): give a smaller outer depth or cell size");
    const std::size_t nv = points.size();
    stats.quads = quads.size();
    stats.vertices = nv;

    // Winding: (c1 - c0) x (c3 - c0) along the inward direction (-gradient), by majority.
    {
        long vote = 0;
        for (const auto& q : quads) {
            const Vec3d c0(points[q[0]]), c1(points[q[1]]), c2(points[q[2]]), c3(points[q[3]]);
            const Vec3d n = (c2 - c0).cross(c3 - c1);
            vote += n.dot(-unitGradient(*distance, 0.25 * (c0 + c1 + c2 + c3))) > 0 ? 1 : -1;
        }
        if (vote < 0)
            for (auto& q : quads) std::swap(q[1], q[3]);
    }
    std::vector<int> turn;
    stats.seamEdges = alignQuads(quads, points, turn);

    // 3. Corners: each vertex onto the outer offset surface, then layer by layer inward along
    // the gradient flow, each layer relaxed along its surface (Laplacian steps re-projected onto
    // it) so that vertices crowding behind a convex edge spread out instead of folding cells.
    std::vector<Vec3d> normal(nv, Vec3d(0.0));  // outward, from the quads (fallback directions)
    std::vector<std::vector<int>> neighbours(nv);
    for (const auto& q : quads) {
        const Vec3d c0(points[q[0]]), c1(points[q[1]]), c2(points[q[2]]), c3(points[q[3]]);
        const Vec3d n = -(c2 - c0).cross(c3 - c1);
        for (int i = 0; i < 4; ++i) {
            normal[q[i]] += n;
            neighbours[q[i]].push_back(int(q[(i + 1) % 4]));
            neighbours[q[i]].push_back(int(q[(i + 3) % 4]));
        }
    }
    for (std::size_t v = 0; v < nv; ++v) {
        if (normal[v].length() > 0.0) normal[v].normalize();
        auto& n = neighbours[v];
        std::sort(n.begin(), n.end());
        n.erase(std::unique(n.begin(), n.end()), n.end());
    }
    const double tol = 1e-6 * h;
    std::vector<Vec3d> corners(nv * (layers + 1), Vec3d(0.0));
    std::vector<char> valid(corners.size(), 0);
    auto relax = [&](int k, double depth) {
        for (int round = 0; round < 4; ++round) {
            std::vector<Vec3d> moved(nv);
            tbb::parallel_for(std::size_t(0), nv, [&](std::size_t v) {
                const std::size_t at = k * nv + v;
                moved[v] = corners[at];
                if (!valid[at]) return;
                Vec3d mean(0.0);
                int count = 0;
                for (int u : neighbours[v])
                    if (valid[k * nv + u]) {
                        mean += corners[k * nv + u];
                        ++count;
                    }
                if (count < 3) return;
                Vec3d p = corners[at] + 0.5 * (mean / count - corners[at]);
                if (toDepth(*distance, p, depth, normal[v], 0.25 * h, tol)) moved[v] = p;
            });
            for (std::size_t v = 0; v < nv; ++v) corners[k * nv + v] = moved[v];
        }
    };
    tbb::parallel_for(std::size_t(0), nv, [&](std::size_t v) {
        Vec3d p(points[v]);
        if (toDepth(*distance, p, a, normal[v], 0.25 * h, tol)) {
            corners[v] = p;
            valid[v] = 1;
        }
    });
    relax(0, a);
    for (int k = 1; k <= layers; ++k) {
        const double depth = a + (b - a) * k / layers;
        tbb::parallel_for(std::size_t(0), nv, [&](std::size_t v) {
            if (!valid[(k - 1) * nv + v]) return;
            Vec3d p = corners[(k - 1) * nv + v];
            if (toDepth(*distance, p, depth, normal[v], 0.25 * h, tol)) {
                corners[k * nv + v] = p;
                valid[k * nv + v] = 1;
            }
        });
        relax(k, depth);
    }

    // 4. Cells: quad x layer, (u, v) from the quad's turned corners, w inward.
    std::vector<std::array<int, 8>> hexes;
    std::vector<char> outer;
    const double layerDepth = (b - a) / layers;
    for (int k = 0; k < layers; ++k)
        for (std::size_t q = 0; q < quads.size(); ++q) {
            std::array<int, 4> c;
            for (int i = 0; i < 4; ++i) c[i] = int(quads[q][(i + turn[q]) % 4]);
            // Trilinear order: (0,0), (1,0), (0,1), (1,1) in (u, v) = quad corners 0, 1, 3, 2.
            const int uv[4] = {c[0], c[1], c[3], c[2]};
            std::array<int, 8> hex;
            bool ok = true;
            for (int w = 0; w < 2; ++w)
                for (int i = 0; i < 4; ++i) {
                    hex[4 * w + i] = int((k + w) * nv) + uv[i];
                    ok = ok && valid[hex[4 * w + i]];
                }
            if (!ok) ++stats.unreached;
            if (ok) {
                // Right-handed and not folded: det J > 0 at every corner.
                for (int i = 0; i < 8 && ok; ++i) {
                    const int bu = i & 1, bv = (i >> 1) & 1, bw = (i >> 2) & 1;
                    const Vec3d p = corners[hex[i]];
                    const Vec3d du = bu ? p - corners[hex[i - 1]] : corners[hex[i + 1]] - p;
                    const Vec3d dv = bv ? p - corners[hex[i - 2]] : corners[hex[i + 2]] - p;
                    const Vec3d dw = bw ? p - corners[hex[i - 4]] : corners[hex[i + 4]] - p;
                    ok = du.dot(dv.cross(dw)) > 1e-6 * h * h * layerDepth;
                }
            }
            if (!ok) {
                ++stats.dropped;
                continue;
            }
            hexes.push_back(hex);
            outer.push_back(k == 0);
        }
    stats.hexes = hexes.size();
    if (hexes.empty())
        throw InputError("no cell reaches " + mm(b) + " mm below the part's surface (the part is at most about " +
                         mm(2 * stats.deepest) + " mm thick, " + mm(stats.deepest) +
                         " mm deep in the middle): give a smaller inner depth");
    return std::make_shared<SkinCells>(std::move(corners), std::move(hexes), std::move(outer), layout.extension,
                                       layout.extension > 0.0 ? distance : nullptr, -a);
}

Frame skinFrame(const UnitCell& cell, const SkinCells& cells)
{
    double shortest = 1e300;
    for (std::size_t h = 0; h < cells.size(); ++h) {
        const auto& c = cells.hex(h);
        for (int i = 0; i < 8; ++i)
            for (int bit : {1, 2, 4})
                if (!(i & bit))
                    shortest = std::min(shortest, (cells.corners()[c[i | bit]] - cells.corners()[c[i]]).length());
    }
    FrameBuilder builder(1e-6 * shortest);
    for (std::size_t h = 0; h < cells.size(); ++h)
        for (const auto& s : cell.struts) builder.strut(cells.map(h, cell.nodes[s[0]]), cells.map(h, cell.nodes[s[1]]));
    return builder.take();
}

bool quarterTurnSymmetric(const UnitCell& cell)
{
    constexpr double tol = 1e-7;
    auto onSide = [&](const Vec3d& p) {
        return std::abs(p[0]) < tol || std::abs(p[0] - 1) < tol || std::abs(p[1]) < tol || std::abs(p[1] - 1) < tol;
    };
    for (const Vec3d& p : cell.nodes) {
        if (!onSide(p)) continue;
        const Vec3d turned(1.0 - p[1], p[0], p[2]);
        const bool found = std::any_of(cell.nodes.begin(), cell.nodes.end(),
                                       [&](const Vec3d& q) { return (q - turned).length() < tol; });
        if (!found) return false;
    }
    return true;
}

}  // namespace voxlat
