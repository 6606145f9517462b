#include "mesher/tolerance/CreaseRefinement.h"

#include "mesher/extract/PhaseProgress.h"

#include "fields/shapes/SurfaceDistance.h"
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

std::size_t chunkCount(std::size_t n)
{
    return (n + kBatchSize - 1) / kBatchSize;
}

/// The signed first-order distance to the solid, max over the surfaces of f / |grad f|, at
/// @a points; with @a normal, the unit gradient of the surface giving it. Fixed batches in
/// parallel.
void solidDistance(const SurfaceList& list, const std::vector<Vec3d>& points, std::vector<double>& distance,
                   std::vector<Vec3d>* normal = nullptr, const std::function<void()>& check = {})
{
    const std::size_t n = points.size();
    distance.resize(n);
    if (normal) normal->resize(n);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunkCount(n), 1), [&](const auto& range) {
        std::array<double, kBatchSize> v;
        std::array<Vec3d, kBatchSize> g;
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            if (check) check();  // per batch: a range may hold many
            const std::size_t begin = c * kBatchSize, count = std::min(kBatchSize, n - begin);
            const std::span<const Vec3d> p(points.data() + begin, count);
            for (int s = 0; s < list.size(); ++s) {
                list.evaluate(s, p, std::span<double>(v.data(), count), std::span<Vec3d>(g.data(), count));
                for (std::size_t k = 0; k < count; ++k) {
                    const double length = g[k].length();
                    const double d = firstOrderSignedDistance(v[k], length);
                    if (s == 0 || d > distance[begin + k]) {
                        distance[begin + k] = d;
                        if (normal) (*normal)[begin + k] = length > 0.0 ? g[k] / length : Vec3d(0.0);
                    }
                }
            }
        }
    });
}

/// Which surfaces each of @a points lies on (within @a near), as bit masks.
std::vector<std::uint32_t> surfaceMasks(const SurfaceList& list, const std::vector<Vec3d>& points, double near)
{
    const std::size_t n = points.size();
    std::vector<std::uint32_t> mask(n, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunkCount(n), 1), [&](const auto& range) {
        std::array<double, kBatchSize> v;
        std::array<Vec3d, kBatchSize> g;
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            const std::size_t begin = c * kBatchSize, count = std::min(kBatchSize, n - begin);
            for (int s = 0; s < list.size(); ++s) {
                list.evaluate(s, std::span<const Vec3d>(points.data() + begin, count),
                              std::span<double>(v.data(), count), std::span<Vec3d>(g.data(), count));
                for (std::size_t k = 0; k < count; ++k)
                    if (firstOrderDistance(v[k], g[k]) <= near) mask[begin + k] |= 1u << s;
            }
        }
    });
    return mask;
}

/// Largest |distance| to the solid over a barycentric grid on each of @a triangles (spacing at
/// most @a spacing, at least two steps per edge).
std::vector<double> sampleTriangles(const SurfaceList& list, const TriangleMesh& mesh,
                                    const std::vector<std::uint32_t>& triangles, double spacing,
                                    const std::function<void()>& check = {})
{
    std::vector<Vec3d> points;
    std::vector<std::size_t> first(triangles.size() + 1, 0);
    for (std::size_t k = 0; k < triangles.size(); ++k) {
        const openvdb::Vec3I& t = mesh.triangles[triangles[k]];
        const Vec3d a = toDouble(mesh.points[t[0]]), e1 = toDouble(mesh.points[t[1]]) - a,
                    e2 = toDouble(mesh.points[t[2]]) - a;
        const double longest = std::max({e1.length(), e2.length(), (e2 - e1).length()});
        const int steps = std::max(2, int(std::ceil(longest / spacing)));
        first[k] = points.size();
        for (int i = 0; i <= steps; ++i)
            for (int j = 0; i + j <= steps; ++j)
                points.push_back(a + (double(i) / steps) * e1 + (double(j) / steps) * e2);
    }
    first[triangles.size()] = points.size();
    std::vector<double> distance;
    solidDistance(list, points, distance, nullptr, check);
    std::vector<double> worst(triangles.size(), 0.0);
    for (std::size_t k = 0; k < triangles.size(); ++k)
        for (std::size_t i = first[k]; i < first[k + 1]; ++i) worst[k] = std::max(worst[k], std::abs(distance[i]));
    return worst;
}

struct Edge {
    std::uint32_t p, q;
    bool operator<(const Edge& o) const { return p < o.p || (p == o.p && q < o.q); }
    bool operator==(const Edge& o) const { return p == o.p && q == o.q; }
};

/// Unit normals of the surfaces a point lies on (three at most).
struct Normals {
    std::array<Vec3d, 3> n;
    int count = 0;
};

