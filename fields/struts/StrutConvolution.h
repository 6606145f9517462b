/// @file StrutConvolution.h
/// @brief A strut lattice as a Gaussian convolution surface: F = sum_j F_j, one closed-form
/// segment integral per strut (GaussianSegment.h), each cut off beyond its radius r_c.
#pragma once

#include "fields/core/PlaneBands.h"
#include "fields/struts/CoarseNodes.h"
#include "fields/struts/GaussianSegment.h"
#include "fields/struts/StrutIndex.h"

#include <array>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <vector>

namespace voxlat {

/// One strut of a convolution lattice: a segment, its kernel width and its end weights.
struct ConvolutionStrut {
    Vec3d a{0.0}, b{0.0};
    double sigma = 1.0;
    double w0 = 1.0, w1 = 1.0;  ///< weights at a and b (linear in between), > 0
};

/// The raw field F >= 0 (larger inside). Wrap it in LevelSolid(SolidSide::Above, t) for the
/// solid F >= t. Strut j contributes only where the distance to its segment is below
/// r_c,j = sigma_j sqrt(2 ln(1/eps)); the dropped tail is below eps * w_j sigma_j sqrt(2 pi) per
/// strut. Every evaluation path applies that same rule and sums in strut index order, so values,
/// gridValues and bounds agree and results do not depend on threads; grid batches on a known
/// lattice may instead come from nodes every second voxel (setGridTolerance, CoarseNodes.h),
/// within their proven bound of those values (bounds are the exact field's).
class StrutConvolution final : public FieldNode, public PlaneBands {
public:
    /// @a interrupt, when set, is called every 2^14 struts and before the index is built (a
    /// plate's 10^5-10^6 struts take seconds): it throws to stop.
    explicit StrutConvolution(const std::vector<ConvolutionStrut>& struts, double eps = 1e-4,
                              const std::function<void()>& interrupt = {});

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    /// Gathers the struts that reach the block once, then evaluates its points row by row (rows
    /// along z; a plane batch, nz = 1, along y). Where a plane batch lies within 0.1 sigma of its
    /// centre along a strut (a pixel's sub-samples), that strut's erf integral J(h) is its cubic
    /// Taylor polynomial about the centre: at most 2.1e-5 of the strut's peak off (see the .cpp).
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    /// [sum of per-strut minima, sum of per-strut maxima] over the box, using the box's
    /// distances to each segment; struts whose cut-off does not reach the box add nothing.
    Interval bound(const Box3& box) const override;
    /// A slicer's plane with the struts gathered once: each tile's upper bound (per strut, its peak
    /// times the kernel at the least distance from the tile's centre less its half diagonal, plus
    /// 2.5e-5 of the peaks counted: the table and Taylor paths' error) proves the tiles below
    /// band.lo (-1), a lower bound (per strut whose cut-off holds the footprint, its least weight
    /// times the closed form at the line's distance from the footprint's farthest corner) those
    /// above band.hi (+1), and only the other tiles and their
    /// halo are evaluated (the rest are 0; struts that reach no open tile are left out, as they
    /// add nothing there). Skipped tiles are left out and Exact ones evaluated (@a need). Where
    /// the struts' least sigma and their directions allow (ColumnStencils: every fourth column at
    /// the Saturn 4's 19 um for a cube's diagonals of sigma 0.2 mm in planes four blocks across or
    /// more, every third in one block), only the nodes' columns are evaluated and the others
    /// interpolated, within planeTolerance() of the peaks near (and the cut-offs' steps:
    /// ColumnStencils.h); with tolerance 0, every column is gridValues' own doubles. The upper
    /// bounds go eight tiles at a time where the CPU has AVX-512F (TileBounds.h: the same doubles).
    void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                     std::span<signed char> side, std::span<const TileNeed> need) const override;

