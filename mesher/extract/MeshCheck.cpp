#include "mesher/extract/MeshCheck.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cstdint>
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
                        if (faces == 1) ++acc.boundary;
                        if (faces > 2) ++acc.nonManifoldEdges;
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
    return result;
}

}  // namespace voxlat
