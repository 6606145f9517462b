#include "mesher/extract/MarchingCubes.h"

#include "mesher/extract/ExtractProgress.h"
#include "mesher/extract/SignWords.h"

#include <openvdb/tree/ValueAccessor.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/parallel_pipeline.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

namespace voxlat {

namespace {

////////////////////////////////////////////////////////////////////////////////////////////////////
// Cube geometry
//
// Corner c of a cube sits at offset (c & 1, (c >> 1) & 1, (c >> 2) & 1) from the cube's minimum
// voxel. Edge e runs along axis e >> 2; bits 0 and 1 of (e & 3) give its offset along the other two
// axes in increasing axis order. Face f lies on axis f >> 1 at side f & 1 (0: minimum, 1: maximum).

constexpr int kNumCases = 256 * 64;
constexpr int kCentroidBase = 12;  // triangle vertex ids >= this name a loop centroid

/// The two axes other than @a axis, in increasing order.
constexpr std::array<int, 2> otherAxes(int axis)
{
    return axis == 0 ? std::array<int, 2>{1, 2} : axis == 1 ? std::array<int, 2>{0, 2} : std::array<int, 2>{0, 1};
}

constexpr int cornerBit(int corner, int axis)
{
    return (corner >> axis) & 1;
}

constexpr int edgeAxis(int edge)
{
    return edge >> 2;
}

constexpr int edgeLowerCorner(int edge)
{
    const int axis = edgeAxis(edge);
    const auto [u, v] = otherAxes(axis);
    return ((edge & 1) << u) | (((edge >> 1) & 1) << v);
}

constexpr int edgeUpperCorner(int edge)
{
    return edgeLowerCorner(edge) | (1 << edgeAxis(edge));
}

/// Edge @a e's lower corner offsets and axis as one table entry {dx, dy, dz, axis}: the mesher's
/// inner loops read this instead of decoding the edge number each time.
struct EdgeStep {
    int dx, dy, dz, axis;
};
constexpr std::array<EdgeStep, 12> kEdgeSteps = [] {
    std::array<EdgeStep, 12> steps{};
    for (int e = 0; e < 12; ++e) {
        const int c = edgeLowerCorner(e);
        steps[std::size_t(e)] = {cornerBit(c, 0), cornerBit(c, 1), cornerBit(c, 2), edgeAxis(e)};
    }
    return steps;
}();

/// The four corners of face @a face in cyclic order around it.
constexpr std::array<int, 4> faceCorners(int face)
{
    const int axis = face >> 1, side = face & 1;
    const auto [u, v] = otherAxes(axis);
    const int base = side << axis;
    return {base, base | (1 << u), base | (1 << u) | (1 << v), base | (1 << v)};
}

constexpr int edgeBetween(int c0, int c1)
{
    for (int e = 0; e < 12; ++e) {
        const int lo = edgeLowerCorner(e), hi = edgeUpperCorner(e);
        if ((lo == c0 && hi == c1) || (lo == c1 && hi == c0)) return e;
    }
    return -1;
}

constexpr bool edgeOnFace(int edge, int face)
{
    const int axis = face >> 1, side = face & 1;
    return edgeAxis(edge) != axis && cornerBit(edgeLowerCorner(edge), axis) == side;
}

constexpr bool edgesShareFace(int e0, int e1)
{
    for (int f = 0; f < 6; ++f) {
        if (edgeOnFace(e0, f) && edgeOnFace(e1, f)) return true;
    }
    return false;
}

using Vec3d = openvdb::Vec3d;

Vec3d cornerPosition(int corner)
{
    return Vec3d(cornerBit(corner, 0), cornerBit(corner, 1), cornerBit(corner, 2));
}

Vec3d edgeMidpoint(int edge)
{
    return 0.5 * (cornerPosition(edgeLowerCorner(edge)) + cornerPosition(edgeUpperCorner(edge)));
}

////////////////////////////////////////////////////////////////////////////////////////////////////
// Case table

constexpr int kMaxTriangles = 12;
constexpr int kMaxCentroids = 4;

/// Triangles of one (corner case, ambiguous face decisions) combination, in cube-edge numbering.
struct CaseEntry {
    std::uint8_t numTriangles = 0;
    std::uint8_t numCentroids = 0;
    /// Per centroid vertex: bit mask of the cube edges whose vertices it averages.
    std::uint16_t centroidLoop[kMaxCentroids] = {};
    std::uint8_t triangles[kMaxTriangles][3] = {};
};

struct CaseTable {
    std::array<CaseEntry, kNumCases> entries;
    /// Per corner case: faces whose inside corners lie on one diagonal (need the decider).
    std::array<std::uint8_t, 256> ambiguousFaces{};
    /// Per corner case: cube edges with a sign change.
    std::array<std::uint16_t, 256> crossingEdges{};
    MarchingCubesTableInfo info;
};

/// One oriented segment of the surface on a cube face, from vertex (edge) @c from to @c to.
struct Segment {
    int from, to;
};

/// Segments on @a face for corner case @a cs, oriented so the inside corners are on the right
/// when the face is viewed from outside the cube. @a connectInside is the decider's verdict, used
/// only if the face is ambiguous.
std::vector<Segment> faceSegments(int cs, int face, bool connectInside)
{
    const std::array<int, 4> corners = faceCorners(face);
    auto inside = [cs](int corner) { return ((cs >> corner) & 1) != 0; };
    std::array<int, 4> sideEdge{};  // sideEdge[i] joins corners[i] and corners[i + 1]
    int numCrossing = 0;
    for (int i = 0; i < 4; ++i) {
        sideEdge[i] = edgeBetween(corners[i], corners[(i + 1) % 4]);
        if (inside(corners[i]) != inside(corners[(i + 1) % 4])) ++numCrossing;
    }

    const int axis = face >> 1;
    Vec3d normal(0.0);
    normal[axis] = (face & 1) ? 1.0 : -1.0;
    // Orients a segment given a face corner it separates from the rest of the face: viewed along
    // -normal, a point p is on the left of a -> b exactly when ((b - a) x (p - a)) . normal > 0.
    auto orient = [&](int e0, int e1, int corner) {
        const Vec3d a = edgeMidpoint(e0), b = edgeMidpoint(e1);
        const bool onLeft = (b - a).cross(cornerPosition(corner) - a).dot(normal) > 0.0;
        return onLeft == inside(corner) ? Segment{e1, e0} : Segment{e0, e1};
    };

    std::vector<Segment> segments;
    if (numCrossing == 2) {
        int ends[2], n = 0;
        for (int i = 0; i < 4; ++i) {
            if (inside(corners[i]) != inside(corners[(i + 1) % 4])) ends[n++] = sideEdge[i];
        }
        // Every corner lies on a side whose corners all share its state, so any will do.
        segments.push_back(orient(ends[0], ends[1], corners[0]));
    } else if (numCrossing == 4) {
        // Two segments, each cutting off one corner: the outside corners when the inside ones are
        // connected across the face centre, the inside corners otherwise.
        for (int i = 0; i < 4; ++i) {
            if (inside(corners[i]) == connectInside) continue;
            segments.push_back(orient(sideEdge[(i + 3) % 4], sideEdge[i], corners[i]));
        }
    }
    return segments;
}

bool isAmbiguousFace(int cs, int face)
{
    const std::array<int, 4> c = faceCorners(face);
    auto inside = [cs](int corner) { return ((cs >> corner) & 1) != 0; };
    return inside(c[0]) == inside(c[2]) && inside(c[1]) == inside(c[3]) && inside(c[0]) != inside(c[1]);
}

/// Checks that the triangles of an entry form a surface patch whose boundary is exactly the face
/// segments (each once, in their direction) and whose interior edges pair up with opposite
/// directions. This is what makes neighbouring cubes glue into a closed oriented manifold.
void validateEntry(const CaseEntry& entry, const std::vector<Segment>& segments, int index)
{
    std::vector<std::pair<int, int>> directed;
    for (int t = 0; t < entry.numTriangles; ++t) {
        for (int k = 0; k < 3; ++k) directed.emplace_back(entry.triangles[t][k], entry.triangles[t][(k + 1) % 3]);
    }
    std::sort(directed.begin(), directed.end());
    auto fail = [index](const char* what) {
        throw std::logic_error("marching cubes table entry " + std::to_string(index) + ": " + what);
    };
    if (std::adjacent_find(directed.begin(), directed.end()) != directed.end()) fail("repeated half-edge");
    for (const Segment& s : segments) {
        if (!std::binary_search(directed.begin(), directed.end(), std::make_pair(s.from, s.to)))
            fail("missing segment");
        if (std::binary_search(directed.begin(), directed.end(), std::make_pair(s.to, s.from))) fail("doubled segment");
    }
    for (const auto& [a, b] : directed) {
        const bool isSegment = std::any_of(segments.begin(), segments.end(),
                                           [&, a = a, b = b](const Segment& s) { return s.from == a && s.to == b; });
        if (!isSegment && !std::binary_search(directed.begin(), directed.end(), std::make_pair(b, a))) {
            fail("unpaired interior edge");
        }
    }
}

std::unique_ptr<CaseTable> buildCaseTable()
{
    auto table = std::make_unique<CaseTable>();
    MarchingCubesTableInfo& info = table->info;

    for (int cs = 0; cs < 256; ++cs) {
        std::uint16_t crossing = 0;
        for (int e = 0; e < 12; ++e) {
            if (((cs >> edgeLowerCorner(e)) & 1) != ((cs >> edgeUpperCorner(e)) & 1)) crossing |= 1u << e;
        }
        table->crossingEdges[cs] = crossing;
        std::uint8_t ambiguous = 0;
        for (int f = 0; f < 6; ++f) {
            if (isAmbiguousFace(cs, f)) ambiguous |= 1u << f;
        }
        table->ambiguousFaces[cs] = ambiguous;

        for (int decisions = 0; decisions < 64; ++decisions) {
            // Decision bits of unambiguous faces are always 0 at run time.
            if (decisions & ~ambiguous) continue;
            const int index = (cs << 6) | decisions;
            CaseEntry& entry = table->entries[index];
            ++info.entries;

            std::vector<Segment> segments;
            for (int f = 0; f < 6; ++f) {
                for (const Segment& s : faceSegments(cs, f, ((decisions >> f) & 1) != 0)) segments.push_back(s);
            }
            // Every edge vertex lies on exactly two faces, so it must start one segment and end one.
            std::array<int, 12> next;
            next.fill(-1);
            std::array<int, 12> incoming{};
            for (const Segment& s : segments) {
                if (next[s.from] != -1) throw std::logic_error("marching cubes table: vertex starts two segments");
                next[s.from] = s.to;
                ++incoming[s.to];
            }
            for (int e = 0; e < 12; ++e) {
                const bool crosses = (crossing >> e) & 1;
                if (crosses != (next[e] != -1) || incoming[e] != (crosses ? 1 : 0)) {
                    throw std::logic_error("marching cubes table: segments do not form loops");
                }
            }

            std::array<bool, 12> visited{};
            for (int start = 0; start < 12; ++start) {
                if (next[start] == -1 || visited[start]) continue;
                std::vector<int> loop;
                for (int e = start; !visited[e]; e = next[e]) {
                    visited[e] = true;
                    loop.push_back(e);
                }
                ++info.loops;
                const int n = int(loop.size());

                // A fan diagonal between two vertices on one cube face could coincide with an edge
                // the neighbour across that face also uses; any other diagonal is private to this
                // cube. Take the first apex all of whose diagonals are private.
                int apex = -1;
                for (int i = 0; i < n && apex < 0; ++i) {
                    bool ok = true;
                    for (int j = 2; j + 1 < n && ok; ++j) ok = !edgesShareFace(loop[i], loop[(i + j) % n]);
                    if (ok) apex = i;
                }
                auto addTriangle = [&](int a, int b, int c) {
                    if (entry.numTriangles == kMaxTriangles)
                        throw std::logic_error("marching cubes table: too many triangles");
                    std::uint8_t* t = entry.triangles[entry.numTriangles++];
                    t[0] = std::uint8_t(a), t[1] = std::uint8_t(b), t[2] = std::uint8_t(c);
                };
                if (apex >= 0) {
                    for (int j = 1; j + 1 < n; ++j)
                        addTriangle(loop[apex], loop[(apex + j) % n], loop[(apex + j + 1) % n]);
                } else {
                    if (entry.numCentroids == kMaxCentroids)
                        throw std::logic_error("marching cubes table: too many centroids");
                    const int centroid = kCentroidBase + entry.numCentroids;
                    std::uint16_t mask = 0;
                    for (int e : loop) mask |= 1u << e;
                    entry.centroidLoop[entry.numCentroids++] = mask;
                    for (int j = 0; j < n; ++j) addTriangle(centroid, loop[j], loop[(j + 1) % n]);
                    ++info.centroidLoops;
                }
            }
            info.maxTriangles = std::max<std::size_t>(info.maxTriangles, entry.numTriangles);
            validateEntry(entry, segments, index);
        }
    }
    return table;
}

const CaseTable& caseTable()
{
    // Function-local statics are initialised exactly once, even under concurrent first calls.
    static const std::unique_ptr<CaseTable> table = buildCaseTable();
    return *table;
}

////////////////////////////////////////////////////////////////////////////////////////////////////
// Block bookkeeping
//
// Work is split into 8^3 blocks: every leaf node, plus every tile/background block directly below
// a leaf in x, y or z ("tile blocks"). A block owns the cubes whose minimum corner it contains and
// the edges (three per voxel, towards +x, +y, +z) whose lower voxel it contains; only leaves own
// edges with vertices, since tile voxels never border the surface.

using FloatTree = openvdb::FloatTree;
using LeafType = FloatTree::LeafNodeType;
using Coord = openvdb::Coord;

constexpr int kDim = 9;         // a block plus one layer from the +x/+y/+z neighbours
constexpr int kMaskWords = 24;  // 3 axes x 8 words of 64 bits; word = axis * 8 + x, bit = y * 8 + z

/// Where the Stream pass keeps the vertex of the edge along @a axis from voxel (x, y, z) of a
/// block, each coordinate in [0, 8]: the block's own vertices and those its +x/+y/+z neighbours
/// own on its far faces, so every cube of a leaf reads its corners from one table.
constexpr int blockVertexSlot(int axis, int x, int y, int z)
{
    return ((axis * kDim + x) * kDim + y) * kDim + z;
}
constexpr int kBlockVertexSlots = 3 * kDim * kDim * kDim;

/// Per edge, its blockVertexSlot() relative to that of the cube's minimum voxel along x.
constexpr std::array<int, 12> kEdgeSlotOffset = [] {
    std::array<int, 12> offsets{};
    for (int e = 0; e < 12; ++e) {
        const EdgeStep& s = kEdgeSteps[std::size_t(e)];
        offsets[std::size_t(e)] = blockVertexSlot(s.axis, s.dx, s.dy, s.dz);
    }
    return offsets;
}();

/// Offset from a block's origin to the origin of its neighbour s (bit 0: +x, bit 1: +y, bit 2: +z).
Coord neighbourOffset(int s)
{
    const int dim = int(LeafType::DIM);
    return Coord((s & 1) * dim, ((s >> 1) & 1) * dim, (s >> 2) * dim);
}

/// Open-addressing map from block origin to block index. Written by one thread, then read-only.
/// Key and index share a 16-byte slot, so a probe costs one cache line, not two.
/// When the blocks' bounding box holds few enough blocks (dense(): at most 16 M, and at most 16
/// per block present), find() reads a plain array indexed by position instead: 4 bytes a slot,
/// neighbours of consecutive blocks close together, where hashed slots were a cache miss each
/// (a twelfth of the mesher's time on the acceptance gyroid).
class BlockMap {
public:
    explicit BlockMap(std::size_t expected) { rehash(std::bit_ceil(std::max<std::size_t>(64, 2 * expected))); }