/// Whether a piece with normal @a n faces out at a corner with normals @a c: along at least one
/// of the surfaces there.
bool facesOut(const Vec3d& n, const Normals& c)
{
    for (int i = 0; i < c.count; ++i)
        if (n.dot(c.n[i]) > 0.0) return true;
    return false;
}

/// Where a new point starts from and which surfaces it goes onto at first (0: the one farthest
/// out at the start).
struct Start {
    Vec3d point;
    std::uint32_t active = 0;
};

/// Puts a point on the solid's surface near each start: Newton on the surfaces of an active set
/// (the given ones, else the one farthest out; then any the converged point still lies outside
/// of, three at most), least-norm steps. @a found says whether it converged within o.maxMove of
/// its start; @a target is the point rounded to float, @a normals the unit gradients there of
/// the surfaces it is on.
void placeOnSurface(const SurfaceList& list, const std::vector<Start>& starts, const RefinementOptions& o,
                    std::vector<Vec3d>& target, std::vector<std::uint8_t>& found, std::vector<Normals>& normals,
                    const std::function<void()>& check = {})
{
    const std::size_t m = starts.size();
    target.assign(m, Vec3d(0.0));
    found.assign(m, 0);
    normals.assign(m, Normals{});
    const int numSurfaces = list.size();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunkCount(m), 1), [&](const auto& range) {
        std::vector<Vec3d> x, batch;
        std::vector<std::uint32_t> active, open;
        std::vector<std::vector<double>> values(numSurfaces);
        std::vector<std::vector<Vec3d>> grads(numSurfaces);
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            if (check) check();  // per batch: a range may hold many
            const std::size_t begin = c * kBatchSize, count = std::min(kBatchSize, m - begin);
            x.resize(count);
            active.resize(count);
            open.clear();
            for (std::size_t k = 0; k < count; ++k) {
                x[k] = starts[begin + k].point;
                active[k] = starts[begin + k].active;
                open.push_back(std::uint32_t(k));
            }
            for (int iteration = 0; iteration <= o.maxIterations && !open.empty(); ++iteration) {
                batch.resize(open.size());
                for (std::size_t j = 0; j < open.size(); ++j) batch[j] = x[open[j]];
                for (int s = 0; s < numSurfaces; ++s) {
                    values[s].resize(batch.size());
                    grads[s].resize(batch.size());
                    list.evaluate(s, batch, values[s], grads[s]);
                }
                std::size_t kept = 0;
                for (std::size_t j = 0; j < open.size(); ++j) {
                    const std::uint32_t k = open[j];
                    const Vec3d& start = starts[begin + k].point;
                    std::array<double, 32> d;
                    for (int s = 0; s < numSurfaces; ++s) {
                        const double length = grads[s][j].length();
                        d[s] = length > 0.0 ? values[s][j] / length : 0.0;
                    }
                    if (active[k] == 0)
                        active[k] = 1u << int(std::max_element(d.begin(), d.begin() + numSurfaces) - d.begin());
                    // Whether the active surfaces are reached, and the farthest out of the others.
                    bool onActive = true;
                    int farthest = -1;
                    double most = -std::numeric_limits<double>::infinity();
                    for (int s = 0; s < numSurfaces; ++s) {
                        if (active[k] >> s & 1u)
                            onActive = onActive && std::abs(d[s]) <= o.tolerance;
                        else if (d[s] > most) {
                            most = d[s];
                            farthest = s;
                        }
                    }
                    if (onActive) {
                        if (!(most > o.tolerance)) {
                            found[begin + k] = (x[k] - start).length() <= o.maxMove;
                            Normals& n = normals[begin + k];
                            for (int s = 0; s < numSurfaces && n.count < 3; ++s)
                                if (active[k] >> s & 1u) {
                                    const double length = grads[s][j].length();
                                    n.n[n.count++] = length > 0.0 ? grads[s][j] / length : Vec3d(0.0);
                                }
                            continue;
                        }
                        // Converged, but outside another surface: the point belongs on both.
                        if (std::popcount(active[k]) == 3) continue;
                        active[k] |= 1u << farthest;
                    }
                    if (iteration == o.maxIterations) continue;
                    std::array<double, 3> res{};
                    std::array<Vec3d, 3> jac;
                    int rows = 0;
                    for (int s = 0; s < numSurfaces; ++s)
                        if (active[k] >> s & 1u) {
                            res[rows] = values[s][j];
                            jac[rows] = grads[s][j];
                            ++rows;
                        }
                    std::array<std::array<double, 3>, 3> a{};
                    for (int r = 0; r < rows; ++r)
                        for (int q = 0; q < rows; ++q) a[r][q] = jac[r].dot(jac[q]);
                    std::array<double, 3> y{};
                    if (!solveSmall(rows, a, res, y)) continue;
                    for (int r = 0; r < rows; ++r) x[k] -= y[r] * jac[r];
                    if (!((x[k] - start).length() <= 2.0 * o.maxMove)) continue;  // wandered off
                    open[kept++] = k;
                }
                open.resize(kept);
            }
            for (std::size_t k = 0; k < count; ++k) target[begin + k] = asStored(x[k]);
        }
    });
}

