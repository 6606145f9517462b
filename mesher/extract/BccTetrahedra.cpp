#include "mesher/extract/BccTetrahedra.h"

#include "mesher/extract/ExtractProgress.h"

#include <openvdb/tree/ValueAccessor.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdint>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <utility>
#include <vector>

namespace voxlat {

namespace {

using Coord = openvdb::Coord;
using Vec3d = openvdb::Vec3d;
using FloatTree = openvdb::FloatTree;
using LeafType = FloatTree::LeafNodeType;

////////////////////////////////////////////////////////////////////////////////////////////////////
// The lattice
//
// Index space: corner node p (a grid voxel) sits at p, the centre node of cube p (the cube whose
// minimum corner is voxel p) at p + (1/2, 1/2, 1/2). Every lattice edge has one owner, a voxel p,
// and a slot there:
//   slot a (0..2)    corner p -> corner p + e_a            (marching cubes' edges)
//   slot 3 + a       centre of cube p - e_a -> centre of p (between cubes across p's lower face)
//   slot 6 + k       centre of p -> corner p + k, k = (k & 1, (k >> 1) & 1, k >> 2)
// The owner of a centre-to-centre edge is the upper cube: a crossing edge then always belongs to
// a leaf, because a cube whose minimum corner lies in a tile has that tile's sign at its centre,
// at its eight corners and at the centres of its three lower neighbours (all within the tile's
// box grown by one voxel, over which the tile's bound was taken).
//
// Tetrahedra: one per (face between cubes, edge of that face). Cube p owns the twelve on its three
// lower faces: for axis a, the centres of p - e_a and p and one of the four edges of the face
// {p + i e_b + j e_c}. They are congruent, tile space face to face and have volume h^3 / 12.

constexpr int kSlots = 14;
constexpr int kMaskWords = kSlots * 8;  // word = slot * 8 + x, bit = y * 8 + z
constexpr int kTetsPerCube = 12;

constexpr std::array<int, 2> otherAxes(int axis)
{
    return axis == 0 ? std::array<int, 2>{1, 2} : axis == 1 ? std::array<int, 2>{0, 2} : std::array<int, 2>{0, 1};
}

/// The tetrahedron edges as node pairs (index into a tetrahedron's six edges).
constexpr int kEdgeNodes[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};

/// One edge of a tetrahedron: the owner's slot and the owner's offset from the tetrahedron's cube.
struct TetEdge {
    int slot = 0;
    int offset[3] = {0, 0, 0};
};

/// A node of a tetrahedron relative to its cube: a corner (offset in {0, 1}^3) or a centre (offset
/// 0 or -e_a: the cube's own centre or its lower neighbour's).
struct TetNode {
    bool centre = false;
    int offset[3] = {0, 0, 0};
};

/// One of a cube's twelve tetrahedra, its nodes in positive orientation (det > 0).
struct TetTemplate {
    TetNode nodes[4];
    TetEdge edges[6];
};

/// Marching tetrahedra: per inside-node mask, the crossing edges in counter-clockwise order seen
/// from outside (the normal points from the inside nodes to the outside ones).
struct TetCase {
    int size = 0;  // 0, 3 or 4
    int edges[4] = {0, 0, 0, 0};
};

struct Tables {
    std::array<TetTemplate, kTetsPerCube> tets;
    std::array<TetCase, 16> cases;
};

Vec3d nodePosition(const TetNode& n)
{
    Vec3d p(n.offset[0], n.offset[1], n.offset[2]);
    if (n.centre) p += Vec3d(0.5);
    return p;
}

TetEdge edgeBetween(const TetNode& u, const TetNode& v, int axis)
{
    TetEdge e;
    if (u.centre && v.centre) {
        e.slot = 3 + axis;  // owned by the upper cube, whose offset is 0
        return e;
    }
    if (u.centre != v.centre) {
        const TetNode& c = u.centre ? u : v;
        const TetNode& k = u.centre ? v : u;
        int bits = 0;
        for (int i = 0; i < 3; ++i) {
            const int d = k.offset[i] - c.offset[i];
            if (d != 0 && d != 1) throw std::logic_error("bcc: corner not on its cube");
            bits |= d << i;
            e.offset[i] = c.offset[i];
        }
        e.slot = 6 + bits;
        return e;
    }
    int along = -1;
    for (int i = 0; i < 3; ++i) {
        e.offset[i] = std::min(u.offset[i], v.offset[i]);
        if (u.offset[i] != v.offset[i]) along = i;
    }
    e.slot = along;
    return e;
}

std::unique_ptr<Tables> buildTables()
{
    auto t = std::make_unique<Tables>();
    int n = 0;
    for (int axis = 0; axis < 3; ++axis) {
        const auto [b, c] = otherAxes(axis);
        // The four edges of the lower face, as (i, j) pairs along b and c.
        const int faceEdges[4][2][2] = {{{0, 0}, {1, 0}}, {{0, 1}, {1, 1}}, {{0, 0}, {0, 1}}, {{1, 0}, {1, 1}}};
        for (const auto& fe : faceEdges) {
            TetTemplate& tet = t->tets[n++];
            tet.nodes[0].centre = true;
            tet.nodes[0].offset[axis] = -1;
            tet.nodes[1].centre = true;
            for (int k = 0; k < 2; ++k) {
                tet.nodes[2 + k].offset[b] = fe[k][0];
                tet.nodes[2 + k].offset[c] = fe[k][1];
            }
            const Vec3d p0 = nodePosition(tet.nodes[0]);
            const double det = (nodePosition(tet.nodes[1]) - p0)
                                   .cross(nodePosition(tet.nodes[2]) - p0)
                                   .dot(nodePosition(tet.nodes[3]) - p0);
            if (std::abs(std::abs(det) - 0.5) > 1e-12) throw std::logic_error("bcc: tetrahedron volume is not 1/12");
            if (det < 0.0) std::swap(tet.nodes[2], tet.nodes[3]);
            for (int e = 0; e < 6; ++e)
                tet.edges[e] = edgeBetween(tet.nodes[kEdgeNodes[e][0]], tet.nodes[kEdgeNodes[e][1]], axis);
        }
    }

    // Cases, from a positively oriented reference tetrahedron: crossing edges' midpoints sorted by
    // angle about the inside-to-outside direction, so any positively oriented tetrahedron (an
    // orientation-preserving affine image) gets them counter-clockwise seen from outside.
    const Vec3d ref[4] = {Vec3d(0, 0, 0), Vec3d(1, 0, 0), Vec3d(0, 1, 0), Vec3d(0, 0, 1)};
    for (int mask = 1; mask < 15; ++mask) {
        TetCase& tc = t->cases[mask];
        Vec3d in(0.0), out(0.0), centroid(0.0);
        int numIn = 0;
        std::vector<int> edges;
        for (int i = 0; i < 4; ++i) {
            if ((mask >> i) & 1) {
                in += ref[i];
                ++numIn;
            } else {
                out += ref[i];
            }
        }
        const Vec3d normal = out / double(4 - numIn) - in / double(numIn);
        for (int e = 0; e < 6; ++e) {
            const int a = kEdgeNodes[e][0], b = kEdgeNodes[e][1];
            if (((mask >> a) & 1) == ((mask >> b) & 1)) continue;
            edges.push_back(e);
            centroid += 0.5 * (ref[a] + ref[b]);
        }
        centroid /= double(edges.size());
        auto mid = [&](int e) { return 0.5 * (ref[kEdgeNodes[e][0]] + ref[kEdgeNodes[e][1]]); };
        const Vec3d u = (mid(edges[0]) - centroid).unit();
        const Vec3d w = normal.cross(u).unit();
        std::sort(edges.begin(), edges.end(), [&](int e0, int e1) {
            const Vec3d d0 = mid(e0) - centroid, d1 = mid(e1) - centroid;
            return std::atan2(d0.dot(w), d0.dot(u)) < std::atan2(d1.dot(w), d1.dot(u));
        });
        tc.size = int(edges.size());
        for (int i = 0; i < tc.size; ++i) tc.edges[i] = edges[i];
        const Vec3d turn = (mid(edges[1]) - mid(edges[0])).cross(mid(edges[2]) - mid(edges[0]));
        if (turn.dot(normal) <= 0.0) throw std::logic_error("bcc: case polygon turned inward");
    }
    return t;
}

const Tables& tables()
{
    static const std::unique_ptr<Tables> t = buildTables();
    return *t;
}

////////////////////////////////////////////////////////////////////////////////////////////////////
// Blocks

/// Serialized, monotonic progress reporting in whole percents (as marching cubes reports).
/// Neighbour index of the block at offset (dx, dy, dz) in {-1, 0, 1}^3.
constexpr int neighbourSlot(int dx, int dy, int dz)
{
    return (dx + 1) * 9 + (dy + 1) * 3 + (dz + 1);
}

/// The values one block's cubes see: corners in [0, 8]^3 (the block and its +x/+y/+z neighbours)
/// and centres of cubes in [-1, 7]^3 with at most one coordinate -1 (the block and its three lower
/// face neighbours). A neighbour that is no leaf is a constant: its tile or background value.
struct View {
    Coord origin;
    const float* corner[8];  // sub-block s (bit 0: +x, bit 1: +y, bit 2: +z); null if constant
    float cornerConst[8];
    const float* centre[4];  // 0: this block, 1 + a: the block at -e_a; null if no leaf
    float centreConst[4];

