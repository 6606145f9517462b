#include "mesher/tolerance/SurfaceProjection.h"

#include "mesher/checks/MeshCheck.h"
#include "mesher/extract/PhaseProgress.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <mutex>
#include <vector>

namespace voxlat {

namespace {

/// First-order distance to the level set from a value offset @a r and gradient @a g.
double distanceEstimate(double r, const Vec3d& g)
{
    const double length = g.length();
    if (length > 0.0) return std::abs(r) / length;
    return r == 0.0 ? 0.0 : std::numeric_limits<double>::infinity();
}

std::size_t chunkCount(std::size_t n)
{
    return (n + kBatchSize - 1) / kBatchSize;
}

/// Reports progress over @a total units from worker threads: serialised, strictly increasing,
/// about a hundred calls at most.
class ChunkProgress {
public:
    ChunkProgress(const ProgressFn& fn, std::size_t total) : mFn(fn), mTotal(total) {}
    void add(std::size_t units)
    {
        if (!mFn || mTotal == 0) return;
        std::lock_guard<std::mutex> lock(mMutex);
        mDone += units;
        const int percent = int(100 * mDone / mTotal);
        if (percent > mPercent) {
            mPercent = percent;
            mFn(double(mDone) / double(mTotal));
        }
    }

private:
    const ProgressFn& mFn;
    std::size_t mTotal, mDone = 0;
    int mPercent = -1;
    std::mutex mMutex;
};

/// The Newton iteration for the vertices [begin, begin + count): writes the best position of
/// each to @a target, its distance estimate before and after to @a before / @a after, and
/// whether it reached the move limit to @a limited.
void newtonChunk(const TriangleMesh& mesh, const FieldNode& field, const ProjectionOptions& o, std::size_t begin,
                 std::size_t count, std::vector<Vec3d>& target, std::vector<double>& before,
                 std::vector<std::uint8_t>& limited)
{
    std::array<Vec3d, kBatchSize> start, current, best, batch, grad;
    std::array<double, kBatchSize> bestError, value;
    std::array<std::uint32_t, kBatchSize> active;
    for (std::size_t k = 0; k < count; ++k) start[k] = current[k] = best[k] = toDouble(mesh.points[begin + k]);
    field.gradients(std::span<const Vec3d>(start.data(), count), std::span<double>(value.data(), count),
                    std::span<Vec3d>(grad.data(), count));
    std::size_t numActive = 0;
    // value/grad hold each active vertex's residual and gradient at `current`, indexed by vertex.
    std::array<double, kBatchSize> residual;
    std::array<Vec3d, kBatchSize> gradient;
    for (std::size_t k = 0; k < count; ++k) {
        residual[k] = value[k] - o.level;
        gradient[k] = grad[k];
        bestError[k] = distanceEstimate(residual[k], gradient[k]);
        before[begin + k] = bestError[k];
        limited[begin + k] = 0;
        if (bestError[k] > o.tolerance && std::isfinite(bestError[k])) active[numActive++] = std::uint32_t(k);
    }
    const double maxMove2 = o.maxMove * o.maxMove;
    for (int iteration = 0; iteration < o.maxIterations && numActive > 0; ++iteration) {
        for (std::size_t a = 0; a < numActive; ++a) {
            const std::uint32_t k = active[a];
            const Vec3d& g = gradient[k];
            Vec3d q = current[k] - (residual[k] / g.lengthSqr()) * g;
            const Vec3d offset = q - start[k];
            if (offset.lengthSqr() > maxMove2) {
                q = start[k] + offset * (o.maxMove / offset.length());
                limited[begin + k] = 1;
            }
            batch[a] = q;
        }
        field.gradients(std::span<const Vec3d>(batch.data(), numActive), std::span<double>(value.data(), numActive),
                        std::span<Vec3d>(grad.data(), numActive));
        std::size_t kept = 0;
        for (std::size_t a = 0; a < numActive; ++a) {
            const std::uint32_t k = active[a];
            const double r = value[a] - o.level;
            const double error = distanceEstimate(r, grad[a]);
            const bool improved = error < bestError[k];
            if (improved) {
                bestError[k] = error;
                best[k] = batch[a];
            }
            // A step that ends on the move limit without getting closer will not get closer next
            // time either; a flat spot (zero gradient) gives no direction.
            const bool stuck = !improved && limited[begin + k];
            if (error <= o.tolerance || stuck || !(grad[a].lengthSqr() > 0.0) || !std::isfinite(r)) continue;
            current[k] = batch[a];
            residual[k] = r;
            gradient[k] = grad[a];
            active[kept++] = k;
        }
        numActive = kept;
    }
    for (std::size_t k = 0; k < count; ++k) target[begin + k] = best[k];
}

/// Values and gradients of @a field at @a points, in fixed batches, in parallel.
/// @a check (optional) runs once per batch, from any thread, and may throw to cancel.
void evaluateAll(const FieldNode& field, const std::vector<Vec3d>& points, std::vector<double>& values,
                 std::vector<Vec3d>& gradients, const std::function<void()>& check = {})
{
    values.resize(points.size());
    gradients.resize(points.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunkCount(points.size()), 1), [&](const auto& range) {
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            if (check) check();
            const std::size_t begin = c * kBatchSize, count = std::min(kBatchSize, points.size() - begin);
            field.gradients(std::span<const Vec3d>(points.data() + begin, count),
                            std::span<double>(values.data() + begin, count),
                            std::span<Vec3d>(gradients.data() + begin, count));
        }
    });
}