    /// A map whose blocks all have their origins in [@a lo, @a hi]: a plain array over that box
    /// from the start when it is small enough (as densify() would make it), so inserting costs no
    /// hashing and no probes into a table of megabytes.
    BlockMap(std::size_t expected, const Coord& lo, const Coord& hi)
    {
        const Coord dims = ((hi - lo) >> 3) + Coord(1);
        const std::uint64_t volume = std::uint64_t(dims.x()) * std::uint64_t(dims.y()) * std::uint64_t(dims.z());
        if (volume > (std::uint64_t(1) << 24) || volume > 16 * std::uint64_t(expected)) {
            rehash(std::bit_ceil(std::max<std::size_t>(64, 2 * expected)));
            return;
        }
        mDenseOrigin = lo;
        mDenseDims = dims;
        mDense.assign(volume, -1);
    }

    /// Switches find() to a dense array over the blocks inserted so far, if their box is small
    /// enough. Nothing may be inserted afterwards.
    void densify()
    {
        if (mSize == 0 || !mDense.empty()) return;
        Coord lo(std::numeric_limits<int>::max()), hi(std::numeric_limits<int>::min());
        for (const Entry& e : mEntries) {
            if (e.index < 0) continue;
            lo.minComponent(e.key);
            hi.maxComponent(e.key);
        }
        const Coord dims = ((hi - lo) >> 3) + Coord(1);
        const std::uint64_t volume = std::uint64_t(dims.x()) * std::uint64_t(dims.y()) * std::uint64_t(dims.z());
        if (volume > (std::uint64_t(1) << 24) || volume > 16 * std::uint64_t(mSize)) return;
        mDenseOrigin = lo;
        mDenseDims = dims;
        mDense.assign(volume, -1);
        for (const Entry& e : mEntries)
            if (e.index >= 0) mDense[denseSlot(e.key)] = e.index;
    }

