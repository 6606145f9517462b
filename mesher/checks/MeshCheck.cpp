#include "mesher/checks/MeshCheck.h"

#include "mesher/extract/PhaseProgress.h"

#include "mesher/checks/PairFilter.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/task_arena.h>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <numeric>
#include <utility>
#include <vector>

namespace voxlat {

namespace {

/// Counts gathered per vertex; integers, so the parallel sum does not depend on the split.
struct Tally {
    std::size_t boundary = 0, nonManifoldEdges = 0, nonManifoldVertices = 0, inconsistent = 0;
    std::size_t vertices = 0, edges = 0;

    void add(const Tally& o)
    {
        boundary += o.boundary;
        nonManifoldEdges += o.nonManifoldEdges;
        nonManifoldVertices += o.nonManifoldVertices;
        inconsistent += o.inconsistent;
        vertices += o.vertices;
        edges += o.edges;
    }
};

/// What one triangle incident to a vertex v says about the edge v-w.
struct Spoke {
    uint32_t w;
    bool outgoing;  // the triangle runs v -> w (else w -> v)
    bool operator<(const Spoke& o) const { return w < o.w || (w == o.w && outgoing < o.outgoing); }
};

/// A triangle around a vertex v, as the two corners after v in its order: it runs v -> next -> prev.
struct Corner {
    uint32_t next, prev;
};

/// Fans with more triangles than this take the general path (the cycle test is quadratic).
constexpr std::size_t kMaxFastFan = 16;

/// The topology's rows are sorted by at most this many parts, each with a count per vertex (4
/// bytes a vertex each, beside the rows' 48).
constexpr std::size_t kMaxRowParts = 8;

/// Whether the triangles @a row around a vertex form one closed fan, each edge at the vertex
/// shared by exactly two of them in opposite directions: every @a next distinct, every @a prev
/// some triangle's next, and stepping from a triangle to the one whose next is its prev visits
/// all of them in one cycle. Then the general test (spokes and link components) finds every
/// edge manifold and consistent and the link one cycle, which is what almost every vertex of a
/// closed mesh is. Fixed loops without early exits: the rows are short and the exits would be
/// mispredicted. @a step: for each triangle, the one after it in the cycle (whose next is its
/// prev).
bool closedFan(const Corner* row, std::size_t n, std::array<uint8_t, kMaxFastFan>& step)
{
    if (n > kMaxFastFan) return false;
    unsigned repeated = 0, unmatched = 0;
    for (std::size_t i = 0; i < n; ++i) {
        unsigned matches = 0, to = 0;
        for (std::size_t j = 0; j < n; ++j) {
            const unsigned hit = row[j].next == row[i].prev;
            matches += hit;
            to += hit * unsigned(j);
            repeated += j < i && row[j].next == row[i].next;
        }
        unmatched += matches != 1;
        step[i] = uint8_t(to);
    }
    if (repeated != 0 || unmatched != 0) return false;
    // Back at the first triangle after n steps and not before: one cycle through all n.
    std::size_t current = 0, early = 0;
    for (std::size_t k = 1; k < n; ++k) {
        current = step[current];
        early += current == 0;
    }
    return early == 0 && step[current] == 0;
}

/// Whether the closed fan of triangles around vertex @a v (@a row: each triangle with corner v
/// as the corners after v in its order, all of them, chained in one cycle by @a step as
/// closedFan() found) lies apart but for v: no two of them that share only v meet anywhere else,
/// so none need the pair test. Shown by a projection: along n, the sum of the fan's normals,
/// every triangle projects with a positive area (beyond a margin far above the roundings), and
/// the chain of triangles around v winds around it once. Then the projected triangles are
/// sectors of angles below pi that tile the plane around v's image once: two that do not share
/// an edge meet only in v's image, which each triangle covers only at v. A fan wound twice (a
/// fold) is not shown apart, and its pairs are tested.
bool fanApart(const std::vector<openvdb::Vec3f>& points, uint32_t v, const Corner* row, std::size_t k,
              const std::array<uint8_t, kMaxFastFan>& step)
{
    if (k < 3) return false;
    const openvdb::Vec3d centre(points[v]);
    // The rays in chain order: each triangle starts (its next) where the one before ends (its prev).
    // Each sector's cross product is kept for its turn below (the same bits as computed again).
    std::array<openvdb::Vec3d, kMaxFastFan + 1> ray;
    std::array<openvdb::Vec3d, kMaxFastFan> sector;
    openvdb::Vec3d n(0.0);
    std::size_t current = 0;
    ray[0] = openvdb::Vec3d(points[row[0].next]) - centre;
    for (std::size_t i = 0; i < k; ++i) {
        ray[i + 1] = openvdb::Vec3d(points[row[current].prev]) - centre;
        sector[i] = ray[i].cross(ray[i + 1]);
        n += sector[i];
        current = step[current];
    }
    // Turns as seen along n: the sectors, then whether any but the last reaches the first ray
    // again. Margins compared squared: |turn| > 1e-9 |n| |u| |w|.
    const double n2 = 1e-18 * n.lengthSqr();
    std::array<double, kMaxFastFan + 1> length2;
    for (std::size_t i = 0; i <= k; ++i) length2[i] = ray[i].lengthSqr();
    auto clear = [&](double t, std::size_t i, std::size_t j) { return t * t > n2 * length2[i] * length2[j]; };
    for (std::size_t i = 0; i < k; ++i)
        if (const double t = n.dot(sector[i]); !(t > 0.0 && clear(t, i, i + 1))) return false;
    // Turns to and from the first ray: n . (u x r0) = u . (r0 x n) and n . (r0 x u) = -u . (r0 x n),
    // one cross product for all.
    const openvdb::Vec3d aside = ray[0].cross(n);
    for (std::size_t i = 1; i + 1 < k; ++i) {
        const double in = ray[i].dot(aside), out = -ray[i + 1].dot(aside);
        if (!(clear(in, i, 0) && clear(out, 0, i + 1))) return false;
        if (in > 0.0 && out > 0.0) return false;  // the first ray again: wound more than once
    }
    return true;
}

/// Union-find over vertices shared by threads: a root is linked (by compare-and-swap) only
/// under a lower root, so each set's root is its lowest vertex whatever order the unions come
/// in; path halving only shortens paths to an ancestor.
uint32_t findRoot(std::vector<std::atomic<uint32_t>>& parent, uint32_t i)
{
    for (;;) {
        uint32_t p = parent[i].load(std::memory_order_relaxed);
        if (p == i) return i;
        const uint32_t g = parent[p].load(std::memory_order_relaxed);
        if (g != p) parent[i].compare_exchange_weak(p, g, std::memory_order_relaxed);
        i = g;
    }
}

void unite(std::vector<std::atomic<uint32_t>>& parent, uint32_t a, uint32_t b)
{
    for (;;) {
        a = findRoot(parent, a);
        b = findRoot(parent, b);
        if (a == b) return;
        if (a < b) std::swap(a, b);
        uint32_t expected = a;
        if (parent[a].compare_exchange_strong(expected, b, std::memory_order_relaxed)) return;
    }
}

uint32_t findRoot(std::vector<uint32_t>& parent, uint32_t i)
{
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
}

}  // namespace

MeshTopology checkTopology(const TriangleMesh& mesh, std::vector<uint8_t>* fansApart, const ProgressFn& progress)
{
    MeshTopology result;
    // Each pass reports where it starts, and its loops report it again (so they can cancel).
    PhaseProgress phases(progress);
    const std::size_t numPoints = mesh.points.size(), numTriangles = mesh.triangles.size();

    // Triangles with repeated or invalid indices have no meaningful edges; leave them out of the
    // topology and only count them. Zero-area triangles are topologically fine and stay in.
    auto valid = [numPoints](const openvdb::Vec3I& tri) {
        return tri[0] < numPoints && tri[1] < numPoints && tri[2] < numPoints && tri[0] != tri[1] && tri[1] != tri[2] &&
               tri[0] != tri[2];
    };
    // Vertex -> the incident valid triangles (as the corners after it), compressed rows in
    // triangle order: a counting sort over fixed ranges of triangles, one per part. Each part
    // counts its corners per vertex (and its valid and degenerate triangles), the counts become
    // each part's cursors within each row, and each part fills its corners in order: every
    // triangle is read twice in all, and the rows are the same for any split.
    const std::size_t parts =
        std::clamp<std::size_t>(std::size_t(tbb::this_task_arena::max_concurrency()), 1, kMaxRowParts);
    auto partBegin = [&](std::size_t part) { return numTriangles * part / parts; };
    std::vector<uint32_t> cursor(parts * numPoints, 0);  // part-major
    std::vector<std::size_t> partValid(parts, 0), partDegenerate(parts, 0);
    tbb::parallel_for(std::size_t(0), parts, [&](std::size_t part) {
        uint32_t* count = cursor.data() + part * numPoints;
        std::size_t numValid = 0, numDegenerate = 0;
        for (std::size_t t = partBegin(part); t < partBegin(part + 1); ++t) {
            phases.checkEvery(t);
            const openvdb::Vec3I& tri = mesh.triangles[t];
            if (!valid(tri)) {
                ++numDegenerate;
                continue;
            }
            ++numValid;
            const openvdb::Vec3d a(mesh.points[tri[0]]), b(mesh.points[tri[1]]), c(mesh.points[tri[2]]);
            if ((b - a).cross(c - a) == openvdb::Vec3d(0.0)) ++numDegenerate;
            for (int k = 0; k < 3; ++k) ++count[tri[k]];
        }
        partValid[part] = numValid;
        partDegenerate[part] = numDegenerate;
    });
    const std::size_t numValid = std::accumulate(partValid.begin(), partValid.end(), std::size_t(0));
    result.degenerateTriangles = std::accumulate(partDegenerate.begin(), partDegenerate.end(), std::size_t(0));
    // Per vertex its row's length, and each part's counts turned into its start within the row.
    std::vector<std::size_t> first(numPoints + 1, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numPoints, 1 << 14), [&](const auto& range) {
        phases.check();
        for (std::size_t v = range.begin(); v != range.end(); ++v) {
            uint32_t running = 0;
            for (std::size_t part = 0; part < parts; ++part) {
                const uint32_t c = cursor[part * numPoints + v];
                cursor[part * numPoints + v] = running;
                running += c;
            }
            first[v + 1] = running;
        }
    });
    phases.check();
    std::partial_sum(first.begin(), first.end(), first.begin());
    phases.check();
    // Left uninitialised (every entry is filled below): the rows are the largest array here, and
    // a fresh one is paged in as it is written.
    const std::unique_ptr<Corner[]> corners(new Corner[first.back()]);
    phases.begin(0.3);
    tbb::parallel_for(std::size_t(0), parts, [&](std::size_t part) {
        uint32_t* at = cursor.data() + part * numPoints;
        for (std::size_t t = partBegin(part); t < partBegin(part + 1); ++t) {
            phases.checkEvery(t);
            const openvdb::Vec3I& tri = mesh.triangles[t];
            if (!valid(tri)) continue;
            for (int k = 0; k < 3; ++k)
                corners[first[tri[k]] + at[tri[k]]++] = Corner{tri[(k + 1) % 3], tri[(k + 2) % 3]};
        }
    });
    std::vector<uint32_t>().swap(cursor);

