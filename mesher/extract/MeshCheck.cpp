#include "mesher/extract/MeshCheck.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
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

uint32_t findRoot(std::vector<uint32_t>& parent, uint32_t i)
{
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
}

}  // namespace

MeshTopology checkTopology(const TriangleMesh& mesh)
{
    MeshTopology result;
    const std::size_t numPoints = mesh.points.size();

    // Triangles with repeated or invalid indices have no meaningful edges; leave them out of the
    // topology and only count them. Zero-area triangles are topologically fine and stay in.
    std::vector<uint32_t> valid;
    valid.reserve(mesh.triangles.size());
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        if (tri[0] >= numPoints || tri[1] >= numPoints || tri[2] >= numPoints || tri[0] == tri[1] || tri[1] == tri[2] ||
            tri[0] == tri[2]) {
            ++result.degenerateTriangles;
            continue;
        }
        const openvdb::Vec3d a(mesh.points[tri[0]]), b(mesh.points[tri[1]]), c(mesh.points[tri[2]]);
        if ((b - a).cross(c - a) == openvdb::Vec3d(0.0)) ++result.degenerateTriangles;
        valid.push_back(uint32_t(t));
    }

    // Vertex -> incident triangles, compressed rows.
    std::vector<std::size_t> first(numPoints + 1, 0);
    for (uint32_t t : valid) {
        for (int k = 0; k < 3; ++k) ++first[mesh.triangles[t][k] + 1];
    }
    std::partial_sum(first.begin(), first.end(), first.begin());
    std::vector<uint32_t> incident(first.back());
    {
        std::vector<std::size_t> fill(first.begin(), first.end() - 1);
        for (uint32_t t : valid) {
            for (int k = 0; k < 3; ++k) incident[fill[mesh.triangles[t][k]]++] = t;
        }
    }

    // Pieces: vertices joined by the triangles (union-find, serial: a pass over the triangles).
    std::vector<uint32_t> piece(numPoints);
    std::iota(piece.begin(), piece.end(), 0u);
    for (uint32_t t : valid) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        for (int k = 1; k < 3; ++k) {
            const uint32_t a = findRoot(piece, tri[0]), b = findRoot(piece, tri[k]);
            if (b != a) piece[std::max(a, b)] = std::min(a, b);
        }
    }
    // Edges each vertex owns (those to higher neighbours), and how many of them are open or
    // non-manifold, for the per-piece Euler characteristic.
    std::vector<uint32_t> ownedEdges(numPoints, 0), ownedBad(numPoints, 0);

    const Tally tally = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, numPoints, 1024), Tally{},
        [&](const tbb::blocked_range<std::size_t>& range, Tally acc) {
            std::vector<Spoke> spokes;
            std::vector<uint32_t> nodes, parent;
            for (std::size_t v = range.begin(); v != range.end(); ++v) {
                if (first[v] == first[v + 1]) continue;
                ++acc.vertices;
                spokes.clear();
                for (std::size_t i = first[v]; i != first[v + 1]; ++i) {
                    const openvdb::Vec3I& tri = mesh.triangles[incident[i]];
                    const int k = tri[0] == v ? 0 : tri[1] == v ? 1 : 2;
                    spokes.push_back({tri[(k + 1) % 3], true});
                    spokes.push_back({tri[(k + 2) % 3], false});
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
                        ++ownedEdges[v];
                        if (faces == 1) ++acc.boundary;
                        if (faces > 2) ++acc.nonManifoldEdges;
                        if (faces != 2) ++ownedBad[v];
                        // Sorted with outgoing last: two equal flags mean the same direction twice.
                        if (faces == 2 && spokes[i].outgoing == spokes[i + 1].outgoing) ++acc.inconsistent;
                    }
                    i = j;
                }
                // ...and its link (the opposite edges, over the neighbours) is connected.
                parent.resize(nodes.size());
                std::iota(parent.begin(), parent.end(), 0u);
                std::size_t components = nodes.size();
                for (std::size_t i = first[v]; i != first[v + 1]; ++i) {
                    const openvdb::Vec3I& tri = mesh.triangles[incident[i]];
                    const int k = tri[0] == v ? 0 : tri[1] == v ? 1 : 2;
                    auto node = [&](uint32_t w) {
                        return uint32_t(std::lower_bound(nodes.begin(), nodes.end(), w) - nodes.begin());
                    };
                    const uint32_t a = findRoot(parent, node(tri[(k + 1) % 3]));
                    const uint32_t b = findRoot(parent, node(tri[(k + 2) % 3]));
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
    result.eulerCharacteristic = int(int64_t(tally.vertices) - int64_t(tally.edges) + int64_t(valid.size()));

    // Per piece (indexed by its root, the piece's lowest vertex): V - E + F and open edges.
    std::vector<int64_t> chi(numPoints, 0);
    std::vector<uint32_t> bad(numPoints, 0);
    std::vector<uint8_t> used(numPoints, 0);
    for (uint32_t t : valid) {
        const uint32_t root = findRoot(piece, mesh.triangles[t][0]);
        ++chi[root];
        for (int k = 0; k < 3; ++k) used[mesh.triangles[t][k]] = 1;
    }
    for (std::size_t v = 0; v < numPoints; ++v) {
        if (!used[v]) continue;
        const uint32_t root = findRoot(piece, uint32_t(v));
        chi[root] += 1 - int64_t(ownedEdges[v]);
        bad[root] += ownedBad[v];
        if (root == v) ++result.pieces;
    }
    for (std::size_t v = 0; v < numPoints; ++v) {
        if (!used[v] || piece[v] != v || bad[v] != 0) continue;
        ++result.closedPieces;
        result.genus += int(1 - chi[v] / 2);
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
