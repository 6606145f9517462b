/// @file StrutFrames.h
/// @brief Lattice frames (IntraLattice's frame module): unit cells mapped into a box, a
/// cylinder or any solid (trimmed at its boundary), or a wireframe read from a file. Nodes and
/// struts shared by neighbouring cells appear once.
#pragma once

#include "engine/frames/UnitCells.h"

#include <array>
#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <tuple>
#include <unordered_map>
#include <unordered_set>

namespace voxlat {

/// Nodes and struts (node index pairs, each strut once) of a lattice.
struct Frame {
    std::vector<Vec3d> nodes;
    std::vector<std::array<int, 2>> struts;
    /// Radii at the two ends of each strut (mm) when the frame came with them (a wireframe CSV
    /// with `r1,r2` columns); empty otherwise.
    std::vector<std::array<double, 2>> radii;
    /// The box the frame was laid to fill when its struts run past it (a box frame laid one cell
    /// past the domain and cut by it): what "the frame's box" means for its density and graded
    /// radii. Unset: bounds().
    std::optional<Box3> layoutBox{};

    /// The box holding every node.
    Box3 bounds() const;
    /// layoutBox when set, else bounds().
    Box3 box() const { return layoutBox ? *layoutBox : bounds(); }
};

/// Builds a frame, merging nodes closer than a tolerance and dropping repeated or
/// zero-length struts. Insertion order is kept, so frames are deterministic.
class FrameBuilder {
public:
    explicit FrameBuilder(double tolerance) : mTol(tolerance) {}
    int node(const Vec3d& p);
    /// Adds the strut a-b unless it has zero length or exists already; true if added.
    bool strut(const Vec3d& a, const Vec3d& b);
    Frame take() { return std::move(mFrame); }

private:
    struct BinHash {
        std::size_t operator()(const std::array<long, 3>& k) const noexcept
        {
            std::uint64_t h = 0x9e3779b97f4a7c15ULL;
            for (const long v : k) h = (h ^ std::uint64_t(v)) * 0xff51afd7ed558ccdULL;
            return std::size_t(h ^ (h >> 32));
        }
    };
    double mTol;
    Frame mFrame;
    /// Nodes by bins four tolerances wide: a point looks in the one bin it rounds to, or in two to
    /// eight when it lies within the tolerance of a bin's face.
    std::unordered_map<std::array<long, 3>, std::vector<int>, BinHash> mBins;
    /// Struts by their (lower, higher) node pair packed in 64 bits.
    std::unordered_set<std::uint64_t> mStruts;
};

/// Refuses (JobError), before anything is allocated, a frame of @a counts cells of @a cell whose
/// struts would not fit in half the free memory.
void checkStrutCount(const UnitCell& cell, const std::array<int, 3>& counts);

/// Called between rows of cells while a frame is laid (a plate holds 10^5-10^6 struts, seconds of
/// work): it throws to stop (a job's JobContext::checkCancelled), or is empty.
using FrameInterrupt = std::function<void()>;

/// Cells of size @a cellSize from @a origin, @a counts per axis.
Frame boxFrame(const UnitCell& cell, const Vec3d& origin, const Vec3d& cellSize, const std::array<int, 3>& counts,
               const FrameInterrupt& interrupt = {});

/// Cells mapped into a cylinder around the z axis through @a base (its bottom centre): the cell's
/// x runs radially from @a innerRadius to @a outerRadius, y around the axis, z along it.
/// @a counts = {axial, angular, radial}. Struts are straight between the mapped nodes.
Frame cylinderFrame(const UnitCell& cell, const Vec3d& base, double innerRadius, double outerRadius, double height,
                    const std::array<int, 3>& counts, const FrameInterrupt& interrupt = {});

/// Cells mapped into a spherical shell around @a centre: the cell's x runs radially from
/// @a innerRadius to @a outerRadius, y around the z axis (azimuth), z from the +z pole to the -z
/// pole (polar angle). @a counts = {polar, azimuthal, radial}. Nodes that meet at the poles and
/// at the centre (inner radius 0) merge, and struts that shrink to a point there are dropped.
Frame sphereFrame(const UnitCell& cell, const Vec3d& centre, double innerRadius, double outerRadius,
                  const std::array<int, 3>& counts, const FrameInterrupt& interrupt = {});

/// Cells mapped into a structured grid of hexahedra (IntraLattice's conformal frames between
/// two surfaces): @a gridNodes holds the (counts[0] + 1)(counts[1] + 1)(counts[2] + 1) corners,
/// node (i, j, k) at index (i (counts[1] + 1) + j)(counts[2] + 1) + k. Cell (i, j, k) is the
/// hexahedron of corners (i..i+1, j..j+1, k..k+1); a unit cell's node (a, b, c) goes to the
/// trilinear blend of its corners, so cell corners land exactly on grid nodes. Struts are straight
/// between mapped nodes. Nodes closer than 1e-9 of the grid's size merge (closed or collapsed
/// surfaces: a seam, an axis, a point) and struts that shrink to a point are dropped.
Frame hexGridFrame(const UnitCell& cell, const std::vector<Vec3d>& gridNodes, const std::array<int, 3>& counts,
                   const FrameInterrupt& interrupt = {});

/// Uniform cells filling @a region, kept where @a inside says a point is in the design space
/// (value <= 0): struts with both ends inside are kept whole, struts with one end inside are
/// trimmed at the boundary (found by bisection) unless the piece is shorter than
/// @a minLength (dropped) or the cut-off part is (kept whole); struts with both ends outside go.
Frame clippedFrame(const UnitCell& cell, const Box3& region, const Vec3d& cellSize,
                   const std::function<double(const Vec3d&)>& inside, double minLength);

/// A wireframe file: OBJ (`v` and `l` elements) or CSV (rows `node,x,y,z` and `strut,i,j` with
/// 0-based node indices, or six numbers `x1,y1,z1,x2,y2,z2` per strut, or eight
/// `x1,y1,z1,x2,y2,z2,r1,r2` with the radii at its ends, as a frame output writes them; a header
/// row first is skipped). Radii, when every strut row has them, land in Frame::radii. Throws
/// InputError naming file and line for dangling indices, zero-length struts and unreadable rows.
Frame readWireframe(const std::string& path);

}  // namespace voxlat