    int32_t find(const Coord& origin) const
    {
        if (!mDense.empty()) {
            const Coord d = (origin - mDenseOrigin) >> 3;
            if (std::uint32_t(d.x()) >= std::uint32_t(mDenseDims.x()) ||
                std::uint32_t(d.y()) >= std::uint32_t(mDenseDims.y()) ||
                std::uint32_t(d.z()) >= std::uint32_t(mDenseDims.z()))
                return -1;
            return mDense[denseSlot(origin)];
        }
        for (std::size_t i = slot(origin);; i = (i + 1) & mMask) {
            const Entry& e = mEntries[i];
            if (e.index < 0) return -1;
            if (e.key == origin) return e.index;
        }
    }

    /// Inserts @a origin -> @a index unless present; returns the index stored for @a origin.
    int32_t insert(const Coord& origin, int32_t index)
    {
        if (!mDense.empty()) {
            int32_t& stored = mDense[denseSlot(origin)];
            if (stored < 0) stored = index;
            return stored;
        }
        if (2 * (mSize + 1) > mEntries.size()) rehash(2 * mEntries.size());
        for (std::size_t i = slot(origin);; i = (i + 1) & mMask) {
            Entry& e = mEntries[i];
            if (e.index < 0) {
                e = {origin, index};
                ++mSize;
                return index;
            }
            if (e.key == origin) return e.index;
        }
    }

private:
    struct Entry {
        Coord key;
        int32_t index = -1;
    };

    std::size_t slot(const Coord& c) const
    {
        const std::uint64_t h = std::uint64_t(std::uint32_t(c.x() >> 3)) * 0x9E3779B97F4A7C15ull ^
                                std::uint64_t(std::uint32_t(c.y() >> 3)) * 0xC2B2AE3D27D4EB4Full ^
                                std::uint64_t(std::uint32_t(c.z() >> 3)) * 0x165667B19E3779F9ull;
        return std::size_t(h ^ (h >> 29)) & mMask;
    }

    void rehash(std::size_t capacity)
    {
        std::vector<Entry> entries(capacity);
        entries.swap(mEntries);
        mMask = capacity - 1;
        mSize = 0;
        for (const Entry& e : entries)
            if (e.index >= 0) insert(e.key, e.index);
    }

    std::size_t denseSlot(const Coord& origin) const
    {
        const Coord d = (origin - mDenseOrigin) >> 3;
        return (std::size_t(d.x()) * std::size_t(mDenseDims.y()) + std::size_t(d.y())) * std::size_t(mDenseDims.z()) +
               std::size_t(d.z());
    }

    std::vector<Entry> mEntries;
    std::size_t mMask = 0, mSize = 0;
    std::vector<int32_t> mDense;  ///< by position in the blocks' box, when dense enough
    Coord mDenseOrigin, mDenseDims;
};

struct Block {
    Coord origin;
    const LeafType* leaf = nullptr;  // null for a tile block
};

/// Per-block results of the counting pass.
struct BlockCounts {
    uint32_t edgeVertices = 0;
    uint32_t centroids = 0;
    uint32_t triangles = 0;
    uint32_t droppedCubes = 0;
};

/// A sign-changing edge without a vertex: lower voxel and axis.
struct SkippedEdge {
    Coord voxel;
    int axis;
    bool operator<(const SkippedEdge& o) const { return voxel < o.voxel || (voxel == o.voxel && axis < o.axis); }
    bool operator==(const SkippedEdge& o) const { return voxel == o.voxel && axis == o.axis; }
};

/// Serialized, monotonic progress reporting in whole percents.
/// The values a block's cubes can see: the block itself and its +x/+y/+z neighbours, each either
/// a leaf buffer or a constant (tile or background). Reading through it costs no copy of the
/// 9x9x9 neighbourhood, which matters because most blocks only need their sign bits.
struct Neighbourhood {
    const float* data[8];  // sub-block s (bit 0: +x, bit 1: +y, bit 2: +z); null if constant
    float constant[8];

