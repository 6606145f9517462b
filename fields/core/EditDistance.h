/// @file EditDistance.h
/// @brief Levenshtein distance, for "did you mean" suggestions in recipes and equations.
#pragma once

#include <algorithm>
#include <string>
#include <vector>

namespace voxlat {

/// Insertions, deletions and substitutions turning @a a into @a b (two-row dynamic programme).
inline std::size_t editDistance(const std::string& a, const std::string& b)
{
    std::vector<std::size_t> prev(b.size() + 1), cur(b.size() + 1);
    for (std::size_t j = 0; j <= b.size(); ++j) prev[j] = j;
    for (std::size_t i = 1; i <= a.size(); ++i) {
        cur[0] = i;
        for (std::size_t j = 1; j <= b.size(); ++j)
            cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (a[i - 1] != b[j - 1])});
        std::swap(prev, cur);
    }
    return prev[b.size()];
}

}  // namespace voxlat
