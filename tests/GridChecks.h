// Grid comparisons shared by the evaluation tests: two grids' values bit for bit.
#pragma once

#include <openvdb/openvdb.h>

#include <cstdint>
#include <cstring>

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

}  // namespace voxlat::test
