#include "engine/checks/Pieces.h"
#include "engine/checks/UnionFind.h"

#include "mesher/extract/SignWords.h"

#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <array>
#include <bit>
#include <numeric>
#include <utility>
#include <vector>

namespace voxlat {

namespace {

using openvdb::Coord;

/// The voxels of an 8^3 block as 512 bits: word x (the voxel's x offset), bit 8 y + z, the order
/// of a leaf's voxel offsets (x << 6 | y << 3 | z). Flood fills run on whole words: one step grows
/// a set by a voxel along every axis in about thirty word operations.
using Bits = std::array<std::uint64_t, 8>;

constexpr std::uint64_t kZ0 = 0x0101010101010101ull;  // the bits with z = 0
constexpr std::uint64_t kZ7 = kZ0 << 7;               // ... with z = 7
constexpr std::uint64_t kY0 = 0xFFull;                // ... with y = 0
constexpr std::uint64_t kY7 = kY0 << 56;              // ... with y = 7

/// Calls an optional interrupter every 2^12 steps of a loop (any thread) or now.
class Every {
public:
    explicit Every(const std::function<void()>& interrupt) : mInterrupt(interrupt) {}
    void step(std::size_t n) const
    {
        if (mInterrupt && (n & 4095) == 0) mInterrupt();
    }
    void now() const
    {
        if (mInterrupt) mInterrupt();
    }

private:
    const std::function<void()>& mInterrupt;
};

bool isEmpty(const Bits& b)
{
    std::uint64_t any = 0;
    for (std::uint64_t w : b) any |= w;
    return any == 0;
}

bool isFull(const Bits& b)
{
    std::uint64_t all = ~0ull;
    for (std::uint64_t w : b) all &= w;
    return all == ~0ull;
}

/// @a set grown by one voxel across every face, within @a within.
Bits grow(const Bits& set, const Bits& within)
{
    Bits out;
    for (int x = 0; x < 8; ++x) {
        const std::uint64_t w = set[std::size_t(x)];
        std::uint64_t g = w | ((w << 1) & ~kZ0) | ((w >> 1) & ~kZ7) | (w << 8) | (w >> 8);
        if (x > 0) g |= set[std::size_t(x - 1)];
        if (x < 7) g |= set[std::size_t(x + 1)];
        out[std::size_t(x)] = g & within[std::size_t(x)];
    }
    return out;
}

using Block = SolidBlock;

}  // namespace

std::vector<SolidBlock> solidBlocks(const openvdb::FloatGrid& grid, std::vector<SolidBlock> leaves,
                                    const std::function<void()>& interrupt)
{
    const Every every(interrupt);
    // As sdfInteriorMask + voxelizeActiveTiles would give, at a fraction of the cost.
    std::vector<const openvdb::FloatTree::LeafNodeType*> own;
    own.reserve(grid.tree().leafCount());
    for (auto it = grid.tree().cbeginLeaf(); it; ++it) {
        own.push_back(&*it);
        every.step(own.size());
    }
    std::vector<Block> blocks = std::move(leaves);
    const std::size_t given = blocks.size();
    blocks.resize(given + own.size());
    tbb::parallel_for(std::size_t(0), own.size(), [&](std::size_t n) {
        every.step(n);
        blocks[given + n].origin = own[n]->origin();
        belowWords(own[n]->buffer().data(), 0.0f, blocks[given + n].bits.data());
    });
    blocks.erase(std::remove_if(blocks.begin(), blocks.end(), [](const Block& b) { return isEmpty(b.bits); }),
                 blocks.end());
    auto it = grid.tree().cbeginValueAll();
    it.setMaxDepth(openvdb::FloatTree::ValueAllCIter::LEAF_DEPTH - 1);  // tiles only, not leaf voxels
    for (; it; ++it) {
        if (!(*it < 0.0f)) continue;  // tiles below zero only
        const openvdb::CoordBBox box = it.getBoundingBox();
        for (int x = box.min().x(); x <= box.max().x(); x += 8)
            for (int y = box.min().y(); y <= box.max().y(); y += 8)
                for (int z = box.min().z(); z <= box.max().z(); z += 8) {
                    Block b;
                    b.origin = Coord(x, y, z);
                    b.bits.fill(~0ull);
                    blocks.push_back(b);
                    every.step(blocks.size());
                }
    }
    every.now();
    // Origins are distinct: the order is the same whatever order the blocks came in.
    tbb::parallel_sort(blocks.begin(), blocks.end(),
                       [](const Block& a, const Block& b) { return a.origin < b.origin; });
    every.now();
    return blocks;
}

namespace {

/// One connected set of a block's voxels (6-connected within the block).
struct Part {
    Bits bits;
    std::uint32_t voxels = 0;
    openvdb::CoordBBox bounds;  ///< index bounds of its voxels
};

/// The index bounds of the voxels of @a b, a block at @a origin.
openvdb::CoordBBox boundsOf(const Bits& b, const Coord& origin)
{
    int x0 = 8, x1 = -1;
    std::uint64_t yz = 0;
    for (int x = 0; x < 8; ++x)
        if (b[std::size_t(x)]) {
            x0 = std::min(x0, x);
            x1 = x;
            yz |= b[std::size_t(x)];
        }
    std::uint64_t z = yz;  // the OR of the eight rows of z bits
    z |= z >> 32;
    z |= z >> 16;
    z |= z >> 8;
    z &= 0xFF;
    int y0 = 8, y1 = -1;
    for (int y = 0; y < 8; ++y)
        if ((yz >> (8 * y)) & 0xFF) {
            y0 = std::min(y0, y);
            y1 = y;
        }
    const int z0 = std::countr_zero(z), z1 = 63 - std::countl_zero(z);
    return {origin + Coord(x0, y0, z0), origin + Coord(x1, y1, z1)};
}

/// The parts of @a block appended to @a out, in the order of their first voxel (the lowest offset).
void splitBlock(const Block& block, std::vector<Part>& out)
{
    if (isFull(block.bits)) {  // a whole block (inside tiles end up so): one part, no search
        out.push_back({block.bits, 512u, openvdb::CoordBBox(block.origin, block.origin + Coord(7))});
        return;
    }
    Bits left = block.bits;
    for (int x = 0; x < 8; ++x)
        while (left[std::size_t(x)]) {
            Bits set{};
            set[std::size_t(x)] = left[std::size_t(x)] & (~left[std::size_t(x)] + 1);  // the lowest voxel left
            for (;;) {
                const Bits next = grow(set, left);
                if (next == set) break;
                set = next;
            }
            std::uint32_t voxels = 0;
            for (int i = 0; i < 8; ++i) {
                left[std::size_t(i)] &= ~set[std::size_t(i)];
                voxels += std::uint32_t(std::popcount(set[std::size_t(i)]));
            }
            out.push_back({set, voxels, boundsOf(set, block.origin)});
        }
}

/// Whether part @a a of a block touches part @a b of the next block along @a axis across their face.
bool touches(const Bits& a, const Bits& b, int axis)
{
    if (axis == 0) return (a[7] & b[0]) != 0;
    std::uint64_t any = 0;
    for (int x = 0; x < 8; ++x)
        any |= axis == 1 ? ((a[std::size_t(x)] & kY7) >> 56) & b[std::size_t(x)] & kY0
                         : ((a[std::size_t(x)] & kZ7) >> 7) & b[std::size_t(x)] & kZ0;
    return any != 0;
}

void unite(std::vector<int>& parent, int a, int b)
{
    a = findRoot(parent, a);
    b = findRoot(parent, b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);  // the lower id is the root: deterministic
}

/// Position of the block at an origin in a list of blocks sorted by origin. A plain array over
/// the blocks' bounding box when it holds at most 16 M slots and at most 16 per block (the usual
/// case: O(1), neighbouring blocks close together in memory); otherwise a binary search.
class SortedBlockIndex {
public:
    explicit SortedBlockIndex(const std::vector<Block>& blocks) : mBlocks(blocks)
    {
        if (blocks.empty()) return;
        Coord lo = blocks.front().origin, hi = lo;
        for (const Block& b : blocks) {
            lo.minComponent(b.origin);
            hi.maxComponent(b.origin);
        }
        const Coord dims = ((hi - lo) >> 3) + Coord(1);
        const std::uint64_t volume = std::uint64_t(dims.x()) * std::uint64_t(dims.y()) * std::uint64_t(dims.z());
        if (volume > (std::uint64_t(1) << 24) || volume > 16 * std::uint64_t(blocks.size())) return;
        mOrigin = lo;
        mDims = dims;
        mDense.assign(volume, -1);
        for (std::size_t n = 0; n < blocks.size(); ++n) mDense[slot(blocks[n].origin)] = std::int32_t(n);
    }