    float cornerValue(int x, int y, int z) const
    {
        const int s = (x >> 3) | ((y >> 3) << 1) | ((z >> 3) << 2);
        const float* d = corner[s];
        return d ? d[((x & 7) << 6) | ((y & 7) << 3) | (z & 7)] : cornerConst[s];
    }
    static int centreBlock(int x, int y, int z) { return x < 0 ? 1 : y < 0 ? 2 : z < 0 ? 3 : 0; }
};

struct BlockCounts {
    uint32_t vertices = 0;
    uint32_t triangles = 0;
    uint32_t crossingTets = 0;
    uint32_t droppedTets = 0;
    uint32_t tileCentres = 0;
};

class BccMesher {
public:
    BccMesher(const openvdb::FloatGrid& grid, const FieldNode& field, float iso)
        : mGrid(grid), mTree(grid.tree()), mField(field), mIso(iso), mTables(tables())
    {
        const auto map = grid.transform().baseMap();
        if (map->isType<openvdb::math::ScaleTranslateMap>() || map->isType<openvdb::math::UniformScaleTranslateMap>())
            mScaleTranslate = static_cast<const openvdb::math::ScaleTranslateMap*>(map.get());
    }

    TriangleMesh run(ProgressFn progressFn, BccStats& stats);

private:
    using Accessor = openvdb::tree::ValueAccessor<const FloatTree, /*IsSafe=*/false>;