    /// Value at (x, y, z) relative to the block origin, each coordinate in [0, 8].
    float value(int x, int y, int z) const
    {
        const int s = (x >> 3) | ((y >> 3) << 1) | ((z >> 3) << 2);
        const float* d = data[s];
        return d ? d[((x & 7) << 6) | ((y & 7) << 3) | (z & 7)] : constant[s];
    }
};

/// std::popcount is a library call unless the target has POPCNT; this is the inline fallback.
inline int popcount64(std::uint64_t x)
{
#if defined(__POPCNT__)
    return std::popcount(x);
#else
    x -= (x >> 1) & 0x5555555555555555ull;
    x = (x & 0x3333333333333333ull) + ((x >> 2) & 0x3333333333333333ull);
    x = (x + (x >> 4)) & 0x0F0F0F0F0F0F0F0Full;
    return int((x * 0x0101010101010101ull) >> 56);
#endif
}

/// One chunk's triangles for the Stream pass. Appending has no capacity test per triangle:
/// processBlock() makes room for a block's most triangles before the block.
class CornerBuffer {
public:
    void clear() { mSize = 0; }
    void reserveMore(std::size_t n)
    {
        if (mSize + n <= mCapacity) return;
        const std::size_t capacity = std::max(2 * mCapacity, mSize + n);
        auto data = std::make_unique_for_overwrite<TriangleCorners[]>(capacity);
        std::copy(mData.get(), mData.get() + mSize, data.get());
        mData = std::move(data);
        mCapacity = capacity;
    }
    /// After reserveMore(): room is there.
    void push(const openvdb::Vec3f& a, const openvdb::Vec3f& b, const openvdb::Vec3f& c)
    {
        TriangleCorners& t = mData[mSize++];
        t[0] = a;
        t[1] = b;
        t[2] = c;
    }
    std::span<const TriangleCorners> triangles() const { return {mData.get(), mSize}; }

private:
    std::unique_ptr<TriangleCorners[]> mData;
    std::size_t mSize = 0, mCapacity = 0;
};

/// What processBlock() does: count (and record neighbours and edge masks), emit into an indexed
/// mesh, or emit triangles as corner positions (no indices).
enum class Pass { Count, Emit, Stream };

/// Consecutive blocks per chunk of the streamed pass (marchingCubesStreamed()): what each
/// consumer call sees, whatever the thread count.
constexpr std::size_t kChunkBlocks = 256;

class Mesher {
public:
    Mesher(const openvdb::FloatGrid& grid, float iso) : mGrid(grid), mTree(grid.tree()), mIso(iso), mTable(caseTable())
    {
        // Grids made by the engine map index to world by scale and translation: call that map
        // directly (its applyMap is final, so the call inlines) instead of through the virtual
        // MapBase for each of millions of vertices. Same function, same bits.
        const auto map = grid.transform().baseMap();
        if (map->isType<openvdb::math::ScaleTranslateMap>() || map->isType<openvdb::math::UniformScaleTranslateMap>())
            mScaleTranslate = static_cast<const openvdb::math::ScaleTranslateMap*>(map.get());
    }

    TriangleMesh run(ProgressFn progressFn, MarchingCubesStats& stats);
    StreamedMeshCounts runStreamed(const TriangleStream& stream, ProgressFn progressFn, MarchingCubesStats& stats);

private:
    using Accessor = openvdb::tree::ValueAccessor<const FloatTree, /*IsSafe=*/false>;

    void collectBlocks();
    void computeSigns(std::size_t leaf);
    using Neighbours = std::array<int32_t, 8>;  ///< [0]: self, [s]: block at +s; -1 unless a leaf
    Neighbourhood neighbourhood(std::size_t b, const Neighbours& nb, Accessor& acc) const;
    void insideRows(const Neighbours& nb, const Neighbourhood& n, std::uint16_t* rows) const;
    template <Pass P>
    void processBlock(std::size_t b, Accessor& acc, TriangleMesh* mesh, CornerBuffer* corners = nullptr);
    /// After collectBlocks(): sizes the per-block arrays (with @a indexed, also those the Emit
    /// pass reads: neighbours, edge masks and ranks) and makes every leaf's sign words.
    void prepare(bool indexed);
    /// After collectBlocks(): prepare(), the counting pass, then the prefix sums.
    void countAll(ExtractProgress& progress);
    void fillStats(MarchingCubesStats& stats);
    static bool cubeHasVertices(int x, int y, int z, std::uint16_t crossing, std::uint8_t available);
    int decisions(int cs, const Neighbourhood& n, int x, int y, int z) const;
    uint32_t neighbourVertexIndex(std::size_t owner, int axis, int lx, int ly, int lz) const;
    /// World position of the centroid of a cube's loop (edge bits @a loop): the loop's edge points
    /// averaged in index space, then mapped like any other vertex. Rare.
    openvdb::Vec3f centroid(const Neighbourhood& n, const Coord& origin, int x, int y, int z, std::uint16_t loop) const
    {
        Vec3d sum(0.0);
        int count = 0;
        for (std::uint16_t bits = loop; bits; bits &= bits - 1, ++count) {
            const int e = std::countr_zero(bits), c = edgeLowerCorner(e);
            sum += edgePoint(n, origin, x + cornerBit(c, 0), y + cornerBit(c, 1), z + cornerBit(c, 2), edgeAxis(e));
        }
        return openvdb::Vec3f(indexToWorld(sum / double(count)));
    }
    [[gnu::always_inline]] Vec3d edgePoint(const Neighbourhood& n, const Coord& origin, int x, int y, int z,
                                           int axis) const;

    Vec3d indexToWorld(const Vec3d& p) const
    {
        return mScaleTranslate ? mScaleTranslate->applyMap(p) : mGrid.indexToWorld(p);
    }

    const openvdb::FloatGrid& mGrid;
    const openvdb::math::ScaleTranslateMap* mScaleTranslate = nullptr;  ///< the grid's map, if of that type
    const FloatTree& mTree;
    const float mIso;
    const CaseTable& mTable;

    std::vector<Block> mBlocks;
    std::size_t mNumLeaves = 0;
    std::unique_ptr<BlockMap> mMap;

    /// Per leaf, the voxels below the iso-value: word x, bit (y << 3) | z. Made once from the
    /// leaf's values read in order; both passes build their cube rows from these 64 bytes per
    /// leaf instead of reading scattered values of four leaves each time (the +z neighbour's
    /// z = 0 plane alone touches every cache line of its leaf).
    std::vector<std::array<std::uint64_t, 8>> mSigns;

    // Filled by the counting pass for the Emit pass (the Stream pass keeps them on its stack).
    std::vector<Neighbours> mNeighbours;
    std::vector<std::array<std::uint64_t, kMaskWords>> mEdgeMasks;  // leaves only
    std::vector<std::array<std::uint16_t, kMaskWords>> mEdgeRanks;  // set bits before each word
    std::vector<BlockCounts> mCounts;
    std::vector<SkippedEdge> mSkipped;
    std::mutex mSkippedMutex;

