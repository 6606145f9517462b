// Grid comparisons shared by the evaluation tests: two grids' values bit for bit.
#pragma once

#include <openvdb/openvdb.h>

#include <cstdint>
#include <cstring>
#include <limits>

namespace voxlat::test {

/// Voxels of @a a's leaves whose float differs, bit for bit, from @a b's value there.
inline std::uint64_t mismatchedVoxels(const openvdb::FloatGrid& a, const openvdb::FloatGrid& b)
{
    auto acc = b.getConstAccessor();
    std::uint64_t mismatched = 0;
    for (auto leaf = a.tree().cbeginLeaf(); leaf; ++leaf)
        for (int i = 0; i < 512; ++i) {
            const float x = leaf->getValue(i), y = acc.getValue(leaf->offsetToGlobalCoord(i));
            mismatched += std::memcmp(&x, &y, sizeof x) != 0;
        }
    return mismatched;
}

/// Voxels where @a held, a grid whose cull decided leaves from values held (FieldNode::heldRange),
/// differs from @a fresh, the same grid culled by bounds alone: each of @a held's leaves must be
/// @a fresh's bit for bit, and each leaf of @a fresh that @a held leaves out a tile of its side
/// there: the leaf's voxels and the ring one voxel past them all below 0 in @a fresh (inside) or
/// none (outside), and @a held's value at them on that side. @a leftOut: how many leaves it left.
inline std::uint64_t heldCullMismatches(const openvdb::FloatGrid& fresh, const openvdb::FloatGrid& held,
                                        std::uint64_t* leftOut = nullptr)
{
    std::uint64_t mismatched = mismatchedVoxels(held, fresh), left = 0;
    auto freshAt = fresh.getConstAccessor();
    auto heldAt = held.getConstAccessor();
    for (auto leaf = fresh.tree().cbeginLeaf(); leaf; ++leaf) {
        if (heldAt.probeConstLeaf(leaf->origin())) continue;
        ++left;
        const openvdb::Coord o = leaf->origin();
        const bool inside = freshAt.getValue(o) < 0.0f;
        for (int i = -1; i <= 8; ++i)
            for (int j = -1; j <= 8; ++j)
                for (int k = -1; k <= 8; ++k) {
                    const openvdb::Coord c = o + openvdb::Coord(i, j, k);
                    mismatched += (freshAt.getValue(c) < 0.0f) != inside;
                    const bool inLeaf = i >= 0 && j >= 0 && k >= 0 && i < 8 && j < 8 && k < 8;
                    if (inLeaf) mismatched += (heldAt.getValue(c) < 0.0f) != inside;
                }
    }
    if (leftOut) *leftOut = left;
    return mismatched;
}

}  // namespace voxlat::test