    void collectLeaves();
    int32_t findLeaf(const Coord& origin) const;
    void evaluateCentres(std::size_t b);
    View view(std::size_t b, Accessor& acc) const;
    void insideRows(const View& v, std::uint16_t* cornerRows, std::uint16_t* centreRows) const;
    double centreValue(const View& v, int x, int y, int z, uint32_t* evaluated) const;
    Vec3d edgePoint(const View& v, int slot, int x, int y, int z, uint32_t* evaluated) const;
    /// Global index of the vertex on edge @a slot of voxel (x, y, z) relative to block @a b (each in
    /// [-1, 8]); UINT32_MAX when the edge's owner is no leaf.
    uint32_t vertexIndex(std::size_t b, int slot, int x, int y, int z) const;
    /// The leaf owning voxel (x, y, z) relative to block @a b (each in [-1, 8]), or -1.
    int32_t ownerLeaf(std::size_t b, int x, int y, int z) const;
    template <bool Emit>
    void processBlock(std::size_t b, Accessor& acc, TriangleMesh* mesh);

    Vec3d indexToWorld(const Vec3d& p) const
    {
        return mScaleTranslate ? mScaleTranslate->applyMap(p) : mGrid.indexToWorld(p);
    }

    const openvdb::FloatGrid& mGrid;
    const FloatTree& mTree;
    const FieldNode& mField;
    const float mIso;
    const Tables& mTables;
    const openvdb::math::ScaleTranslateMap* mScaleTranslate = nullptr;