    // Pieces: vertices joined by the edges, united at each edge's lower end in the pass below.
    std::vector<std::atomic<uint32_t>> piece(numPoints);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numPoints, 1 << 16), [&](const auto& range) {
        phases.check();
        for (std::size_t v = range.begin(); v != range.end(); ++v)
            piece[v].store(uint32_t(v), std::memory_order_relaxed);
    });
    // Per vertex, for the per-piece Euler characteristic and open edges: 1 - (edges it owns, those
    // to higher neighbours) + (triangles it owns, those whose lowest corner it is), and whether
    // any of its edges is open or non-manifold.
    std::vector<int64_t> ownedChi(numPoints, 0);
    std::vector<uint8_t> ownedBad(numPoints, 0);
    // Whether each closed fan lies apart (fanApart()), when every triangle is in the rows.
    if (fansApart) fansApart->assign(numPoints, 0);
    const bool everyFanWhole = fansApart && numValid == numTriangles;

    phases.begin(0.6);
    const Tally tally = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, numPoints, 1024), Tally{},
        [&](const tbb::blocked_range<std::size_t>& range, Tally acc) {
            phases.check();
            std::vector<Spoke> spokes;
            std::vector<uint32_t> nodes, parent;
            std::array<uint8_t, kMaxFastFan> step;
            for (std::size_t v = range.begin(); v != range.end(); ++v) {
                const std::size_t n = first[v + 1] - first[v];
                if (n == 0) continue;
                const Corner* row = corners.get() + first[v];
                ++acc.vertices;
                int64_t owned = 1;
                for (std::size_t i = 0; i < n; ++i) owned += row[i].next > v && row[i].prev > v;
                if (closedFan(row, n, step)) {
                    if (everyFanWhole) (*fansApart)[v] = fanApart(mesh.points, uint32_t(v), row, n, step);
                    // Each neighbour is one triangle's next and another's prev: two triangles per
                    // edge, opposite directions, the link one cycle.
                    for (std::size_t i = 0; i < n; ++i)
                        if (row[i].next > v) {
                            ++acc.edges;
                            --owned;
                            unite(piece, uint32_t(v), row[i].next);
                        }
                    ownedChi[v] = owned;
                    continue;
                }
                spokes.clear();
                for (std::size_t i = 0; i < n; ++i) {
                    spokes.push_back({row[i].next, true});
                    spokes.push_back({row[i].prev, false});
                }
                std::sort(spokes.begin(), spokes.end());

                // Edges v-w, each counted once, at its lower vertex. A vertex is a fan only if every
                // edge at it has at most two triangles...
                bool fan = true;
                nodes.clear();
                for (std::size_t i = 0; i < spokes.size();) {
                    std::size_t j = i;
                    while (j < spokes.size() && spokes[j].w == spokes[i].w) ++j;
                    const std::size_t faces = j - i;
                    nodes.push_back(spokes[i].w);
                    if (faces > 2) fan = false;
                    if (spokes[i].w > v) {
                        ++acc.edges;
                        --owned;
                        unite(piece, uint32_t(v), spokes[i].w);
                        if (faces == 1) ++acc.boundary;
                        if (faces > 2) ++acc.nonManifoldEdges;
                        if (faces != 2) ownedBad[v] = 1;
                        // Sorted with outgoing last: two equal flags mean the same direction twice.
                        if (faces == 2 && spokes[i].outgoing == spokes[i + 1].outgoing) ++acc.inconsistent;
                    }
                    i = j;
                }
                ownedChi[v] = owned;
                // ...and its link (the opposite edges, over the neighbours) is connected.
                parent.resize(nodes.size());
                std::iota(parent.begin(), parent.end(), 0u);
                std::size_t components = nodes.size();
                auto node = [&](uint32_t w) {
                    return uint32_t(std::lower_bound(nodes.begin(), nodes.end(), w) - nodes.begin());
                };
                for (std::size_t i = 0; i < n; ++i) {
                    const uint32_t a = findRoot(parent, node(row[i].next));
                    const uint32_t b = findRoot(parent, node(row[i].prev));
                    if (a != b) {
                        parent[a] = b;
                        --components;
                    }
                }
                if (!fan || components != 1) ++acc.nonManifoldVertices;
            }
            return acc;
        },
        [](Tally a, const Tally& b) {
            a.add(b);
            return a;
        });

    result.boundaryEdges = tally.boundary;
    result.nonManifoldEdges = tally.nonManifoldEdges;
    result.nonManifoldVertices = tally.nonManifoldVertices;
    result.inconsistentlyOrientedEdges = tally.inconsistent;
    result.eulerCharacteristic = int(int64_t(tally.vertices) - int64_t(tally.edges) + int64_t(numValid));

    // Per piece (indexed by its root, the piece's lowest vertex): V - E + F and open edges,
    // gathered at the root. A root is below its other vertices, so in ascending order each
    // vertex is added to its root after its own sum is complete (and roots are not added on).
    phases.begin(0.9);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numPoints, 1 << 14), [&](const auto& range) {
        phases.check();
        for (std::size_t v = range.begin(); v != range.end(); ++v)
            piece[v].store(findRoot(piece, uint32_t(v)), std::memory_order_relaxed);
    });
    for (std::size_t v = 0; v < numPoints; ++v) {
        phases.checkEvery(v);
        if (first[v] == first[v + 1]) continue;
        const uint32_t root = piece[v].load(std::memory_order_relaxed);
        if (root == v) {
            ++result.pieces;
            continue;
        }
        ownedChi[root] += ownedChi[v];
        ownedBad[root] |= ownedBad[v];
    }
    for (std::size_t v = 0; v < numPoints; ++v) {
        phases.checkEvery(v);
        if (first[v] == first[v + 1] || piece[v].load(std::memory_order_relaxed) != v || ownedBad[v]) continue;
        ++result.closedPieces;
        result.genus += int(1 - ownedChi[v] / 2);
    }
    return result;
}

