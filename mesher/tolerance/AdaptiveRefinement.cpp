#include "mesher/tolerance/AdaptiveRefinement.h"

#include "fields/shapes/SurfaceDistance.h"
#include "mesher/checks/TriangleCheck.h"
#include "mesher/tolerance/SplitTriangle.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <numbers>
#include <span>
#include <vector>

namespace voxlat {

namespace {

using EdgeKey = std::uint64_t;

EdgeKey edgeKey(std::uint32_t a, std::uint32_t b)
{
    return std::uint64_t(std::min(a, b)) << 32 | std::max(a, b);
}

/// Index of @a key in the sorted @a keys, or -1.
std::ptrdiff_t find(const std::vector<EdgeKey>& keys, EdgeKey key)
{
    const auto it = std::lower_bound(keys.begin(), keys.end(), key);
    return it != keys.end() && *it == key ? it - keys.begin() : -1;
}

/// Sorted, without repeats (the same for any thread count: equal keys are equal).
void sortUnique(std::vector<EdgeKey>& keys)
{
    tbb::parallel_sort(keys.begin(), keys.end());
    keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
}

/// The indices i < @a n for which @a keep(i) holds, ascending: found in parallel in fixed blocks,
/// joined in order (the same list for any thread count). For scans of every triangle or point
/// that pick a few.
template <typename Keep>
void indicesWhere(std::size_t n, Keep&& keep, std::vector<std::uint32_t>& indices)
{
    constexpr std::size_t kBlock = 1 << 14;
    std::vector<std::vector<std::uint32_t>> found((n + kBlock - 1) / kBlock);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, found.size(), 1), [&](const auto& r) {
        for (std::size_t b = r.begin(); b != r.end(); ++b)
            for (std::size_t i = b * kBlock; i < std::min(n, (b + 1) * kBlock); ++i)
                if (keep(i)) found[b].push_back(std::uint32_t(i));
    });
    indices.clear();
    for (const auto& f : found) indices.insert(indices.end(), f.begin(), f.end());
}

template <typename Keep>
std::vector<std::uint32_t> indicesWhere(std::size_t n, Keep&& keep)
{
    std::vector<std::uint32_t> indices;
    indicesWhere(n, keep, indices);
    return indices;
}

/// Sorted edge keys indexed by their lower vertex: an edge is found in the few keys of its lower
/// end (a binary search over W9's 300 000 split edges took 0.05 s a round).
class EdgeIndex {
public:
    /// Sorts @a keys (of edges between @a numPoints points) and drops their repeats by their lower
    /// vertex, a counting sort (W9's 190 000 split edges: 1.5 ms against 4 ms for a parallel
    /// sort), and indexes them by it.
    void sortAndBuild(std::vector<EdgeKey>& keys, std::size_t numPoints)
    {
        mKeys = &keys;
        mFirst.assign(numPoints + 1, 0);
        for (EdgeKey e : keys) ++mFirst[(e >> 32) + 1];
        for (std::size_t v = 0; v < numPoints; ++v) mFirst[v + 1] += mFirst[v];
        mSorted.resize(keys.size());
        // Each row's start is its cursor, left at the next row's start: shifted back after.
        for (EdgeKey e : keys) mSorted[mFirst[e >> 32]++] = e;
        std::copy_backward(mFirst.begin(), mFirst.end() - 1, mFirst.end());
        mFirst[0] = 0;
        // Each row (a vertex's few edges) sorted and its repeats dropped, packed from the front.
        std::uint32_t packed = 0;
        for (std::size_t v = 0; v < numPoints; ++v) {
            const std::uint32_t begin = mFirst[v], end = mFirst[v + 1];
            mFirst[v] = packed;
            for (std::uint32_t i = begin + 1; i < end; ++i)
                for (std::uint32_t j = i; j > begin && mSorted[j - 1] > mSorted[j]; --j)
                    std::swap(mSorted[j - 1], mSorted[j]);
            for (std::uint32_t i = begin; i < end; ++i)
                if (i == begin || mSorted[i] != mSorted[i - 1]) mSorted[packed++] = mSorted[i];
        }
        mFirst[numPoints] = packed;
        mSorted.resize(packed);
        keys.swap(mSorted);
    }

    /// Index of edge (a, b) in the keys, or -1.
    std::ptrdiff_t find(std::uint32_t a, std::uint32_t b) const
    {
        const EdgeKey key = edgeKey(a, b);
        const std::uint32_t low = std::min(a, b);
        for (std::uint32_t j = mFirst[low]; j < mFirst[low + 1]; ++j)
            if ((*mKeys)[j] == key) return j;
        return -1;
    }

private:
    const std::vector<EdgeKey>* mKeys = nullptr;
    std::vector<std::uint32_t> mFirst;
    std::vector<EdgeKey> mSorted;  // sortAndBuild()'s rows, kept for its next call
};

/// The field the distances are taken against.
struct Solid {
    const FieldNode& field;
    double level;

    /// Values minus the level and gradients of the field at @a points (at most kBatchSize), on
    /// this thread.
    void evaluateBatch(std::span<const Vec3d> points, std::span<double> values, std::span<Vec3d> gradients) const
    {
        field.gradients(points, values, gradients);
        for (double& v : values) v -= level;
    }

    /// The same at any number of points, in fixed batches in parallel.
    void evaluate(const std::vector<Vec3d>& points, std::vector<double>& values, std::vector<Vec3d>& gradients) const
    {
        const std::size_t n = points.size();
        values.resize(n);
        gradients.resize(n);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, (n + kBatchSize - 1) / kBatchSize, 1), [&](const auto& r) {
            for (std::size_t c = r.begin(); c != r.end(); ++c) {
                const std::size_t begin = c * kBatchSize, count = std::min(kBatchSize, n - begin);
                evaluateBatch(std::span<const Vec3d>(points.data() + begin, count),
                              std::span<double>(values.data() + begin, count),
                              std::span<Vec3d>(gradients.data() + begin, count));
            }
        });
    }

    /// The field's signed first-order distance (f - level) / |grad f| at @a points.
    std::vector<double> distances(const std::vector<Vec3d>& points) const
    {
        std::vector<double> v;
        std::vector<Vec3d> g;
        evaluate(points, v, g);
        for (std::size_t k = 0; k < points.size(); ++k) v[k] = distance(v[k], g[k]);
        return v;
    }

    static double distance(double value, const Vec3d& gradient)
    {
        return firstOrderSignedDistance(value, gradient.length());
    }
};