    std::vector<const LeafType*> mLeaves;
    std::vector<std::pair<std::uint64_t, int32_t>> mKeys;  // sorted (packed origin, leaf)
    std::vector<std::array<int32_t, 27>> mNeighbours;      // leaf at each offset, -1 if none
    std::vector<std::array<float, 512>> mCentres;          // cube centre values per leaf
    std::vector<std::array<std::uint64_t, kMaskWords>> mEdgeMasks;
    std::vector<std::array<std::uint16_t, kMaskWords>> mEdgeRanks;
    std::vector<BlockCounts> mCounts;
    std::vector<std::uint64_t> mVertexOffsets, mTriangleOffsets;
};

std::uint64_t packOrigin(const Coord& c)
{
    constexpr std::uint64_t kMask = (std::uint64_t(1) << 21) - 1;
    auto part = [&](int v) { return std::uint64_t(std::uint32_t(v >> 3) + (1u << 20)) & kMask; };
    return (part(c.x()) << 42) | (part(c.y()) << 21) | part(c.z());
}

void BccMesher::collectLeaves()
{
    for (auto it = mTree.cbeginLeaf(); it; ++it) mLeaves.push_back(it.getLeaf());
    mKeys.resize(mLeaves.size());
    for (std::size_t i = 0; i < mLeaves.size(); ++i) mKeys[i] = {packOrigin(mLeaves[i]->origin()), int32_t(i)};
    std::sort(mKeys.begin(), mKeys.end());
}

int32_t BccMesher::findLeaf(const Coord& origin) const
{
    const std::uint64_t key = packOrigin(origin);
    const auto it = std::lower_bound(mKeys.begin(), mKeys.end(), std::make_pair(key, int32_t(-1)));
    return it != mKeys.end() && it->first == key ? it->second : -1;
}

void BccMesher::evaluateCentres(std::size_t b)
{
    const Coord o = mLeaves[b]->origin();
    std::array<double, 512> values;
    const Vec3d first(o.x() + 0.5, o.y() + 0.5, o.z() + 0.5);
    if (mScaleTranslate) {
        // One grid batch: separable nodes (a TPMS) share their per-axis work.
        GridBatch batch;
        batch.origin = indexToWorld(first);
        batch.spacing = indexToWorld(first + Vec3d(1.0)) - batch.origin;
        mField.gridValues(batch, values);
    } else {
        std::vector<Vec3d> points(512);
        for (int i = 0; i < 512; ++i) points[i] = mGrid.indexToWorld(first + Vec3d(i >> 6, (i >> 3) & 7, i & 7));
        mField.values(points, values);
    }
    for (int i = 0; i < 512; ++i) mCentres[b][i] = float(values[i]);
}

View BccMesher::view(std::size_t b, Accessor& acc) const
{
    View v;
    v.origin = mLeaves[b]->origin();
    const std::array<int32_t, 27>& nb = mNeighbours[b];
    for (int s = 0; s < 8; ++s) {
        const int32_t i = nb[neighbourSlot(s & 1, (s >> 1) & 1, s >> 2)];
        v.corner[s] = i >= 0 ? mLeaves[i]->buffer().data() : nullptr;
        v.cornerConst[s] =
            i >= 0 ? 0.0f : acc.getValue(v.origin + Coord((s & 1) * 8, ((s >> 1) & 1) * 8, (s >> 2) * 8));
    }
    for (int s = 0; s < 4; ++s) {
        Coord d(0);
        if (s > 0) d[s - 1] = -1;
        const int32_t i = nb[neighbourSlot(d.x(), d.y(), d.z())];
        v.centre[s] = i >= 0 ? mCentres[i].data() : nullptr;
        // A tile's cubes have its sign at their centres (see the lattice notes above).
        v.centreConst[s] = i >= 0 ? 0.0f : acc.getValue(v.origin + Coord(d.x() * 8, d.y() * 8, d.z() * 8));
    }
    return v;
}

void BccMesher::insideRows(const View& v, std::uint16_t* cornerRows, std::uint16_t* centreRows) const
{
    // cornerRows[x * 9 + y], x, y in [0, 8]: bit z (0..8) set when corner (x, y, z) is inside.
    for (int x = 0; x < 9; ++x) {
        for (int y = 0; y < 9; ++y) {
            unsigned bits = 0;
            for (int z = 0; z < 9; ++z) bits |= unsigned(v.cornerValue(x, y, z) < mIso) << z;
            cornerRows[x * 9 + y] = std::uint16_t(bits);
        }
    }
    // centreRows[(x + 1) * 9 + y + 1], x, y in [-1, 7]: bit z + 1 (z in [-1, 7]) set when the centre
    // of cube (x, y, z) is inside; only entries with at most one coordinate -1 are meaningful.
    auto centreInside = [&](int s, int x, int y, int z) {
        const float* d = v.centre[s];
        const float value = d ? d[((x & 7) << 6) | ((y & 7) << 3) | (z & 7)] : v.centreConst[s];
        return unsigned(value < mIso);
    };
    for (int x = -1; x < 8; ++x) {
        for (int y = -1; y < 8; ++y) {
            unsigned bits = 0;
            if (x >= 0 || y >= 0) {
                const int s = x < 0 ? 1 : y < 0 ? 2 : 0;
                for (int z = 0; z < 8; ++z) bits |= centreInside(s, x, y, z) << (z + 1);
                if (s == 0) bits |= centreInside(3, x, y, -1);
            }
            centreRows[(x + 1) * 9 + y + 1] = std::uint16_t(bits);
        }
    }
}

double BccMesher::centreValue(const View& v, int x, int y, int z, uint32_t* evaluated) const
{
    const int s = View::centreBlock(x, y, z);
    if (const float* d = v.centre[s]) return d[((x & 7) << 6) | ((y & 7) << 3) | (z & 7)];
    // A tile's cube next to a leaf: its centre's true value (rare, one point at a time).
    if (evaluated) ++*evaluated;
    return mField.value(indexToWorld(Vec3d(v.origin.x() + x + 0.5, v.origin.y() + y + 0.5, v.origin.z() + z + 0.5)));
}

Vec3d BccMesher::edgePoint(const View& v, int slot, int x, int y, int z, uint32_t* evaluated) const
{
    // Index space relative to the block origin; doubles of small integers and halves, so every
    // block that computes a vertex gets the same bits.
    Vec3d p0, p1;
    double v0, v1;
    if (slot < 3) {
        int q[3] = {x, y, z};
        p0 = Vec3d(x, y, z);
        v0 = v.cornerValue(x, y, z);
        ++q[slot];
        p1 = Vec3d(q[0], q[1], q[2]);
        v1 = v.cornerValue(q[0], q[1], q[2]);
    } else if (slot < 6) {
        int q[3] = {x, y, z};
        --q[slot - 3];
        p0 = Vec3d(q[0] + 0.5, q[1] + 0.5, q[2] + 0.5);
        v0 = centreValue(v, q[0], q[1], q[2], evaluated);
        p1 = Vec3d(x + 0.5, y + 0.5, z + 0.5);
        v1 = centreValue(v, x, y, z, evaluated);
    } else {
        const int k = slot - 6;
        p0 = Vec3d(x + 0.5, y + 0.5, z + 0.5);
        v0 = centreValue(v, x, y, z, evaluated);
        const int q[3] = {x + (k & 1), y + ((k >> 1) & 1), z + (k >> 2)};
        p1 = Vec3d(q[0], q[1], q[2]);
        v1 = v.cornerValue(q[0], q[1], q[2]);
    }
    double t = (double(mIso) - v0) / (v1 - v0);
    if (!std::isfinite(t)) t = 0.5;
    // Keep vertices off the nodes so no triangle can collapse onto one.
    t = std::clamp(t, 1e-3, 1.0 - 1e-3);
    return p0 + t * (p1 - p0) + Vec3d(v.origin.x(), v.origin.y(), v.origin.z());
}

int32_t BccMesher::ownerLeaf(std::size_t b, int x, int y, int z) const
{
    const int dx = x < 0 ? -1 : x >> 3, dy = y < 0 ? -1 : y >> 3, dz = z < 0 ? -1 : z >> 3;
    return mNeighbours[b][neighbourSlot(dx, dy, dz)];
}

uint32_t BccMesher::vertexIndex(std::size_t b, int slot, int x, int y, int z) const
{
    const int32_t owner = ownerLeaf(b, x, y, z);
    if (owner < 0) return UINT32_MAX;
    const int lx = x & 7, ly = y & 7, lz = z & 7;
    const int word = slot * 8 + lx, bit = (ly << 3) | lz;
    const std::uint64_t below = mEdgeMasks[owner][word] & ((std::uint64_t(1) << bit) - 1);
    return uint32_t(mVertexOffsets[owner] + mEdgeRanks[owner][word] + std::popcount(below));
}

template <bool Emit>
void BccMesher::processBlock(std::size_t b, Accessor& acc, TriangleMesh* mesh)
{
    const View v = view(b, acc);
    std::uint16_t cr[81], ce[81];
    insideRows(v, cr, ce);
    auto cornerIn = [&](int x, int y, int z) { return (cr[x * 9 + y] >> z) & 1; };
    auto centreIn = [&](int x, int y, int z) { return (ce[(x + 1) * 9 + y + 1] >> (z + 1)) & 1; };

    BlockCounts counts;
    if constexpr (!Emit) {
        std::array<std::uint64_t, kMaskWords>& mask = mEdgeMasks[b];
        mask.fill(0);
        for (int x = 0; x < 8; ++x) {
            for (int y = 0; y < 8; ++y) {
                const unsigned r = cr[x * 9 + y];
                const unsigned c = ce[(x + 1) * 9 + y + 1];
                const unsigned own = c >> 1;
                const int shift = 8 * y;
                mask[0 * 8 + x] |= std::uint64_t((r ^ cr[(x + 1) * 9 + y]) & 0xFF) << shift;
                mask[1 * 8 + x] |= std::uint64_t((r ^ cr[x * 9 + y + 1]) & 0xFF) << shift;
                mask[2 * 8 + x] |= std::uint64_t((r ^ (r >> 1)) & 0xFF) << shift;
                mask[3 * 8 + x] |= std::uint64_t((own ^ (ce[x * 9 + y + 1] >> 1)) & 0xFF) << shift;
                mask[4 * 8 + x] |= std::uint64_t((own ^ (ce[(x + 1) * 9 + y] >> 1)) & 0xFF) << shift;
                mask[5 * 8 + x] |= std::uint64_t((own ^ c) & 0xFF) << shift;
                for (int k = 0; k < 8; ++k) {
                    const unsigned corners = cr[(x + (k & 1)) * 9 + y + ((k >> 1) & 1)] >> (k >> 2);
                    mask[(6 + k) * 8 + x] |= std::uint64_t((own ^ corners) & 0xFF) << shift;
                }
            }
        }
        std::array<std::uint16_t, kMaskWords>& ranks = mEdgeRanks[b];
        uint32_t total = 0;
        for (int w = 0; w < kMaskWords; ++w) {
            ranks[w] = std::uint16_t(total);
            total += uint32_t(std::popcount(mask[w]));
        }
        counts.vertices = total;
    } else {
        // Owned vertices in mask bit order, the order vertexIndex() ranks them in.
        const std::array<std::uint64_t, kMaskWords>& mask = mEdgeMasks[b];
        std::uint64_t next = mVertexOffsets[b];
        uint32_t evaluated = 0;
        for (int w = 0; w < kMaskWords; ++w) {
            const int slot = w >> 3, x = w & 7;
            for (std::uint64_t bits = mask[w]; bits; bits &= bits - 1) {
                const int bit = std::countr_zero(bits);
                mesh->points[next++] =
                    openvdb::Vec3f(indexToWorld(edgePoint(v, slot, x, bit >> 3, bit & 7, &evaluated)));
            }
        }
        mCounts[b].tileCentres = evaluated;
    }

    openvdb::Vec3I* out = nullptr;
    if constexpr (Emit) out = mesh->triangles.data() + mTriangleOffsets[b];
    for (int x = 0; x < 8; ++x) {
        for (int y = 0; y < 8; ++y) {
            // Cubes with a sign change among the twelve nodes their tetrahedra use (and corner
            // (1, 1, 1), which only widens the test).
            const unsigned r00 = cr[x * 9 + y], r10 = cr[(x + 1) * 9 + y], r01 = cr[x * 9 + y + 1],
                           r11 = cr[(x + 1) * 9 + y + 1];
            const unsigned cAny = r00 | r10 | r01 | r11, cAll = r00 & r10 & r01 & r11;
            const unsigned own = ce[(x + 1) * 9 + y + 1] >> 1, lowZ = ce[(x + 1) * 9 + y + 1];
            const unsigned lowX = ce[x * 9 + y + 1] >> 1, lowY = ce[(x + 1) * 9 + y] >> 1;
            const unsigned any = cAny | (cAny >> 1) | own | lowX | lowY | lowZ;
            const unsigned all = cAll & (cAll >> 1) & own & lowX & lowY & lowZ;
            for (unsigned mixed = (any & ~all) & 0xFF; mixed; mixed &= mixed - 1) {
                const int z = std::countr_zero(mixed);
                for (const TetTemplate& tet : mTables.tets) {
                    int nodeMask = 0;
                    for (int i = 0; i < 4; ++i) {
                        const TetNode& n = tet.nodes[i];
                        const int px = x + n.offset[0], py = y + n.offset[1], pz = z + n.offset[2];
                        nodeMask |= int(n.centre ? centreIn(px, py, pz) : cornerIn(px, py, pz)) << i;
                    }
                    if (nodeMask == 0 || nodeMask == 15) continue;
                    const TetCase& tc = mTables.cases[nodeMask];
                    uint32_t index[4];
                    bool complete = true;
                    for (int i = 0; i < tc.size; ++i) {
                        const TetEdge& e = tet.edges[tc.edges[i]];
                        const int ex = x + e.offset[0], ey = y + e.offset[1], ez = z + e.offset[2];
                        if constexpr (Emit) {
                            index[i] = vertexIndex(b, e.slot, ex, ey, ez);
                            complete = complete && index[i] != UINT32_MAX;
                        } else {
                            // Masks and offsets are not known yet: only whether the owner is a leaf.
                            complete = complete && ownerLeaf(b, ex, ey, ez) >= 0;
                        }
                    }
                    if constexpr (!Emit) {
                        ++counts.crossingTets;
                        if (!complete)
                            ++counts.droppedTets;
                        else
                            counts.triangles += uint32_t(tc.size - 2);
                        continue;
                    } else {
                        if (!complete) continue;
                        if (tc.size == 3) {
                            *out++ = openvdb::Vec3I(index[0], index[1], index[2]);
                            continue;
                        }
                        // A quadrilateral: split along the shorter diagonal. The diagonal lies inside
                        // this tetrahedron, so the choice is its own; positions are recomputed
                        // here exactly as their owners compute them.
                        Vec3d p[4];
                        for (int i = 0; i < 4; ++i) {
                            const TetEdge& e = tet.edges[tc.edges[i]];
                            p[i] = edgePoint(v, e.slot, x + e.offset[0], y + e.offset[1], z + e.offset[2], nullptr);
                        }
                        if ((p[2] - p[0]).lengthSqr() <= (p[3] - p[1]).lengthSqr()) {
                            *out++ = openvdb::Vec3I(index[0], index[1], index[2]);
                            *out++ = openvdb::Vec3I(index[0], index[2], index[3]);
                        } else {
                            *out++ = openvdb::Vec3I(index[1], index[2], index[3]);
                            *out++ = openvdb::Vec3I(index[1], index[3], index[0]);
                        }
                    }
                }
            }
        }
    }
    if constexpr (!Emit) mCounts[b] = counts;
}

TriangleMesh BccMesher::run(ProgressFn progressFn, BccStats& stats)
{
    collectLeaves();
    const std::size_t numLeaves = mLeaves.size();
    mNeighbours.resize(numLeaves);
    mCentres.resize(numLeaves);
    mEdgeMasks.resize(numLeaves);
    mEdgeRanks.resize(numLeaves);
    mCounts.resize(numLeaves);
    // Evaluating the centres costs about as much as the other two passes together.
    ExtractProgress progress(std::move(progressFn), 4 * numLeaves);

    // The result never depends on how ranges are split: every leaf writes only its own slots.
    constexpr std::size_t kGrain = 16;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numLeaves, kGrain), [&](const auto& r) {
        for (std::size_t b = r.begin(); b != r.end(); ++b) {
            const Coord o = mLeaves[b]->origin();
            for (int dx = -1; dx <= 1; ++dx)
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dz = -1; dz <= 1; ++dz)
                        mNeighbours[b][neighbourSlot(dx, dy, dz)] = findLeaf(o + Coord(dx * 8, dy * 8, dz * 8));
            evaluateCentres(b);
            progress.advance(2);
        }
    });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numLeaves, kGrain), [&](const auto& r) {
        Accessor acc(mTree);
        for (std::size_t b = r.begin(); b != r.end(); ++b) {
            processBlock<false>(b, acc, nullptr);
            progress.advance();
        }
    });

    mVertexOffsets.resize(numLeaves + 1);
    mTriangleOffsets.resize(numLeaves + 1);
    mVertexOffsets[0] = mTriangleOffsets[0] = 0;
    for (std::size_t b = 0; b < numLeaves; ++b) {
        mVertexOffsets[b + 1] = mVertexOffsets[b] + mCounts[b].vertices;
        mTriangleOffsets[b + 1] = mTriangleOffsets[b] + mCounts[b].triangles;
    }
    if (mVertexOffsets[numLeaves] > std::uint64_t(UINT32_MAX) - 1)
        throw std::length_error("bccTetrahedra: more than 2^32 vertices");

    TriangleMesh mesh;
    tbb::parallel_invoke([&] { mesh.points.resize(mVertexOffsets[numLeaves]); },
                         [&] { mesh.triangles.resize(mTriangleOffsets[numLeaves]); });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numLeaves, kGrain), [&](const auto& r) {
        Accessor acc(mTree);
        for (std::size_t b = r.begin(); b != r.end(); ++b) {
            if (mCounts[b].vertices != 0 || mCounts[b].triangles != 0) processBlock<true>(b, acc, &mesh);
            progress.advance();
        }
    });

    stats = BccStats{};
    stats.leafBlocks = numLeaves;
    stats.centreValues = 512 * numLeaves;
    for (const BlockCounts& c : mCounts) {
        stats.tileCentreValues += c.tileCentres;
        stats.crossingTetrahedra += c.crossingTets;
        stats.droppedTetrahedra += c.droppedTets;
    }
    progress.finish();
    return mesh;
}

}  // namespace

TriangleMesh bccTetrahedra(const openvdb::FloatGrid& grid, const FieldNode& field, float isoValue, ProgressFn progress,
                           BccStats* stats)
{
    BccStats local;
    BccMesher mesher(grid, field, isoValue);
    TriangleMesh mesh = mesher.run(std::move(progress), local);
    if (stats) *stats = local;
    return mesh;
}

}  // namespace voxlat
