#include "engine/properties/CellTopology.h"

#include <cstdlib>
#include <numeric>

namespace voxlat::homogenization {

namespace {

using Shift = std::array<std::int32_t, 3>;

/// Union-find over voxels that also tracks periodic copies: shift[v] is the copy of v (in cells)
/// that lies in the same connected piece of the tiling as the base copy of v's parent.
struct PeriodicUnionFind {
    std::vector<std::int32_t> parent;
    std::vector<Shift> shift;
    std::vector<std::int32_t> size;

    explicit PeriodicUnionFind(std::size_t n) : parent(n), shift(n, Shift{0, 0, 0}), size(n, 1)
    {
        std::iota(parent.begin(), parent.end(), 0);
    }

    /// The root of v and the copy of v that is connected to the root's base copy.
    std::int32_t find(std::int32_t v, Shift& s)
    {
        // Two passes, iteratively (a component may be millions of voxels long): find the root
        // summing the shifts, then point every voxel on the path straight at the root.
        std::int32_t root = v;
        Shift total{0, 0, 0};
        while (parent[root] != root) {
            for (int k = 0; k < 3; ++k) total[k] += shift[root][k];
            root = parent[root];
        }
        s = total;
        Shift rest = total;
        while (parent[v] != v) {
            const std::int32_t next = parent[v];
            const Shift own = shift[v];
            parent[v] = root;
            shift[v] = rest;
            for (int k = 0; k < 3; ++k) rest[k] -= own[k];
            v = next;
        }
        return root;
    }
};

/// Keeps at most three independent integer vectors; a vector is added when it is independent.
struct LatticeSpan {
    std::vector<std::array<std::int64_t, 3>> basis;

    void add(const Shift& g)
    {
        const std::array<std::int64_t, 3> v{g[0], g[1], g[2]};
        if (v[0] == 0 && v[1] == 0 && v[2] == 0) return;
        if (basis.size() == 1) {
            const auto& a = basis[0];
            const std::array<std::int64_t, 3> c{a[1] * v[2] - a[2] * v[1], a[2] * v[0] - a[0] * v[2],
                                                a[0] * v[1] - a[1] * v[0]};
            if (c[0] == 0 && c[1] == 0 && c[2] == 0) return;
        } else if (basis.size() == 2) {
            const auto& a = basis[0];
            const auto& b = basis[1];
            const std::int64_t det = a[0] * (b[1] * v[2] - b[2] * v[1]) - a[1] * (b[0] * v[2] - b[2] * v[0]) +
                                     a[2] * (b[0] * v[1] - b[1] * v[0]);
            if (det == 0) return;
        } else if (basis.size() == 3) {
            return;
        }
        basis.push_back(v);
    }
};

}  // namespace

CellTopology analyzeCell(const std::array<int, 3>& n, const std::vector<std::uint8_t>& solid)
{
    const std::size_t count = std::size_t(n[0]) * n[1] * n[2];
    PeriodicUnionFind uf(count);
    std::vector<std::pair<std::int32_t, Shift>> wraps;  // (a root at the time, wrap vector)

    // The 13 "forward" neighbour offsets: each pair of 26-neighbours is visited once.
    std::vector<std::array<int, 3>> offsets;
    for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx)
                if (dz > 0 || (dz == 0 && (dy > 0 || (dy == 0 && dx > 0)))) offsets.push_back({dx, dy, dz});

    for (int z = 0; z < n[2]; ++z)
        for (int y = 0; y < n[1]; ++y)
            for (int x = 0; x < n[0]; ++x) {
                const std::int32_t v = std::int32_t(x + std::size_t(n[0]) * (y + std::size_t(n[1]) * z));
                if (!solid[v]) continue;
                const int c[3] = {x, y, z};
                for (const auto& d : offsets) {
                    int w[3];
                    Shift s{0, 0, 0};  // the neighbour is copy s of voxel w
                    for (int k = 0; k < 3; ++k) {
                        w[k] = c[k] + d[k];
                        if (w[k] < 0) w[k] += n[k], s[k] = -1;
                        if (w[k] >= n[k]) w[k] -= n[k], s[k] = 1;
                    }
                    const std::int32_t wi = std::int32_t(w[0] + std::size_t(n[0]) * (w[1] + std::size_t(n[1]) * w[2]));
                    if (!solid[wi]) continue;
                    Shift tv, tw;
                    const std::int32_t rv = uf.find(v, tv);
                    const std::int32_t rw = uf.find(wi, tw);
                    // Copy s + tv of w is connected to rv's base copy; copy tw of w to rw's.
                    Shift g;
                    for (int k = 0; k < 3; ++k) g[k] = s[k] + tv[k] - tw[k];
                    if (rv == rw) {
                        if (g[0] != 0 || g[1] != 0 || g[2] != 0) wraps.push_back({rv, g});
                        continue;
                    }
                    // Union by size; copy g of rw's root is connected to rv's base copy.
                    if (uf.size[rv] >= uf.size[rw]) {
                        uf.parent[rw] = rv;
                        uf.shift[rw] = g;
                        uf.size[rv] += uf.size[rw];
                    } else {
                        uf.parent[rv] = rw;
                        uf.shift[rv] = Shift{-g[0], -g[1], -g[2]};
                        uf.size[rw] += uf.size[rv];
                    }
                }
            }

    // Wrap vectors are translations of the whole component, the same whichever root saw them.
    std::vector<std::int32_t> spanOf(count, -1);
    std::vector<LatticeSpan> spans;
    for (const auto& [r, g] : wraps) {
        Shift unused;
        const std::int32_t root = uf.find(r, unused);
        if (spanOf[root] < 0) spanOf[root] = std::int32_t(spans.size()), spans.emplace_back();
        spans[spanOf[root]].add(g);
    }

    CellTopology t;
    t.label.assign(count, -1);
    std::vector<std::int32_t> componentOfRoot(count, -2);  // -2 unseen, -1 island
    for (std::size_t v = 0; v < count; ++v) {
        if (!solid[v]) continue;
        Shift unused;
        const std::int32_t root = uf.find(std::int32_t(v), unused);
        std::int32_t& id = componentOfRoot[root];
        if (id == -2) {
            const int rank = spanOf[root] < 0 ? 0 : int(spans[spanOf[root]].basis.size());
            if (rank == 0) {
                id = -1;
                ++t.islands;
            } else {
                id = t.components++;
                t.rank.push_back(rank);
                for (const auto& b : spans[spanOf[root]].basis)
                    for (int k = 0; k < 3; ++k)
                        if (b[k] != 0) t.percolates[k] = true;
            }
        }
        t.label[v] = id;
        if (id >= 0)
            ++t.keptVoxels;
        else
            ++t.islandVoxels;
    }
    return t;
}

}  // namespace voxlat::homogenization