/// A batch of triangles to check, side by side (structure of arrays): their corners, the
/// distances at their corners, edge midpoints and centres (with the positive parts on a face of
/// the box, as TriangleQuadratic takes them), and what compute() finds. Side by side, the
/// compiler takes compute()'s loops two triangles at a time (the same bits as one at a time).
struct CheckBatch {
    static constexpr std::size_t kSize = kBatchSize / 4;
    std::array<std::array<double, kSize>, 3> x, y, z;  // corner i of each triangle
    std::array<std::array<double, kSize>, 3> s, m;     // corner i, and midpoint of edge (i, i + 1)
    std::array<double, kSize> centre, largest, margin, meanSquare, area;
    std::array<double, kBatchSize> d;              // distances at the points sampled
    std::array<std::uint16_t, kBatchSize> source;  // per triangle its midpoints' and centre's index in d

    /// The points to sample for triangles pending[begin, begin + n) of @a mesh into @a at: each
    /// triangle's edge midpoints, then its centre. A midpoint of an edge that one of the two
    /// triangles before has too (siblings of a split, marching cubes' neighbours in a cube) is
    /// not sampled again: the same bits either way round, so the same distance.
    void sample(const TriangleMesh& mesh, const std::vector<std::uint32_t>& pending, std::size_t begin, std::size_t n,
                const std::vector<Vec3d>& points, std::vector<Vec3d>& at)
    {
        at.clear();
        for (std::size_t j = 0; j < n; ++j) {
            const openvdb::Vec3I& tri = mesh.triangles[pending[begin + j]];
            for (int i = 0; i < 3; ++i) {
                const auto a = tri[i], b = tri[(i + 1) % 3];
                int shared = -1;
                for (std::size_t back = 1; back <= std::min<std::size_t>(2, j) && shared < 0; ++back) {
                    const openvdb::Vec3I& before = mesh.triangles[pending[begin + j - back]];
                    for (int e = 0; e < 3; ++e)
                        if ((before[e] == b && before[(e + 1) % 3] == a) ||
                            (before[e] == a && before[(e + 1) % 3] == b))
                            shared = source[4 * (j - back) + std::size_t(e)];
                }
                if (shared >= 0) {
                    source[4 * j + std::size_t(i)] = std::uint16_t(shared);
                    continue;
                }
                source[4 * j + std::size_t(i)] = std::uint16_t(at.size());
                at.push_back(0.5 * (points[tri[i]] + points[tri[(i + 1) % 3]]));
            }
            source[4 * j + 3] = std::uint16_t(at.size());
            at.push_back((points[tri[0]] + points[tri[1]] + points[tri[2]]) / 3.0);
        }
    }

    /// Distances (f - level) / |grad f| of the values @a v and gradients @a g: branch-free
    /// firstOrderSignedDistance().
    static double distance(double v, const Vec3d& g)
    {
        const double length = std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
        return length > 0.0 ? v / length : (v == 0.0 ? 0.0 : std::copysign(1e30, v));
    }

    /// Triangles pending[begin, begin + n) of @a mesh, with the values @a v and gradients @a g at
    /// the points sample() gave.
    void gather(const TriangleMesh& mesh, const std::vector<std::uint32_t>& pending, std::size_t begin, std::size_t n,
                const std::vector<Vec3d>& points, const std::vector<double>& vertexDistance,
                const std::vector<double>& v, const std::vector<Vec3d>& g, const std::optional<Box3>& box)
    {
        for (std::size_t q = 0; q < v.size(); ++q) d[q] = distance(v[q], g[q]);
        for (std::size_t j = 0; j < n; ++j) {
            const openvdb::Vec3I& tri = mesh.triangles[pending[begin + j]];
            for (int i = 0; i < 3; ++i) {
                const Vec3d& p = points[tri[i]];
                x[i][j] = p[0];
                y[i][j] = p[1];
                z[i][j] = p[2];
                s[i][j] = vertexDistance[tri[i]];
                m[i][j] = d[source[4 * j + std::size_t(i)]];
            }
            centre[j] = d[source[4 * j + 3]];
            // On a face of the box, the solid's distance is max(f, 0).
            if (onBoxFace(corners(j), box)) {
                for (int i = 0; i < 3; ++i) {
                    s[i][j] = std::max(s[i][j], 0.0);
                    m[i][j] = std::max(m[i][j], 0.0);
                }
                centre[j] = std::max(centre[j], 0.0);
            }
        }
    }

    /// Each triangle's largest |q|, margin, mean of q squared and area (TriangleQuadratic's).
    void compute(std::size_t n)
    {
        for (std::size_t j = 0; j < n; ++j) {
            const double s0 = s[0][j], s1 = s[1][j], s2 = s[2][j], m0 = m[0][j], m1 = m[1][j], m2 = m[2][j];
            largest[j] = quadratic::largest(s0, s1, s2, m0, m1, m2);
            margin[j] = std::abs(centre[j] - quadratic::atCentre(s0, s1, s2, m0, m1, m2));
            meanSquare[j] = quadratic::meanSquare(s0, s1, s2, m0, m1, m2);
            // Half the cross product's length, as (p1 - p0).cross(p2 - p0).length() / 2.
            const double ux = x[1][j] - x[0][j], uy = y[1][j] - y[0][j], uz = z[1][j] - z[0][j];
            const double wx = x[2][j] - x[0][j], wy = y[2][j] - y[0][j], wz = z[2][j] - z[0][j];
            const double cx = uy * wz - uz * wy, cy = uz * wx - ux * wz, cz = ux * wy - uy * wx;
            area[j] = 0.5 * std::sqrt(cx * cx + cy * cy + cz * cz);
        }
    }

    std::array<Vec3d, 3> corners(std::size_t j) const
    {
        return {Vec3d(x[0][j], y[0][j], z[0][j]), Vec3d(x[1][j], y[1][j], z[1][j]), Vec3d(x[2][j], y[2][j], z[2][j])};
    }

    /// How far each edge's midpoint value lies off the chord between its ends (TriangleQuadratic::bend()).
    std::array<double, 3> bends(std::size_t j) const
    {
        std::array<double, 3> b;
        for (int i = 0; i < 3; ++i) b[i] = quadratic::bend(s[i][j], s[(i + 1) % 3][j], m[i][j]);
        return b;
    }
};

/// A triangle's deviation as last checked: the largest, q squared integrated over it, and its
/// area then (the mesh's RMS deviation is their sums' quotient: no pass over the corners after).
struct Checked {
    float largest = 0.0f, squared = 0.0f, area = 0.0f;  // float: 12 bytes a triangle (W9: 1.2 M, twice)
};

