/// @file SplitTriangle.h
/// @brief A triangle split at points on some of its edges: the pieces, shared by the crease split
/// and the refinement so both cut a triangle the same way.
#pragma once

#include <openvdb/Types.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <vector>

namespace voxlat {

/// A piece of a split triangle: corners 0..2 are the parent's, 3..5 the split points of its
/// edges (i, i + 1).
using SplitPiece = std::array<int, 3>;

/// At most four pieces, held in place (no allocation: the refinement asks for the pieces of
/// every triangle it splits, several times per round).
class SplitPieces {
public:
    SplitPieces() = default;
    SplitPieces(std::initializer_list<SplitPiece> pieces)
    {
        for (const SplitPiece& p : pieces) mPieces[mCount++] = p;
    }
    const SplitPiece* begin() const { return mPieces.data(); }
    const SplitPiece* end() const { return mPieces.data() + mCount; }
    std::size_t size() const { return mCount; }
    bool empty() const { return mCount == 0; }

private:
    std::array<SplitPiece, 4> mPieces{};
    std::size_t mCount = 0;
};

/// The pieces of a triangle with positions @a p (corners, then split points) split on the edges
/// flagged in @a split; with two splits, the quad left over by its shorter diagonal.
inline SplitPieces splitPieces(const std::array<openvdb::Vec3d, 6>& p, const std::array<bool, 3>& split)
{
    const int count = int(split[0]) + int(split[1]) + int(split[2]);
    if (count == 3) return {{0, 3, 5}, {3, 1, 4}, {5, 4, 2}, {3, 4, 5}};
    if (count == 1) {
        const int i = split[0] ? 0 : split[1] ? 1 : 2;
        return {{i, 3 + i, (i + 2) % 3}, {3 + i, (i + 1) % 3, (i + 2) % 3}};
    }
    if (count == 2) {
        // The unsplit edge is (a, b); c lies between the two split edges.
        const int j = !split[0] ? 0 : !split[1] ? 1 : 2;
        const int a = j, b = (j + 1) % 3, c = (j + 2) % 3;
        const int mb = 3 + b, mc = 3 + c;
        if ((p[a] - p[mb]).lengthSqr() <= (p[b] - p[mc]).lengthSqr()) return {{mb, c, mc}, {a, b, mb}, {a, mb, mc}};
        return {{mb, c, mc}, {a, b, mc}, {b, mb, mc}};
    }
    return {};
}

/// Which edges of a triangle split: those with an edge slot (>= 0) that is @a active.
template <typename Slot>
std::array<bool, 3> splitEdges(const std::array<Slot, 3>& edges, const std::vector<std::uint8_t>& active)
{
    std::array<bool, 3> s;
    for (int i = 0; i < 3; ++i)
        s[std::size_t(i)] = edges[std::size_t(i)] >= 0 && active[std::size_t(edges[std::size_t(i)])];
    return s;
}

/// The positions splitPieces() takes: the corners of @a tri in @a points, then each edge's split
/// point (@a target by edge slot where the edge splits, else the origin, unused).
template <typename Slot>
std::array<openvdb::Vec3d, 6> splitPositions(const openvdb::Vec3I& tri, const std::array<Slot, 3>& edges,
                                             const std::vector<openvdb::Vec3d>& points,
                                             const std::vector<std::uint8_t>& active,
                                             const std::vector<openvdb::Vec3d>& target)
{
    std::array<openvdb::Vec3d, 6> p;
    for (int i = 0; i < 3; ++i) {
        p[std::size_t(i)] = points[tri[i]];
        const Slot e = edges[std::size_t(i)];
        p[std::size_t(3 + i)] = e >= 0 && active[std::size_t(e)] ? target[std::size_t(e)] : openvdb::Vec3d(0.0);
    }
    return p;
}

}  // namespace voxlat
