/// @file SparseEvaluator.h
/// @brief Evaluates a field onto a sparse OpenVDB grid, following the surface, not the volume.
#pragma once

#include "engine/core/Domain.h"
#include "engine/core/JobContext.h"

#include <openvdb/openvdb.h>

#include <optional>

#include <cmath>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace voxlat {

/// The test behind the cull's proofs from values known at points of a box (KnownSamples,
/// FieldNode::meets()): fed the values one by one, it holds once one is at least @a band's low end
/// and one at most its high end, each by a slack of @a error plus 1e-6 relative (rounding, values
/// held as floats). Values of +-1e30 and beyond (masks' outside values, tiles) prove nothing.
class BandMet {
public:
    explicit BandMet(const Interval& band, double error = 0.0) : mBand(band), mError(error) {}
    /// Takes one value; true once the values taken prove the band met.
    bool add(double v)
    {
        if (!(std::abs(v) < 1e30)) return false;
        const double slack = mError + 1e-6 * (1.0 + std::abs(v));
        mLow = mLow || v - slack >= mBand.lo;
        mHigh = mHigh || v + slack <= mBand.hi;
        return mLow && mHigh;
    }

private:
    Interval mBand;
    double mError;
    bool mLow = false, mHigh = false;
};

/// Whether the values of @a grid's leaves at the voxels in @a voxels prove @a band met (BandMet):
/// FieldNode::meets() for a node holding a grid of its values (KeptGridLeaves).
bool heldValuesMeet(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& voxels, const Interval& band);

/// The range of the values of @a grid's leaves at the voxels in @a voxels, when leaves with values
/// hold every one of them (std::nullopt otherwise): FieldNode::heldRange() for a node holding a
/// grid of its values (KeptGridLeaves).
std::optional<Interval> heldValuesRange(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& voxels);

/// A field's values already known at every stride-th voxel (a density solve's coarse pass): sample
/// (i, j, k) is the value at the voxel centre of index origin + stride (i, j, k), within @a error
/// of what the field's bound() encloses. They prove a box straddles a band without its bound: any
/// enclosure of the field over a box holds the values at the samples inside it, so when one of
/// them is at least the band's low end and one at most its high end (the same one or two), the
/// enclosure meets the band. The cull then skips the bound, and finds the same leaves.
struct KnownSamples {
    openvdb::Coord origin{0, 0, 0};
    int stride = 1;
    openvdb::Coord count{0, 0, 0};  ///< samples along each axis
    std::vector<float> values;      ///< x-major, z fastest (count.x() count.y() count.z())
    double error = 0.0;             ///< on top of a relative 1e-6 (rounding, float samples)

    /// Whether the samples at voxel indices within @a voxels prove that any enclosure of the
    /// field over those voxels' centres meets @a band. Samples of +-1e30 and beyond (masks'
    /// outside values) prove nothing.
    bool meets(const openvdb::CoordBBox& voxels, const Interval& band) const;
};