/// Bit a (0..2) set where both ends of an edge lie on a face of @a box across axis a (the new
/// point stays on it).
std::uint8_t sharedFaces(const Vec3d& p, const Vec3d& q, const std::optional<Box3>& box)
{
    std::uint8_t faces = 0;
    if (!box) return faces;
    for (int a = 0; a < 3; ++a)
        if (p[a] == q[a] && onBoxPlane(p[a], *box, a)) faces |= std::uint8_t(1u << a);
    return faces;
}

/// placeChunkOnSurface()'s tables, kept from call to call so that their memory is used again.
struct PlacementTables {
    std::vector<Vec3d> start;
    std::vector<std::uint8_t> held;
    std::vector<std::uint32_t> open;
    std::vector<Vec3d> batch, gradients, direction;
    std::vector<double> values;
    std::vector<std::uint8_t> keep;
};

/// Newton from each start onto the level set along the line of the gradient there, the axes in
/// @a heldFaces fixed (a point that would leave the box is put back onto the face it crosses, which
/// holds that axis from then on). Along a fixed line, not the gradient of each step: a midpoint
/// goes onto the surface across its edge, never along it (where the chord passes a saddle, the
/// gradient's path can slide towards an end, and the split makes a sliver again and again).
/// @a found: converged (or one step from it, taken unconfirmed) within o.maxMove of the start.
/// Positions are rounded to float.
void placeChunkOnSurface(const Solid& solid, const AdaptiveRefinementOptions& o, std::span<Vec3d> x,
                         std::span<const std::uint8_t> heldFaces, std::span<std::uint8_t> found,
                         PlacementTables& tables)
{
    const std::size_t n = x.size();
    // Plain references, not a structured binding: lambdas below capture them (clang before 16
    // cannot capture structured bindings, and the fuzz build uses clang).
    std::vector<Vec3d>& start = tables.start;
    std::vector<std::uint8_t>& held = tables.held;
    std::vector<std::uint32_t>& open = tables.open;
    std::vector<Vec3d>& batch = tables.batch;
    std::vector<Vec3d>& g = tables.gradients;
    std::vector<Vec3d>& direction = tables.direction;
    std::vector<double>& v = tables.values;
    std::vector<std::uint8_t>& keep = tables.keep;
    start.assign(x.begin(), x.end());
    held.assign(heldFaces.begin(), heldFaces.end());
    std::fill(found.begin(), found.end(), std::uint8_t(0));
    open.resize(n);
    for (std::size_t k = 0; k < n; ++k) open[k] = std::uint32_t(k);
    direction.assign(n, Vec3d(0.0));
    // One Newton step of point k (batch slot j): whether it stays open.
    auto step = [&](std::size_t j, std::uint32_t k, int iteration) -> bool {
        const double length = g[j].length();
        if (!(length > 0.0)) return false;
        if (std::abs(v[j]) / length <= o.newtonTolerance) {
            found[k] = (x[k] - start[k]).length() <= o.maxMove;
            return false;
        }
        if (iteration == o.maxIterations) return false;
        // The line is the gradient's at its start (within the held faces): Newton along it.
        if (direction[k] == Vec3d(0.0)) {
            Vec3d d = g[j];
            for (int a = 0; a < 3; ++a)
                if (held[k] >> a & 1u) d[a] = 0.0;
            if (!(d.length() > 1e-6 * length)) return false;
            direction[k] = d / d.length();
        }
        const double along = g[j].dot(direction[k]);
        if (!(std::abs(along) > 1e-3 * length)) return false;  // the line runs along the surface
        x[k] -= (v[j] / along) * direction[k];
        bool clamped = false;
        if (o.box)
            for (int a = 0; a < 3; ++a) {
                if (held[k] >> a & 1u) continue;
                const double inside = std::clamp(x[k][a], o.box->min[a], o.box->max[a]);
                if (inside != x[k][a]) {
                    // Onto the face it crossed, then along the gradient within it.
                    x[k][a] = inside;
                    held[k] |= std::uint8_t(1u << a);
                    direction[k] = Vec3d(0.0);
                    clamped = true;
                }
            }
        const double moved = (x[k] - start[k]).length();
        // Newton converges quadratically: a step from within a hundred tolerances leaves about
        // c r^2 (c = |f''| / 2 |f'| along the line: 0.65 / mm for W9's gyroid, 5 / mm for a
        // 0.1 mm strut), far within the tolerance; it is taken without the evaluation that would
        // confirm it (a third of the placement's). The point's distance is measured after, and the
        // check counts it.
        if (!clamped && std::abs(v[j]) / length <= 100.0 * o.newtonTolerance) {
            found[k] = moved <= o.maxMove;
            return false;
        }
        return moved <= 2.0 * o.maxMove;  // else wandered off
    };
    for (int iteration = 0; iteration <= o.maxIterations && !open.empty(); ++iteration) {
        batch.resize(open.size());
        for (std::size_t j = 0; j < open.size(); ++j) batch[j] = x[open[j]];
        solid.evaluate(batch, v, g);
        // Each point's step is its own: taken in parallel, the open ones kept in order after.
        keep.resize(open.size());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, open.size(), 4096), [&](const auto& r) {
            for (std::size_t j = r.begin(); j != r.end(); ++j) keep[j] = step(j, open[j], iteration);
        });
        std::size_t kept = 0;
        for (std::size_t j = 0; j < open.size(); ++j)
            if (keep[j]) open[kept++] = open[j];
        open.resize(kept);
    }
    for (Vec3d& p : x) p = asStored(p);
}

/// placeChunkOnSurface() over @a x in chunks: each point's Newton steps are its own, and a
/// chunk's @a tables (a start, a direction, a batch and its values and gradients per point, 150
/// bytes) serve every chunk and call (W9's first round places 190 000 points: 29 MB at once, and
/// tables made afresh per chunk cost the kernel's clearing of their pages: 8 ms of that round's
/// 10 ms).
void placeOnSurface(const Solid& solid, const AdaptiveRefinementOptions& o, std::vector<Vec3d>& x,
                    const std::vector<std::uint8_t>& held, std::vector<std::uint8_t>& found, PlacementTables& tables)
{
    constexpr std::size_t kChunk = std::size_t(1) << 16;
    found.assign(x.size(), 0);
    for (std::size_t begin = 0; begin < x.size(); begin += kChunk) {
        const std::size_t count = std::min(kChunk, x.size() - begin);
        placeChunkOnSurface(solid, o, std::span<Vec3d>(x.data() + begin, count),
                            std::span<const std::uint8_t>(held.data() + begin, count),
                            std::span<std::uint8_t>(found.data() + begin, count), tables);
    }
}

