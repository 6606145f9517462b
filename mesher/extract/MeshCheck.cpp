#include "mesher/extract/MeshCheck.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <atomic>
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

/// Whether the triangles @a row around a vertex form one closed fan, each edge at the vertex
/// shared by exactly two of them in opposite directions: every @a next distinct, every @a prev
/// some triangle's next, and stepping from a triangle to the one whose next is its prev visits
/// all of them in one cycle. Then the general test (spokes and link components) finds every
/// edge manifold and consistent and the link one cycle, which is what almost every vertex of a
/// closed mesh is. Fixed loops without early exits: the rows are short and the exits would be
/// mispredicted.
bool closedFan(const Corner* row, std::size_t n)
{
    if (n > kMaxFastFan) return false;
    std::array<uint8_t, kMaxFastFan> step;
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

MeshTopology checkTopology(const TriangleMesh& mesh)
{
    MeshTopology result;
    const std::size_t numPoints = mesh.points.size(), numTriangles = mesh.triangles.size();

    // Triangles with repeated or invalid indices have no meaningful edges; leave them out of the
    // topology and only count them. Zero-area triangles are topologically fine and stay in.
    auto valid = [numPoints](const openvdb::Vec3I& tri) {
        return tri[0] < numPoints && tri[1] < numPoints && tri[2] < numPoints && tri[0] != tri[1] && tri[1] != tri[2] &&
               tri[0] != tri[2];
    };
    // Per fixed block of triangles: the valid and degenerate ones and the span of their
    // vertices, so that the passes below skip blocks that do not touch their vertices.
    struct Block {
        std::size_t valid = 0, degenerate = 0;
        uint32_t lo = std::numeric_limits<uint32_t>::max(), hi = 0;
    };
    constexpr std::size_t kBlock = 1 << 12;
    std::vector<Block> blocks((numTriangles + kBlock - 1) / kBlock);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks.size(), 16), [&](const auto& range) {
        for (std::size_t b = range.begin(); b != range.end(); ++b) {
            Block& block = blocks[b];
            for (std::size_t t = b * kBlock; t < std::min(numTriangles, (b + 1) * kBlock); ++t) {
                const openvdb::Vec3I& tri = mesh.triangles[t];
                if (!valid(tri)) {
                    ++block.degenerate;
                    continue;
                }
                ++block.valid;
                block.lo = std::min({block.lo, tri[0], tri[1], tri[2]});
                block.hi = std::max({block.hi, tri[0], tri[1], tri[2]});
                const openvdb::Vec3d a(mesh.points[tri[0]]), b(mesh.points[tri[1]]), c(mesh.points[tri[2]]);
                if ((b - a).cross(c - a) == openvdb::Vec3d(0.0)) ++block.degenerate;
            }
        }
    });
    std::size_t numValid = 0;
    for (const Block& block : blocks) {
        numValid += block.valid;
        result.degenerateTriangles += block.degenerate;
    }

    // Vertex -> the incident valid triangles (as the corners after it), compressed rows in
    // triangle order. Each task owns a range of vertices and scans the blocks that reach it for
    // its corners: no counter is shared, and the rows come out the same for any split.
    const std::size_t parts = std::size_t(std::max(1, tbb::this_task_arena::max_concurrency()));
    auto partBegin = [&](std::size_t part) { return numPoints * part / parts; };
    auto forCorners = [&](std::size_t part, auto&& visit) {
        const std::size_t lo = partBegin(part), hi = partBegin(part + 1);
        for (std::size_t b = 0; b < blocks.size(); ++b) {
            if (blocks[b].valid == 0 || blocks[b].hi < lo || blocks[b].lo >= hi) continue;
            for (std::size_t t = b * kBlock; t < std::min(numTriangles, (b + 1) * kBlock); ++t) {
                const openvdb::Vec3I& tri = mesh.triangles[t];
                if (!valid(tri)) continue;
                for (int k = 0; k < 3; ++k)
                    if (tri[k] >= lo && tri[k] < hi) visit(tri[k], Corner{tri[(k + 1) % 3], tri[(k + 2) % 3]});
            }
        }
    };
    std::vector<std::size_t> first(numPoints + 1, 0);
    tbb::parallel_for(std::size_t(0), parts,
                      [&](std::size_t part) { forCorners(part, [&](uint32_t v, const Corner&) { ++first[v + 1]; }); });
    std::partial_sum(first.begin(), first.end(), first.begin());
    // Left uninitialised (every entry is filled below): the rows are the largest array here, and
    // a fresh one is paged in as it is written. Each row's start serves as its cursor, leaving it
    // at the next row's start: shifted back by one row after.
    const std::unique_ptr<Corner[]> corners(new Corner[first.back()]);
    tbb::parallel_for(std::size_t(0), parts, [&](std::size_t part) {
        forCorners(part, [&](uint32_t v, const Corner& c) { corners[first[v]++] = c; });
    });
    std::copy_backward(first.begin(), first.end() - 1, first.end());
    first[0] = 0;

    // Pieces: vertices joined by the edges, united at each edge's lower end in the pass below.
    std::vector<std::atomic<uint32_t>> piece(numPoints);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numPoints, 1 << 16), [&](const auto& range) {
        for (std::size_t v = range.begin(); v != range.end(); ++v)
            piece[v].store(uint32_t(v), std::memory_order_relaxed);
    });
    // Per vertex, for the per-piece Euler characteristic and open edges: 1 - (edges it owns, those
    // to higher neighbours) + (triangles it owns, those whose lowest corner it is), and whether
    // any of its edges is open or non-manifold.
    std::vector<int64_t> ownedChi(numPoints, 0);
    std::vector<uint8_t> ownedBad(numPoints, 0);

    const Tally tally = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, numPoints, 1024), Tally{},
        [&](const tbb::blocked_range<std::size_t>& range, Tally acc) {
            std::vector<Spoke> spokes;
            std::vector<uint32_t> nodes, parent;
            for (std::size_t v = range.begin(); v != range.end(); ++v) {
                const std::size_t n = first[v + 1] - first[v];
                if (n == 0) continue;
                const Corner* row = corners.get() + first[v];
                ++acc.vertices;
                int64_t owned = 1;
                for (std::size_t i = 0; i < n; ++i) owned += row[i].next > v && row[i].prev > v;
                if (closedFan(row, n)) {
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
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numPoints, 1 << 14), [&](const auto& range) {
        for (std::size_t v = range.begin(); v != range.end(); ++v)
            piece[v].store(findRoot(piece, uint32_t(v)), std::memory_order_relaxed);
    });
    for (std::size_t v = 0; v < numPoints; ++v) {
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

bool trianglesCross(const TriangleMesh& mesh, const openvdb::Vec3I& s, const openvdb::Vec3I& t)
{
    int shared = 0;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) shared += s[i] == t[j];
    if (shared >= 2) return false;
    auto point = [&](uint32_t v) { return openvdb::Vec3d(mesh.points[v]); };
    const openvdb::Vec3d sa = point(s[0]), sb = point(s[1]), sc = point(s[2]);
    const openvdb::Vec3d ta = point(t[0]), tb = point(t[1]), tc = point(t[2]);
    auto has = [](const openvdb::Vec3I& tri, uint32_t v) { return tri[0] == v || tri[1] == v || tri[2] == v; };
    // Most pairs that share a cell lie apart: the corners of one (those it does not share) all
    // strictly on one side of the other's plane leave no edge of either through the other.
    // "Strictly" is a margin far below what segmentCrossesTriangle resolves (its ends and
    // parameters within 1e-9 of an edge do not count), so only the work changes.
    auto oneSide = [&](const openvdb::Vec3I& plane, const openvdb::Vec3d& a, const openvdb::Vec3d& b,
                       const openvdb::Vec3d& c, const openvdb::Vec3I& other, const openvdb::Vec3d* corners) {
        const openvdb::Vec3d n = (b - a).cross(c - a);
        const double span =
            std::max({std::abs(a.x()), std::abs(a.y()), std::abs(a.z()), (b - a).length(), (c - a).length()});
        const double margin = 1e-12 * n.length() * (span + (corners[0] - a).length());
        bool above = true, below = true;
        for (int k = 0; k < 3; ++k) {
            if (has(plane, other[k])) continue;
            const double d = n.dot(corners[k] - a);
            above = above && d > margin;
            below = below && d < -margin;
        }
        return above || below;
    };
    const openvdb::Vec3d sCorners[3] = {sa, sb, sc}, tCorners[3] = {ta, tb, tc};
    if (oneSide(s, sa, sb, sc, t, tCorners) || oneSide(t, ta, tb, tc, s, sCorners)) return false;
    // Edges of one through the other; an edge ending at a shared vertex cannot cross the interior
    // without the other edges doing so too, except in the coplanar case, which is not counted.
    for (int i = 0; i < 3; ++i) {
        const uint32_t p = s[i], q = s[(i + 1) % 3];
        if (has(t, p) || has(t, q)) continue;
        if (segmentCrossesTriangle(point(p), point(q), ta, tb, tc)) return true;
    }
    for (int i = 0; i < 3; ++i) {
        const uint32_t p = t[i], q = t[(i + 1) % 3];
        if (has(s, p) || has(s, q)) continue;
        if (segmentCrossesTriangle(point(p), point(q), sa, sb, sc)) return true;
    }
    return false;
}

}  // namespace