    // Prefix sums.
    std::vector<std::uint64_t> mVertexOffsets, mTriangleOffsets;
};

void Mesher::collectBlocks()
{
    mBlocks.reserve(2 * std::size_t(mTree.leafCount()));
    Coord lo(std::numeric_limits<int>::max()), hi(std::numeric_limits<int>::min());
    for (auto it = mTree.cbeginLeaf(); it; ++it) {
        mBlocks.push_back({it->origin(), it.getLeaf()});
        lo.minComponent(it->origin());
        hi.maxComponent(it->origin());
    }
    mNumLeaves = mBlocks.size();
    if (mNumLeaves == 0) {
        mMap = std::make_unique<BlockMap>(0);
        return;
    }
    // The blocks below leaves reach one block lower on each axis.
    mMap = std::make_unique<BlockMap>(mNumLeaves + mNumLeaves / 4, lo - Coord(int(LeafType::DIM)), hi);
    for (std::size_t i = 0; i < mNumLeaves; ++i) mMap->insert(mBlocks[i].origin, int32_t(i));
    // A cube whose minimum corner is a tile voxel can still reach into a leaf above it. Give the
    // blocks below leaves an owner too, appended in leaf order so the result stays deterministic.
    for (std::size_t i = 0; i < mNumLeaves; ++i) {
        for (int s = 1; s < 8; ++s) {
            const Coord origin = mBlocks[i].origin - neighbourOffset(s);
            const int32_t next = int32_t(mBlocks.size());
            if (mMap->insert(origin, next) == next) mBlocks.push_back({origin, nullptr});
        }
    }
    mMap->densify();
}

Neighbourhood Mesher::neighbourhood(std::size_t b, const Neighbours& nb, Accessor& acc) const
{
    Neighbourhood n;
    for (int s = 0; s < 8; ++s) {
        const int32_t i = nb[s];
        if (i >= 0) {
            n.data[s] = mBlocks[i].leaf->buffer().data();
            n.constant[s] = 0.0f;
        } else {
            // Not a leaf: a tile or the background, constant over the whole 8^3 block.
            n.data[s] = nullptr;
            n.constant[s] = acc.getValue(mBlocks[b].origin + neighbourOffset(s));
        }
    }
    return n;
}

void Mesher::computeSigns(std::size_t leaf)
{
    // "< iso", never "<=": a value exactly at the threshold is outside, on both sides of every edge.
    belowWords(mBlocks[leaf].leaf->buffer().data(), mIso, mSigns[leaf].data());
}

void Mesher::insideRows(const Neighbours& nb, const Neighbourhood& n, std::uint16_t* rows) const
{
    // rows[x * 9 + y] has bit z set when voxel (x, y, z) is inside, from the sign words of the
    // block and its +x/+y/+z neighbours (constant sub-blocks: all or none).
    const std::uint64_t* words[8];
    std::uint64_t constant[8];
    for (int s = 0; s < 8; ++s) {
        const int32_t i = nb[s];
        words[s] = i >= 0 ? mSigns[std::size_t(i)].data() : nullptr;
        constant[s] = n.constant[s] < mIso ? ~std::uint64_t(0) : 0;
    }
    auto row = [&](int s, int x) { return words[s] ? words[s][x] : constant[s]; };
    for (int x = 0; x < kDim; ++x) {
        const int sx = x >> 3, lx = x & 7;
        const std::uint64_t low = row(sx, lx), lowY = row(sx | 2, lx);
        const std::uint64_t high = row(sx | 4, lx), highY = row(sx | 6, lx);
        // Byte y of a word is row y's bits: as bytes (little-endian), the eight rows vectorise.
        std::uint8_t lowBytes[8], highBytes[8];
        if constexpr (std::endian::native == std::endian::little) {
            std::memcpy(lowBytes, &low, 8);
            std::memcpy(highBytes, &high, 8);
        } else {
            for (int y = 0; y < 8; ++y) {
                lowBytes[y] = std::uint8_t(low >> (8 * y));
                highBytes[y] = std::uint8_t(high >> (8 * y));
            }
        }
        for (int y = 0; y < 8; ++y) rows[x * kDim + y] = std::uint16_t(lowBytes[y] | ((highBytes[y] & 1u) << 8));
        rows[x * kDim + 8] = std::uint16_t((lowY & 0xFF) | ((highY & 1) << 8));
    }
}

bool Mesher::cubeHasVertices(int x, int y, int z, std::uint16_t crossing, std::uint8_t available)
{
    for (int e = 0; e < 12; ++e) {
        if (!((crossing >> e) & 1)) continue;
        const int c = edgeLowerCorner(e);
        const int s =
            ((x + cornerBit(c, 0)) >> 3) | (((y + cornerBit(c, 1)) >> 3) << 1) | (((z + cornerBit(c, 2)) >> 3) << 2);
        if (!((available >> s) & 1)) return false;
    }
    return true;
}

int Mesher::decisions(int cs, const Neighbourhood& n, int x, int y, int z) const
{
    int bits = 0;
    for (std::uint8_t amb = mTable.ambiguousFaces[cs]; amb; amb &= amb - 1) {
        const int f = std::countr_zero(amb);
        const std::array<int, 4> c = faceCorners(f);
        double v[4];
        for (int i = 0; i < 4; ++i) {
            v[i] =
                double(n.value(x + cornerBit(c[i], 0), y + cornerBit(c[i], 1), z + cornerBit(c[i], 2))) - double(mIso);
        }
        // Products of the diagonal pairs, exactly as the neighbour across the face computes them
        // (IEEE multiplication commutes), so both cubes reach the same verdict bit for bit.
        const double d02 = v[0] * v[2], d13 = v[1] * v[3];
        const bool firstDiagonalInside = (cs >> c[0]) & 1;
        const bool connectInside = firstDiagonalInside ? d02 > d13 : d13 > d02;
        if (connectInside) bits |= 1 << f;
    }
    return bits;
}

uint32_t Mesher::neighbourVertexIndex(std::size_t owner, int axis, int lx, int ly, int lz) const
{
    // Rank of the edge among the owner's sign-changing edges: whole words before it, then the
    // bits below it in its word.
    const int word = axis * 8 + lx, bit = (ly << 3) | lz;
    const std::uint64_t below = mEdgeMasks[owner][word] & ((std::uint64_t(1) << bit) - 1);
    return uint32_t(mVertexOffsets[owner] + mEdgeRanks[owner][word] + popcount64(below));
}

inline Vec3d Mesher::edgePoint(const Neighbourhood& n, const Coord& origin, int x, int y, int z, int axis) const
{
    const double v0 = n.value(x, y, z);
    const double v1 = n.value(x + (axis == 0), y + (axis == 1), z + (axis == 2));
    // Keep vertices off the corners so no triangle can collapse onto a corner.
    const double t = std::clamp((double(mIso) - v0) / (v1 - v0), 1e-3, 1.0 - 1e-3);
    Vec3d p(origin.x() + x, origin.y() + y, origin.z() + z);
    p[axis] += t;
    return p;
}

template <Pass P>
void Mesher::processBlock(std::size_t b, Accessor& acc, TriangleMesh* mesh, CornerBuffer* corners)
{
    constexpr bool Counts = P != Pass::Emit;  // the Stream pass counts as it goes: no pass before it
    const Block& block = mBlocks[b];
    const bool isLeaf = b < mNumLeaves;

    // The Stream pass needs a block's neighbours and edge mask only while it works on the block:
    // on the stack, not in arrays over all blocks (tens of MB to allocate and zero).
    Neighbours localNeighbours;
    std::array<std::uint64_t, kMaskWords> localMask;
    Neighbours& nb = P == Pass::Stream ? localNeighbours : mNeighbours[b];
    std::array<std::uint64_t, kMaskWords>& mask = P == Pass::Stream ? localMask : mEdgeMasks[std::min(b, mNumLeaves)];
    if constexpr (Counts) {
        nb[0] = isLeaf ? int32_t(b) : -1;
        for (int s = 1; s < 8; ++s) {
            const int32_t i = mMap->find(block.origin + neighbourOffset(s));
            nb[s] = (i >= 0 && std::size_t(i) < mNumLeaves) ? i : -1;
        }
    }
    std::uint8_t available = 0;  // sub-blocks (self + 7 upper neighbours) that own edge vertices
    for (int s = 0; s < 8; ++s) available |= std::uint8_t(nb[s] >= 0) << s;

    const Neighbourhood n = neighbourhood(b, nb, acc);
    std::uint16_t rows[kDim * kDim];
    insideRows(nb, n, rows);

    BlockCounts counts;
    // All 9^3 voxels on one side (a block inside or outside, or a tile block away from the
    // surface): no edge crosses, so no vertex, cube or triangle.
    unsigned anyInside = 0, allInside = 0x1FF;
    for (const std::uint16_t r : rows) anyInside |= r, allInside &= r;
    if (anyInside == 0 || allInside == 0x1FF) {
        if constexpr (Counts) {
            if (isLeaf) mask.fill(0);
            if constexpr (P == Pass::Count)
                if (isLeaf) mEdgeRanks[b].fill(0);
            mCounts[b] = counts;
        }
        return;
    }
    // Pass 2: global index of each vertex this leaf owns, by mask bit (word * 64 + bit). Only
    // written and read for set bits; a per-thread scratch, never a per-voxel array for the grid.
    std::uint32_t ownIndex[P == Pass::Emit ? kMaskWords * 64 : 1];
    openvdb::Vec3f position9[P == Pass::Stream ? kBlockVertexSlots : 1];  // by blockVertexSlot()
    if (isLeaf) {
        if constexpr (Counts) {
            mask.fill(0);
            for (int x = 0; x < 8; ++x) {
                for (int y = 0; y < 8; ++y) {
                    const std::uint16_t r = rows[x * kDim + y];
                    const std::uint64_t alongX = (r ^ rows[(x + 1) * kDim + y]) & 0xFF;
                    const std::uint64_t alongY = (r ^ rows[x * kDim + y + 1]) & 0xFF;
                    const std::uint64_t alongZ = (r ^ (r >> 1)) & 0xFF;
                    mask[0 * 8 + x] |= alongX << (8 * y);
                    mask[1 * 8 + x] |= alongY << (8 * y);
                    mask[2 * 8 + x] |= alongZ << (8 * y);
                }
            }
            uint32_t total = 0;
            for (int w = 0; w < kMaskWords; ++w) {
                if constexpr (P == Pass::Count) mEdgeRanks[b][w] = std::uint16_t(total);
                total += uint32_t(popcount64(mask[w]));
            }
            counts.edgeVertices = total;
        }
        if constexpr (P == Pass::Stream) {
            // Each vertex a cube of the leaf can use, once: the owned ones by mask bit, then
            // those the upper neighbours own on the far faces (x, y or z = 8), where a
            // neighbour is a leaf. The latter from the same two values and integer offsets as
            // their owner computes them: the same bits.
            auto put = [&](int axis, int x, int y, int z) {
                position9[blockVertexSlot(axis, x, y, z)] =
                    openvdb::Vec3f(indexToWorld(edgePoint(n, block.origin, x, y, z, axis)));
            };
            for (int w = 0; w < kMaskWords; ++w) {
                const int axis = w >> 3, x = w & 7;
                for (std::uint64_t bits = mask[w]; bits; bits &= bits - 1) {
                    const int bit = std::countr_zero(bits);
                    put(axis, x, bit >> 3, bit & 7);
                }
            }
            if (available & 0xFE) {
                auto along = [&](int axis, int x, int y, unsigned zBits) {
                    for (; zBits; zBits &= zBits - 1) put(axis, x, y, std::countr_zero(zBits));
                };
                // Which z of a column (x, y) have a leaf for owner: bits 0-7 the column's
                // sub-block @a sxy, bit 8 the one above it.
                auto owned = [&](int sxy) {
                    return (((available >> sxy) & 1) ? 0xFFu : 0u) | (((available >> (sxy | 4)) & 1) ? 0x100u : 0u);
                };
                // The plane z = 8 over the block's own columns (owner: +z): edges along x and y.
                if (available & 0x10) {
                    unsigned top[kDim];  // bit y: voxel (x, y, 8) inside
                    for (int x = 0; x < kDim; ++x) {
                        unsigned t = 0;
                        for (int y = 0; y < kDim; ++y) t |= ((unsigned(rows[x * kDim + y]) >> 8) & 1u) << y;
                        top[x] = t;
                    }
                    for (int x = 0; x < 8; ++x) {
                        for (unsigned b = (top[x] ^ top[x + 1]) & 0xFF; b; b &= b - 1)
                            put(0, x, std::countr_zero(b), 8);
                        for (unsigned b = (top[x] ^ (top[x] >> 1)) & 0xFF; b; b &= b - 1)
                            put(1, x, std::countr_zero(b), 8);
                    }
                }
                // The face y = 8 (x < 8): edges along x and z; the face x = 8: along y and z.
                const unsigned ownedY = owned(2), ownedX = owned(1), ownedXY = owned(3);
                for (int x = 0; x < 8; ++x) {
                    const unsigned r = rows[x * kDim + 8];
                    along(0, x, 8, (r ^ rows[(x + 1) * kDim + 8]) & ownedY);
                    along(2, x, 8, (r ^ (r >> 1)) & ownedY & 0xFF);
                }
                for (int y = 0; y < kDim; ++y) {
                    const unsigned r = rows[8 * kDim + y];
                    if (y < 8) along(1, 8, y, (r ^ rows[8 * kDim + y + 1]) & ownedX);
                    along(2, 8, y, (r ^ (r >> 1)) & (y < 8 ? ownedX : ownedXY) & 0xFF);
                }
            }
        }
        if constexpr (P == Pass::Emit) {
            // Owned vertices in mask bit order, the order neighbourVertexIndex() ranks them in.
            std::uint64_t next = mVertexOffsets[b];
            for (int w = 0; w < kMaskWords; ++w) {
                const int axis = w >> 3, x = w & 7;
                for (std::uint64_t bits = mask[w]; bits; bits &= bits - 1) {
                    const int bit = std::countr_zero(bits);
                    const Vec3d p = indexToWorld(edgePoint(n, block.origin, x, bit >> 3, bit & 7, axis));
                    mesh->points[next] = openvdb::Vec3f(p);
                    ownIndex[w * 64 + bit] = uint32_t(next++);
                }
            }
        }
    }
    if constexpr (P == Pass::Stream) corners->reserveMore(std::size_t(kMaxTriangles) * 512);
    std::uint64_t nextCentroid = 0;
    openvdb::Vec3I* outTriangles = nullptr;
    if constexpr (P == Pass::Emit) {
        nextCentroid = mVertexOffsets[b] + mCounts[b].edgeVertices;
        outTriangles = mesh->triangles.data() + mTriangleOffsets[b];
    }

    for (int x = 0; x < 8; ++x) {
        for (int y = 0; y < 8; ++y) {
            const unsigned r00 = rows[x * kDim + y], r10 = rows[(x + 1) * kDim + y];
            const unsigned r01 = rows[x * kDim + y + 1], r11 = rows[(x + 1) * kDim + y + 1];
            const unsigned any = r00 | r10 | r01 | r11, all = r00 & r10 & r01 & r11;
            unsigned mixed = ((any | (any >> 1)) & ~(all & (all >> 1))) & 0xFF;
            for (; mixed; mixed &= mixed - 1) {
                const int z = std::countr_zero(mixed);
                const int cs = ((r00 >> z) & 1) | (((r10 >> z) & 1) << 1) | (((r01 >> z) & 1) << 2) |
                               (((r11 >> z) & 1) << 3) | (((r00 >> (z + 1)) & 1) << 4) | (((r10 >> (z + 1)) & 1) << 5) |
                               (((r01 >> (z + 1)) & 1) << 6) | (((r11 >> (z + 1)) & 1) << 7);
                const std::uint16_t crossing = mTable.crossingEdges[cs];
                // Only cubes on the block's upper shell (or in a tile block) have edges owned elsewhere.
                if (available != 0xFF && (!isLeaf || x == 7 || y == 7 || z == 7) &&
                    !cubeHasVertices(x, y, z, crossing, available)) {
                    if constexpr (Counts) {
                        ++counts.droppedCubes;
                        std::lock_guard<std::mutex> lock(mSkippedMutex);
                        for (int e = 0; e < 12; ++e) {
                            const int c = edgeLowerCorner(e);
                            const int ox = x + cornerBit(c, 0), oy = y + cornerBit(c, 1), oz = z + cornerBit(c, 2);
                            const int s = (ox >> 3) | ((oy >> 3) << 1) | ((oz >> 3) << 2);
                            if (((crossing >> e) & 1) && !((available >> s) & 1)) {
                                mSkipped.push_back({block.origin + Coord(ox, oy, oz), edgeAxis(e)});
                            }
                        }
                    }
                    continue;
                }
                const int ambiguous = mTable.ambiguousFaces[cs] ? decisions(cs, n, x, y, z) : 0;
                const CaseEntry& entry = mTable.entries[(cs << 6) | ambiguous];
                if constexpr (Counts) {
                    counts.triangles += entry.numTriangles;
                    counts.centroids += entry.numCentroids;
                }
                if constexpr (P == Pass::Stream) {
                    // A leaf's cubes without a loop centroid (nearly all) take their corners
                    // straight from the block's table of vertices.
                    if (isLeaf && entry.numCentroids == 0) {
                        const openvdb::Vec3f* own = position9 + blockVertexSlot(0, x, y, z);
                        for (int t = 0; t < entry.numTriangles; ++t) {
                            const std::uint8_t* tri = entry.triangles[t];
                            corners->push(own[kEdgeSlotOffset[tri[0]]], own[kEdgeSlotOffset[tri[1]]],
                                          own[kEdgeSlotOffset[tri[2]]]);
                        }
                        continue;
                    }
                    // Each position from the same two values and integer offsets as its owner
                    // computes it in the Emit pass: the same bits.
                    openvdb::Vec3f position[kCentroidBase + kMaxCentroids];
                    for (std::uint16_t bits = crossing; bits; bits &= bits - 1) {
                        const int e = std::countr_zero(bits);
                        const EdgeStep& step = kEdgeSteps[std::size_t(e)];
                        const int axis = step.axis, ox = x + step.dx, oy = y + step.dy, oz = z + step.dz;
                        if (isLeaf)
                            position[e] = position9[blockVertexSlot(axis, ox, oy, oz)];
                        else
                            position[e] = openvdb::Vec3f(indexToWorld(edgePoint(n, block.origin, ox, oy, oz, axis)));
                    }
                    for (int k = 0; k < entry.numCentroids; ++k) {
                        position[kCentroidBase + k] = centroid(n, block.origin, x, y, z, entry.centroidLoop[k]);
                    }
                    for (int t = 0; t < entry.numTriangles; ++t) {
                        const std::uint8_t* tri = entry.triangles[t];
                        corners->push(position[tri[0]], position[tri[1]], position[tri[2]]);
                    }
                } else if constexpr (P == Pass::Emit) {
                    uint32_t index[kCentroidBase + kMaxCentroids];
                    for (std::uint16_t bits = crossing; bits; bits &= bits - 1) {
                        const int e = std::countr_zero(bits);
                        const EdgeStep& step = kEdgeSteps[std::size_t(e)];
                        const int axis = step.axis, ox = x + step.dx, oy = y + step.dy, oz = z + step.dz;
                        const int s = (ox >> 3) | ((oy >> 3) << 1) | ((oz >> 3) << 2);
                        index[e] = s == 0 ? ownIndex[(axis * 8 + ox) * 64 + ((oy << 3) | oz)]
                                          : neighbourVertexIndex(std::size_t(nb[s]), axis, ox & 7, oy & 7, oz & 7);
                    }
                    for (int k = 0; k < entry.numCentroids; ++k) {
                        // Rare: average the loop in index space, then map like any other vertex.
                        mesh->points[nextCentroid] = centroid(n, block.origin, x, y, z, entry.centroidLoop[k]);
                        index[kCentroidBase + k] = uint32_t(nextCentroid++);
                    }
                    for (int t = 0; t < entry.numTriangles; ++t) {
                        const std::uint8_t* tri = entry.triangles[t];
                        *outTriangles++ = openvdb::Vec3I(index[tri[0]], index[tri[1]], index[tri[2]]);
                    }
                }
            }
        }
    }
    if constexpr (Counts) mCounts[b] = counts;
}

// The grain keeps accessor set-up and scheduling overhead small; the result never depends on how
// ranges are split, since every block writes only its own slots.
constexpr std::size_t kGrain = 16;

void Mesher::prepare(bool indexed)
{
    const std::size_t numBlocks = mBlocks.size();
    if (indexed) {
        mNeighbours.resize(numBlocks);
        mEdgeMasks.resize(mNumLeaves + 1);  // + 1: a tile block's (unused) reference
        mEdgeRanks.resize(mNumLeaves);
    }
    mCounts.resize(numBlocks);
    mSigns.resize(mNumLeaves);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, mNumLeaves, 64),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t b = r.begin(); b != r.end(); ++b) computeSigns(b);
                      });
}