/// The unit normals at @a points of the surfaces each lies on (@a mask), or of the one farthest
/// out where it lies on none.
std::vector<Normals> normalsAt(const SurfaceList& list, const std::vector<Vec3d>& points,
                               const std::vector<std::uint32_t>& mask, const std::function<void()>& check = {})
{
    const std::size_t n = points.size();
    std::vector<Normals> out(n);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunkCount(n), 1), [&](const auto& range) {
        std::array<double, kBatchSize> v;
        std::array<Vec3d, kBatchSize> g;
        std::array<double, kBatchSize> most;
        std::array<Vec3d, kBatchSize> mostNormal;
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            if (check) check();  // per batch: a range may hold many
            const std::size_t begin = c * kBatchSize, count = std::min(kBatchSize, n - begin);
            for (int s = 0; s < list.size(); ++s) {
                list.evaluate(s, std::span<const Vec3d>(points.data() + begin, count),
                              std::span<double>(v.data(), count), std::span<Vec3d>(g.data(), count));
                for (std::size_t k = 0; k < count; ++k) {
                    const double length = g[k].length();
                    const Vec3d unit = length > 0.0 ? g[k] / length : Vec3d(0.0);
                    const double d = length > 0.0 ? v[k] / length : 0.0;
                    if (s == 0 || d > most[k]) {
                        most[k] = d;
                        mostNormal[k] = unit;
                    }
                    Normals& o = out[begin + k];
                    if ((mask[begin + k] >> s & 1u) && o.count < 3) o.n[o.count++] = unit;
                }
            }
            for (std::size_t k = 0; k < count; ++k)
                if (out[begin + k].count == 0) out[begin + k] = {{mostNormal[k]}, 1};
        }
    });
    return out;
}

using Piece = SplitPiece;

/// Triangles of @a mesh (not flagged in @a skip) with a corner in a cell (of edge @a cell) next to a
/// cell holding one of @a seeds.
std::vector<std::uint32_t> trianglesNear(const TriangleMesh& mesh, const std::vector<Vec3d>& points,
                                         const std::vector<Vec3d>& seeds, double cell,
                                         const std::vector<std::uint8_t>& skip)
{
    auto key = [&](const Vec3d& p, int dx, int dy, int dz) {
        const auto c = [&](double v, int d) {
            return std::uint64_t(std::int64_t(std::floor(v / cell)) + d + (1 << 20)) & 0x1fffff;
        };
        return c(p.x(), dx) << 42 | c(p.y(), dy) << 21 | c(p.z(), dz);
    };
    std::vector<std::uint64_t> cells;
    for (const Vec3d& p : seeds)
        for (int dx = -1; dx <= 1; ++dx)
            for (int dy = -1; dy <= 1; ++dy)
                for (int dz = -1; dz <= 1; ++dz) cells.push_back(key(p, dx, dy, dz));
    std::sort(cells.begin(), cells.end());
    cells.erase(std::unique(cells.begin(), cells.end()), cells.end());
    // Each vertex looked up once (in parallel; flags only, so the same for any thread count),
    // not once per triangle around it.
    std::vector<std::uint8_t> marked(points.size(), 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, points.size(), 1 << 14), [&](const auto& r) {
        for (std::size_t v = r.begin(); v != r.end(); ++v)
            marked[v] = std::binary_search(cells.begin(), cells.end(), key(points[v], 0, 0, 0));
    });
    std::vector<std::uint32_t> out;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        if (skip[t]) continue;
        const openvdb::Vec3I& tri = mesh.triangles[t];
        if (marked[tri[0]] || marked[tri[1]] || marked[tri[2]]) out.push_back(std::uint32_t(t));
    }
    return out;
}