/// What to evaluate and what to skip.
struct SparseOptions {
    /// Leaves whose bound meets this interval are evaluated voxel by voxel. Regions whose bound
    /// lies wholly below become inside tiles; wholly above, background. Bounds are taken over
    /// each box grown by one voxel, so every grid edge that crosses a level inside the interval
    /// has both ends in evaluated leaves (what the mesher relies on).
    Interval band{0.0, 0.0};
    float insideValue = -1.0f;  ///< value of inside tiles
    float outsideValue = 1.0f;  ///< background
    int margin = 1;             ///< voxels beyond the domain on every side (1 caps the mesh)
    /// Intersect with the domain box (max with its signed distance) so the solid is capped where
    /// it meets the domain. Applied to leaves within a voxel of the boundary only: deeper inside
    /// the box's distance is below -1.5 voxels and never changes a sign.
    bool clipToDomain = false;
    std::uint64_t maxLeaves = 0;  ///< 0: as many as available memory allows
    /// What one evaluated leaf costs: the grid's share and whatever the caller keeps per leaf
    /// beside it (a coverage solve keeps each band voxel's value and samples). The estimate the
    /// refusal (and SparseStats::estimatedBytes) uses; 0: kBytesPerLeaf.
    std::uint64_t bytesPerLeaf = 0;
    /// What the caller holds beside the leaves whatever their number (a streamed mesh's chunks in
    /// flight, kStreamedMeshBytes): added to the estimate, and taken off the memory the leaves may use.
    std::uint64_t bytesBeside = 0;
    /// When set, evaluated leaves are not kept: each is handed to this function (from any thread,
    /// once, in no fixed order) with its origin and its 512 values as the grid would hold them,
    /// and the grid returned holds the tiles only. For measures that need the values once (the
    /// density solve's count): no leaf is allocated, nothing is walked twice.
    std::function<void(const openvdb::Coord& origin, const float* values)> leafVisitor = nullptr;
    /// Leaves evaluated together along z, as one batch of 8 x 8 x (8 stackLeaves) points: a stack
    /// holds the leaves whose index z lies in [s, s + 8 stackLeaves) for s a multiple of
    /// 8 stackLeaves, its batch's origin domain.worldOf() of its first point. A stack is made whole
    /// when any of its leaves is needed (the others are dropped), so a leaf's values depend on its
    /// stack alone, whatever band, margin or thread asks for it: two evaluations with the same
    /// stackLeaves hand a field the same batches (what GridValueMemo's contract needs). Longer rows
    /// share a strut row's set-up (a convolution lattice's rows of 8 points are mostly set-up).
    /// 1, 2, 4, 8 or 16 (a stack stays within one 128^3 block); 1: one batch per leaf. The clip
    /// (clipToDomain) is applied per leaf, as without stacks.
    int stackLeaves = 1;
    std::string stage = "evaluating field";
    const JobContext* context = nullptr;  ///< progress and cancellation (none: silent)
    /// Values known in advance (KnownSamples): boxes they prove straddling the band are taken
    /// without a bound (not with clipToDomain). Not owned; the grid is the same with or without.
    const KnownSamples* known = nullptr;
};

struct SparseStats {
    std::uint64_t leaves = 0;         ///< evaluated 8^3 leaves (kept in the grid or visited)
    std::uint64_t stackedLeaves = 0;  ///< leaves made in stacks (stackLeaves > 1), the dropped ones too
    /// Leaves times the options' bytes per leaf, plus their bytes beside: the memory estimate.
    std::uint64_t estimatedBytes = 0;
    std::uint64_t insideTiles = 0;  ///< inside tiles (any level)
    std::uint64_t culledBoxes = 0;  ///< boxes skipped as outside
    /// Voxels of the domain (index box [0, dims)) whose value is below 0, in leaves and inside
    /// tiles: countBelow(grid, domain.indexBox(), 0) counted as the leaves are made, while
    /// their values are in cache, instead of in a second pass over the grid.
    std::uint64_t domainVoxelsBelowZero = 0;
};

/// Evaluates @a field over the domain (plus the margin) in parallel: hierarchical culling by
/// bounds over 128^3 blocks and 8^3 leaves, then one batched gridValues() call per leaf. The
/// result is identical for any thread count. Throws JobError when the leaves would not fit in
/// memory or the field returns a non-finite value.
openvdb::FloatGrid::Ptr evaluateSparse(const FieldNode& field, const Domain& domain, const SparseOptions& options,
                                       SparseStats* stats = nullptr);

/// The stack height (SparseOptions::stackLeaves: 1, 2, 4, 8 or 16) for a field whose rows gain
/// from tall stacks, at most @a most, on @a domain. A stack is evaluated whole, so stacks that
/// overrun the domain's top make points nobody reads: the height s taken is the one of least
/// covered(s) (1 + 1 / s), covered(s) the voxels along z of the stacks over the domain's height
/// and 1 / s the share of a point in its rows' set-up (W2g's wireframe at 25 mm, CPU 16.3, 10.4,
/// 9.3, 8.4 s for 1, 4, 8, 16 leaves: A + B / s with B about A), the taller on a tie. A 50 mm
/// frame at 0.1 mm (500 voxels) takes 16, a 40 mm one 8 (16 would cover 512 voxels for 400), a
/// 2 mm plate at 0.05 mm 8.
int stackLeavesFor(const Domain& domain, int most);

/// Bytes one evaluated leaf costs through evaluation and meshing (grid values plus mesh share).
inline constexpr std::uint64_t kBytesPerLeaf = 6 * 1024;

}  // namespace voxlat