namespace {

/// Whether the segment p-q passes through the interior of triangle abc (not merely touching
/// its edges or ends, with a relative margin), in double precision. Coplanar: no.
bool segmentCrossesTriangle(const openvdb::Vec3d& p, const openvdb::Vec3d& q, const openvdb::Vec3d& a,
                            const openvdb::Vec3d& b, const openvdb::Vec3d& c)
{
    constexpr double eps = 1e-9;
    const openvdb::Vec3d e1 = b - a, e2 = c - a, d = q - p;
    const openvdb::Vec3d h = d.cross(e2);
    const double det = e1.dot(h);
    const double scale = e1.length() * e2.length() * d.length();
    if (!(std::abs(det) > 1e-12 * scale)) return false;
    const double inv = 1.0 / det;
    const openvdb::Vec3d s = p - a;
    const double u = s.dot(h) * inv;
    if (u <= eps || u >= 1.0 - eps) return false;
    const openvdb::Vec3d r = s.cross(e1);
    const double w = d.dot(r) * inv;
    if (w <= eps || u + w >= 1.0 - eps) return false;
    const double t = e2.dot(r) * inv;
    return t > eps && t < 1.0 - eps;
}

/// An upper bound of @a v.length() as computed in double, without a square root: the sum of the
/// magnitudes (at least the length) raised by far more than the roundings of either. For vectors
/// between points in single precision, neither underflows nor overflows in double.
inline double lengthBound(const openvdb::Vec3d& v)
{
    return (std::abs(v.x()) + std::abs(v.y()) + std::abs(v.z())) * (1.0 + 1e-6);
}

/// A triangle as the crossing test reads it: its corners (indices and positions in double), its
/// normal, and upper bounds of the terms of its side-test margin, gathered once per cell it is
/// tested in rather than once per pair.
struct CrossingTriangle {
    openvdb::Vec3I tri;
    openvdb::Vec3d corner[3];
    openvdb::Vec3d normal;  // (b - a) x (c - a)
    double scaleBound;      // >= scale()
    double spanBound;       // >= span()