/// Moves the corners of the flagged triangles that lie on no surface (the projection held them
/// back) onto the solid's surface (onto a crease when they lie outside a second surface), where
/// every triangle around them keeps its area, faces out along a surface at each corner, and
/// crosses no triangle near it; moves that fail are undone, in rounds.
void moveOntoSurface(const SurfaceList& list, TriangleMesh& mesh, std::vector<Vec3d>& points,
                     std::vector<std::uint32_t>& mask, const std::vector<std::uint8_t>& flagged,
                     const RefinementOptions& o, double near, RefinementStats& stats)
{
    std::vector<std::int64_t> slot(points.size(), -1);
    std::vector<std::uint32_t> movers;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
        if (flagged[t])
            for (int i = 0; i < 3; ++i) {
                const std::uint32_t v = mesh.triangles[t][i];
                if (mask[v] == 0 && slot[v] < 0) {
                    slot[v] = std::int64_t(movers.size());
                    movers.push_back(v);
                }
            }
    if (movers.empty()) return;
    std::vector<Start> starts;
    for (std::uint32_t v : movers) starts.push_back({points[v], 0u});
    std::vector<Vec3d> placed;
    std::vector<std::uint8_t> moved;
    std::vector<Normals> placedNormals;
    RefinementOptions within = o;
    within.maxMove = 0.5 * o.maxMove;
    placeOnSurface(list, starts, within, placed, moved, placedNormals);
    // The triangles around the movers, and the surfaces' normals at their corners.
    std::vector<std::uint32_t> around;
    std::vector<std::uint8_t> isAround(mesh.triangles.size(), 0);
    std::vector<std::int64_t> cornerSlot(points.size(), -1);
    std::vector<Vec3d> corners;
    std::vector<std::uint32_t> cornerMask;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        if (slot[tri[0]] < 0 && slot[tri[1]] < 0 && slot[tri[2]] < 0) continue;
        around.push_back(std::uint32_t(t));
        isAround[t] = 1;
        for (int i = 0; i < 3; ++i)
            if (cornerSlot[tri[i]] < 0) {
                cornerSlot[tri[i]] = std::int64_t(corners.size());
                corners.push_back(points[tri[i]]);
                cornerMask.push_back(mask[tri[i]]);
            }
    }
    const std::vector<Normals> cornerNormals = normalsAt(list, corners, cornerMask);
    // moved: 2 all the way, 1 half way (as the projection holds back), 0 not at all.
    for (std::uint8_t& level : moved) level = level ? 2 : 0;
    auto position = [&](std::uint32_t v) {
        if (slot[v] < 0) return points[v];
        const std::size_t k = std::size_t(slot[v]);
        return moved[k] == 2 ? placed[k] : moved[k] == 1 ? 0.5 * (points[v] + placed[k]) : points[v];
    };
    auto normalsOf = [&](std::uint32_t v) -> const Normals& {
        return slot[v] >= 0 && moved[std::size_t(slot[v])] == 2 ? placedNormals[std::size_t(slot[v])]
                                                                : cornerNormals[std::size_t(cornerSlot[v])];
    };
    auto undo = [&](const openvdb::Vec3I& tri) {
        bool any = false;
        for (int i = 0; i < 3; ++i)
            if (slot[tri[i]] >= 0 && moved[std::size_t(slot[tri[i]])]) {
                --moved[std::size_t(slot[tri[i]])];
                any = true;
            }
        return any;
    };
    std::vector<Vec3d> seeds;
    for (std::size_t k = 0; k < movers.size(); ++k) seeds.push_back(placed[k]);
    for (const Vec3d& c : corners) seeds.push_back(c);
    const std::vector<std::uint32_t> others = trianglesNear(mesh, points, seeds, std::max(o.maxMove, 1e-6), isAround);
    for (;;) {
        bool undone = false;
        for (std::uint32_t t : around) {
            const openvdb::Vec3I& tri = mesh.triangles[t];
            const Vec3d a0 = points[tri[0]], b0 = points[tri[1]], c0 = points[tri[2]];
            const Vec3d a = position(tri[0]), b = position(tri[1]), c = position(tri[2]);
            const Vec3d n0 = (b0 - a0).cross(c0 - a0), n1 = (b - a).cross(c - a);
            bool good = n1.length() > 1e-6 * n0.length() && toFloat(a) != toFloat(b) && toFloat(b) != toFloat(c) &&
                        toFloat(c) != toFloat(a);
            // A triangle that faced in at a corner already (a chamfer) need only not turn over.
            bool wasGood = true;
            for (int i = 0; i < 3; ++i)
                wasGood = wasGood && facesOut(n0, cornerNormals[std::size_t(cornerSlot[tri[i]])]);
            if (wasGood)
                for (int i = 0; i < 3 && good; ++i) good = facesOut(n1, normalsOf(tri[i]));
            else
                good = good && n1.dot(n0) > 0.0;
            if (!good) undone = undo(tri) || undone;
        }
        if (undone) continue;
        TriangleMesh local;
        local.points = mesh.points;
        for (std::size_t k = 0; k < movers.size(); ++k)
            if (moved[k]) local.points[movers[k]] = toFloat(position(movers[k]));
        for (std::uint32_t t : around) local.triangles.push_back(mesh.triangles[t]);
        for (std::uint32_t t : others) local.triangles.push_back(mesh.triangles[t]);
        std::vector<std::uint8_t> tested(local.triangles.size(), 0);
        std::fill(tested.begin(), tested.begin() + std::ptrdiff_t(around.size()), 1);
        for (const auto& [x, y] : selfIntersections(local, tested))
            for (const std::uint32_t t : {x, y})
                if (t < around.size()) undone = undo(local.triangles[t]) || undone;
        if (!undone) break;
    }
    std::vector<std::uint32_t> done;
    for (std::size_t k = 0; k < movers.size(); ++k)
        if (moved[k]) {
            const Vec3d p = asStored(position(movers[k]));
            points[movers[k]] = p;
            mesh.points[movers[k]] = toFloat(p);
            done.push_back(movers[k]);
            ++stats.moved;
        }
    std::vector<Vec3d> at;
    for (std::uint32_t v : done) at.push_back(points[v]);
    const std::vector<std::uint32_t> newMask = surfaceMasks(list, at, near);
    for (std::size_t k = 0; k < done.size(); ++k) mask[done[k]] = newMask[k];
}

}  // namespace

