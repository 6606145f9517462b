// Union-find over indices (path halving), shared by the checks.
#pragma once

#include <vector>

namespace voxlat {

/// The root of @a i's set in the forest @a parent, halving the path on the way.
inline int findRoot(std::vector<int>& parent, int i)
{
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
}

}  // namespace voxlat