    void gather(const TriangleMesh& mesh, uint32_t t)
    {
        tri = mesh.triangles[t];
        for (int k = 0; k < 3; ++k) corner[k] = openvdb::Vec3d(mesh.points[tri[k]]);
        const openvdb::Vec3d &a = corner[0], &b = corner[1], &c = corner[2];
        normal = (b - a).cross(c - a);
        scaleBound = 1e-12 * lengthBound(normal);
        spanBound =
            std::max({std::abs(a.x()), std::abs(a.y()), std::abs(a.z()), lengthBound(b - a), lengthBound(c - a)});
    }
    /// The side test's margin per length (rounding is monotonic: the bounds above, computed
    /// from larger terms by the same operations, are no smaller).
    double scale() const { return 1e-12 * normal.length(); }
    /// The side test's length scale: the largest of |a| per axis, |b - a| and |c - a|.
    double span() const
    {
        const openvdb::Vec3d &a = corner[0], &b = corner[1], &c = corner[2];
        return std::max({std::abs(a.x()), std::abs(a.y()), std::abs(a.z()), (b - a).length(), (c - a).length()});
    }
    bool has(uint32_t v) const { return tri[0] == v || tri[1] == v || tri[2] == v; }
};

/// Whether the corners of @a other that @a plane does not share all lie strictly on one side of
/// @a plane's plane, beyond a margin far below what segmentCrossesTriangle resolves (its ends and
/// parameters within 1e-9 of an edge do not count): then no edge of either passes through the
/// other. Decided against an upper bound of the margin first (no square roots): corners beyond
/// it on one side are beyond the margin, corners beyond it on both sides straddle the plane
/// whatever the margin; only corners within it (rare: the margin is 1e-12 of the sizes) take
/// the margin itself. A NaN or infinite bound fails both shortcuts, and a NaN distance fails
/// the sides against the bound as against the margin.
bool oneSide(const CrossingTriangle& plane, const CrossingTriangle& other)
{
    const openvdb::Vec3d& a = plane.corner[0];
    bool shared[3];
    double d[3];
    for (int k = 0; k < 3; ++k) {
        shared[k] = plane.has(other.tri[k]);
        d[k] = plane.normal.dot(other.corner[k] - a);
    }
    // Fixed loops without early exits (which corner is shared varies; exits would be mispredicted).
    auto sides = [&](double margin, bool& above, bool& below) {
        above = below = true;
        for (int k = 0; k < 3; ++k) {
            above &= shared[k] | (d[k] > margin);
            below &= shared[k] | (d[k] < -margin);
        }
    };
    bool above, below;
    const double bound = plane.scaleBound * (plane.spanBound + lengthBound(other.corner[0] - a));
    sides(bound, above, below);
    if (above | below) return true;
    bool up = false, down = false;
    for (int k = 0; k < 3; ++k) {
        up |= !shared[k] & (d[k] > bound);
        down |= !shared[k] & (d[k] < -bound);
    }
    if (up & down) return false;
    sides(plane.scale() * (plane.span() + (other.corner[0] - a).length()), above, below);
    return above | below;
}

/// A triangle's cells (lowest and highest per axis; none when lo > hi) and its bounds in single
/// precision, widened by a rounding.
struct TriangleCells {
    float min[3], max[3];
    uint16_t lo[3], hi[3];
};

/// std::nextafter(x, -infinity) for a float, by its bits (inline: six per triangle).
inline float floatBelow(float x)
{
    if (x != x || x == -std::numeric_limits<float>::infinity()) return x;
    if (x == 0.0f) return -std::numeric_limits<float>::denorm_min();
    const uint32_t bits = std::bit_cast<uint32_t>(x);
    return std::bit_cast<float>(x > 0.0f ? bits - 1 : bits + 1);
}

/// std::nextafter(x, +infinity) for a float, by its bits.
inline float floatAbove(float x)
{
    if (x != x || x == std::numeric_limits<float>::infinity()) return x;
    if (x == 0.0f) return std::numeric_limits<float>::denorm_min();
    const uint32_t bits = std::bit_cast<uint32_t>(x);
    return std::bit_cast<float>(x > 0.0f ? bits + 1 : bits - 1);
}

/// A corner index no mesh uses (its triangles index fewer points), marking a CrossingTriangle
/// not gathered yet.
constexpr uint32_t kNotGathered = std::numeric_limits<uint32_t>::max();

/// Whether triangles @a s and @a t, sharing at most one corner, cross (see
/// countSelfIntersections()).
bool trianglesCross(const CrossingTriangle& s, const CrossingTriangle& t)
{
    // Most pairs that share a cell lie apart: the corners of one (those it does not share) all
    // strictly on one side of the other's plane leave no edge of either through the other.
    if (oneSide(s, t) || oneSide(t, s)) return false;
    // Edges of one through the other; an edge ending at a shared vertex cannot cross the interior
    // without the other edges doing so too, except in the coplanar case, which is not counted.
    auto edgesThrough = [](const CrossingTriangle& edges, const CrossingTriangle& other) {
        for (int i = 0; i < 3; ++i) {
            if (other.has(edges.tri[i]) || other.has(edges.tri[(i + 1) % 3])) continue;
            if (segmentCrossesTriangle(edges.corner[i], edges.corner[(i + 1) % 3], other.corner[0], other.corner[1],
                                       other.corner[2]))
                return true;
        }
        return false;
    };
    return edgesThrough(s, t) || edgesThrough(t, s);
}

}  // namespace