RefinementStats refineCreases(TriangleMesh& mesh, const CreaseSurfaces& surfaces, const RefinementOptions& options,
                              const ProgressFn& progress)
{
    RefinementStats stats;
    // Each round reports its share at its steps (the same fraction again still checks the cancel).
    PhaseProgress phases(progress);
    const std::function<void()> check = phases.checker();
    const ProgressFn checkFraction = [&](double) { phases.check(); };
    const SurfaceList list(surfaces, options.level);
    if (mesh.triangles.empty() || list.size() < 1 || list.size() > 32) return stats;
    std::vector<Vec3d> points(mesh.points.size());
    for (std::size_t v = 0; v < points.size(); ++v) points[v] = toDouble(mesh.points[v]);

    // Triangles whose corners all lie on one and the same surface are not sampled.
    const double near = 1e-2 * options.threshold;
    std::vector<std::uint32_t> mask = surfaceMasks(list, points, near);
    const double unknown = -1.0;
    std::vector<double> worst(mesh.triangles.size(), unknown);
    std::vector<std::uint8_t> candidate(mesh.triangles.size(), 0), attempts(mesh.triangles.size(), 0);
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        const std::uint32_t m = mask[tri[0]];
        candidate[t] = !(m == mask[tri[1]] && m == mask[tri[2]] && std::popcount(m) == 1);
    }

    {
        std::vector<std::uint32_t> checked;
        for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
            if (candidate[t]) checked.push_back(std::uint32_t(t));
        const std::vector<double> sampled = sampleTriangles(list, mesh, checked, options.spacing);
        stats.checked = checked.size();
        for (double w : sampled) {
            stats.over += w > options.threshold;
            stats.maxBefore = std::max(stats.maxBefore, w);
        }
    }
    check();
    moveOntoSurface(list, mesh, points, mask, candidate, options, near, stats);

    for (int round = 0;; ++round) {
        phases.begin(double(round + 1) / double(options.rounds + 2));
        std::vector<std::uint32_t> checked;
        for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
            if (candidate[t]) checked.push_back(std::uint32_t(t));
        const std::vector<double> sampled = sampleTriangles(list, mesh, checked, options.spacing, check);
        check();
        std::vector<std::uint32_t> bad;
        for (std::size_t k = 0; k < checked.size(); ++k) {
            worst[checked[k]] = sampled[k];
            if (sampled[k] > options.threshold) bad.push_back(checked[k]);
        }
        // Bad triangles that tried all three edges are left as they are.
        std::vector<Edge> edges;
        for (std::uint32_t t : bad) {
            if (attempts[t] >= 4) continue;
            const openvdb::Vec3I& tri = mesh.triangles[t];
            // First every edge across a crease (ends on no common surface: splitting both of a
            // chamfer's separates its corner on one surface from the others), else the longest;
            // once that was dropped, each edge alone, longest first.
            std::array<std::pair<double, int>, 3> byLength;
            std::array<bool, 3> across;
            for (int i = 0; i < 3; ++i) {
                const std::uint32_t a = mask[tri[i]], b = mask[tri[(i + 1) % 3]];
                across[i] = a != 0 && b != 0 && (a & b) == 0;
                byLength[i] = {-(points[tri[(i + 1) % 3]] - points[tri[i]]).lengthSqr(), i};
            }
            std::sort(byLength.begin(), byLength.end());
            auto add = [&](int i) {
                const std::uint32_t p = tri[i], q = tri[(i + 1) % 3];
                edges.push_back({std::min(p, q), std::max(p, q)});
            };
            if (attempts[t] == 0 && (across[0] || across[1] || across[2])) {
                for (int i = 0; i < 3; ++i)
                    if (across[i]) add(i);
            } else {
                add(byLength[std::max(0, attempts[t] - 1)].second);
            }
        }
        std::fill(candidate.begin(), candidate.end(), 0);
        for (std::uint32_t t : bad) candidate[t] = 1;
        if (edges.empty() || round == options.rounds) break;
        ++stats.rounds;
        std::sort(edges.begin(), edges.end());
        edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
        const std::size_t m = edges.size();

        // Where each new point may go: onto the surface from the edge's midpoint; for an edge
        // from one surface to another, onto their crease from the midpoint, then from either end
        // (where the crease runs past a corner of the triangle, the point nearest the midpoint
        // can lie beyond it, and the one below an end is the right one).
        std::vector<Start> starts;
        std::vector<std::size_t> firstStart(m + 1, 0);
        for (std::size_t e = 0; e < m; ++e) {
            firstStart[e] = starts.size();
            const std::uint32_t p = edges[e].p, q = edges[e].q;
            const std::uint32_t both = mask[p] | mask[q];
            const bool across = mask[p] != 0 && mask[q] != 0 && (mask[p] & mask[q]) == 0 && std::popcount(both) <= 3;
            starts.push_back({0.5 * (points[p] + points[q]), across ? both : 0u});
            if (across) {
                starts.push_back({points[p], both});
                starts.push_back({points[q], both});
            }
        }
        firstStart[m] = starts.size();
        std::vector<Vec3d> placed;
        std::vector<std::uint8_t> found;
        std::vector<Normals> placedNormals;
        placeOnSurface(list, starts, options, placed, found, placedNormals, check);
        check();

        // The triangles around the split edges, with their edges' indices (-1: not split).
        auto edgeIndex = [&](std::uint32_t a, std::uint32_t b) -> std::ptrdiff_t {
            const Edge e{std::min(a, b), std::max(a, b)};
            const auto it = std::lower_bound(edges.begin(), edges.end(), e);
            return it != edges.end() && *it == e ? it - edges.begin() : -1;
        };
        std::vector<std::uint32_t> touched;
        std::vector<std::array<std::ptrdiff_t, 3>> touchedEdges;
        {
            std::vector<std::uint8_t> endpoint(points.size(), 0);
            for (const Edge& e : edges) endpoint[e.p] = endpoint[e.q] = 1;
            for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
                const openvdb::Vec3I& tri = mesh.triangles[t];
                if (!endpoint[tri[0]] && !endpoint[tri[1]] && !endpoint[tri[2]]) continue;
                std::array<std::ptrdiff_t, 3> e;
                bool any = false;
                for (int i = 0; i < 3; ++i) {
                    e[i] = edgeIndex(tri[i], tri[(i + 1) % 3]);
                    any = any || e[i] >= 0;
                }
                if (any) {
                    touched.push_back(std::uint32_t(t));
                    touchedEdges.push_back(e);
                }
            }
        }
        // The surfaces' normals at the corners of those triangles.
        std::vector<std::int64_t> slot(points.size(), -1);
        std::vector<Normals> cornerNormals;
        {
            std::vector<Vec3d> corners;
            std::vector<std::uint32_t> cornerMask;
            for (std::uint32_t t : touched)
                for (int i = 0; i < 3; ++i) {
                    const std::uint32_t v = mesh.triangles[t][i];
                    if (slot[v] >= 0) continue;
                    slot[v] = std::int64_t(corners.size());
                    corners.push_back(points[v]);
                    cornerMask.push_back(mask[v]);
                }
            cornerNormals = normalsAt(list, corners, cornerMask, check);
        }
        check();

        // Each edge takes the first of its points whose split alone leaves every piece of the
        // triangles on either side with area and facing out along a surface at each corner.
        std::vector<Vec3d> target(m, Vec3d(0.0));
        std::vector<Normals> targetNormals(m);
        std::vector<std::uint8_t> active(m, 0);
        auto splits = [&](std::size_t k) { return splitEdges(touchedEdges[k], active); };
        auto positions = [&](std::size_t k) {
            return splitPositions(mesh.triangles[touched[k]], touchedEdges[k], points, active, target);
        };
        // Whether triangle k split on @a s (points as in positions(k)) gives good pieces.
        auto piecesGood = [&](std::size_t k, const std::array<bool, 3>& s) {
            const std::array<Vec3d, 6> p = positions(k);
            const openvdb::Vec3I& tri = mesh.triangles[touched[k]];
            std::array<const Normals*, 6> normal;
            for (int i = 0; i < 3; ++i) {
                normal[i] = &cornerNormals[std::size_t(slot[tri[i]])];
                normal[3 + i] = s[i] ? &targetNormals[std::size_t(touchedEdges[k][i])] : nullptr;
            }
            const Vec3d n0 = (p[1] - p[0]).cross(p[2] - p[0]);
            for (const Piece& piece : splitPieces(p, s)) {
                const Vec3d n1 = (p[piece[1]] - p[piece[0]]).cross(p[piece[2]] - p[piece[0]]);
                if (!(n1.length() > 1e-6 * n0.length())) return false;
                for (int c : piece)
                    if (!facesOut(n1, *normal[c])) return false;
            }
            return true;
        };
        {
            // Each edge starts with its first point found; then, in a few passes, each takes the
            // first of its points that leaves the triangles on either side good with their
            // other splits as they stand.
            std::vector<std::vector<std::uint32_t>> sides(m);
            for (std::size_t k = 0; k < touched.size(); ++k)
                for (int i = 0; i < 3; ++i)
                    if (touchedEdges[k][i] >= 0) sides[std::size_t(touchedEdges[k][i])].push_back(std::uint32_t(k));
            std::vector<std::size_t> choice(m, 0);
            for (std::size_t e = 0; e < m; ++e)
                for (std::size_t j = firstStart[e]; j < firstStart[e + 1]; ++j)
                    if (found[j]) {
                        choice[e] = j;
                        target[e] = placed[j];
                        targetNormals[e] = placedNormals[j];
                        active[e] = 1;
                        break;
                    }
            for (int pass = 0; pass < 3; ++pass) {
                bool changed = false;
                for (std::size_t e = 0; e < m; ++e) {
                    if (!active[e]) continue;
                    for (std::size_t j = firstStart[e]; j < firstStart[e + 1]; ++j) {
                        if (!found[j]) continue;
                        target[e] = placed[j];
                        targetNormals[e] = placedNormals[j];
                        bool good = true;
                        for (std::uint32_t k : sides[e]) good = good && piecesGood(k, splits(k));
                        if (good) {
                            changed = changed || j != choice[e];
                            choice[e] = j;
                            break;
                        }
                    }
                    target[e] = placed[choice[e]];
                    targetNormals[e] = placedNormals[choice[e]];
                }
                if (!changed) break;
            }
        }
        auto drop = [&](std::size_t k) {
            bool dropped = false;
            for (int i = 0; i < 3; ++i)
                if (touchedEdges[k][i] >= 0 && active[touchedEdges[k][i]]) {
                    active[touchedEdges[k][i]] = 0;
                    dropped = true;
                }
            return dropped;
        };
        // With several split edges a triangle's pieces differ: the same test, dropping the
        // splits of a triangle that fails it (which changes its neighbours), in rounds.
        auto dropTurned = [&] {
            for (;;) {
                bool dropped = false;
                for (std::size_t k = 0; k < touched.size(); ++k) {
                    const std::array<bool, 3> s = splits(k);
                    if ((s[0] || s[1] || s[2]) && !piecesGood(k, s)) dropped = drop(k) || dropped;
                }
                if (!dropped) break;
            }
        };

        // No piece may cross a triangle around it (the pieces of the split parents and the
        // triangles sharing a corner with them); a parent whose pieces cross drops its splits.
        // Around: every triangle with a corner in a cell (of the move limit) next to one holding a
        // corner or new point of the split triangles.
        std::vector<std::uint32_t> around;
        {
            std::vector<Vec3d> seeds;
            std::vector<std::uint8_t> skip(mesh.triangles.size(), 0);
            for (std::uint32_t t : touched) {
                skip[t] = 1;
                for (int i = 0; i < 3; ++i) seeds.push_back(points[mesh.triangles[t][i]]);
            }
            for (std::size_t e = 0; e < m; ++e)
                for (std::size_t j = firstStart[e]; j < firstStart[e + 1]; ++j)
                    if (found[j]) seeds.push_back(placed[j]);
            around = trianglesNear(mesh, points, seeds, std::max(options.maxMove, 1e-6), skip);
        }
        for (;;) {
            check();
            dropTurned();
            TriangleMesh local;
            local.points = mesh.points;
            std::vector<std::uint32_t> newIndex(m, 0);
            for (std::size_t e = 0; e < m; ++e)
                if (active[e]) {
                    newIndex[e] = std::uint32_t(local.points.size());
                    local.points.push_back(toFloat(target[e]));
                }
            std::vector<std::int64_t> parent;
            for (std::size_t k = 0; k < touched.size(); ++k) {
                const std::array<bool, 3> s = splits(k);
                const openvdb::Vec3I& tri = mesh.triangles[touched[k]];
                if (!s[0] && !s[1] && !s[2]) {
                    // Left whole: one of the triangles around.
                    local.triangles.push_back(tri);
                    parent.push_back(-1);
                    continue;
                }
                std::array<std::uint32_t, 6> index{tri[0], tri[1], tri[2], 0, 0, 0};
                for (int i = 0; i < 3; ++i)
                    if (s[i]) index[3 + i] = newIndex[touchedEdges[k][i]];
                for (const Piece& piece : splitPieces(positions(k), s)) {
                    local.triangles.emplace_back(index[piece[0]], index[piece[1]], index[piece[2]]);
                    parent.push_back(std::int64_t(k));
                }
            }
            if (std::none_of(parent.begin(), parent.end(), [](std::int64_t k) { return k >= 0; })) break;
            for (std::uint32_t t : around) {
                local.triangles.push_back(mesh.triangles[t]);
                parent.push_back(-1);
            }
            bool dropped = false;
            // Pieces without area as stored (two points rounded to one position).
            for (std::size_t t = 0; t < local.triangles.size(); ++t) {
                if (parent[t] < 0) continue;
                const openvdb::Vec3I& tri = local.triangles[t];
                const Vec3d a = toDouble(local.points[tri[0]]);
                if ((toDouble(local.points[tri[1]]) - a).cross(toDouble(local.points[tri[2]]) - a) == Vec3d(0.0))
                    dropped = drop(std::size_t(parent[t])) || dropped;
            }
            std::vector<std::uint8_t> tested(parent.size(), 0);
            for (std::size_t t = 0; t < parent.size(); ++t) tested[t] = parent[t] >= 0;
            for (const auto& [x, y] : selfIntersections(local, tested, nullptr, checkFraction))
                for (const std::int64_t k : {parent[x], parent[y]})
                    if (k >= 0) dropped = drop(std::size_t(k)) || dropped;
            if (!dropped) break;
        }

        // New vertices in edge order; each split parent replaced in place by its pieces.
        std::vector<std::uint32_t> newVertex(m, 0);
        std::size_t madeHere = 0;
        for (std::size_t e = 0; e < m; ++e) {
            if (!active[e]) continue;
            newVertex[e] = std::uint32_t(mesh.points.size());
            mesh.points.push_back(toFloat(target[e]));
            points.push_back(target[e]);
            ++madeHere;
        }
        stats.split += madeHere;
        stats.dropped += m - madeHere;
        // A bad triangle whose chosen edge was not split tries its next edge in the next round.
        for (std::uint32_t t : bad) {
            const auto it = std::lower_bound(touched.begin(), touched.end(), t);
            if (it == touched.end() || *it != t) continue;
            const std::array<bool, 3> s = splits(std::size_t(it - touched.begin()));
            if (!s[0] && !s[1] && !s[2]) ++attempts[t];
        }
        if (madeHere == 0) continue;
        std::vector<std::uint32_t> newMask =
            surfaceMasks(list, std::vector<Vec3d>(points.end() - std::ptrdiff_t(madeHere), points.end()), near);
        mask.insert(mask.end(), newMask.begin(), newMask.end());
        std::vector<openvdb::Vec3I> triangles;
        std::vector<double> nextWorst;
        std::vector<std::uint8_t> nextCandidate, nextAttempts;
        triangles.reserve(mesh.triangles.size() + 3 * madeHere);
        std::size_t next = 0;
        for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
            const openvdb::Vec3I& tri = mesh.triangles[t];
            SplitPieces pieces;
            std::array<bool, 3> s{false, false, false};
            std::array<std::uint32_t, 6> index{tri[0], tri[1], tri[2], 0, 0, 0};
            if (next < touched.size() && touched[next] == t) {
                s = splits(next);
                for (int i = 0; i < 3; ++i)
                    if (s[i]) index[3 + i] = newVertex[touchedEdges[next][i]];
                pieces = splitPieces(positions(next), s);
                ++next;
            }
            if (pieces.empty()) {
                triangles.push_back(tri);
                nextWorst.push_back(worst[t]);
                nextCandidate.push_back(candidate[t]);
                nextAttempts.push_back(attempts[t]);
                continue;
            }
            for (const Piece& piece : pieces) {
                triangles.emplace_back(index[piece[0]], index[piece[1]], index[piece[2]]);
                nextWorst.push_back(unknown);
                nextCandidate.push_back(1);
                nextAttempts.push_back(0);
            }
        }
        mesh.triangles = std::move(triangles);
        worst = std::move(nextWorst);
        candidate = std::move(nextCandidate);
        attempts = std::move(nextAttempts);
    }
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        stats.maxAfter = std::max(stats.maxAfter, worst[t]);
        stats.remaining += worst[t] > options.threshold;
    }
    if (progress) progress(1.0);
    return stats;
}

}  // namespace voxlat
