#include "mesher/tolerance/ClusterDecimation.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <unordered_map>

#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/parallel_sort.h>

namespace voxlat {

namespace {

/// Points or triangles per chunk of the parallel passes, whose results are joined in chunk order.
constexpr std::size_t kChunk = std::size_t(1) << 16;

/// The mesh clustered on cells of @a cell mm from @a origin (the points' lower corner): each
/// cell's vertices merged into their mean, cells numbered in the order of their first vertex,
/// triangles that collapse dropped and repeats (the same cells, rotated) kept once, in the order
/// of their first copy. Cells are found in a plain array over the points' box when it holds at
/// most 2^24 cells (the report page's meshes), else in a hash map; repeats by sorting.
TriangleMesh clustered(const TriangleMesh& mesh, const openvdb::Vec3d& origin, const openvdb::Vec3d& extent,
                       double cell)
{
    std::uint64_t dims[3];
    for (int a = 0; a < 3; ++a) dims[a] = std::uint64_t(std::max(0.0, std::floor(extent[a] / cell))) + 1;
    const bool dense = dims[0] <= (1u << 21) && dims[1] <= (1u << 21) && dims[2] <= (1u << 21) &&
                       dims[0] * dims[1] * dims[2] <= (std::uint64_t(1) << 24);
    std::vector<std::uint32_t> denseIndex(dense ? dims[0] * dims[1] * dims[2] : 0, UINT32_MAX);
    std::unordered_map<std::uint64_t, std::uint32_t> cellIndex;
    std::vector<std::uint32_t> vertexCell(mesh.points.size());
    std::vector<openvdb::Vec3d> sums;
    std::vector<std::uint32_t> counts;
    auto cellAt = [&](const openvdb::Vec3d& p, std::uint64_t at[3]) {
        for (int a = 0; a < 3; ++a) at[a] = std::uint64_t(std::max(0.0, std::floor((p[a] - origin[a]) / cell)));
    };
    // Each point's place in the dense array found in parallel (kept in vertexCell until the
    // points are numbered in order below).
    if (dense)
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, mesh.points.size(), 1 << 14), [&](const auto& r) {
            for (std::size_t v = r.begin(); v != r.end(); ++v) {
                std::uint64_t at[3];
                cellAt(openvdb::Vec3d(mesh.points[v]), at);
                vertexCell[v] =
                    std::uint32_t((std::min(at[0], dims[0] - 1) * dims[1] + std::min(at[1], dims[1] - 1)) * dims[2] +
                                  std::min(at[2], dims[2] - 1));
            }
        });
    for (std::size_t v = 0; v < mesh.points.size(); ++v) {
        const openvdb::Vec3d p(mesh.points[v]);
        std::uint32_t* slot;
        if (dense) {
            slot = &denseIndex[vertexCell[v]];
        } else {
            std::uint64_t at[3];
            cellAt(p, at);
            const std::uint64_t key = ((at[0] & 0x1fffff) << 42) | ((at[1] & 0x1fffff) << 21) | (at[2] & 0x1fffff);
            slot = &cellIndex.emplace(key, UINT32_MAX).first->second;
        }
        if (*slot == UINT32_MAX) {
            *slot = std::uint32_t(sums.size());
            sums.emplace_back(0.0);
            counts.push_back(0);
        }
        vertexCell[v] = *slot;
        sums[*slot] += p;
        ++counts[*slot];
    }
    TriangleMesh out;
    out.points.reserve(sums.size());
    for (std::size_t c = 0; c < sums.size(); ++c) out.points.emplace_back(sums[c] / double(counts[c]));
    // Each surviving triangle with the smallest cell first (one key however its corners are
    // rotated) and its position; sorted by key then position, the first of each key is kept.
    struct Candidate {
        std::uint64_t first2;  ///< the key's first two cells
        std::uint32_t third, position;
        bool sameKey(const Candidate& o) const { return first2 == o.first2 && third == o.third; }
    };
    // In fixed chunks of triangles, each gathered alone and joined in order: the serial loop's
    // candidates in its order, for any thread count.
    const std::size_t n = mesh.triangles.size(), chunks = (n + kChunk - 1) / kChunk;
    std::vector<std::vector<Candidate>> chunked(chunks);
    tbb::parallel_for(std::size_t(0), chunks, [&](std::size_t chunk) {
        std::vector<Candidate>& out = chunked[chunk];
        for (std::size_t i = chunk * kChunk; i < std::min(n, (chunk + 1) * kChunk); ++i) {
            const openvdb::Vec3I& t = mesh.triangles[i];
            const std::array<std::uint32_t, 3> c{vertexCell[t[0]], vertexCell[t[1]], vertexCell[t[2]]};
            if (c[0] == c[1] || c[1] == c[2] || c[0] == c[2]) continue;
            const int first = int(std::min_element(c.begin(), c.end()) - c.begin());
            out.push_back({(std::uint64_t(c[first]) << 32) | c[(first + 1) % 3], c[(first + 2) % 3], std::uint32_t(i)});
        }
    });
    std::size_t total = 0;
    for (const auto& c : chunked) total += c.size();
    std::vector<Candidate> candidates;
    candidates.reserve(total);
    for (std::vector<Candidate>& c : chunked) {
        candidates.insert(candidates.end(), c.begin(), c.end());
        std::vector<Candidate>().swap(c);
    }
    // A total order (positions differ): the same sequence from any sort.
    tbb::parallel_sort(candidates.begin(), candidates.end(), [](const Candidate& x, const Candidate& y) {
        if (x.first2 != y.first2) return x.first2 < y.first2;
        return x.third != y.third ? x.third < y.third : x.position < y.position;
    });
    std::vector<Candidate> kept;
    for (std::size_t i = 0; i < candidates.size(); ++i)
        if (i == 0 || !candidates[i].sameKey(candidates[i - 1])) kept.push_back(candidates[i]);
    std::sort(kept.begin(), kept.end(), [](const Candidate& x, const Candidate& y) { return x.position < y.position; });
    out.triangles.reserve(kept.size());
    for (const Candidate& k : kept)
        out.triangles.emplace_back(std::uint32_t(k.first2 >> 32), std::uint32_t(k.first2 & 0xFFFFFFFFu), k.third);
    return out;
}
}  // namespace

