/// @file LeafSteps.h
/// @brief The coverage samples' steps of a whole 8^3 leaf at once: each voxel's per-voxel change
/// along x, y and z (central differences, one-sided where a neighbour is absent) and its length,
/// a CoverageSample's step, for the 512 voxels of a leaf whose neighbours are all in the
/// region. The density solve's coverage passes walk the band leaf by leaf (W2g's 50 mm trimmed
/// frame: 200 thousand leaves, twice); voxel by voxel, their branches were 13 % of its CPU.
///
/// The loops here are the baseline's: IEEE operations without contraction or reassociation, the
/// same as coverage's voxel-by-voxel form (axisChange(): float differences, their squares summed
/// in double in x, y, z order, the square root rounded to float). LeafStepsAvx512.cpp does the
/// same operations in the same order in AVX-512F lanes, sixteen voxels at a time, and
/// LeafStepsAvx2.cpp in AVX2 lanes, eight at a time (CPUs without AVX-512F): the same floats.
#pragma once

#include <cstdint>
#include <limits>

namespace voxlat::coverage {

/// A leaf's values and its six neighbours' (next[axis][0] below, next[axis][1] above): a
/// neighbour leaf that is absent reads as kNoNeighbour (leafNoNeighbours()), as one whose values
/// are 1e30 or more does (tiles, outside a density mask): not a neighbour.
struct LeafWithNeighbours {
    const float* data;
    const float* next[3][2];
};

/// A value no neighbour holds: reads as absent.
constexpr float kNoNeighbour = std::numeric_limits<float>::max();

/// 512 values of kNoNeighbour: an absent neighbour leaf's buffer.
const float* leafNoNeighbours();

// The loops are static: each build of them (the baseline's, AVX-512F's) keeps its own copy,
// where an inline function's copies would be merged into one at link time, whichever's flags.
/// A voxel's change along one axis from its neighbours' values @a up and @a down (absent when 1e30
/// or more): axisChange()'s, branch-free.
static inline double laneChange(float value, float up, float down)
{
    const bool hasUp = up < 1e30f, hasDown = down < 1e30f;
    const double both = 0.5 * double(up - down);
    const double oneUp = double(up - value);
    const double oneDown = double(value - down);
    const double one = hasUp ? oneUp : (hasDown ? oneDown : 0.0);
    return hasUp && hasDown ? both : one;
}

/// The 64 values of the x plane above (@a up) or below a leaf's plane @a x: the leaf's own, or
/// the neighbour leaf's nearest plane at the leaf's x faces (each form of the steps reads them).
static inline const float* xPlane(const LeafWithNeighbours& leaf, int x, bool up)
{
    if (up) return x < 7 ? leaf.data + (x + 1) * 64 : leaf.next[0][1];
    return x > 0 ? leaf.data + (x - 1) * 64 : leaf.next[0][0] + 7 * 64;
}

/// steps[i] for each of the leaf's 512 voxels (offset order): the length of its change.
static inline void leafStepsLoop(const LeafWithNeighbours& leaf, float* steps)
{
    const float* data = leaf.data;
    for (int x = 0; x < 8; ++x) {
        const float *xUp = xPlane(leaf, x, true), *xDown = xPlane(leaf, x, false);
        for (int y = 0; y < 8; ++y) {
            const int r = x * 64 + y * 8;
            const float* row = data + r;
            const float* yUp = y < 7 ? row + 8 : leaf.next[1][1] + x * 64;
            const float* yDown = y > 0 ? row - 8 : leaf.next[1][0] + x * 64 + 56;
            float zUp[8], zDown[8];
            for (int k = 0; k < 7; ++k) zUp[k] = row[k + 1];
            zUp[7] = leaf.next[2][1][r];
            zDown[0] = leaf.next[2][0][r + 7];
            for (int k = 1; k < 8; ++k) zDown[k] = row[k - 1];
            for (int k = 0; k < 8; ++k) {
                const float v = row[k];
                const double cx = laneChange(v, xUp[y * 8 + k], xDown[y * 8 + k]);
                const double cy = laneChange(v, yUp[k], yDown[k]);
                const double cz = laneChange(v, zUp[k], zDown[k]);
                const double sum = cx * cx + cy * cy + cz * cz;
                steps[r + k] = float(__builtin_sqrt(sum));
            }
        }
    }
}

/// What a leaf holds over a bracket [a, b] (straddlingSamples()' per-leaf counts).
struct LeafStraddle {
    /// Voxels below lo by value, or within [lo, hi] and covered whole over [a, b].
    std::uint32_t below = 0;
    /// Voxels below countLo, and within [countLo, countHi].
    std::uint32_t countBelow = 0, countWithin = 0;
    /// Voxels within [lo, hi] whose coverage changes over [a, b], bit i % 64 of word i / 64.
    std::uint64_t changing[8] = {};
};

/// The bounds leafStraddleLoop() sorts a leaf's voxels by.
struct StraddleBounds {
    double a, b;             ///< the bracket
    float lo, hi;            ///< the band whose steps are taken: [a - reach, b + reach]
    float countLo, countHi;  ///< the count's band
};

/// Sorts a leaf's voxels (@a data, their @a steps) over a bracket as straddlingSamples() does:
/// a voxel within [lo, hi] is covered whole when its ramp (value -+ half its step) ends at or
/// below a (a step of 0: valued below a), changing when the ramp meets (a, b) (a step of 0:
/// valued in [a, b)), else empty.
static inline LeafStraddle leafStraddleLoop(const float* data, const float* steps, const StraddleBounds& s)
{
    LeafStraddle out;
    const double a = s.a, b = s.b;
    const float lo = s.lo, hi = s.hi, countLo = s.countLo, countHi = s.countHi;
    for (int w = 0; w < 8; ++w) {
        std::uint32_t below = 0, countBelow = 0, countWithin = 0;
        std::uint64_t changing = 0;
        for (int j = 0; j < 64; ++j) {
            const float v = data[w * 64 + j];
            const double value = v, half = 0.5 * double(steps[w * 64 + j]);
            const bool inBand = !(v < lo || v > hi);
            const bool stepped = half > 0.0;
            const bool full = stepped ? value + half <= a : value < a;
            const bool empty = stepped ? value - half >= b : !(value < b);
            below += std::uint32_t(v < lo) + std::uint32_t(inBand && full);
            countBelow += std::uint32_t(v < countLo);
            countWithin += std::uint32_t(!(v < countLo) && v <= countHi);
            changing |= std::uint64_t(inBand && !full && !empty) << j;
        }
        out.below += below;
        out.countBelow += countBelow;
        out.countWithin += countWithin;
        out.changing[w] = changing;
    }
    return out;
}

/// The largest step of a voxel valued within [lo, hi] (below 1e29; 0 when none).
static inline float leafWidestLoop(const float* data, const float* steps, float lo, float hi)
{
    float widest = 0.0f;
    for (int i = 0; i < 512; ++i) {
        const bool counted = !(data[i] < lo || data[i] > hi) && steps[i] < 1e29f;
        const float step = counted ? steps[i] : 0.0f;
        widest = step > widest ? step : widest;
    }
    return widest;
}

/// Whether any of a leaf's 512 values lies within [lo, hi].
static inline bool leafMeetsLoop(const float* data, float lo, float hi)
{
    bool meets = false;
    for (int i = 0; i < 512; ++i) meets |= !(data[i] < lo || data[i] > hi);
    return meets;
}

/// One build of the loops above: the baseline's, or a lane form's.
struct LeafStepForms {
    void (*steps)(const LeafWithNeighbours& leaf, float* steps, float lo, float hi);
    LeafStraddle (*straddle)(const float* data, const float* steps, const StraddleBounds& s);
    float (*widest)(const float* data, const float* steps, float lo, float hi);
    bool (*meets)(const float* data, float lo, float hi);
};

/// The AVX-512F forms (LeafStepsAvx512.cpp), null where the build has none; run them only where
/// hasAvx512Rows().
const LeafStepForms* avx512LeafSteps();
/// The AVX2 forms (LeafStepsAvx2.cpp), null where the build has none; run them only where
/// hasAvx2Rows().
const LeafStepForms* avx2LeafSteps();

/// The loops above, in AVX-512F lanes where the CPU has them (hasAvx512Rows()), else in AVX2
/// lanes where it has those (hasAvx2Rows()), else the baseline's: the same results. leafSteps()
/// gives the steps of the voxels valued within [@a lo, @a hi] (what its callers read); the
/// others' are unspecified (the lane forms skip rows where none is in it: the widest step's pass
/// reads a band a few voxels wide).
void leafSteps(const LeafWithNeighbours& leaf, float* steps, float lo, float hi);
LeafStraddle leafStraddle(const float* data, const float* steps, const StraddleBounds& s);
float leafWidest(const float* data, const float* steps, float lo, float hi);
bool leafMeets(const float* data, float lo, float hi);

}  // namespace voxlat::coverage