std::size_t filterPairs(const PairRows& rows, std::size_t x, std::size_t count, const bool apartX[3],
                        std::uint32_t* candidates)
{
    std::size_t numCandidates = 0;
    // Tested only in the lowest cell both cover (both cover this one: their cell ranges overlap),
    // one of them flagged, their bounds overlapping (written so that a NaN bound rejects nothing).
#if defined(__SSE2__)
    // Four at a time.
    const __m128i cornerX = _mm_set1_epi32(rows.corner[x]), full = _mm_set1_epi32(15);
    __m128 lowX[3], highX[3];
    __m128i cornerOfX[3];
    for (int a = 0; a < 3; ++a) {
        lowX[a] = _mm_set1_ps(rows.lo[a][x]);
        highX[a] = _mm_set1_ps(rows.hi[a][x]);
        cornerOfX[a] = _mm_set1_epi32(rows.vertex[a][x]);
    }
    for (std::size_t y = x + 1; y < count; y += 4) {
        const __m128i both = _mm_or_si128(cornerX, _mm_loadu_si128(reinterpret_cast<const __m128i*>(rows.corner + y)));
        __m128 keep = _mm_castsi128_ps(_mm_cmpeq_epi32(both, full));
        for (int a = 0; a < 3; ++a) {
            keep = _mm_and_ps(keep, _mm_cmpnlt_ps(highX[a], _mm_loadu_ps(rows.lo[a] + y)));
            keep = _mm_and_ps(keep, _mm_cmpnlt_ps(_mm_loadu_ps(rows.hi[a] + y), lowX[a]));
        }
        // Corners shared (each match -1), and whether a shared corner's fan is apart.
        __m128i matches = _mm_setzero_si128(), sharedApart = _mm_setzero_si128();
        for (int k = 0; k < 3; ++k) {
            __m128i matchesK = _mm_setzero_si128();
            for (int j = 0; j < 3; ++j)
                matchesK = _mm_add_epi32(
                    matchesK, _mm_cmpeq_epi32(cornerOfX[k],
                                              _mm_loadu_si128(reinterpret_cast<const __m128i*>(rows.vertex[j] + y))));
            matches = _mm_add_epi32(matches, matchesK);
            if (apartX[k]) sharedApart = _mm_or_si128(sharedApart, matchesK);
        }
        const __m128i none = _mm_cmpeq_epi32(matches, _mm_setzero_si128());
        const __m128i oneNotApart = _mm_and_si128(_mm_cmpeq_epi32(matches, _mm_set1_epi32(-1)),
                                                  _mm_cmpeq_epi32(sharedApart, _mm_setzero_si128()));
        keep = _mm_and_ps(keep, _mm_castsi128_ps(_mm_or_si128(none, oneNotApart)));
        for (unsigned bits = unsigned(_mm_movemask_ps(keep)); bits != 0; bits &= bits - 1)
            candidates[numCandidates++] = uint32_t(y + unsigned(__builtin_ctz(bits)));
    }
#else
    const unsigned cx = unsigned(rows.corner[x]);
    for (std::size_t y = x + 1; y < count; ++y) {
        int matches = 0;
        bool sharedApart = false;
        for (int k = 0; k < 3; ++k) {
            const int matchesK = int(rows.vertex[k][x] == rows.vertex[0][y]) +
                                 int(rows.vertex[k][x] == rows.vertex[1][y]) +
                                 int(rows.vertex[k][x] == rows.vertex[2][y]);
            matches += matchesK;
            sharedApart = sharedApart || (matchesK > 0 && apartX[k]);
        }
        unsigned keep = unsigned((cx | unsigned(rows.corner[y])) == 15u);
        for (int a = 0; a < 3; ++a)
            keep &= unsigned(!(rows.hi[a][x] < rows.lo[a][y])) & unsigned(!(rows.hi[a][y] < rows.lo[a][x]));
        keep &= unsigned(matches == 0 || (matches == 1 && !sharedApart));
        candidates[numCandidates] = uint32_t(y);
        numCandidates += keep;
    }
#endif
    return numCandidates;
}

