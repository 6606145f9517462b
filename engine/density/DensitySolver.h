/// @file DensitySolver.h
/// @brief Finds the level at which a solid fills a target share of the domain.
#pragma once

#include "engine/core/Domain.h"
#include "engine/core/JobContext.h"

#include <openvdb/openvdb.h>

#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <vector>

namespace voxlat {

struct DensitySolution {
    double level = 0.0;     ///< level of the indicator field: solid = {g < level}
    double achieved = 0.0;  ///< share of domain voxel centres inside, measured on the grid
    std::uint64_t insideVoxels = 0;
    std::uint64_t domainVoxels = 0;  ///< the denominator: domain voxels (inside the mask, if any)
    /// With a mask: its inside in voxels by distanceCoverage() (the region's volume as a mesh of
    /// it would enclose; the count above is half a voxel off along faces in planes of samples).
    double maskCoverageVoxels = 0.0;
    bool coverage = false;  ///< measured with sub-voxel coverage (value ties), not a count
    int rounds = 0;         ///< fine passes needed (1 unless the coarse bracket missed)
    /// d achieved / d level about the level found, the solve's own measure over a window of about
    /// 1 % of the target either side (a secant; 0 when the values give none): how far a level
    /// must move to change the share, for a correction aimed at another measure (the mesh's).
    double slope = 0.0;
    std::uint64_t evaluatedLeaves = 0;
    /// The most memory the solve's checks found it holding, in bytes: its evaluated leaves
    /// (kBytesPerLeaf each) and what it kept beside them once counted (the bracket's values, or
    /// the band's coverage samples): `memory_estimate_mb` in report.json. The solve throws
    /// JobError where that passes 70 % of the free memory.
    std::uint64_t estimatedBytes = 0;
};

/// Solves vol{g < level} / vol(domain) = @a target over the domain's voxel centres, as an exact
/// quantile: a coarse strided pass brackets the level, a sparse pass evaluates only the leaves
/// whose bound meets the bracket, and a selection over the bracketed values picks the level. The
/// achieved share is within half a voxel's share of the target. When value ties (a symmetric
/// field on a regular grid) leave no level within 0.05 % of the target by count, the level is
/// bisected on a sub-voxel coverage measure instead (continuous in the level). @a subVoxel
/// always uses the coverage measure: for solids whose features line up with the voxel lattice
/// (strut lattices with cells of a whole number of voxels), where counting voxel centres aliases.
///
/// With a @a mask the density is relative to the space the mask encloses: the denominator is the
/// number of domain voxels whose centre has mask < 0, the numerator those that are also inside
/// the solid. Regions whose mask bound is wholly positive are never evaluated.
///
/// @a marginVoxels more voxels past the domain on every side are measured as well (the domain's voxel
/// lattice continued, so the leaves are the domain's): a frame whose box pokes out of the job's
/// domain is measured on the job's voxels, the box as the mask.
///
/// @a levelWithin, when set, is called (at most once) with an interval the level will lie in,
/// as soon as the solve knows one narrower than the band it evaluated: the count's bracket once
/// its straddling samples show it holds the target, else, before the wide band's coverage pass,
/// the band that pass bisects in. A caller keeping the indicator's values for a grid at the
/// level (GridValueMemo::dropOutside()) drops those that grid cannot read before the bisection
/// (and before the wide band's samples are allocated).
///
/// @a stackLeaves: the indicator's leaves are evaluated in stacks along z (SparseOptions::stackLeaves),
/// as a grid of the same stacks will ask for them (a GridValueMemo then serves its batches).
///
/// @a keepGrid, when set, is handed (at most once) the grid its coverage pass measured, after
/// that pass has taken its samples, in place of freeing it: leaves of evaluateSparse(indicator,
/// domain, o) for options o of the solve (band, stacks, no clipToDomain), those with a voxel
/// outside @a mask left out (tiles). A caller keeping the indicator's values
/// (GridValueMemo::keepLeaves()) keeps this grid instead of a second copy of them. A solve with a
/// mask or subVoxel always gets there.
DensitySolution solveDensity(const FieldNode& indicator, const Domain& domain, double target,
                             const FieldNode* mask = nullptr, bool subVoxel = false,
                             const JobContext* context = nullptr, int marginVoxels = 0,
                             const std::function<void(Interval)>& levelWithin = {}, int stackLeaves = 1,
                             const std::function<void(openvdb::FloatGrid::Ptr)>& keepGrid = {});

/// A part of a measuring region, sampled on its own domain and counted @a weight times.
struct DensityPiece {
    Domain domain;
    double weight = 1.0;
    /// The region measured: samples on its faces take one-sided differences, all others see
    /// their neighbours (evaluated as a margin). Unset: the union of the pieces.
    std::optional<Box3> within{};
};

/// Pieces that measure @a box for a field that repeats with @a period at least @a reach inside
/// the box (PeriodicTiling's condition), so only one period of the deep interior is sampled.
/// All pieces share one lattice of spacing period / n, n = ceil(period / voxel), from the box's
/// corner. Per axis, with m samples in the box and a face zone of z samples (reach plus one):
/// the low zone; one period between the zones, its first e samples counted k + 1 times and the
/// rest k times, where k whole periods and e more samples fit between the zones (the e samples
/// past the last whole period repeat the period's first e); and the high zone. Where the field
/// is @a mirror symmetric about the box's middle along an axis (and so is the lattice) the high
/// zone is the low zone's mirror image: the low zone is counted twice instead; and, periodic between
/// the zones, the field is then symmetric within the period as well (sample m's image is sample
/// -m - 1 modulo the period, and each of the period's two parts is its own image), so each part
/// is measured by its first half counted twice (an odd part's middle sample once). The 3D pieces are
/// the products; their weighted voxels are exactly the box's. Empty when that does not apply
/// (the box is not a whole number of periods, fewer than two periods fold, or the period
/// differs between axes). A period of 0 along an axis: the field does not repeat along it, and
/// one segment spans the whole axis there (the box must still be a whole number of the other
/// axes' period along it). With @a swapXY (the field is its own image when x and y are swapped
/// about the box's corner) and x and y cut into the same segments, a piece and its transpose
/// are the same samples: only one of each pair is kept, counted twice.
std::vector<DensityPiece> periodicPieces(const Box3& box, const Vec3d& period, double reach, double voxel,
                                         std::array<bool, 3> mirror = {}, bool swapXY = false);

/// solveDensity() over weighted @a pieces: the level at which the weighted share of {g < level}
/// is @a target of the pieces' weighted voxels, each voxel's share being the exact volume below
/// the plane through its value with its per-axis changes (central differences; one-sided only on
/// the faces of the pieces' union, each piece being evaluated with a voxel of margin). Every
/// voxel of every piece is evaluated, onto a dense array per piece (pieces are meant to be
/// small). Histograms of where each voxel's coverage begins and ends bracket the level in one
/// pass; only the voxels the bracket cuts take the cube-plane volume, and regula falsi
/// (Illinois) closes the bracket. All sums run over fixed chunks in a fixed order: the level is
/// the same for any thread count.
DensitySolution solveDensity(const FieldNode& indicator, std::span<const DensityPiece> pieces, double target,
                             const JobContext* context = nullptr);

}  // namespace voxlat
