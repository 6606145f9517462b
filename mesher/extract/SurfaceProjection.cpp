#include "mesher/extract/SurfaceProjection.h"

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

Vec3d toDouble(const openvdb::Vec3f& p)
{
    return {p.x(), p.y(), p.z()};
}

openvdb::Vec3f toFloat(const Vec3d& p)
{
    return {float(p.x()), float(p.y()), float(p.z())};
}

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

}  // namespace

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
        std::sort(changed.begin(), changed.end());
        changed.erase(std::unique(changed.begin(), changed.end()), changed.end());
        if (changed.empty()) break;
        for (std::uint32_t v : changed) {
            ++holdBack[v];
            mesh.points[v] = placed(v);
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
