#include "mesher/tolerance/CreaseSplit.h"

#include "mesher/extract/PhaseProgress.h"

#include "mesher/checks/MeshCheck.h"
#include "mesher/tolerance/SplitTriangle.h"
#include "mesher/tolerance/SurfaceList.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace voxlat {

namespace {

struct CreaseEdge {
    std::uint32_t p, q;
    std::uint32_t surfaces;  ///< bit mask of the surfaces the split point lies on
};

}  // namespace

CreaseSplitStats splitCreaseEdges(TriangleMesh& mesh, const CreaseSurfaces& surfaces, const ProjectionOptions& options,
                                  const ProgressFn& progress)
{
    CreaseSplitStats stats;
    PhaseProgress phases(progress);
    const SurfaceList list(surfaces, options.level);
    const int numSurfaces = list.size();
    const std::size_t n = mesh.points.size();
    if (n == 0 || numSurfaces < 2 || numSurfaces > 32) return stats;
    std::vector<Vec3d> points(n);
    for (std::size_t v = 0; v < n; ++v) points[v] = toDouble(mesh.points[v]);

    phases.begin(0.0);
    // 1. Which surfaces each vertex lies on (within a hundredth of the move limit: a vertex the
    // projection held back part way still counts).
    const double near = 1e-2 * options.maxMove;
    std::vector<std::uint32_t> mask(n, 0);
    {
        std::vector<double> values(n);
        std::vector<Vec3d> gradients(n);
        for (int s = 0; s < numSurfaces; ++s) {
            tbb::parallel_for(tbb::blocked_range<std::size_t>(0, (n + kBatchSize - 1) / kBatchSize, 1),
                              [&](const auto& range) {
                                  phases.check();
                                  for (std::size_t c = range.begin(); c != range.end(); ++c) {
                                      const std::size_t begin = c * kBatchSize, count = std::min(kBatchSize, n - begin);
                                      list.evaluate(s, std::span<const Vec3d>(points.data() + begin, count),
                                                    std::span<double>(values.data() + begin, count),
                                                    std::span<Vec3d>(gradients.data() + begin, count));
                                  }
                              });
            for (std::size_t v = 0; v < n; ++v)
                if (firstOrderDistance(values[v], gradients[v]) <= near) mask[v] |= 1u << s;
        }
    }

    phases.begin(0.3);
    // 2. Crease edges: the ends lie on different surfaces and neither on all of them.
    std::vector<CreaseEdge> edges;
    for (const openvdb::Vec3I& t : mesh.triangles) {
        if (mask[t[0]] == mask[t[1]] && mask[t[1]] == mask[t[2]]) continue;
        for (int i = 0; i < 3; ++i) {
            const std::uint32_t p = std::min(t[i], t[(i + 1) % 3]), q = std::max(t[i], t[(i + 1) % 3]);
            const std::uint32_t both = mask[p] | mask[q];
            if (mask[p] == 0 || mask[q] == 0 || mask[p] == both || mask[q] == both) continue;
            const int count = std::popcount(both);
            if (count < 2 || count > 3) continue;
            edges.push_back({p, q, both});
        }
    }
    std::sort(edges.begin(), edges.end(),
              [](const CreaseEdge& a, const CreaseEdge& b) { return a.p < b.p || (a.p == b.p && a.q < b.q); });
    edges.erase(std::unique(edges.begin(), edges.end(),
                            [](const CreaseEdge& a, const CreaseEdge& b) { return a.p == b.p && a.q == b.q; }),
                edges.end());
    stats.creaseEdges = edges.size();
    if (edges.empty()) return stats;

    phases.begin(0.4);
    // 3. The point on all the edge's surfaces nearest its midpoint: Newton, least-norm steps.
    const std::size_t m = edges.size();
    std::vector<Vec3d> target(m);
    std::vector<std::uint8_t> found(m, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, (m + kBatchSize - 1) / kBatchSize, 1), [&](const auto& r) {
        std::vector<Vec3d> x, g(kBatchSize * 3);
        std::vector<double> val(kBatchSize * 3);
        phases.check();
        for (std::size_t c = r.begin(); c != r.end(); ++c) {
            const std::size_t begin = c * kBatchSize, count = std::min(kBatchSize, m - begin);
            x.resize(count);
            for (std::size_t k = 0; k < count; ++k) {
                const CreaseEdge& e = edges[begin + k];
                x[k] = 0.5 * (points[e.p] + points[e.q]);
            }
            std::vector<std::uint8_t> done(count, 0);
            for (int iteration = 0; iteration <= options.maxIterations; ++iteration) {
                // Each surface over the whole batch (a surface an edge does not use is evaluated
                // needlessly; the batch stays one call per surface).
                std::array<std::vector<double>, 32> values;
                std::array<std::vector<Vec3d>, 32> grads;
                // All surfaces: the point must lie inside the ones it is not on.
                const std::uint32_t used = numSurfaces == 32 ? ~0u : (1u << numSurfaces) - 1u;
                for (int s = 0; s < numSurfaces; ++s) {
                    if (!(used >> s & 1u)) continue;
                    values[s].resize(count);
                    grads[s].resize(count);
                    list.evaluate(s, x, values[s], grads[s]);
                }
                bool moving = false;
                for (std::size_t k = 0; k < count; ++k) {
                    if (done[k]) continue;
                    const CreaseEdge& e = edges[begin + k];
                    std::array<double, 3> res{};
                    std::array<Vec3d, 3> jac;
                    int rows = 0;
                    bool close = true;
                    for (int s = 0; s < numSurfaces; ++s) {
                        if (!(e.surfaces >> s & 1u)) continue;
                        res[rows] = values[s][k];
                        jac[rows] = grads[s][k];
                        close = close && firstOrderDistance(res[rows], jac[rows]) <= options.tolerance;
                        ++rows;
                    }
                    const Vec3d mid = 0.5 * (points[e.p] + points[e.q]);
                    if (close) {
                        done[k] = 1;
                        bool inside = true;
                        for (int t = 0; t < numSurfaces; ++t)
                            if (!(e.surfaces >> t & 1u))
                                inside = inside && values[t][k] <= options.tolerance * grads[t][k].length();
                        found[begin + k] = inside && (x[k] - mid).length() <= options.maxMove;
                        // Rounded as it will be stored, so the checks below see the triangles
                        // as written (two edges' corner points may round to one position).
                        target[begin + k] = asStored(x[k]);
                        continue;
                    }
                    if (iteration == options.maxIterations) continue;
                    std::array<std::array<double, 3>, 3> a{};
                    for (int i = 0; i < rows; ++i)
                        for (int j = 0; j < rows; ++j) a[i][j] = jac[i].dot(jac[j]);
                    std::array<double, 3> y{};
                    if (!solveSmall(rows, a, res, y)) {
                        done[k] = 1;
                        continue;
                    }
                    for (int i = 0; i < rows; ++i) x[k] -= y[i] * jac[i];
                    if (!((x[k] - mid).length() <= 2.0 * options.maxMove)) {
                        done[k] = 1;  // wandered off
                        continue;
                    }
                    moving = true;
                }
                if (!moving) break;
            }
        }
    });

    phases.begin(0.6);
    // 4. Split: each triangle is divided by its split edges; a parent whose pieces would turn
    // over drops its splits (and so its neighbours across them change), in rounds.
    std::vector<std::uint8_t> active(found);
    // A split point stored at the position of a vertex (one already on the crease) or of another
    // edge's split point (two edges meeting at a corner of three surfaces) would make two vertices
    // at one position: read by position (an STL), four triangles at an edge. The later one is dropped.
    {
        auto key = [](const Vec3d& p) { return std::array<double, 3>{p.x(), p.y(), p.z()}; };
        std::vector<std::pair<std::array<double, 3>, std::uint32_t>> split;
        for (std::size_t e = 0; e < m; ++e)
            if (active[e]) split.emplace_back(key(target[e]), std::uint32_t(e));
        std::sort(split.begin(), split.end());
        for (std::size_t i = 1; i < split.size(); ++i)
            if (split[i].first == split[i - 1].first) active[std::max(split[i].second, split[i - 1].second)] = 0;
        for (std::size_t v = 0; v < n && !split.empty(); ++v) {
            const auto k = key(points[v]);
            auto it = std::lower_bound(split.begin(), split.end(), std::make_pair(k, std::uint32_t(0)));
            for (; it != split.end() && it->first == k; ++it) active[it->second] = 0;
        }
        for (std::size_t e = 0; e < m; ++e) stats.coincident += found[e] && !active[e];
    }
    auto edgeIndex = [&](std::uint32_t a, std::uint32_t b) -> std::ptrdiff_t {
        const std::uint32_t p = std::min(a, b), q = std::max(a, b);
        const auto it = std::lower_bound(
            edges.begin(), edges.end(), CreaseEdge{p, q, 0},
            [](const CreaseEdge& x, const CreaseEdge& y) { return x.p < y.p || (x.p == y.p && x.q < y.q); });
        if (it == edges.end() || it->p != p || it->q != q) return -1;
        return it - edges.begin();
    };
    // Triangles with at least one crease edge, and their edges' indices.
    std::vector<std::uint32_t> touched;
    std::vector<std::array<std::ptrdiff_t, 3>> touchedEdges;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        if (mask[tri[0]] == mask[tri[1]] && mask[tri[1]] == mask[tri[2]]) continue;
        std::array<std::ptrdiff_t, 3> e;
        bool any = false;
        for (int i = 0; i < 3; ++i) {
            e[i] = edgeIndex(tri[i], tri[(i + 1) % 3]);
            any = any || (e[i] >= 0 && found[e[i]]);
        }
        if (any) {
            touched.push_back(std::uint32_t(t));
            touchedEdges.push_back(e);
        }
    }
    auto positions = [&](std::size_t k) {
        return splitPositions(mesh.triangles[touched[k]], touchedEdges[k], points, active, target);
    };
    auto splits = [&](std::size_t k) { return splitEdges(touchedEdges[k], active); };
    std::vector<std::uint8_t> bad(touched.size());
    auto dropTurned = [&] {
        for (;;) {
            phases.check();
            tbb::parallel_for(tbb::blocked_range<std::size_t>(0, touched.size(), 1024), [&](const auto& r) {
                for (std::size_t k = r.begin(); k != r.end(); ++k) {
                    const std::array<Vec3d, 6> p = positions(k);
                    const Vec3d n0 = (p[1] - p[0]).cross(p[2] - p[0]);
                    bad[k] = 0;
                    for (const SplitPiece& piece : splitPieces(p, splits(k))) {
                        const Vec3d& a = p[piece[0]];
                        const Vec3d n1 = (p[piece[1]] - a).cross(p[piece[2]] - a);
                        // A piece on one of the two surfaces may face up to half the crease's
                        // dihedral angle away from the chamfer it replaces (more than 90 degrees at a
                        // sharp wedge); one turned over faces the other way (near 180).
                        const double l0 = n0.length(), l1 = n1.length();
                        if (!(n1.dot(n0) > -0.5 * l0 * l1) || !(l1 > 1e-6 * l0)) bad[k] = 1;
                    }
                }
            });
            bool dropped = false;
            for (std::size_t k = 0; k < touched.size(); ++k)
                if (bad[k])
                    for (int i = 0; i < 3; ++i)
                        if (touchedEdges[k][i] >= 0 && active[touchedEdges[k][i]]) {
                            active[touchedEdges[k][i]] = 0;
                            dropped = true;
                        }
            if (!dropped) break;
        }
    };
    dropTurned();

    phases.begin(0.7);
    // 5. No piece may cross another triangle: the pieces of the split parents and the triangles
    // around them are checked, and a parent whose pieces cross drops its splits, in rounds.
    {
        std::vector<std::uint8_t> nearSplit(n, 0);
        for (std::uint32_t t : touched)
            for (int i = 0; i < 3; ++i) nearSplit[mesh.triangles[t][i]] = 1;
        std::vector<std::uint32_t> around;
        for (std::size_t t = 0, k = 0; t < mesh.triangles.size(); ++t) {
            if (k < touched.size() && touched[k] == t) {
                ++k;
                continue;
            }
            const openvdb::Vec3I& tri = mesh.triangles[t];
            if (nearSplit[tri[0]] || nearSplit[tri[1]] || nearSplit[tri[2]]) around.push_back(std::uint32_t(t));
        }
        for (;;) {
            phases.check();
            // Dropped splits change their neighbours' pieces: those are checked again first.
            dropTurned();
            TriangleMesh local;
            local.points = mesh.points;
            std::vector<std::uint32_t> newIndex(m, 0);
            for (std::size_t e = 0; e < m; ++e)
                if (active[e]) {
                    newIndex[e] = std::uint32_t(local.points.size());
                    local.points.emplace_back(float(target[e].x()), float(target[e].y()), float(target[e].z()));
                }
            std::vector<std::int64_t> parent;
            for (std::size_t k = 0; k < touched.size(); ++k) {
                const std::array<bool, 3> s = splits(k);
                if (!s[0] && !s[1] && !s[2]) continue;
                const openvdb::Vec3I& tri = mesh.triangles[touched[k]];
                std::array<std::uint32_t, 6> index{tri[0], tri[1], tri[2], 0, 0, 0};
                for (int i = 0; i < 3; ++i)
                    if (s[i]) index[3 + i] = newIndex[touchedEdges[k][i]];
                for (const SplitPiece& piece : splitPieces(positions(k), s)) {
                    local.triangles.emplace_back(index[piece[0]], index[piece[1]], index[piece[2]]);
                    parent.push_back(std::int64_t(k));
                }
            }
            if (local.triangles.empty()) break;
            for (std::uint32_t t : around) {
                local.triangles.push_back(mesh.triangles[t]);
                parent.push_back(-1);
            }
            bool dropped = false;
            auto drop = [&](std::int64_t k) {
                for (int i = 0; i < 3; ++i)
                    if (touchedEdges[k][i] >= 0 && active[touchedEdges[k][i]]) {
                        active[touchedEdges[k][i]] = 0;
                        dropped = true;
                    }
            };
            // Pieces without area as written (two split points stored at one position).
            for (std::size_t t = 0; t < local.triangles.size(); ++t) {
                if (parent[t] < 0) continue;
                const openvdb::Vec3I& tri = local.triangles[t];
                const Vec3d a = toDouble(local.points[tri[0]]);
                if ((toDouble(local.points[tri[1]]) - a).cross(toDouble(local.points[tri[2]]) - a) == Vec3d(0.0))
                    drop(parent[t]);
            }
            for (const auto& [x, y] : selfIntersections(local))
                for (const std::int64_t k : {parent[x], parent[y]}) {
                    if (k < 0) continue;
                    for (int i = 0; i < 3; ++i)
                        if (touchedEdges[k][i] >= 0 && active[touchedEdges[k][i]]) {
                            active[touchedEdges[k][i]] = 0;
                            dropped = true;
                        }
                }
            if (!dropped) break;
        }
    }

    phases.begin(0.9);
    // 6. New vertices in edge order, then the triangles: untouched ones as they were, the others
    // replaced by their pieces in place of the parent (so the order stays deterministic).
    std::vector<std::uint32_t> newVertex(m, 0);
    for (std::size_t e = 0; e < m; ++e) {
        if (!active[e]) continue;
        newVertex[e] = std::uint32_t(mesh.points.size());
        mesh.points.emplace_back(float(target[e].x()), float(target[e].y()), float(target[e].z()));
        ++stats.split;
    }
    stats.leftFlat = stats.creaseEdges - stats.split;
    if (stats.split == 0) return stats;
    std::vector<openvdb::Vec3I> triangles;
    triangles.reserve(mesh.triangles.size() + 2 * stats.split);
    std::size_t next = 0;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        if (next < touched.size() && touched[next] == t) {
            const std::array<bool, 3> s = splits(next);
            const openvdb::Vec3I& tri = mesh.triangles[t];
            std::array<std::uint32_t, 6> index{tri[0], tri[1], tri[2], 0, 0, 0};
            for (int i = 0; i < 3; ++i)
                if (s[i]) index[3 + i] = newVertex[touchedEdges[next][i]];
            const SplitPieces pieces = splitPieces(positions(next), s);
            if (pieces.empty()) triangles.push_back(tri);
            for (const SplitPiece& piece : pieces)
                triangles.emplace_back(index[piece[0]], index[piece[1]], index[piece[2]]);
            ++next;
            continue;
        }
        triangles.push_back(mesh.triangles[t]);
    }
    mesh.triangles = std::move(triangles);
    return stats;
}

}  // namespace voxlat