/// Whether triangle @a t of @a mesh, at its current points, turned over or vanished against
/// @a original.
bool turnedOver(const TriangleMesh& mesh, const std::vector<openvdb::Vec3f>& original, const openvdb::Vec3I& t)
{
    const Vec3d a0 = toDouble(original[t[0]]), b0 = toDouble(original[t[1]]), c0 = toDouble(original[t[2]]);
    const Vec3d n0 = (b0 - a0).cross(c0 - a0);
    const Vec3d a1 = toDouble(mesh.points[t[0]]), b1 = toDouble(mesh.points[t[1]]), c1 = toDouble(mesh.points[t[2]]);
    const Vec3d n1 = (b1 - a1).cross(c1 - a1);
    return n0 != Vec3d(0.0) && (n1.dot(n0) <= 0.0 || n1 == Vec3d(0.0));
}

}  // namespace

CreaseStats sharpenCreases(TriangleMesh& mesh, const FieldNode& a, const FieldNode& b, const ProjectionOptions& options,
                           const ProgressFn& progress)
{
    CreaseStats stats;
    PhaseProgress phases(progress);
    const std::function<void()> check = phases.checker();
    const std::size_t n = mesh.points.size();
    if (n == 0) return stats;
    std::vector<Vec3d> points(n);
    for (std::size_t v = 0; v < n; ++v) points[v] = toDouble(mesh.points[v]);
    // Which surface each vertex is on (1: a, 2: b, 3: both), within a thousandth of the move limit.
    // Only vertices near b = level can end a crease edge, so a is evaluated only there.
    const double near = 1e-3 * options.maxMove;
    std::vector<double> va, vb;
    std::vector<Vec3d> ga, gb;
    phases.begin(0.0);
    evaluateAll(b, points, vb, gb, check);
    std::vector<std::uint32_t> close;
    std::vector<Vec3d> closePoints;
    std::vector<std::uint8_t> side(n, 0);
    for (std::size_t v = 0; v < n; ++v) {
        const double db = distanceEstimate(vb[v] - options.level, gb[v]);
        if (db <= near) side[v] = 2;
        if (db <= 4.0 * options.maxMove) {
            close.push_back(std::uint32_t(v));
            closePoints.push_back(points[v]);
        }
    }
    phases.begin(0.3);
    evaluateAll(a, closePoints, va, ga, check);
    for (std::size_t k = 0; k < close.size(); ++k)
        if (distanceEstimate(va[k] - options.level, ga[k]) <= near) side[close[k]] |= 1;
    // Crease edges, each once (the lower index first).
    std::vector<std::pair<std::uint32_t, std::uint32_t>> edges;
    for (const openvdb::Vec3I& t : mesh.triangles)
        for (int i = 0; i < 3; ++i) {
            const std::uint32_t p = t[i], q = t[(i + 1) % 3];
            if ((side[p] == 1 && side[q] == 2) || (side[p] == 2 && side[q] == 1))
                edges.emplace_back(std::min(p, q), std::max(p, q));
        }
    std::sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    stats.creaseEdges = edges.size();
    if (edges.empty()) return stats;

    // The crease point nearest each end: Newton on (a, b) = (level, level), least-norm steps.
    std::vector<std::uint32_t> ends;
    for (const auto& [p, q] : edges) {
        ends.push_back(p);
        ends.push_back(q);
    }
    std::sort(ends.begin(), ends.end());
    ends.erase(std::unique(ends.begin(), ends.end()), ends.end());
    std::vector<Vec3d> crease(ends.size());
    std::vector<std::uint8_t> found(ends.size(), 0);
    for (std::size_t k = 0; k < ends.size(); ++k) crease[k] = points[ends[k]];
    std::vector<double> ca, cb;
    std::vector<Vec3d> cga, cgb;
    for (int iteration = 0; iteration <= options.maxIterations; ++iteration) {
        phases.begin(0.4 + 0.4 * iteration / std::max(1, options.maxIterations));
        evaluateAll(a, crease, ca, cga, check);
        evaluateAll(b, crease, cb, cgb, check);
        for (std::size_t k = 0; k < ends.size(); ++k) {
            const double ra = ca[k] - options.level, rb = cb[k] - options.level;
            found[k] = distanceEstimate(ra, cga[k]) <= options.tolerance &&
                       distanceEstimate(rb, cgb[k]) <= options.tolerance &&
                       (crease[k] - points[ends[k]]).length() <= options.maxMove;
            if (found[k] || iteration == options.maxIterations) continue;
            const double aa = cga[k].dot(cga[k]), ab = cga[k].dot(cgb[k]), bb = cgb[k].dot(cgb[k]);
            const double det = aa * bb - ab * ab;
            if (!(det > 1e-12 * aa * bb)) continue;  // the surfaces touch without crossing
            const double ya = (bb * ra - ab * rb) / det, yb = (aa * rb - ab * ra) / det;
            crease[k] -= ya * cga[k] + yb * cgb[k];
        }
    }

    // Each crease edge moves its end nearer the crease (the lower index on a tie), unless an end
    // already moves.
    auto endIndex = [&](std::uint32_t v) {
        return std::size_t(std::lower_bound(ends.begin(), ends.end(), v) - ends.begin());
    };
    std::vector<std::uint8_t> move(n, 0);
    for (const auto& [p, q] : edges) {
        if (move[p] || move[q]) continue;
        const std::size_t kp = endIndex(p), kq = endIndex(q);
        const double far = std::numeric_limits<double>::infinity();
        const double dp = found[kp] ? (crease[kp] - points[p]).length() : far;
        const double dq = found[kq] ? (crease[kq] - points[q]).length() : far;
        if (dp == far && dq == far) continue;
        move[dp <= dq ? p : q] = 1;
    }
    const std::vector<openvdb::Vec3f> original = mesh.points;
    for (std::size_t k = 0; k < ends.size(); ++k)
        if (move[ends[k]]) mesh.points[ends[k]] = toFloat(crease[k]);

    // Undo moves that turn a triangle over, in rounds (each undoes at least one; with none left it
    // is the original mesh).
    std::vector<std::uint8_t> flipped(mesh.triangles.size());
    for (;;) {
        phases.begin(0.9);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, mesh.triangles.size(), 1 << 14), [&](const auto& r) {
            for (std::size_t t = r.begin(); t != r.end(); ++t)
                flipped[t] = turnedOver(mesh, original, mesh.triangles[t]);
        });
        bool undone = false;
        for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
            if (flipped[t])
                for (int i = 0; i < 3; ++i) {
                    const std::uint32_t v = mesh.triangles[t][i];
                    if (mesh.points[v] != original[v]) {
                        mesh.points[v] = original[v];
                        undone = true;
                    }
                }
        if (!undone) break;
    }
    for (std::size_t v = 0; v < n; ++v) stats.moved += mesh.points[v] != original[v];
    for (const auto& [p, q] : edges) stats.leftFlat += mesh.points[p] == original[p] && mesh.points[q] == original[q];
    if (progress) progress(1.0);
    return stats;
}