void Mesher::countAll(ExtractProgress& progress)
{
    const std::size_t numBlocks = mBlocks.size();
    prepare(true);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numBlocks, kGrain),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          Accessor acc(mTree);
                          for (std::size_t b = r.begin(); b != r.end(); ++b) {
                              processBlock<Pass::Count>(b, acc, nullptr);
                              progress.advance();
                          }
                      });
    mVertexOffsets.resize(numBlocks + 1);
    mTriangleOffsets.resize(numBlocks + 1);
    mVertexOffsets[0] = mTriangleOffsets[0] = 0;
    for (std::size_t b = 0; b < numBlocks; ++b) {
        mVertexOffsets[b + 1] = mVertexOffsets[b] + mCounts[b].edgeVertices + mCounts[b].centroids;
        mTriangleOffsets[b + 1] = mTriangleOffsets[b] + mCounts[b].triangles;
    }
}

void Mesher::fillStats(MarchingCubesStats& stats)
{
    stats = MarchingCubesStats{};
    stats.leafBlocks = mNumLeaves;
    stats.tileBlocks = mBlocks.size() - mNumLeaves;
    for (std::size_t b = 0; b < mBlocks.size(); ++b) {
        stats.centroidVertices += mCounts[b].centroids;
        stats.droppedCubes += mCounts[b].droppedCubes;
        if (b >= mNumLeaves) stats.tileBlockTriangles += mCounts[b].triangles;
    }
    std::sort(mSkipped.begin(), mSkipped.end());
    stats.skippedEdges = std::size_t(std::unique(mSkipped.begin(), mSkipped.end()) - mSkipped.begin());
    std::uint64_t triangles = 0;
    for (std::size_t b = 0; b < mBlocks.size(); ++b) {
        triangles += mCounts[b].triangles;
        if ((b + 1) % kChunkBlocks == 0 || b + 1 == mBlocks.size()) stats.chunkTriangleEnds.push_back(triangles);
    }
}

