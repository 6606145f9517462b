#include "engine/checks/Pieces.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <numeric>

namespace voxlat {

namespace {

using openvdb::Coord;
using Mask = openvdb::util::NodeMask<3>;

/// An 8^3 block of the solid: a leaf's voxels below zero, or all of a block inside a tile.
struct Block {
    Coord origin;
    Mask mask;
    bool isValueMaskOn() const { return mask.isOn(); }
    bool isValueOn(int v) const { return mask.isOn(openvdb::Index32(v)); }
    Coord offsetToGlobalCoord(int v) const { return origin + Coord(v >> 6, (v >> 3) & 7, v & 7); }
};

/// The solid's blocks, sorted by origin: a leaf's voxels with value < 0, and every 8^3 block of an
/// inside tile (as sdfInteriorMask + voxelizeActiveTiles would give, at a fraction of the cost).
std::vector<Block> solidBlocks(const openvdb::FloatGrid& grid)
{
    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    for (auto it = grid.tree().cbeginLeaf(); it; ++it) leaves.push_back(&*it);
    std::vector<Block> blocks(leaves.size());
    tbb::parallel_for(std::size_t(0), leaves.size(), [&](std::size_t n) {
        blocks[n].origin = leaves[n]->origin();
        const float* v = leaves[n]->buffer().data();
        for (int i = 0; i < 512; ++i)
            if (v[i] < 0.0f) blocks[n].mask.setOn(openvdb::Index32(i));
    });
    blocks.erase(std::remove_if(blocks.begin(), blocks.end(), [](const Block& b) { return b.mask.isOff(); }),
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
                    b.mask.setOn();
                    blocks.push_back(b);
                }
    }
    std::sort(blocks.begin(), blocks.end(), [](const Block& a, const Block& b) { return a.origin < b.origin; });
    return blocks;
}

/// Per leaf: a label (0-based, local) for each active voxel, -1 elsewhere, by flood fill; and
/// each label's voxel count and index bounds.
struct LeafLabels {
    std::array<std::int16_t, 512> label;
    int count = 0;
    std::vector<std::uint32_t> voxels;
    std::vector<openvdb::CoordBBox> bounds;
};

void labelLeaf(const Block& leaf, LeafLabels& out)
{
    if (leaf.isValueMaskOn()) {  // a whole leaf (inside tiles end up so): one label, no search
        out.label.fill(0);
        out.count = 1;
        out.voxels = {512};
        out.bounds = {openvdb::CoordBBox(leaf.origin, leaf.origin + Coord(7))};
        return;
    }
    out.label.fill(-1);
    std::array<std::int16_t, 512> stack;
    for (int start = 0; start < 512; ++start) {
        if (!leaf.isValueOn(start) || out.label[start] >= 0) continue;
        const auto id = std::int16_t(out.count++);
        int top = 0;
        stack[top++] = std::int16_t(start);
        out.label[start] = id;
        while (top > 0) {
            const int v = stack[--top];
            const int x = v >> 6, y = (v >> 3) & 7, z = v & 7;
            const int next[6][2] = {{x > 0, v - 64}, {x < 7, v + 64}, {y > 0, v - 8},
                                    {y < 7, v + 8},  {z > 0, v - 1},  {z < 7, v + 1}};
            for (const auto& [ok, n] : next)
                if (ok && leaf.isValueOn(n) && out.label[n] < 0) {
                    out.label[n] = id;
                    stack[top++] = std::int16_t(n);
                }
        }
    }
    out.voxels.assign(std::size_t(out.count), 0);
    out.bounds.assign(std::size_t(out.count), openvdb::CoordBBox());
    for (int v = 0; v < 512; ++v)
        if (out.label[v] >= 0) {
            ++out.voxels[std::size_t(out.label[v])];
            out.bounds[std::size_t(out.label[v])].expand(leaf.offsetToGlobalCoord(v));
        }
}

int findRoot(std::vector<int>& parent, int i)
{
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
}

void unite(std::vector<int>& parent, int a, int b)
{
    a = findRoot(parent, a);
    b = findRoot(parent, b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);  // the lower id is the root: deterministic
}

}  // namespace

PieceCount countPieces(const openvdb::FloatGrid& grid)
{
    const std::vector<Block> blocks = solidBlocks(grid);
    std::vector<const Block*> leaves;
    for (const Block& b : blocks) leaves.push_back(&b);

    std::vector<LeafLabels> labels(leaves.size());
    tbb::parallel_for(std::size_t(0), leaves.size(), [&](std::size_t n) { labelLeaf(*leaves[n], labels[n]); });
    std::vector<int> first(leaves.size() + 1, 0);  // the global id of each leaf's label 0
    for (std::size_t n = 0; n < leaves.size(); ++n) first[n + 1] = first[n] + labels[n].count;
    std::vector<int> parent(first.back());
    std::iota(parent.begin(), parent.end(), 0);

    // Join labels across the +x, +y and +z faces of every leaf.
    auto leafIndex = [&](const Coord& origin) -> long {
        const auto it = std::lower_bound(leaves.begin(), leaves.end(), origin,
                                         [](const Block* l, const Coord& c) { return l->origin < c; });
        return it != leaves.end() && (*it)->origin == origin ? long(it - leaves.begin()) : -1;
    };
    for (std::size_t n = 0; n < leaves.size(); ++n) {
        for (int axis = 0; axis < 3; ++axis) {
            Coord next = leaves[n]->origin;
            next[axis] += 8;
            const long m = leafIndex(next);
            if (m < 0) continue;
            if (labels[n].count == 1 && labels[m].count == 1 && leaves[n]->isValueMaskOn() &&
                leaves[m]->isValueMaskOn()) {
                unite(parent, first[n], first[m]);  // two whole leaves
                continue;
            }
            // The 64 voxels of the far face (offset 7 along the axis) against the neighbour's near face.
            const int stride = axis == 0 ? 64 : axis == 1 ? 8 : 1;
            const int s1 = axis == 0 ? 8 : 64, s2 = axis == 2 ? 8 : 1;
            for (int i = 0; i < 8; ++i)
                for (int j = 0; j < 8; ++j) {
                    const int near = i * s1 + j * s2;
                    const int a = labels[n].label[near + 7 * stride], b = labels[m].label[near];
                    if (a >= 0 && b >= 0) unite(parent, first[n] + a, first[m] + b);
                }
        }
    }

    // Sizes and bounds per root, summed over the leaves' labels in leaf order.
    std::vector<int> pieceOf(parent.size(), -1);
    PieceCount result;
    for (std::size_t n = 0; n < leaves.size(); ++n)
        for (int l = 0; l < labels[n].count; ++l) {
            const int root = findRoot(parent, first[n] + l);
            if (pieceOf[root] < 0) {
                pieceOf[root] = int(result.pieces.size());
                result.pieces.push_back({0, openvdb::CoordBBox()});
            }
            Piece& p = result.pieces[std::size_t(pieceOf[root])];
            p.voxels += labels[n].voxels[std::size_t(l)];
            p.bounds.expand(labels[n].bounds[std::size_t(l)]);
            result.solidVoxels += labels[n].voxels[std::size_t(l)];
        }
    std::stable_sort(result.pieces.begin(), result.pieces.end(),
                     [](const Piece& a, const Piece& b) { return a.voxels > b.voxels; });
    return result;
}

}  // namespace voxlat