std::vector<double> levelDistances(std::span<const openvdb::Vec3f> points, const FieldNode& field, double level)
{
    std::vector<double> out(points.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunkCount(points.size()), 1), [&](const auto& range) {
        std::array<Vec3d, kBatchSize> p, g;
        std::array<double, kBatchSize> v;
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            const std::size_t begin = c * kBatchSize, count = std::min(kBatchSize, points.size() - begin);
            for (std::size_t k = 0; k < count; ++k) p[k] = toDouble(points[begin + k]);
            field.gradients(std::span<const Vec3d>(p.data(), count), std::span<double>(v.data(), count),
                            std::span<Vec3d>(g.data(), count));
            for (std::size_t k = 0; k < count; ++k) out[begin + k] = distanceEstimate(v[k] - level, g[k]);
        }
    });
    return out;
}

ProjectionStats projectToSurface(TriangleMesh& mesh, const FieldNode& field, const ProjectionOptions& options,
                                 const ProgressFn& progress)
{
    ProjectionStats stats;
    const std::size_t n = mesh.points.size();
    stats.vertices = n;
    if (n == 0) return stats;

    // 1. Newton per vertex, in fixed batches.
    std::vector<Vec3d> target(n);
    std::vector<double> before(n);
    std::vector<std::uint8_t> limited(n);
    ChunkProgress report(progress, n);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunkCount(n), 1), [&](const auto& range) {
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            const std::size_t begin = c * kBatchSize, count = std::min(kBatchSize, n - begin);
            newtonChunk(mesh, field, options, begin, count, target, before, limited);
            report.add(count);
        }
    });

    // 2. Hold back moves that flip a triangle: a vertex of a flipped triangle goes half way, then
    // back to where it was. Each round holds back at least one vertex, and with every vertex back
    // the mesh is the original, which has no flipped triangle, so the rounds end.
    const std::vector<openvdb::Vec3f> original = mesh.points;
    std::vector<std::uint8_t> holdBack(n, 0);  // 0: full move, 1: half, 2: none
    auto placed = [&](std::size_t v) {
        const Vec3d start = toDouble(original[v]);
        const double share = holdBack[v] == 0 ? 1.0 : holdBack[v] == 1 ? 0.5 : 0.0;
        return toFloat(start + share * (target[v] - start));
    };
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1 << 14), [&](const auto& range) {
        for (std::size_t v = range.begin(); v != range.end(); ++v) mesh.points[v] = placed(v);
    });
    const std::size_t numTriangles = mesh.triangles.size();
    std::vector<std::uint8_t> flipped(numTriangles);
    // The triangles whose corners moved since the last crossing check (first: every one that moved).
    std::vector<std::uint8_t> crossTested(numTriangles, 0);
    std::vector<std::uint8_t> vertexChanged(n, 0);
    std::vector<std::uint8_t> heldForCrossing(n, 0);
    auto markTested = [&] {
        bool any = false;
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numTriangles, 1 << 14), [&](const auto& range) {
            for (std::size_t t = range.begin(); t != range.end(); ++t) {
                const openvdb::Vec3I& tri = mesh.triangles[t];
                crossTested[t] = vertexChanged[tri[0]] | vertexChanged[tri[1]] | vertexChanged[tri[2]];
            }
        });
        for (std::size_t t = 0; t < numTriangles && !any; ++t) any = crossTested[t];
        std::fill(vertexChanged.begin(), vertexChanged.end(), std::uint8_t(0));
        return any;
    };
    if (options.holdBackCrossings)
        for (std::size_t v = 0; v < n; ++v) vertexChanged[v] = mesh.points[v] != original[v];
    // The crossing check reports at the end of the Newton pass's progress (a cancel stops it).
    const ProgressFn atEnd = progress ? ProgressFn([&](double) { progress(1.0); }) : ProgressFn();
    for (;;) {
        ++stats.flipRounds;
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numTriangles, 1 << 14), [&](const auto& range) {
            for (std::size_t t = range.begin(); t != range.end(); ++t) {
                const openvdb::Vec3I& tri = mesh.triangles[t];
                const Vec3d a0 = toDouble(original[tri[0]]), b0 = toDouble(original[tri[1]]),
                            c0 = toDouble(original[tri[2]]);
                const Vec3d n0 = (b0 - a0).cross(c0 - a0);
                const Vec3d a1 = toDouble(mesh.points[tri[0]]), b1 = toDouble(mesh.points[tri[1]]),
                            c1 = toDouble(mesh.points[tri[2]]);
                const Vec3d n1 = (b1 - a1).cross(c1 - a1);
                // A triangle degenerate before is none of the projection's business.
                flipped[t] = n0 != Vec3d(0.0) && (n1.dot(n0) <= 0.0 || n1 == Vec3d(0.0));
            }
        });
        std::vector<std::uint32_t> changed;
        for (std::size_t t = 0; t < numTriangles; ++t) {
            if (!flipped[t]) continue;
            for (int i = 0; i < 3; ++i) {
                const std::uint32_t v = mesh.triangles[t][i];
                if (holdBack[v] < 2 && mesh.points[v] != original[v]) changed.push_back(v);
            }
        }
        bool forCrossings = false;
        if (changed.empty() && options.holdBackCrossings && markTested()) {
            // No triangle flips: the triangles that moved are checked for crossings.
            for (const auto& [s, t] : selfIntersections(mesh, crossTested, nullptr, atEnd))
                for (const std::uint32_t tri : {s, t})
                    for (int i = 0; i < 3; ++i) {
                        const std::uint32_t v = mesh.triangles[tri][i];
                        if (holdBack[v] < 2 && mesh.points[v] != original[v]) changed.push_back(v);
                    }
            forCrossings = true;
        }
        std::sort(changed.begin(), changed.end());
        changed.erase(std::unique(changed.begin(), changed.end()), changed.end());
        if (changed.empty()) break;
        for (std::uint32_t v : changed) {
            ++holdBack[v];
            mesh.points[v] = placed(v);
            vertexChanged[v] = options.holdBackCrossings;
            if (forCrossings && !heldForCrossing[v]) {
                heldForCrossing[v] = 1;
                ++stats.heldBackForCrossings;
            }
        }
    }

    // 3. Numbers for the report, at the positions as stored.
    const std::vector<double> after = levelDistances(mesh.points, field, options.level);
    double sumBefore = 0.0, sumAfter = 0.0;
    for (std::size_t v = 0; v < n; ++v) {
        stats.moved += mesh.points[v] != original[v];
        stats.limited += limited[v];
        stats.heldBack += holdBack[v] != 0;
        if (std::isfinite(before[v])) {
            stats.maxBefore = std::max(stats.maxBefore, before[v]);
            sumBefore += before[v] * before[v];
        }
        if (std::isfinite(after[v])) {
            stats.maxAfter = std::max(stats.maxAfter, after[v]);
            sumAfter += after[v] * after[v];
        }
    }
    stats.rmsBefore = std::sqrt(sumBefore / double(n));
    stats.rmsAfter = std::sqrt(sumAfter / double(n));
    return stats;
}

}  // namespace voxlat