TriangleMesh Mesher::run(ProgressFn progressFn, MarchingCubesStats& stats)
{
    collectBlocks();
    ExtractProgress progress(std::move(progressFn), 2 * mBlocks.size());
    countAll(progress);
    const std::size_t numBlocks = mBlocks.size();
    if (mVertexOffsets[numBlocks] > std::uint64_t(UINT32_MAX)) {
        throw std::length_error("marchingCubes: more than 2^32 vertices");
    }

    TriangleMesh mesh;
    // Resizing zero-fills (and first touches) hundreds of MB for large meshes: both at once.
    tbb::parallel_invoke([&] { mesh.points.resize(mVertexOffsets[numBlocks]); },
                         [&] { mesh.triangles.resize(mTriangleOffsets[numBlocks]); });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numBlocks, kGrain),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          Accessor acc(mTree);
                          for (std::size_t b = r.begin(); b != r.end(); ++b) {
                              // A block that owns no vertex and makes no triangle writes nothing.
                              if (mCounts[b].edgeVertices != 0 || mCounts[b].triangles != 0)
                                  processBlock<Pass::Emit>(b, acc, &mesh);
                              progress.advance();
                          }
                      });
    fillStats(stats);
    progress.finish();
    return mesh;
}

StreamedMeshCounts Mesher::runStreamed(const TriangleStream& stream, ProgressFn progressFn, MarchingCubesStats& stats)
{
    collectBlocks();
    const std::size_t numBlocks = mBlocks.size();
    ExtractProgress progress(std::move(progressFn), numBlocks);
    prepare(false);

    // One pass: chunks of a fixed number of consecutive blocks (so what each consumer call sees
    // does not depend on threads), counted and emitted as they go.
    const std::size_t chunks = (numBlocks + kChunkBlocks - 1) / kChunkBlocks;
    const std::size_t slots = std::max<std::size_t>(1, stream.slots);
    std::vector<CornerBuffer> buffers(slots);
    std::size_t next = 0;
    tbb::parallel_pipeline(
        slots, tbb::make_filter<void, std::size_t>(tbb::filter_mode::serial_in_order,
                                                   [&](tbb::flow_control& fc) -> std::size_t {
                                                       if (next == chunks) fc.stop();
                                                       return next++;
                                                   }) &
                   tbb::make_filter<std::size_t, std::size_t>(
                       tbb::filter_mode::parallel,
                       [&](std::size_t chunk) {
                           if (chunk >= chunks) return chunk;
                           CornerBuffer& corners = buffers[chunk % slots];
                           corners.clear();
                           Accessor acc(mTree);
                           const std::size_t end = std::min(numBlocks, (chunk + 1) * kChunkBlocks);
                           for (std::size_t b = chunk * kChunkBlocks; b != end; ++b) {
                               processBlock<Pass::Stream>(b, acc, nullptr, &corners);
                               progress.advance();
                           }
                           stream.format(chunk, chunk % slots, corners.triangles());
                           return chunk;
                       }) &
                   tbb::make_filter<std::size_t, void>(tbb::filter_mode::serial_in_order, [&](std::size_t chunk) {
                       if (chunk < chunks) stream.write(chunk, chunk % slots);
                   }));
    StreamedMeshCounts counts;
    for (const BlockCounts& c : mCounts) {
        counts.triangles += c.triangles;
        counts.vertices += c.edgeVertices + c.centroids;
    }
    fillStats(stats);
    progress.finish();
    return counts;
}

}  // namespace

