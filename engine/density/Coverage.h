/// @file Coverage.h
/// @brief Sub-voxel coverage, the density measure shared by the quantile solve (when value ties
/// defeat a count) and the periodic pieces: a voxel is covered in proportion to the share of it
/// below the level, the field taken as linear across the voxel.
#pragma once

#include "engine/core/DefaultInitVector.h"
#include "engine/core/Domain.h"
#include "fields/core/Interval.h"

#include <openvdb/openvdb.h>

#include <cstdint>
#include <functional>
#include <span>
#include <vector>

namespace voxlat::coverage {

/// The indicator's value outside the mask: above every level the solve can choose.
constexpr double kOutsideMask = 1e36;

/// A bracketed voxel value and its change across one voxel (central differences of the grid).
struct CoverageSample {
    float value;
    float step;
};
/// A band's coverage samples (millions: sized up front and filled in parallel, not zeroed first).
using CoverageSamples = DefaultInitVector<CoverageSample>;

/// A voxel cut by the plane of its value and per-axis changes, counted `weight` times.
struct PlaneSample {
    float value;
    float change[3];  ///< |per-voxel change| along x, y, z
    float weight;
};

/// A sample's change along one axis: the central difference, one-sided where a neighbour is
/// absent (not evaluated, or outside a density mask), 0 with neither. Inline: the density solve
/// takes three per sample in each of its passes over a period's million samples.
inline double axisChange(float value, float up, bool hasUp, float down, bool hasDown)
{
    if (hasUp && hasDown) return 0.5 * (up - down);
    if (hasUp) return up - value;
    if (hasDown) return value - down;
    return 0.0;
}

/// Band voxels (values in [@a lo, @a hi] inside @a region) with the length of their per-voxel
/// change, for the linear coverage estimate. @a interrupt, when set, is called every 64
/// leaves and throws to stop (a plate's band holds 10^7 voxels). @a leavesBelow, when set,
/// receives the count of the region's leaf voxels below @a lo, taken in the pass that counts the
/// band (countTilesBelow() adds the tiles: countBelow() without a walk of its own). @a beforeHolding,
/// when set, is called with the number of samples once they are counted and before they are
/// allocated: a memory check that throws to refuse them.
CoverageSamples coverageSamples(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, float lo, float hi,
                                const std::function<void()>& interrupt = {}, std::uint64_t* leavesBelow = nullptr,
                                const std::function<void(std::size_t samples)>& beforeHolding = {});

/// The largest step coverageSamples() would give a band voxel (below 1e29), without keeping the
/// samples: what decides how far the band is widened, read from a grid whose band's samples
/// would be held beside it (a 50 mm wireframe: 63 MB) only to be dropped.
float widestCoverageStep(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, float lo, float hi,
                         const std::function<void()>& interrupt = {});

/// What straddlingSamples() found.
struct StraddlingSamples {
    /// The region's leaf voxels whose coverage changes over [a, b] (their ramp, value -+ half
    /// their step, meets (a, b); a step of 0 valued in [a, b)), in leaf order then offset order.
    CoverageSamples samples;
    /// The region's leaf voxels covered whole over [a, b]: ramp ending at or below a, or valued
    /// below a - reach (taken by value, as coverageSamples()' callers take the voxels below its band).
    std::uint64_t fullyBelow = 0;
    /// The region's leaf voxels valued below countBand.lo, and within it (splitByBand()'s count).
    std::uint64_t countBelow = 0, countWithin = 0;
};

/// The samples a bisection over [@a a, @a b] reads, and the voxels it counts as covered: the
/// region's leaf voxels valued within [a - @a reach, b + @a reach] have their step taken (as
/// coverageSamples()); those whose coverage is the same at every level of [a, b] are counted
/// (full) or left out (empty) instead of held. For a bracket of a percent of the density,
/// 37-42 % of what coverageSamples(level -+ reach) holds (W2g's 50 mm trimmed frame: 7.1 of 19.3
/// million; its cylinder frame 7.9 of 18.6). One pass over the leaves in fixed chunks, joined in leaf order: the same
/// samples for any thread count. @a beforeHolding is called with their count before they are joined.
/// The same pass counts the leaf voxels below and within @a countBand (floats, as splitByBand()
/// compares them).
StraddlingSamples straddlingSamples(const openvdb::FloatGrid& grid, const openvdb::CoordBBox& region, double a,
                                    double b, float reach, const std::function<void()>& interrupt = {},
                                    const std::function<void(std::size_t samples)>& beforeHolding = {},
                                    const Interval& countBand = Interval(0.0));

/// Voxels below @a level counted with sub-voxel coverage: a voxel whose value is within half a
/// step of the level is partly inside, linearly in the distance (a plane cutting the voxel).
/// Summed in parallel over fixed blocks: the same double for any thread count.
double coveredVoxels(const CoverageSamples& samples, double level);

/// coveredVoxels() at each of @a levels into @a out (as many), one pass over the samples for all.
void coveredVoxels(const CoverageSamples& samples, std::span<const double> levels, std::span<double> out);

/// What bisectCoverage() found.
struct CoverageLevel {
    double level = 0.0;    ///< where fullyBelow + the samples' coverage reaches `wanted`
    double covered = 0.0;  ///< fullyBelow + the samples' coverage at `level`
    /// d covered / d level over the middle half of [a, b] (voxels per unit of level; 0 when
    /// that half is empty or unbounded)
    double slope = 0.0;
};

/// The level in [a, b] at which fullyBelow + coveredVoxels(samples, level) reaches @a wanted
/// (bisection; samples full, empty or linear over what is left of the bracket are set aside, so
/// each step visits only the samples with a breakpoint inside it; the same level for any thread
/// count). @a samples are reordered in place (hence taken by value: move them in).
/// @a interrupt, when set, is called once per step and every 2^20 samples within one.
CoverageLevel bisectCoverage(CoverageSamples samples, double fullyBelow, double wanted, double a, double b,
                             const std::function<void()>& interrupt = {});

/// The share of a voxel below @a level, the voxel's field taken as the plane through its value
/// with its per-axis changes (exact for planes at any orientation).
double planeCoverage(const PlaneSample& s, double level);

/// Weighted voxels below @a level by planeCoverage().
double planeCovered(const std::vector<PlaneSample>& samples, double level);

/// The level in [a, b] at which @a settled + planeCovered() reaches @a wanted, given that it is
/// at most @a wanted at a and at least at b (regula falsi, Illinois). @a covered, when given,
/// receives the covered weight at the level returned. Sums run over fixed blocks in a fixed
/// order: the same level for any thread count.
double solvePlaneCoverage(std::vector<PlaneSample> active, double settled, double wanted, double a, double b,
                          double* covered = nullptr);

}  // namespace voxlat::coverage