    /// The block at @a origin, or -1.
    long find(const Coord& origin) const
    {
        if (!mDense.empty()) {
            const Coord d = (origin - mOrigin) >> 3;
            if (std::uint32_t(d.x()) >= std::uint32_t(mDims.x()) || std::uint32_t(d.y()) >= std::uint32_t(mDims.y()) ||
                std::uint32_t(d.z()) >= std::uint32_t(mDims.z()))
                return -1;
            return mDense[slot(origin)];
        }
        const auto it = std::lower_bound(mBlocks.begin(), mBlocks.end(), origin,
                                         [](const Block& l, const Coord& c) { return l.origin < c; });
        return it != mBlocks.end() && it->origin == origin ? long(it - mBlocks.begin()) : -1;
    }

private:
    std::size_t slot(const Coord& origin) const
    {
        const Coord d = (origin - mOrigin) >> 3;
        return (std::size_t(d.x()) * std::size_t(mDims.y()) + std::size_t(d.y())) * std::size_t(mDims.z()) +
               std::size_t(d.z());
    }

    const std::vector<Block>& mBlocks;
    std::vector<std::int32_t> mDense;
    Coord mOrigin, mDims;
};

}  // namespace

PieceCount countPieces(const openvdb::FloatGrid& grid)
{
    return countPieces(solidBlocks(grid));
}

PieceCount countPieces(const std::vector<SolidBlock>& blocks, const std::function<void()>& interrupt)
{
    const Every every(interrupt);
    // Each block's parts, found in parallel over fixed runs of blocks and laid out in block order:
    // part ids do not depend on the thread count.
    constexpr std::size_t kRun = 256;
    const std::size_t runs = (blocks.size() + kRun - 1) / kRun;
    std::vector<std::vector<Part>> runParts(runs);
    std::vector<std::vector<int>> runFirst(runs);
    tbb::parallel_for(std::size_t(0), runs, [&](std::size_t r) {
        const std::size_t end = std::min(blocks.size(), (r + 1) * kRun);
        every.now();
        for (std::size_t n = r * kRun; n < end; ++n) {
            runFirst[r].push_back(int(runParts[r].size()));
            splitBlock(blocks[n], runParts[r]);
        }
    });
    std::vector<Part> parts;
    std::vector<int> first(blocks.size() + 1, 0);  // the id of each block's first part
    for (std::size_t r = 0; r < runs; ++r) {
        for (std::size_t i = 0; i < runFirst[r].size(); ++i) first[r * kRun + i] = int(parts.size()) + runFirst[r][i];
        parts.insert(parts.end(), runParts[r].begin(), runParts[r].end());
        std::vector<Part>().swap(runParts[r]);
        every.now();
    }
    first[blocks.size()] = int(parts.size());
    std::vector<int> parent(parts.size());
    std::iota(parent.begin(), parent.end(), 0);

    // Join parts across the +x, +y and +z faces of every block: the touching pairs are found in
    // parallel over the same runs of blocks, then united in run order (the pieces do not depend
    // on the order of unions, and neither do their ids: see below).
    every.now();
    const SortedBlockIndex index(blocks);
    std::vector<std::vector<std::pair<int, int>>> runPairs(runs);
    tbb::parallel_for(std::size_t(0), runs, [&](std::size_t r) {
        every.now();
        const std::size_t end = std::min(blocks.size(), (r + 1) * kRun);
        for (std::size_t n = r * kRun; n < end; ++n) {
            for (int axis = 0; axis < 3; ++axis) {
                Coord next = blocks[n].origin;
                next[axis] += 8;
                const long m = index.find(next);
                if (m < 0) continue;
                for (int a = first[n]; a < first[n + 1]; ++a)
                    for (int b = first[std::size_t(m)]; b < first[std::size_t(m) + 1]; ++b)
                        if (touches(parts[std::size_t(a)].bits, parts[std::size_t(b)].bits, axis))
                            runPairs[r].emplace_back(a, b);
            }
        }
    });
    for (std::size_t r = 0; r < runs; ++r) {
        for (const auto& [a, b] : runPairs[r]) unite(parent, a, b);
        every.now();
    }

    // Sizes and bounds per root, summed over the parts in block order.
    std::vector<int> pieceOf(parent.size(), -1);
    PieceCount result;
    for (std::size_t p = 0; p < parts.size(); ++p) {
        every.step(p);
        const int root = findRoot(parent, int(p));
        if (pieceOf[root] < 0) {
            pieceOf[root] = int(result.pieces.size());
            result.pieces.push_back({0, openvdb::CoordBBox()});
        }
        Piece& piece = result.pieces[std::size_t(pieceOf[root])];
        piece.voxels += parts[p].voxels;
        piece.bounds.expand(parts[p].bounds);
        result.solidVoxels += parts[p].voxels;
    }
    std::stable_sort(result.pieces.begin(), result.pieces.end(),
                     [](const Piece& a, const Piece& b) { return a.voxels > b.voxels; });
    return result;
}

}  // namespace voxlat