/// The smallest angle of the triangle with corners @a a, @a b, @a c (radians; 0 when degenerate).
double smallestAngle(const Vec3d& a, const Vec3d& b, const Vec3d& c)
{
    const std::array<Vec3d, 3> p = {a, b, c};
    double smallest = std::numbers::pi;
    for (int i = 0; i < 3; ++i) {
        const Vec3d u = p[(i + 1) % 3] - p[i], v = p[(i + 2) % 3] - p[i];
        const double lu = u.length(), lv = v.length();
        if (!(lu > 0.0 && lv > 0.0)) return 0.0;
        smallest = std::min(smallest, std::acos(std::clamp(u.dot(v) / (lu * lv), -1.0, 1.0)));
    }
    return smallest;
}

/// Flips the longest edge of each triangle in @a candidates (in order) with the triangle across
/// it, where that gives the pair a larger smallest angle, both new triangles face the old pair's
/// way, the new edge is not in the mesh already, the edge is not a crease (on a face of @a box,
/// only between two caps on it) and neither triangle was flipped this round. The mesh stays closed and conforming
/// (the quad's four sides stay). Returns the flipped triangles (two per flip, in place).
std::vector<std::uint32_t> flipLongestEdges(TriangleMesh& mesh, const std::vector<Vec3d>& points,
                                            const std::vector<std::uint32_t>& candidates,
                                            const std::optional<Box3>& box)
{
    std::vector<std::uint32_t> flipped;
    if (candidates.empty()) return flipped;
    // Each candidate's longest edge (a, b) in its own order, and c opposite.
    struct Flip {
        std::uint32_t t = 0, u = std::numeric_limits<std::uint32_t>::max(), a = 0, b = 0, c = 0, d = 0;
        EdgeKey edge = 0;
    };
    std::vector<Flip> flips;
    for (std::uint32_t t : candidates) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        int longest = 0;
        double most = -1.0;
        for (int i = 0; i < 3; ++i)
            if (const double l = (points[tri[(i + 1) % 3]] - points[tri[i]]).lengthSqr(); l > most) {
                most = l;
                longest = i;
            }
        Flip f;
        f.t = t;
        f.a = std::uint32_t(tri[longest]);
        f.b = std::uint32_t(tri[(longest + 1) % 3]);
        f.c = std::uint32_t(tri[(longest + 2) % 3]);
        f.edge = edgeKey(f.a, f.b);
        flips.push_back(f);
    }
    // The triangle across each edge (b, a in its order), and whether the new edge (c, d) exists.
    std::vector<EdgeKey> edges;
    edges.reserve(flips.size());
    for (const Flip& f : flips) edges.push_back(f.edge);
    sortUnique(edges);
    std::vector<std::uint32_t> across(2 * edges.size(), std::numeric_limits<std::uint32_t>::max());
    std::vector<std::uint8_t> endpoint(points.size(), 0);
    for (EdgeKey e : edges) endpoint[e >> 32] = endpoint[e & 0xffffffffu] = 1;
    // Only triangles with two corners among the edges' ends can have one of the edges.
    auto withTwoEndpoints = [&](std::size_t t) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        return endpoint[tri[0]] + endpoint[tri[1]] + endpoint[tri[2]] >= 2;
    };
    for (std::uint32_t t : indicesWhere(mesh.triangles.size(), withTwoEndpoints)) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        for (int i = 0; i < 3; ++i)
            if (const std::ptrdiff_t e = find(edges, edgeKey(tri[i], tri[(i + 1) % 3])); e >= 0)
                across[2 * e + (across[2 * e] != std::numeric_limits<std::uint32_t>::max())] = std::uint32_t(t);
    }
    std::vector<EdgeKey> made;
    for (Flip& f : flips) {
        const std::ptrdiff_t e = find(edges, f.edge);
        f.u = across[2 * e] == f.t ? across[2 * e + 1] : across[2 * e];
        if (f.u == std::numeric_limits<std::uint32_t>::max()) continue;
        const openvdb::Vec3I& other = mesh.triangles[f.u];
        for (int i = 0; i < 3; ++i)
            if (std::uint32_t(other[i]) == f.b && std::uint32_t(other[(i + 1) % 3]) == f.a)
                f.d = std::uint32_t(other[(i + 2) % 3]);
        made.push_back(edgeKey(f.c, f.d));
    }
    std::vector<EdgeKey> existing = made;
    sortUnique(existing);
    std::vector<std::uint8_t> exists(existing.size(), 0);
    std::fill(endpoint.begin(), endpoint.end(), 0);
    for (EdgeKey e : existing) endpoint[e >> 32] = endpoint[e & 0xffffffffu] = 1;
    for (std::uint32_t t : indicesWhere(mesh.triangles.size(), withTwoEndpoints)) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        for (int i = 0; i < 3; ++i)
            if (const std::ptrdiff_t e = find(existing, edgeKey(tri[i], tri[(i + 1) % 3])); e >= 0) exists[e] = 1;
    }
    std::vector<std::uint8_t> used(mesh.triangles.size(), 0);
    for (const Flip& f : flips) {
        if (f.u == std::numeric_limits<std::uint32_t>::max() || used[f.t] || used[f.u] || f.c == f.d) continue;
        const std::ptrdiff_t e = find(existing, edgeKey(f.c, f.d));
        if (exists[e]) continue;
        const Vec3d &a = points[f.a], &b = points[f.b], &c = points[f.c], &d = points[f.d];
        // An edge on a face of the box is flipped only between two caps on that face: between a cap
        // and a side triangle it is the crease.
        if (const std::uint8_t faces = sharedFaces(a, b, box); faces != 0) {
            bool caps = true;
            for (int ax = 0; ax < 3; ++ax)
                if (faces >> ax & 1u) caps = caps && c[ax] == a[ax] && d[ax] == a[ax];
            if (!caps) continue;
        }
        const Vec3d before = (b - a).cross(c - a) + (a - b).cross(d - b);
        const Vec3d n1 = (d - a).cross(c - a), n2 = (b - d).cross(c - d);
        if (!(n1.dot(before) > 0.0 && n2.dot(before) > 0.0 && n1.dot(n2) > 0.0)) continue;
        if (!(std::min(smallestAngle(a, d, c), smallestAngle(d, b, c)) >
              std::min(smallestAngle(a, b, c), smallestAngle(b, a, d))))
            continue;
        mesh.triangles[f.t] = openvdb::Vec3I(int(f.a), int(f.d), int(f.c));
        mesh.triangles[f.u] = openvdb::Vec3I(int(f.d), int(f.b), int(f.c));
        used[f.t] = used[f.u] = 1;
        exists[e] = 1;  // a second flip may not make it again
        flipped.push_back(f.t);
        flipped.push_back(f.u);
    }
    return flipped;
}

