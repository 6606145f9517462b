/// @file SkinCells.h
/// @brief Hexahedral cells between offset surfaces of a part (a skin-following frame): the
/// trilinear map of each cell, its inverse, and a bin index to find the cell holding a point.
#pragma once

#include "fields/core/FieldNode.h"

#include <array>
#include <vector>

namespace voxlat {

/// The triple product a . (b x c): six times the signed volume of the tetrahedron (0, a, b, c).
inline double triple(const Vec3d& a, const Vec3d& b, const Vec3d& c)
{
    return a.dot(b.cross(c));
}

/// A set of hexahedra, each the trilinear image of the unit cube: x(u, v, w) = sum_i N_i(u, v, w)
/// c_i over its eight corners, corner i at (u, v, w) = (i & 1, (i >> 1) & 1, (i >> 2) & 1). In a
/// skin frame u and v run along the surface and w inward, one layer of cells per unit of w.
///
/// Hexes whose w = 0 face lies on the outer offset surface ("outer" hexes) may also claim the
/// points just outside that face, out to w = -extension, where the clip field is at most the clip
/// level: their faces are chords of a curved surface, and this fills the sliver between the chord
/// and the surface itself (the clip field is the part's distance, the level minus the depth).
///
/// Cells are immutable after construction and safe to query from many threads. Which cell claims
/// a point inside two overlapping cells is fixed (the lowest index), so results do not depend on
/// the order or the batches in which points are asked.
class SkinCells {
public:
    SkinCells(std::vector<Vec3d> corners, std::vector<std::array<int, 8>> hexes, std::vector<char> outer,
              double extension = 0.0, FieldPtr clip = nullptr, double clipLevel = 0.0);

    std::size_t size() const { return mHexes.size(); }
    const std::vector<Vec3d>& corners() const { return mCorners; }
    const std::array<int, 8>& hex(std::size_t h) const { return mHexes[h]; }
    bool outer(std::size_t h) const { return mOuter[h] != 0; }
    double extension() const { return mExtension; }

    /// x(local) in hex @a h; with @a jacobian, its columns dx/du, dx/dv, dx/dw.
    Vec3d map(std::size_t h, const Vec3d& local, std::array<Vec3d, 3>* jacobian = nullptr) const;
    /// Local coordinates of @a p in hex @a h by Newton's method from the centre (the trilinear map
    /// is inverted, not approximated: the result maps back to p within 1e-10 of the cell size);
    /// false when Newton does not converge (p far outside a distorted cell).
    bool inverse(std::size_t h, const Vec3d& p, Vec3d& local) const;
    /// The cell holding @a p (its local coordinates in @a local), or -1.
    int locate(const Vec3d& p, Vec3d& local) const;
    /// False only when no cell (with its extension) can meet @a box: conservative.
    bool touches(const Box3& box) const;
    /// The box holding every cell and its extension.
    const Box3& bounds() const { return mBounds; }

private:
    template <typename Fn>
    void forBins(const Box3& box, Fn&& fn) const;

    std::vector<Vec3d> mCorners;
    std::vector<std::array<int, 8>> mHexes;
    std::vector<char> mOuter;
    double mExtension;
    FieldPtr mClip;
    double mClipLevel;
    std::vector<Box3> mBoxes;  ///< per hex, grown by its extension
    Box3 mBounds;
    double mScale = 1.0;  ///< a typical cell size, for tolerances
    // Uniform bins over mBounds; mBinStart[b] .. mBinStart[b + 1] index mBinHexes (ascending hexes).
    double mBin = 1.0;
    std::array<int, 3> mBinDims{1, 1, 1};
    std::vector<std::uint32_t> mBinStart, mBinHexes;
};

}  // namespace voxlat