bool pairFilterAvx2Available()
{
#if defined(VOXLAT_AVX2_PAIRS)
    return __builtin_cpu_supports("avx2");
#else
    return false;
#endif
}

std::vector<std::pair<uint32_t, uint32_t>> selfIntersections(const TriangleMesh& mesh)
{
    return selfIntersections(mesh, {});
}

std::vector<std::pair<uint32_t, uint32_t>> selfIntersections(const TriangleMesh& mesh,
                                                             const std::vector<std::uint8_t>& tested)
{
    return selfIntersections(mesh, tested, nullptr);
}

std::vector<std::pair<uint32_t, uint32_t>> selfIntersections(const TriangleMesh& mesh,
                                                             const std::vector<std::uint8_t>& tested,
                                                             const std::vector<std::uint8_t>* fansApart,
                                                             const ProgressFn& progress)
{
    const std::size_t n = mesh.triangles.size();
    if (n < 2) return {};
    // The binning below reports 0 from every grain and serial loop, so a cancel stops it too.
    PhaseProgress phases(progress);
    phases.begin(0.0);
    // Bounds of the triangles' corners only: callers pass a few triangles of a large mesh's points.
    // Each triangle's bounds are kept (as the points' floats, exactly) for its cells below: its
    // corners are read once. The edge lengths are summed per fixed block, the blocks' sums in
    // order (the cell size, and so the pairs' order, depend on its bits).
    constexpr std::size_t kGrain = 1 << 14;
    // Left uninitialised, every field written by the two passes below before it is read: zeroing
    // 36 bytes a triangle in one thread took about half a second on a 20 M-triangle mesh, a
    // stretch no cancel could stop.
    const std::unique_ptr<TriangleCells[]> cells(new TriangleCells[n]);
    const std::size_t numGrains = (n + kGrain - 1) / kGrain;
    std::vector<double> edgeSums(numGrains, 0.0);
    std::vector<openvdb::BBoxd> grainBoxes(numGrains);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numGrains, 1), [&](const auto& r) {
        for (std::size_t g = r.begin(); g != r.end(); ++g) {
            phases.check();
            openvdb::BBoxd b;
            double sum = 0.0;
            for (std::size_t t = g * kGrain; t < std::min(n, (g + 1) * kGrain); ++t) {
                const openvdb::Vec3I& tri = mesh.triangles[t];
                const openvdb::Vec3f &p0 = mesh.points[tri[0]], &p1 = mesh.points[tri[1]], &p2 = mesh.points[tri[2]];
                TriangleCells& tc = cells[t];
                for (int a = 0; a < 3; ++a) {
                    tc.min[a] = std::min({p0[a], p1[a], p2[a]});
                    tc.max[a] = std::max({p0[a], p1[a], p2[a]});
                }
                b.expand(openvdb::Vec3d(tc.min[0], tc.min[1], tc.min[2]));
                b.expand(openvdb::Vec3d(tc.max[0], tc.max[1], tc.max[2]));
                sum += (openvdb::Vec3d(p0) - openvdb::Vec3d(p1)).length();
            }
            grainBoxes[g] = b;
            edgeSums[g] = sum;
        }
    });
    openvdb::BBoxd box;
    double edgeSum = 0.0;
    for (std::size_t g = 0; g < numGrains; ++g) {
        box.expand(grainBoxes[g]);
        edgeSum += edgeSums[g];
    }
    const openvdb::Vec3d extent = box.extents();
    // Cells about three times the mean edge, at most 256 per axis (so the cell count stays
    // bounded). W9's refined mesh: 1.5, 2, 2.5, 3, 4, 5 times took 0.101, 0.085, 0.083, 0.081,
    // 0.086, 0.098 s (fewer cells per triangle against more pairs per cell).
    double cell = std::max(3.0 * edgeSum / double(n), 1e-9);
    for (int a = 0; a < 3; ++a) cell = std::max(cell, extent[a] / 256.0);
    int dims[3];
    for (int a = 0; a < 3; ++a) dims[a] = std::max(1, int(std::ceil(extent[a] / cell)) + 1);
    // Times the inverse instead of six divisions a triangle (W9: 1.7 ms of 0.075 s). Monotonic in
    // p, so overlapping bounds still share a cell; the same cells for any thread count.
    const double perCell = 1.0 / cell;
    auto cellOf = [&](double p, int a) {
        return uint16_t(std::clamp(int(std::floor((p - box.min()[a]) * perCell)), 0, dims[a] - 1));
    };
    // Each triangle's cells and its bounds in single precision, widened by a rounding: pairs
    // whose bounds are apart cannot cross, and most pairs sharing a cell are (a test far cheaper
    // than the crossing's). Side by side, as the pair loop reads them together.
    const std::size_t entries = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, n, kGrain), std::size_t(0),
        [&](const tbb::blocked_range<std::size_t>& r, std::size_t sum) {
            phases.check();
            for (std::size_t t = r.begin(); t != r.end(); ++t) {
                TriangleCells& tc = cells[t];
                const openvdb::Vec3d lo(tc.min[0], tc.min[1], tc.min[2]), hi(tc.max[0], tc.max[1], tc.max[2]);
                // A triangle in a face plane of the bounds (a cap where a mesh was cut by a box) has
                // every other triangle on one side: none can pass an edge through its interior, and
                // its edges, in that plane, meet another triangle only on that one's boundary
                // (coplanar overlaps are not counted). Left out, as its cells are often many.
                bool onBounds = false;
                for (int a = 0; a < 3; ++a)
                    onBounds = onBounds || (lo[a] == hi[a] && (lo[a] == box.min()[a] || hi[a] == box.max()[a]));
                for (int a = 0; a < 3; ++a) {
                    tc.lo[a] = onBounds ? 1 : cellOf(lo[a], a);
                    tc.hi[a] = onBounds ? 0 : cellOf(hi[a], a);
                    tc.min[a] = floatBelow(float(lo[a]));
                    tc.max[a] = floatAbove(float(hi[a]));
                }
                sum += std::size_t(tc.hi[0] + 1 - tc.lo[0]) * (tc.hi[1] + 1 - tc.lo[1]) * (tc.hi[2] + 1 - tc.lo[2]);
            }
            return sum;
        },
        std::plus<std::size_t>());
    const std::size_t numCells = std::size_t(dims[0]) * dims[1] * dims[2];
    auto cellIndex = [&](int i, int j, int k) { return (std::size_t(i) * dims[1] + j) * dims[2] + k; };
    auto forCells = [&](const TriangleCells& tc, auto&& visit) {
        for (int i = tc.lo[0]; i <= tc.hi[0]; ++i)
            for (int j = tc.lo[1]; j <= tc.hi[1]; ++j)
                for (int k = tc.lo[2]; k <= tc.hi[2]; ++k) visit(cellIndex(i, j, k));
    };
    // Occupied cells in ascending order, each with its triangles (compressed rows; each row is
    // sorted by triangle index in the pair loop). A few triangles spread over a large box (the
    // refinement's local checks) would make a dense table of mostly empty cells: then
    // (cell, triangle) entries are sorted instead.
    std::vector<std::size_t> occupied;  // occupied cell indices, ascending
    std::vector<std::size_t> first;     // rows into members, one more than cells
    std::vector<uint32_t> members;
    if (numCells <= 4 * entries) {
        // Counted and filled in parallel: the counts are order-independent; each row is filled
        // from its start, so it comes out as the threads' ascending runs interleaved, sorted
        // where it is used.
        std::vector<std::atomic<uint32_t>> count(numCells);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, kGrain), [&](const auto& r) {
            phases.check();
            for (std::size_t t = r.begin(); t != r.end(); ++t)
                forCells(cells[t], [&](std::size_t c) { count[c].fetch_add(1, std::memory_order_relaxed); });
        });
        std::vector<std::size_t> start(numCells + 1);
        start[0] = 0;
        for (std::size_t c = 0; c < numCells; ++c) {
            phases.checkEvery(c);
            const uint32_t k = count[c].load(std::memory_order_relaxed);
            start[c + 1] = start[c] + k;
            if (k >= 2) occupied.push_back(c);
        }
        members.resize(start.back());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, kGrain), [&](const auto& r) {
            phases.check();
            for (std::size_t t = r.begin(); t != r.end(); ++t)
                forCells(cells[t], [&](std::size_t c) {
                    members[start[c + 1] - count[c].fetch_sub(1, std::memory_order_relaxed)] = uint32_t(t);
                });
        });
        first.reserve(2 * occupied.size());
        for (std::size_t c : occupied) {
            first.push_back(start[c]);
            first.push_back(start[c + 1]);
        }
    } else {
        std::vector<std::pair<std::size_t, uint32_t>> list;
        list.reserve(entries);
        for (std::size_t t = 0; t < n; ++t) {
            phases.checkEvery(t);
            forCells(cells[t], [&](std::size_t c) { list.emplace_back(c, uint32_t(t)); });
        }
        phases.check();
        std::sort(list.begin(), list.end());
        phases.check();
        members.resize(list.size());
        for (std::size_t e = 0; e < list.size(); ++e) members[e] = list[e].second;
        for (std::size_t e = 0; e < list.size();) {
            std::size_t end = e + 1;
            while (end < list.size() && list[end].first == list[e].first) ++end;
            if (end - e >= 2) {
                occupied.push_back(list[e].first);
                first.push_back(e);
                first.push_back(end);
            }
            e = end;
        }
    }
    // Per block of occupied cells its own list; blocks joined in order, so the list is the same
    // for any thread count (and pairs come in ascending lowest shared cell, then index order).
    constexpr std::size_t kCellsPerBlock = 256;
    const std::size_t numBlocks = (occupied.size() + kCellsPerBlock - 1) / kCellsPerBlock;
    std::vector<std::vector<std::pair<uint32_t, uint32_t>>> found(numBlocks);
    // Most pairs tested share a corner (W9: 7.0 M of 9.3 M); where that corner's fan lies apart,
    // they need no test. Left out of the local checks of a few flagged triangles, whose fans are
    // open (and whose vertices are a large mesh's).
    if (progress) progress(0.2);
    std::vector<uint8_t> computed;
    if (!fansApart && tested.empty())
        checkTopology(mesh, &computed, progressPart(progress, 0.2, 0.3));  // its rows give the fans
    const std::vector<uint8_t>& apart = fansApart ? *fansApart : computed;
    const bool wide = pairFilterAvx2Available();
    ExtractProgress blocksDone(progressPart(progress, 0.3, 1.0), numBlocks);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numBlocks, 1), [&](const auto& r) {
        // A cell's triangles gathered side by side (structure of arrays): the pairs of a cell
        // are its rows squared, each mostly a few comparisons.
        std::vector<uint32_t> index, candidates;
        std::vector<CrossingTriangle> gathered;
        std::vector<int32_t> corner;  // bits 0-2: this is the lowest cell per axis; 3: flagged
        std::vector<float> lo[3], hi[3];
        std::vector<int32_t> vertex[3];  // the triangles' corners, side by side
        for (std::size_t block = r.begin(); block != r.end(); ++block, blocksDone.advance())
            for (std::size_t o = block * kCellsPerBlock; o < std::min(occupied.size(), (block + 1) * kCellsPerBlock);
                 ++o) {
                const std::size_t c = occupied[o];
                const int ci = int(c / (std::size_t(dims[1]) * dims[2])), cj = int((c / dims[2]) % dims[1]),
                          ck = int(c % dims[2]);
                const std::size_t rowBegin = first[2 * o], count = first[2 * o + 1] - rowBegin;
                // A cell's triangles are scattered over the arrays (and the mesh): their reads
                // are started a cell or two ahead, the corners' once their triangles are in.
                if (o + 2 < occupied.size())
                    for (std::size_t e = first[2 * (o + 2)]; e < first[2 * (o + 2) + 1]; ++e) {
                        __builtin_prefetch(&cells[members[e]]);
                        __builtin_prefetch(&mesh.triangles[members[e]]);
                    }
                if (o + 1 < occupied.size())
                    for (std::size_t e = first[2 * (o + 1)]; e < first[2 * (o + 1) + 1]; ++e) {
                        const openvdb::Vec3I& tri = mesh.triangles[members[e]];
                        for (int k = 0; k < 3; ++k) __builtin_prefetch(&mesh.points[tri[k]]);
                    }
                // Rows padded with seven entries that pair with none: a row read eight at a time
                // from any start ends in them.
                const std::size_t padded = count + 7;
                if (index.size() < padded) {
                    index.resize(padded);
                    gathered.resize(padded);
                    candidates.resize(padded);
                    corner.resize(padded);
                    for (int a = 0; a < 3; ++a) {
                        lo[a].resize(padded);
                        hi[a].resize(padded);
                        vertex[a].resize(padded);
                    }
                }
                for (std::size_t m = count; m < padded; ++m) corner[m] = 16;
                // In triangle order, so the pairs come in index order (insertion: the row is
                // sorted, or nearly).
                uint32_t* row = members.data() + rowBegin;
                for (std::size_t m = 1; m < count; ++m)
                    for (std::size_t i = m; i > 0 && row[i - 1] > row[i]; --i) std::swap(row[i - 1], row[i]);
                for (std::size_t m = 0; m < count; ++m) {
                    const uint32_t t = members[rowBegin + m];
                    index[m] = t;
                    gathered[m].tri[0] = kNotGathered;
                    const TriangleCells& tc = cells[t];
                    // Bits 0-2: whether this is the triangle's lowest cell along each axis; bit 3:
                    // whether it is flagged (or all are tested).
                    corner[m] = int32_t((tc.lo[0] == ci) | (tc.lo[1] == cj) << 1 | (tc.lo[2] == ck) << 2 |
                                        (tested.empty() || tested[t]) << 3);
                    for (int a = 0; a < 3; ++a) {
                        lo[a][m] = tc.min[a];
                        vertex[a][m] = int32_t(mesh.triangles[t][a]);
                        hi[a][m] = tc.max[a];
                    }
                }
                const PairRows rows{corner.data(),
                                    {lo[0].data(), lo[1].data(), lo[2].data()},
                                    {hi[0].data(), hi[1].data(), hi[2].data()},
                                    {vertex[0].data(), vertex[1].data(), vertex[2].data()}};
                for (std::size_t x = 0; x + 1 < count; ++x) {
                    // Pairs sharing an edge (two corners or more) are not tested, nor those sharing
                    // one corner whose fan lies apart.
                    bool apartX[3];
                    for (int k = 0; k < 3; ++k) apartX[k] = !apart.empty() && apart[uint32_t(vertex[k][x])];
                    const std::size_t numCandidates = wide ? filterPairsAvx2(rows, x, count, apartX, candidates.data())
                                                           : filterPairs(rows, x, count, apartX, candidates.data());
                    for (std::size_t e = 0; e < numCandidates; ++e) {
                        const std::size_t y = candidates[e];
                        // Gathered on first use: of the triangles a cell holds only those with a
                        // candidate pair in it are read (a triangle is in about two cells).
                        if (gathered[x].tri[0] == kNotGathered) gathered[x].gather(mesh, index[x]);
                        if (gathered[y].tri[0] == kNotGathered) gathered[y].gather(mesh, index[y]);
                        if (trianglesCross(gathered[x], gathered[y]))
                            found[block].emplace_back(std::min(index[x], index[y]), std::max(index[x], index[y]));
                    }
                }
            }
    });
    blocksDone.finish();
    std::vector<std::pair<uint32_t, uint32_t>> pairs;
    for (const auto& f : found) pairs.insert(pairs.end(), f.begin(), f.end());
    return pairs;
}

std::size_t countSelfIntersections(const TriangleMesh& mesh, const ProgressFn& progress)
{
    return selfIntersections(mesh, {}, nullptr, progress).size();
}

std::size_t countSelfIntersections(const TriangleMesh& mesh, const std::vector<std::uint8_t>& fansApart,
                                   const ProgressFn& progress)
{
    return selfIntersections(mesh, {}, &fansApart, progress).size();
}

std::size_t countCoincidentVertices(const TriangleMesh& mesh)
{
    std::vector<std::array<float, 3>> points(mesh.points.size());
    for (std::size_t i = 0; i < points.size(); ++i)
        points[i] = {mesh.points[i][0], mesh.points[i][1], mesh.points[i][2]};
    std::sort(points.begin(), points.end());
    std::size_t coincident = 0;
    for (std::size_t i = 1; i < points.size(); ++i) coincident += points[i] == points[i - 1];
    return coincident;
}

}  // namespace voxlat