/// Moves onto the surface (within the faces of @a box they lie on) the corners of the triangles
/// in @a failing that lie on a face of the box but off the surface by more than the tolerance:
/// crease points the box cut could not move without turning a piece over, whose triangles no
/// split can bring within the tolerance. A corner moves only where none of its triangles turns
/// over or loses its area (splits around it since may have made room). Returns the triangles
/// around the corners moved (to be checked again); @a vertexDistance follows, @a count counts them.
std::vector<std::uint32_t> moveFaceCornersOntoSurface(TriangleMesh& mesh, std::vector<Vec3d>& points,
                                                      std::vector<double>& vertexDistance, const Solid& solid,
                                                      const AdaptiveRefinementOptions& o,
                                                      const std::vector<std::uint32_t>& failing, std::size_t& count,
                                                      PlacementTables& tables)
{
    std::vector<std::uint32_t> around;
    if (!o.box) return around;
    // The faces of the box corner v lies on, where it is off the surface by more than the
    // tolerance (else none).
    auto facesOff = [&](std::uint32_t v) {
        std::uint8_t faces = 0;
        if (std::abs(vertexDistance[v]) > o.tolerance)
            for (int a = 0; a < 3; ++a)
                if (onBoxPlane(points[v][a], *o.box, a)) faces |= std::uint8_t(1u << a);
        return faces;
    };
    // Most rounds have none (W9's): found before any table is made, in parallel (W9: 150 000
    // failing triangles, 2.5 ms a round in one thread).
    const bool any = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, failing.size(), 4096), false,
        [&](const tbb::blocked_range<std::size_t>& r, bool found) {
            for (std::size_t k = r.begin(); k != r.end() && !found; ++k) {
                const openvdb::Vec3I& tri = mesh.triangles[failing[k]];
                found = facesOff(tri[0]) != 0 || facesOff(tri[1]) != 0 || facesOff(tri[2]) != 0;
            }
            return found;
        },
        std::logical_or<>());
    if (!any) return around;
    // The corners, each once, in order of first appearance (the same for any thread count).
    std::vector<std::uint32_t> corners;
    std::vector<std::uint8_t> held;
    std::vector<std::int32_t> slot(points.size(), -1);
    for (std::uint32_t t : failing)
        for (int i = 0; i < 3; ++i) {
            const std::uint32_t v = mesh.triangles[t][i];
            if (slot[v] >= 0) continue;
            const std::uint8_t faces = facesOff(v);
            if (faces == 0) continue;
            slot[v] = std::int32_t(corners.size());
            corners.push_back(v);
            held.push_back(faces);
        }
    std::vector<Vec3d> target(corners.size());
    for (std::size_t c = 0; c < corners.size(); ++c) target[c] = points[corners[c]];
    std::vector<std::uint8_t> accept;
    placeOnSurface(solid, o, target, held, accept, tables);
    // Their triangles: none may turn over or lose its area with the corners moved (a corner of a
    // triangle that would is held back, until none would).
    around = indicesWhere(mesh.triangles.size(), [&](std::size_t t) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        return slot[tri[0]] >= 0 || slot[tri[1]] >= 0 || slot[tri[2]] >= 0;
    });
    auto position = [&](std::uint32_t v) {
        return slot[v] >= 0 && accept[std::size_t(slot[v])] ? target[std::size_t(slot[v])] : points[v];
    };
    for (bool changed = true; changed;) {
        changed = false;
        for (std::uint32_t t : around) {
            const openvdb::Vec3I& tri = mesh.triangles[t];
            const Vec3d n0 = (points[tri[1]] - points[tri[0]]).cross(points[tri[2]] - points[tri[0]]);
            const Vec3d a = position(tri[0]), b = position(tri[1]), c = position(tri[2]);
            const Vec3d n1 = (b - a).cross(c - a);
            if (n1.dot(n0) > 0.0 && n1.length() > 1e-6 * n0.length()) continue;
            for (int i = 0; i < 3; ++i)
                if (slot[tri[i]] >= 0 && accept[std::size_t(slot[tri[i]])]) {
                    accept[std::size_t(slot[tri[i]])] = 0;
                    changed = true;
                }
        }
    }
    std::vector<Vec3d> moved;
    for (std::size_t c = 0; c < corners.size(); ++c)
        if (accept[c]) moved.push_back(target[c]);
    const std::vector<double> movedDistance = solid.distances(moved);
    std::size_t j = 0;
    for (std::size_t c = 0; c < corners.size(); ++c) {
        if (!accept[c]) continue;
        points[corners[c]] = target[c];
        mesh.points[corners[c]] = toFloat(target[c]);
        vertexDistance[corners[c]] = movedDistance[j++];
        ++count;
    }
    std::erase_if(around, [&](std::uint32_t t) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        for (int i = 0; i < 3; ++i)
            if (slot[tri[i]] >= 0 && accept[std::size_t(slot[tri[i]])]) return false;
        return true;
    });
    return around;
}

}  // namespace