    std::size_t strutCount() const { return mSegments.size(); }
    const GaussianSegment& segment(std::size_t j) const { return mSegments[j]; }
    double cutoffEpsilon() const { return mEps; }
    double cutoffRadius(std::size_t j) const { return std::sqrt(mCutoffSqr[j]); }
    /// Largest total tail dropped at any point: eps times the sum of the struts' peaks that
    /// can be near one point is at most eps * sum_j peak_j; this returns eps * max_j peak_j.
    double peak(std::size_t j) const { return mPeak[j]; }
    /// planeValues' interpolated columns (ColumnStencils.h): the bound K each may have, per unit
    /// of the peaks near (0: every column exact, gridValues' doubles). Set before the field is
    /// shared across threads.
    void setPlaneTolerance(double tolerance) { mPlaneTolerance = tolerance; }
    double planeTolerance() const override { return mPlaneTolerance; }
    /// The default: 2.5e-5, the table and Taylor paths' own (see planeValues).
    static constexpr double kPlaneTolerance = 2.5e-5;
    /// gridValues on a known lattice (GridBatch::onLattice) from exact nodes every second voxel
    /// (CoarseNodes.h) where their bound, per unit of the peaks near, is at most @a tolerance
    /// (0: every point exact). Set before the field is shared across threads.
    void setGridTolerance(double tolerance) { mGridTolerance = tolerance; }
    /// The default: 1e-3 (CoarseNodes.h: at sigma = 0.5 mm and 0.1 mm voxels, a cube's diagonals
    /// bound 1.3e-4, any direction 4.9e-4; nodes once sigma spans about four voxels or more).
    static constexpr double kGridTolerance = 1e-3;
    double gridTolerance() const { return mGridTolerance; }
    /// The bound CoarseNodes would have on a lattice of @a voxel (coarseNodesBound with the
    /// least sigma and the largest C8 per axis of the field's struts).
    double coarseBound(double voxel) const;
    /// coarseBound(@a voxel) where gridValues takes a lattice of that voxel from the coarse
    /// nodes (at most gridTolerance()), else 0.
    double servedBound(double voxel) const;
    /// Whether gridValues takes @a batch from the coarse nodes.
    bool coarseServes(const GridBatch& batch) const;
    /// Bytes the coarse nodes hold (the last lattice's: CoarseNodes).
    std::size_t coarseBytes() const;

private:
    /// F at one point from the candidate struts @a cand (ascending).
    double pointValue(const Vec3d& p, const std::vector<std::uint32_t>& cand) const;
    /// gridValues from the gathered struts @a cand; with @a columnTiles (a plane batch, seen
    /// along y), column i makes only the points of the tiles (of @a tile points) whose bits
    /// columnTiles[i] holds and their one-point halo along y (PlaneBands' layout). @a spans, when
    /// set (a plane batch), holds per strut of @a cand the part of the plane within its reach
    /// (xLo, xHi, yLo, yHi: planeSpan's, which evaluate() otherwise finds itself).
    void evaluate(const GridBatch& batch, std::span<double> out, const std::vector<std::uint32_t>& cand,
                  const std::uint64_t* columnTiles, int tile, const double* spans = nullptr) const;
    /// gridValues with every point exact.
    void exactGridValues(const GridBatch& batch, std::span<double> out) const;

    std::vector<GaussianSegment> mSegments;
    std::vector<Vec3d> mEnd;
    std::vector<double> mCutoffSqr;
    std::vector<double> mPeak;  ///< max(w0, w1) sigma sqrt(2 pi)
    std::vector<double> mWMin;  ///< min(w0, w1)
    double mEps;
    double mPlaneTolerance = kPlaneTolerance;
    /// The largest of the struts' C8 along x, y and z (segmentEighthDerivativeBound): along x
    /// planeValues' stencils, all three CoarseNodes'; and the least sigma.
    std::array<double, 3> mEighthBoundAxes{0.0, 0.0, 0.0};
    double mSigmaMin = std::numeric_limits<double>::infinity();
    double mGridTolerance = kGridTolerance;
    std::unique_ptr<CoarseNodes> mCoarse;
    StrutIndex mIndex;
};

}  // namespace voxlat
