#include "mesher/tolerance/ClusterDecimation.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <unordered_map>
#include <unordered_set>

namespace voxlat {

namespace {
struct TriangleKey {
    std::size_t operator()(const std::array<std::uint32_t, 3>& t) const
    {
        return (std::size_t(t[0]) * 73856093u) ^ (std::size_t(t[1]) * 19349663u) ^ (std::size_t(t[2]) * 83492791u);
    }
};

/// The mesh clustered on cells of @a cell mm from @a origin.
TriangleMesh clustered(const TriangleMesh& mesh, const openvdb::Vec3d& origin, double cell)
{
    std::unordered_map<std::uint64_t, std::uint32_t> cellIndex;
    std::vector<std::uint32_t> vertexCell(mesh.points.size());
    std::vector<openvdb::Vec3d> sums;
    std::vector<std::uint32_t> counts;
    for (std::size_t v = 0; v < mesh.points.size(); ++v) {
        const openvdb::Vec3d p(mesh.points[v]);
        std::uint64_t key = 0;
        for (int a = 0; a < 3; ++a)
            key = (key << 21) | (std::uint64_t(std::max(0.0, std::floor((p[a] - origin[a]) / cell))) & 0x1fffff);
        const auto [it, added] = cellIndex.emplace(key, std::uint32_t(sums.size()));
        if (added) {
            sums.emplace_back(0.0);
            counts.push_back(0);
        }
        vertexCell[v] = it->second;
        sums[it->second] += p;
        ++counts[it->second];
    }
    TriangleMesh out;
    out.points.reserve(sums.size());
    for (std::size_t c = 0; c < sums.size(); ++c) out.points.emplace_back(sums[c] / double(counts[c]));
    std::unordered_set<std::array<std::uint32_t, 3>, TriangleKey> seen;
    for (const openvdb::Vec3I& t : mesh.triangles) {
        const std::array<std::uint32_t, 3> c{vertexCell[t[0]], vertexCell[t[1]], vertexCell[t[2]]};
        if (c[0] == c[1] || c[1] == c[2] || c[0] == c[2]) continue;
        // One copy of a triangle however its corners are rotated (the smallest first).
        const int first = int(std::min_element(c.begin(), c.end()) - c.begin());
        const std::array<std::uint32_t, 3> key{c[first], c[(first + 1) % 3], c[(first + 2) % 3]};
        if (seen.insert(key).second) out.triangles.emplace_back(key[0], key[1], key[2]);
    }
    return out;
}
}  // namespace

TriangleMesh clusterDecimate(const TriangleMesh& mesh, std::size_t maxTriangles)
{
    if (mesh.triangles.size() <= maxTriangles || mesh.points.empty()) return mesh;
    openvdb::Vec3d lo(mesh.points.front()), hi(lo);
    for (const openvdb::Vec3f& p : mesh.points)
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], double(p[a]));
            hi[a] = std::max(hi[a], double(p[a]));
        }
    // A surface clustered on cells of c keeps about area / c^2 vertices: start a little below the
    // cell that gives the budget (from the mean edge length), then grow it by a fifth at a time.
    double edges = 0.0;
    for (const openvdb::Vec3I& t : mesh.triangles)
        edges += (mesh.points[t[0]] - mesh.points[t[1]]).length() + (mesh.points[t[1]] - mesh.points[t[2]]).length() +
                 (mesh.points[t[2]] - mesh.points[t[0]]).length();
    const double meanEdge = edges / (3.0 * double(mesh.triangles.size()));
    double cell = std::max(
        {0.8 * meanEdge * std::sqrt(double(mesh.triangles.size()) / double(std::max<std::size_t>(1, maxTriangles))),
         (hi - lo).length() / 1e6, 1e-9});
    for (;;) {
        TriangleMesh out = clustered(mesh, lo, cell);
        if (out.triangles.size() <= maxTriangles) return out;
        cell *= 1.2;
    }
}

}  // namespace voxlat