TriangleMesh clusterDecimate(const TriangleMesh& mesh, std::size_t maxTriangles)
{
    if (mesh.triangles.size() <= maxTriangles || mesh.points.empty()) return mesh;
    // Bounds and the edges' sum over fixed chunks, summed in chunk order: the same for any thread
    // count (a 50 mm lattice's mesh holds 19 million triangles: the report page waited on them).
    const std::size_t points = mesh.points.size(), pointChunks = (points + kChunk - 1) / kChunk;
    std::vector<openvdb::Vec3d> chunkLo(pointChunks), chunkHi(pointChunks);
    tbb::parallel_for(std::size_t(0), pointChunks, [&](std::size_t c) {
        openvdb::Vec3d l(mesh.points[c * kChunk]), h(l);
        for (std::size_t i = c * kChunk; i < std::min(points, (c + 1) * kChunk); ++i)
            for (int a = 0; a < 3; ++a) {
                l[a] = std::min(l[a], double(mesh.points[i][a]));
                h[a] = std::max(h[a], double(mesh.points[i][a]));
            }
        chunkLo[c] = l;
        chunkHi[c] = h;
    });
    openvdb::Vec3d lo(chunkLo.front()), hi(chunkHi.front());
    for (std::size_t c = 0; c < pointChunks; ++c)
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], chunkLo[c][a]);
            hi[a] = std::max(hi[a], chunkHi[c][a]);
        }
    // A surface clustered on cells of c keeps about area / c^2 vertices: start a little below the
    // cell that gives the budget (from the mean edge length), then grow it by a fifth at a time.
    const std::size_t triangles = mesh.triangles.size(), triangleChunks = (triangles + kChunk - 1) / kChunk;
    std::vector<double> chunkEdges(triangleChunks, 0.0);
    tbb::parallel_for(std::size_t(0), triangleChunks, [&](std::size_t c) {
        double sum = 0.0;
        for (std::size_t i = c * kChunk; i < std::min(triangles, (c + 1) * kChunk); ++i) {
            const openvdb::Vec3I& t = mesh.triangles[i];
            sum += (mesh.points[t[0]] - mesh.points[t[1]]).length() + (mesh.points[t[1]] - mesh.points[t[2]]).length() +
                   (mesh.points[t[2]] - mesh.points[t[0]]).length();
        }
        chunkEdges[c] = sum;
    });
    double edges = 0.0;
    for (const double e : chunkEdges) edges += e;
    const double meanEdge = edges / (3.0 * double(mesh.triangles.size()));
    double cell = std::max(
        {0.8 * meanEdge * std::sqrt(double(mesh.triangles.size()) / double(std::max<std::size_t>(1, maxTriangles))),
         (hi - lo).length() / 1e6, 1e-9});
    // Two cells of the sequence at a time, one per thread (the start is meant to fall short, so a
    // second try is the rule: the report page's mesh of the acceptance gyroid takes two): the first
    // of the pair within the budget wins, so the result is the serial loop's for any thread count.
    // Only for meshes of at most 2^20 triangles (a streamed mesh's page copy comes from at most
    // 2^18 voxels), where the second try's arrays are a few MB; larger ones one try at a time.
    constexpr std::size_t kPairedTriangles = std::size_t(1) << 20;
    while (mesh.triangles.size() > kPairedTriangles) {
        TriangleMesh out = clustered(mesh, lo, hi - lo, cell);
        if (out.triangles.size() <= maxTriangles) return out;
        cell *= 1.2;
    }
    for (;;) {
        const double next = cell * 1.2;
        TriangleMesh first, second;
        tbb::parallel_invoke([&] { first = clustered(mesh, lo, hi - lo, cell); },
                             [&] { second = clustered(mesh, lo, hi - lo, next); });
        if (first.triangles.size() <= maxTriangles) return first;
        if (second.triangles.size() <= maxTriangles) return second;
        cell = next * 1.2;
    }
}

}  // namespace voxlat