TriangleMesh marchingCubes(const openvdb::FloatGrid& grid, float isoValue, ProgressFn progress,
                           MarchingCubesStats* stats)
{
    MarchingCubesStats local;
    Mesher mesher(grid, isoValue);
    TriangleMesh mesh = mesher.run(std::move(progress), local);
    if (stats) *stats = local;
    return mesh;
}

StreamedMeshCounts marchingCubesStreamed(const openvdb::FloatGrid& grid, float isoValue, const TriangleStream& stream,
                                         ProgressFn progress, MarchingCubesStats* stats)
{
    MarchingCubesStats local;
    Mesher mesher(grid, isoValue);
    const StreamedMeshCounts counts = mesher.runStreamed(stream, std::move(progress), local);
    if (stats) *stats = local;
    return counts;
}

namespace {

/// Six times the signed volume of the tetrahedron of corners @a p, @a q, @a r and @a reference.
inline double tetrahedron(const openvdb::Vec3f& p, const openvdb::Vec3f& q, const openvdb::Vec3f& r,
                          const openvdb::Vec3d& reference)
{
    const openvdb::Vec3d a = openvdb::Vec3d(p) - reference, b = openvdb::Vec3d(q) - reference,
                         c = openvdb::Vec3d(r) - reference;
    return a.dot(b.cross(c));
}

}  // namespace

double marchingCubesVolume(const openvdb::FloatGrid& grid, float isoValue, const openvdb::Vec3d& reference,
                           ProgressFn progress)
{
    TriangleStream stream;
    std::vector<double> slotVolume(stream.slots, 0.0);
    double total = 0.0;
    stream.format = [&](std::size_t, std::size_t slot, std::span<const TriangleCorners> triangles) {
        double sum = 0.0;
        for (const TriangleCorners& t : triangles) sum += tetrahedron(t[0], t[1], t[2], reference);
        slotVolume[slot] = sum;
    };
    stream.write = [&](std::size_t, std::size_t slot) { total += slotVolume[slot]; };
    marchingCubesStreamed(grid, isoValue, stream, std::move(progress));
    return total / 6.0;
}

double marchingCubesVolume(const TriangleMesh& mesh, const MarchingCubesStats& stats, const openvdb::Vec3d& reference)
{
    const std::vector<std::uint64_t>& ends = stats.chunkTriangleEnds;
    std::vector<double> chunkVolume(ends.size(), 0.0);
    tbb::parallel_for(std::size_t(0), ends.size(), [&](std::size_t chunk) {
        double sum = 0.0;
        for (std::uint64_t n = chunk == 0 ? 0 : ends[chunk - 1]; n < ends[chunk]; ++n) {
            const openvdb::Vec3I& t = mesh.triangles[n];
            sum += tetrahedron(mesh.points[t[0]], mesh.points[t[1]], mesh.points[t[2]], reference);
        }
        chunkVolume[chunk] = sum;
    });
    double total = 0.0;
    for (const double v : chunkVolume) total += v;
    return total / 6.0;
}

MarchingCubesTableInfo marchingCubesTableInfo()
{
    return caseTable().info;
}

}  // namespace voxlat