std::vector<std::pair<uint32_t, uint32_t>> selfIntersections(const TriangleMesh& mesh)
{
    return selfIntersections(mesh, {});
}

std::vector<std::pair<uint32_t, uint32_t>> selfIntersections(const TriangleMesh& mesh,
                                                             const std::vector<std::uint8_t>& tested)
{
    const std::size_t n = mesh.triangles.size();
    if (n < 2) return {};
    // Bounds of the triangles' corners only: callers pass a few triangles of a large mesh's points.
    openvdb::BBoxd box;
    double edgeSum = 0.0;
    for (std::size_t t = 0; t < n; ++t) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        for (int k = 0; k < 3; ++k) box.expand(openvdb::Vec3d(mesh.points[tri[k]]));
        edgeSum += (openvdb::Vec3d(mesh.points[tri[0]]) - openvdb::Vec3d(mesh.points[tri[1]])).length();
    }
    const openvdb::Vec3d extent = box.extents();
    // Cells about twice the mean edge, at most 256 per axis (so the cell count stays bounded).
    double cell = std::max(2.0 * edgeSum / double(n), 1e-9);
    for (int a = 0; a < 3; ++a) cell = std::max(cell, extent[a] / 256.0);
    int dims[3];
    for (int a = 0; a < 3; ++a) dims[a] = std::max(1, int(std::ceil(extent[a] / cell)) + 1);
    auto cellOf = [&](const openvdb::Vec3d& p, int a) {
        return std::clamp(int(std::floor((p[a] - box.min()[a]) / cell)), 0, dims[a] - 1);
    };
    struct Range {
        int lo[3], hi[3];
    };
    std::vector<Range> ranges(n);
    // Each triangle's bounds in single precision, widened by a rounding: pairs whose bounds are
    // apart cannot cross, and most pairs sharing a cell are (a test far cheaper than the crossing's).
    std::vector<std::array<float, 6>> bounds(n);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1 << 14), [&](const auto& r) {
        for (std::size_t t = r.begin(); t != r.end(); ++t) {
            const openvdb::Vec3I& tri = mesh.triangles[t];
            openvdb::BBoxd b;
            for (int k = 0; k < 3; ++k) b.expand(openvdb::Vec3d(mesh.points[tri[k]]));
            // A triangle in a face plane of the bounds (a cap where a mesh was cut by a box) has
            // every other triangle on one side: none can pass an edge through its interior, and
            // its edges, in that plane, meet another triangle only on that one's boundary
            // (coplanar overlaps are not counted). Left out, as its cells are often many.
            bool onBounds = false;
            for (int a = 0; a < 3; ++a)
                onBounds = onBounds ||
                           (b.min()[a] == b.max()[a] && (b.min()[a] == box.min()[a] || b.max()[a] == box.max()[a]));
            for (int a = 0; a < 3; ++a) {
                ranges[t].lo[a] = onBounds ? 1 : cellOf(b.min(), a);
                ranges[t].hi[a] = onBounds ? 0 : cellOf(b.max(), a);
                bounds[t][a] = std::nextafter(float(b.min()[a]), -std::numeric_limits<float>::infinity());
                bounds[t][3 + a] = std::nextafter(float(b.max()[a]), std::numeric_limits<float>::infinity());
            }
        }
    });
    const std::size_t numCells = std::size_t(dims[0]) * dims[1] * dims[2];
    auto cellIndex = [&](int i, int j, int k) { return (std::size_t(i) * dims[1] + j) * dims[2] + k; };
    // Occupied cells in ascending order, each with its triangles in index order (compressed
    // rows). A few triangles spread over a large box (the refinement's local checks) would make
    // a dense table of mostly empty cells: then (cell, triangle) entries are sorted instead.
    std::vector<std::size_t> cells;  // occupied cell indices, ascending
    std::vector<std::size_t> first;  // rows into members, one more than cells
    std::vector<uint32_t> members;
    std::size_t entries = 0;
    for (const Range& r : ranges)
        entries += std::size_t(r.hi[0] - r.lo[0] + 1) * (r.hi[1] - r.lo[1] + 1) * (r.hi[2] - r.lo[2] + 1);
    if (numCells <= 4 * entries) {
        std::vector<std::size_t> count(numCells + 1, 0);
        for (const Range& r : ranges)
            for (int i = r.lo[0]; i <= r.hi[0]; ++i)
                for (int j = r.lo[1]; j <= r.hi[1]; ++j)
                    for (int k = r.lo[2]; k <= r.hi[2]; ++k) ++count[cellIndex(i, j, k) + 1];
        std::partial_sum(count.begin(), count.end(), count.begin());
        members.resize(count.back());
        std::vector<std::size_t> fill(count.begin(), count.end() - 1);
        for (std::size_t t = 0; t < n; ++t) {
            const Range& r = ranges[t];
            for (int i = r.lo[0]; i <= r.hi[0]; ++i)
                for (int j = r.lo[1]; j <= r.hi[1]; ++j)
                    for (int k = r.lo[2]; k <= r.hi[2]; ++k) members[fill[cellIndex(i, j, k)]++] = uint32_t(t);
        }
        for (std::size_t c = 0; c < numCells; ++c)
            if (count[c + 1] - count[c] >= 2) {
                cells.push_back(c);
                first.push_back(count[c]);
                first.push_back(count[c + 1]);
            }
    } else {
        std::vector<std::pair<std::size_t, uint32_t>> list;
        list.reserve(entries);
        for (std::size_t t = 0; t < n; ++t) {
            const Range& r = ranges[t];
            for (int i = r.lo[0]; i <= r.hi[0]; ++i)
                for (int j = r.lo[1]; j <= r.hi[1]; ++j)
                    for (int k = r.lo[2]; k <= r.hi[2]; ++k) list.emplace_back(cellIndex(i, j, k), uint32_t(t));
        }
        std::sort(list.begin(), list.end());
        members.resize(list.size());
        for (std::size_t e = 0; e < list.size(); ++e) members[e] = list[e].second;
        for (std::size_t e = 0; e < list.size();) {
            std::size_t end = e + 1;
            while (end < list.size() && list[end].first == list[e].first) ++end;
            if (end - e >= 2) {
                cells.push_back(list[e].first);
                first.push_back(e);
                first.push_back(end);
            }
            e = end;
        }
    }
    // Per block of occupied cells its own list; blocks joined in order, so the list is the same
    // for any thread count (and pairs come in ascending lowest shared cell, then index order).
    constexpr std::size_t kCellsPerBlock = 256;
    const std::size_t numBlocks = (cells.size() + kCellsPerBlock - 1) / kCellsPerBlock;
    std::vector<std::vector<std::pair<uint32_t, uint32_t>>> found(numBlocks);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numBlocks, 1), [&](const auto& r) {
        for (std::size_t block = r.begin(); block != r.end(); ++block)
            for (std::size_t o = block * kCellsPerBlock; o < std::min(cells.size(), (block + 1) * kCellsPerBlock);
                 ++o) {
                const std::size_t c = cells[o];
                const int ci = int(c / (std::size_t(dims[1]) * dims[2])), cj = int((c / dims[2]) % dims[1]),
                          ck = int(c % dims[2]);
                for (std::size_t x = first[2 * o]; x < first[2 * o + 1]; ++x)
                    for (std::size_t y = x + 1; y < first[2 * o + 1]; ++y) {
                        if (!tested.empty() && !tested[members[x]] && !tested[members[y]]) continue;
                        const Range &a = ranges[members[x]], &b = ranges[members[y]];
                        // Tested only in the lowest cell both cover.
                        if (std::max(a.lo[0], b.lo[0]) != ci || std::max(a.lo[1], b.lo[1]) != cj ||
                            std::max(a.lo[2], b.lo[2]) != ck)
                            continue;
                        if (a.hi[0] < b.lo[0] || b.hi[0] < a.lo[0] || a.hi[1] < b.lo[1] || b.hi[1] < a.lo[1] ||
                            a.hi[2] < b.lo[2] || b.hi[2] < a.lo[2])
                            continue;
                        const std::array<float, 6>&p = bounds[members[x]], &q = bounds[members[y]];
                        if (p[3] < q[0] || q[3] < p[0] || p[4] < q[1] || q[4] < p[1] || p[5] < q[2] || q[5] < p[2])
                            continue;
                        if (trianglesCross(mesh, mesh.triangles[members[x]], mesh.triangles[members[y]]))
                            found[block].emplace_back(std::min(members[x], members[y]),
                                                      std::max(members[x], members[y]));
                    }
            }
    });
    std::vector<std::pair<uint32_t, uint32_t>> pairs;
    for (const auto& f : found) pairs.insert(pairs.end(), f.begin(), f.end());
    return pairs;
}

std::size_t countSelfIntersections(const TriangleMesh& mesh)
{
    return selfIntersections(mesh).size();
}

}  // namespace voxlat