AdaptiveRefinementStats refineToTolerance(TriangleMesh& mesh, const FieldNode& field,
                                          const AdaptiveRefinementOptions& options, const ProgressFn& progress)
{
    AdaptiveRefinementStats stats;
    stats.trianglesBefore = stats.trianglesAfter = mesh.triangles.size();
    if (mesh.triangles.empty()) return stats;
    const Solid solid{field, options.level};

    // Room for the refined mesh's points first (below), so that they are not copied again.
    const std::size_t points2 = 3 * mesh.points.size();
    std::vector<Vec3d> points;
    points.reserve(points2);
    points.resize(mesh.points.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, points.size(), 1 << 14), [&](const auto& r) {
        for (std::size_t v = r.begin(); v != r.end(); ++v) points[v] = toDouble(mesh.points[v]);
    });
    std::vector<double> vertexDistance;
    vertexDistance.reserve(points2);
    {
        const std::vector<double> d = solid.distances(points);
        vertexDistance.assign(d.begin(), d.end());
    }
    // Triangles to check this round, and per triangle the edges tried in vain (0: the one bending
    // most next) and its deviation as last checked (largest, and q squared integrated).
    std::vector<std::uint32_t> pending(mesh.triangles.size());
    for (std::size_t t = 0; t < pending.size(); ++t) pending[t] = std::uint32_t(t);
    std::vector<std::uint8_t> attempts(mesh.triangles.size(), 0);
    std::vector<Checked> checked(mesh.triangles.size());
    // The rounds' tables, kept from round to round so their memory is used again: fresh pages
    // cost their clearing by the kernel, which varied W9's refinement from 0.4 to 0.75 s.
    std::vector<std::uint8_t> over, checkAgain, isTouched, endpoint, isPending, folding, nextAttempts;
    std::vector<std::int8_t> choice;
    // Per triangle its edges' slots in the split edges (-1: not split).
    std::vector<std::array<std::int32_t, 3>> slots;
    std::vector<std::uint32_t> offset, touched, failing, newVertex, overIndices;
    std::vector<openvdb::Vec3I> triangles;
    std::vector<Checked> nextChecked;
    std::vector<EdgeKey> split;
    EdgeIndex splitIndex;
    PlacementTables placement;
    // Room for the refined mesh, reserved once (W9 grows 2.5 times from its 0.5 mm mesh): each
    // growth copies a table into fresh pages, which took W9's last rebuild 0.007 s of its 0.017 s
    // with room for twice the coarse mesh. Only what is used is ever touched.
    {
        const std::size_t triangles2 = 3 * mesh.triangles.size();
        for (auto* table : {&attempts, &nextAttempts, &checkAgain, &isTouched, &isPending}) table->reserve(triangles2);
        mesh.triangles.reserve(triangles2);
        triangles.reserve(triangles2);
        checked.reserve(triangles2);
        nextChecked.reserve(triangles2);
        slots.reserve(triangles2);
        offset.reserve(triangles2 + 1);
        pending.reserve(triangles2);
        mesh.points.reserve(points2);
        endpoint.reserve(points2);
    }

    // The edge of a failing triangle (corners p, quadratic q) to split after attempts in vain, or
    // -1. After the first choice, only an edge whose midpoint lies off its chord by a tenth of the
    // tolerance: splitting a straight one (the short side of a needle whose long sides cannot be
    // split) would only make needles again, round after round.
    auto chooseEdge = [&](const std::array<Vec3d, 3>& p, const std::array<double, 3>& bend, int attempts, int round) {
        if (attempts >= 3 || round >= options.rounds) return std::int8_t(-1);
        std::array<std::pair<double, int>, 3> byBend;
        for (int i = 0; i < 3; ++i)
            byBend[i] = {-(bend[i] + 1e-3 * options.tolerance) * (p[(i + 1) % 3] - p[i]).length(), i};
        std::sort(byBend.begin(), byBend.end());
        const int i = byBend[attempts].second;
        if (attempts > 0 && bend[i] < 0.1 * options.tolerance) return std::int8_t(-1);
        return std::int8_t(i);
    };
    for (int round = 0; !pending.empty(); ++round) {
        if (progress) progress(double(round) / options.rounds);
        // Each pending triangle's edge midpoints and centre, evaluated in fixed batches of
        // triangles (a midpoint shared with one of the two triangles before once, CheckBatch::
        // sample(); others shared are evaluated twice, at the same bits: no table to find them in).
        constexpr std::size_t kTrianglesPerBatch = kBatchSize / 4;
        over.assign(pending.size(), 0);
        // Each failing triangle's edge to split: the one bending most off its chord (times its
        // length; the longest where none bends) not yet tried. Splitting across the direction the
        // surface curves in, not along it, takes 7 % fewer triangles than the longest edge on W9.
        // -1: none left to try (the triangle stays over the tolerance).
        choice.assign(pending.size(), -1);
        tbb::parallel_for(
            tbb::blocked_range<std::size_t>(0, (pending.size() + kTrianglesPerBatch - 1) / kTrianglesPerBatch, 1),
            [&](const auto& r) {
                std::vector<Vec3d> at;
                std::vector<double> v;
                std::vector<Vec3d> g;
                CheckBatch b;
                for (std::size_t c = r.begin(); c != r.end(); ++c) {
                    const std::size_t begin = c * kTrianglesPerBatch,
                                      end = std::min(pending.size(), begin + kTrianglesPerBatch), n = end - begin;
                    b.sample(mesh, pending, begin, n, points, at);
                    v.resize(at.size());
                    g.resize(at.size());
                    solid.evaluateBatch(at, v, g);
                    // triangleWithin()'s test (without the bound first: the largest value is what
                    // the report gives as the mesh's deviation, and the coarse mesh's before; a
                    // failing triangle is split or checked again), side by side.
                    b.gather(mesh, pending, begin, n, points, vertexDistance, v, g, options.box);
                    b.compute(n);
                    for (std::size_t k = begin; k < end; ++k) {
                        const std::size_t j = k - begin;
                        const std::uint32_t t = pending[k];
                        const double largest = b.largest[j] + b.margin[j];
                        over[k] = !(largest <= options.tolerance);
                        if (!over[k] || round == 0)
                            checked[t] = {float(largest), float(b.meanSquare[j] * b.area[j]), float(b.area[j])};
                        if (over[k]) choice[k] = chooseEdge(b.corners(j), b.bends(j), attempts[t], round);
                    }
                }
            });
        if (round == 0)
            for (const Checked& c : checked) stats.maxBefore = std::max(stats.maxBefore, double(c.largest));
        split.clear();
        failing.clear();
        checkAgain.assign(mesh.triangles.size(), 0);
        // A triangle whose split was dropped before (a needle of marching cubes, whose long sides
        // fold a piece when split) has its longest edge flipped first where that makes the pair
        // rounder; the flipped pair is checked next round.
        bool changed = false;  // flips or corners moved: triangles to check next round
        // The failing triangles (pending[k], k in overIndices) for which @a keep(k) holds, in order.
        auto failingWhere = [&](auto&& keep) {
            std::vector<std::uint32_t> found =
                indicesWhere(overIndices.size(), [&](std::size_t j) { return keep(overIndices[j]); });
            for (std::uint32_t& j : found) j = pending[overIndices[j]];
            return found;
        };
        // The failing ones among the pending (W9: about a third), for the passes below.
        indicesWhere(
            pending.size(), [&](std::size_t k) { return over[k] != 0; }, overIndices);
        if (round < options.rounds) {
            const std::vector<std::uint32_t> candidates =
                failingWhere([&](std::uint32_t k) { return attempts[pending[k]] > 0 || choice[k] < 0; });
            const std::vector<std::uint32_t> flipped = flipLongestEdges(mesh, points, candidates, options.box);
            stats.flips += flipped.size() / 2;
            // Checked next round (a flipped triangle is not split this round: its chosen edge may be
            // gone).
            for (std::uint32_t t : flipped) {
                checkAgain[t] = 1;
                attempts[t] = 0;
            }
            // Corners on a box face left off the surface, moved where their triangles now allow:
            // those triangles are checked next round, not split this one.
            const std::vector<std::uint32_t> stuck =
                failingWhere([&](std::uint32_t k) { return !checkAgain[pending[k]]; });
            const std::vector<std::uint32_t> moved = moveFaceCornersOntoSurface(
                mesh, points, vertexDistance, solid, options, stuck, stats.cornersMoved, placement);
            for (std::uint32_t t : moved) {
                checkAgain[t] = 1;
                attempts[t] = 0;
            }
            changed = !flipped.empty() || !moved.empty();
        }
        // The failing triangles not flipped or moved: split on their chosen edge, or left over.
        stats.remaining += tbb::parallel_reduce(
            tbb::blocked_range<std::size_t>(0, overIndices.size(), 1 << 14), std::size_t(0),
            [&](const tbb::blocked_range<std::size_t>& r, std::size_t left) {
                for (std::size_t j = r.begin(); j != r.end(); ++j)
                    left += !checkAgain[pending[overIndices[j]]] && choice[overIndices[j]] < 0;
                return left;
            },
            std::plus<>());
        const std::vector<std::uint32_t> splitting = indicesWhere(overIndices.size(), [&](std::size_t j) {
            return !checkAgain[pending[overIndices[j]]] && choice[overIndices[j]] >= 0;
        });
        failing.resize(splitting.size());
        split.resize(splitting.size());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, splitting.size(), 4096), [&](const auto& r) {
            for (std::size_t j = r.begin(); j != r.end(); ++j) {
                const std::uint32_t k = overIndices[splitting[j]], t = pending[k];
                const openvdb::Vec3I& tri = mesh.triangles[t];
                const int i = choice[k];
                failing[j] = t;
                checkAgain[t] = 1;
                split[j] = edgeKey(tri[i], tri[(i + 1) % 3]);
            }
        });
        if (split.empty()) {
            if (!changed) break;
            // Only flips (or corners moved) this round: their triangles are checked next round.
            ++stats.rounds;
            indicesWhere(
                mesh.triangles.size(), [&](std::size_t t) { return checkAgain[t] != 0; }, pending);
            continue;
        }
        ++stats.rounds;
        splitIndex.sortAndBuild(split, points.size());
        const std::size_t m = split.size();
        // The new points: from each edge's midpoint onto the surface.
        std::vector<Vec3d> target(m);
        std::vector<std::uint8_t> held(m), active;
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, m, 4096), [&](const auto& r) {
            for (std::size_t e = r.begin(); e != r.end(); ++e) {
                const Vec3d &p = points[split[e] >> 32], &q = points[split[e] & 0xffffffffu];
                target[e] = 0.5 * (p + q);
                held[e] = sharedFaces(p, q, options.box);
            }
        });
        {
            // A midpoint on two faces (a box edge) inside the solid stays where it is: the box's
            // edge is its boundary there, and straight. Outside (the surface crosses the box's
            // edge between the ends), it goes along the box's edge onto the surface as the others
            // go (both other axes held): at the midpoint it would be off the solid's boundary.
            std::vector<std::uint32_t> onEdge;
            std::vector<Vec3d> middle;
            for (std::size_t e = 0; e < m; ++e)
                if (std::popcount(unsigned(held[e])) >= 2) {
                    onEdge.push_back(std::uint32_t(e));
                    middle.push_back(asStored(target[e]));
                }
            const std::vector<double> middleDistance = solid.distances(middle);
            std::vector<std::uint8_t> found;
            placeOnSurface(solid, options, target, held, found, placement);
            active = std::move(found);
            for (std::size_t j = 0; j < onEdge.size(); ++j)
                if (middleDistance[j] <= 0.0) {
                    target[onEdge[j]] = middle[j];
                    active[onEdge[j]] = 1;
                }
        }
        // The triangles around the split edges, with their edges' slots.
        slots.resize(mesh.triangles.size());
        isTouched.assign(mesh.triangles.size(), 0);
        endpoint.assign(points.size(), 0);
        for (EdgeKey e : split) endpoint[e >> 32] = endpoint[e & 0xffffffffu] = 1;
        // A split edge has both ends among the endpoints: only such triangles are searched (the
        // slots of the others are never read).
        const std::vector<std::uint32_t> near = indicesWhere(mesh.triangles.size(), [&](std::size_t t) {
            const openvdb::Vec3I& tri = mesh.triangles[t];
            return endpoint[tri[0]] + endpoint[tri[1]] + endpoint[tri[2]] >= 2;
        });
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, near.size(), 4096), [&](const auto& r) {
            for (std::size_t j = r.begin(); j != r.end(); ++j) {
                const std::uint32_t t = near[j];
                const openvdb::Vec3I& tri = mesh.triangles[t];
                for (int i = 0; i < 3; ++i) {
                    slots[t][i] = std::int32_t(splitIndex.find(tri[i], tri[(i + 1) % 3]));
                    isTouched[t] = isTouched[t] || slots[t][i] >= 0;
                }
            }
        });
        touched.clear();
        for (std::uint32_t t : near)
            if (isTouched[t]) touched.push_back(t);
        // A triangle whose pieces turn against it or lose their area (as stored) drops a split:
        // the one whose loss leaves the best pieces (their smallest area along the parent's
        // normal), else all (where the surface grazes a box face, two split points on the face
        // can fold a piece that one alone does not). That changes its neighbours: in rounds
        // until none fails.
        auto positions = [&](std::uint32_t t) {
            return splitPositions(mesh.triangles[t], slots[t], points, active, target);
        };
        // The smallest piece's area along the parent's normal, over the parent's (at most 1; good
        // above 0 when no piece lost its area).
        auto worstPiece = [&](std::uint32_t t, const std::array<bool, 3>& s) {
            const std::array<Vec3d, 6> p = positions(t);
            const Vec3d n0 = (p[1] - p[0]).cross(p[2] - p[0]);
            double worst = 1.0;
            for (const SplitPiece& piece : splitPieces(p, s)) {
                const Vec3d n1 = (p[piece[1]] - p[piece[0]]).cross(p[piece[2]] - p[piece[0]]);
                const double along = n1.dot(n0) / n0.lengthSqr();
                worst = std::min(worst, n1.length() > 1e-6 * n0.length() ? along : -1.0);
            }
            return worst;
        };
        auto folds = [&](std::uint32_t t) {
            const std::array<bool, 3> s = splitEdges(slots[t], active);
            return (s[0] || s[1] || s[2]) && worstPiece(t, s) <= 0.0;
        };
        // Each pass finds the folding triangles in parallel, then drops their splits in order (a
        // drop changes the neighbour across the edge: it is looked at again, by the next pass).
        folding.resize(touched.size());
        for (;;) {
            tbb::parallel_for(tbb::blocked_range<std::size_t>(0, touched.size(), 4096), [&](const auto& r) {
                for (std::size_t j = r.begin(); j != r.end(); ++j) folding[j] = folds(touched[j]);
            });
            bool dropped = false;
            for (std::size_t j = 0; j < touched.size(); ++j) {
                const std::uint32_t t = touched[j];
                if (!folding[j] || !folds(t)) continue;
                const std::array<bool, 3> s = splitEdges(slots[t], active);
                const int count = int(s[0]) + int(s[1]) + int(s[2]);
                int drop = -1;
                double best = 0.0;
                for (int i = 0; i < 3 && count > 1; ++i) {
                    if (!s[i]) continue;
                    std::array<bool, 3> fewer = s;
                    fewer[i] = false;
                    if (const double w = worstPiece(t, fewer); w > best) {
                        best = w;
                        drop = i;
                    }
                }
                for (int i = 0; i < 3; ++i)
                    if (s[i] && (drop < 0 || i == drop)) active[std::size_t(slots[t][i])] = 0;
                dropped = true;
            }
            if (!dropped) break;
        }
        // New vertices in edge order; each split triangle replaced in place by its pieces, which
        // are checked next round (with failing triangles whose edge was dropped, on their next).
        newVertex.assign(m, 0);
        const std::vector<std::uint32_t> kept = indicesWhere(m, [&](std::size_t e) { return active[e] != 0; });
        const std::size_t firstNew = points.size();
        std::vector<Vec3d> made(kept.size());
        points.resize(firstNew + kept.size());
        mesh.points.resize(firstNew + kept.size());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, kept.size(), 4096), [&](const auto& r) {
            for (std::size_t j = r.begin(); j != r.end(); ++j) {
                const std::uint32_t e = kept[j];
                newVertex[e] = std::uint32_t(firstNew + j);
                made[j] = points[firstNew + j] = target[e];
                mesh.points[firstNew + j] = toFloat(target[e]);
            }
        });
        stats.splits += kept.size();
        stats.dropped += m - kept.size();
        // Where the field has creases of its own (a union of capsules at a joint), splits keep
        // failing and the mesh grows round after round: given up once a round drops a twentieth of
        // its splits (W9 dropped 0.3 %, a capsule lattice 29 %).
        if (m >= 1000 && 20 * (m - made.size()) > m) {
            stats.abandoned = true;
            stats.remaining += failing.size();
        }
        const std::vector<double> madeDistance = solid.distances(made);
        vertexDistance.insert(vertexDistance.end(), madeDistance.begin(), madeDistance.end());
        for (std::uint32_t t : failing) {
            const std::array<bool, 3> s = splitEdges(slots[t], active);
            if (!s[0] && !s[1] && !s[2]) ++attempts[t];
        }
        // The next triangles: each triangle's pieces (or itself) at an offset counted in parallel.
        const std::size_t n = mesh.triangles.size();
        offset.resize(n + 1);
        offset[0] = 0;
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096), [&](const auto& r) {
            for (std::size_t t = r.begin(); t != r.end(); ++t) {
                const std::array<bool, 3> s =
                    isTouched[t] ? splitEdges(slots[t], active) : std::array<bool, 3>{false, false, false};
                offset[t + 1] = std::uint32_t(1 + int(s[0]) + int(s[1]) + int(s[2]));
            }
        });
        for (std::size_t t = 0; t < n; ++t) offset[t + 1] += offset[t];
        triangles.resize(offset[n]);
        nextAttempts.resize(offset[n]);
        isPending.resize(offset[n]);
        nextChecked.resize(offset[n]);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096), [&](const auto& r) {
            for (std::size_t t = r.begin(); t != r.end(); ++t) {
                const openvdb::Vec3I& tri = mesh.triangles[t];
                const std::uint32_t o = offset[t];
                if (offset[t + 1] - o == 1) {
                    triangles[o] = tri;
                    nextAttempts[o] = attempts[t];
                    isPending[o] = checkAgain[t];
                    nextChecked[o] = checked[t];
                    continue;
                }
                const std::array<bool, 3> s = splitEdges(slots[t], active);
                std::array<std::uint32_t, 6> index{tri[0], tri[1], tri[2], 0, 0, 0};
                for (int i = 0; i < 3; ++i)
                    if (s[i]) index[3 + i] = newVertex[std::size_t(slots[t][i])];
                std::uint32_t k = o;
                for (const SplitPiece& piece : splitPieces(positions(std::uint32_t(t)), s)) {
                    triangles[k] = openvdb::Vec3I(index[piece[0]], index[piece[1]], index[piece[2]]);
                    nextAttempts[k] = 0;
                    nextChecked[k] = {};
                    isPending[k++] = 1;
                }
            }
        });
        indicesWhere(
            triangles.size(), [&](std::size_t t) { return isPending[t] != 0; }, pending);
        mesh.triangles.swap(triangles);
        attempts.swap(nextAttempts);
        checked.swap(nextChecked);
        if (stats.abandoned) break;
    }
    stats.trianglesAfter = mesh.triangles.size();
    // Summed in triangle order: the same for any thread count.
    double sum = 0.0, total = 0.0;
    for (const Checked& c : checked) {
        stats.maxDeviation = std::max(stats.maxDeviation, double(c.largest));
        sum += c.squared;
        total += c.area;
    }
    stats.rmsDeviation = total > 0.0 ? std::sqrt(sum / total) : 0.0;
    stats.deviationSamples = mesh.points.size() + 4 * mesh.triangles.size();
    if (progress) progress(1.0);
    return stats;
}

}  // namespace voxlat
