/// @file TileBounds.cpp
/// TileBounds.h's table and its portable form: two tiles at a time (GCC/Clang vector
/// extensions), each lane making the scalar operations in their order.

#include "fields/struts/TileBounds.h"

#include <algorithm>
#include <cmath>
#include <cstddef>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace voxlat {

namespace {

/// Two doubles, and the scalar operations taken on them lane by lane: the same doubles.
using Lanes2 = double __attribute__((vector_size(16)));

/// std::clamp(v, 0, hi) per lane.
inline Lanes2 clampLanes(Lanes2 v, double hi)
{
    const Lanes2 low = v < 0.0 ? Lanes2{} : v;
    return hi < v ? Lanes2{} + hi : low;
}

/// std::sqrt per lane (IEEE square roots, correctly rounded either way).
inline Lanes2 sqrtLanes(Lanes2 v)
{
#if defined(__SSE2__)
    return Lanes2(_mm_sqrt_pd(__m128d(v)));
#else
    return Lanes2{std::sqrt(v[0]), std::sqrt(v[1])};
#endif
}

constexpr int kSteps = 256;
constexpr int kSize = 12 * kSteps + 1;

/// exp(-k / 256) (and 1e-9 more), k < kSize.
struct ExpUpperTable {
    double value[kSize];
    ExpUpperTable()
    {
        for (int k = 0; k < kSize; ++k) value[std::size_t(k)] = std::exp(-double(k) / kSteps) * (1.0 + 1e-9);
    }
};

}  // namespace

ExpUpperNodes expUpperNodes()
{
    static const ExpUpperTable table;
    return {table.value, double(kSteps), kSize};
}

void addTileBoundsScalar(const TileColumnStrut& s, int a0, int a1, int b0, int b1, int tilesY,
                         const ExpUpperNodes& table, double* upper, double* peaks, TileColumnReach* reachOf)
{
    auto expUpper = [&table](double x) {
        const double at = x * table.steps;
        if (!(at < double(table.size - 1))) return std::exp(-x);
        return table.value[std::size_t(at)];  // truncation: the node at or below x
    };
    for (int a = a0; a <= a1; ++a) {
        TileColumnReach reach;
        double* upperA = upper + std::size_t(a) * tilesY;
        double* peaksA = peaks + std::size_t(a) * tilesY;
        const double ex = s.cx0 + a * s.stepX - s.ax;
        // Tile b's bound (a centre within far of the strut): its peak times the kernel at the
        // least distance @a near.
        auto add = [&](int b, double near) {
            upperA[b] += s.peak * expUpper(near * near * s.inv2s2);
            peaksA[b] += s.peak;
        };
        int b = b0;
        // Two tiles at a time: the operations below per lane, in their order (the same doubles),
        // without a branch per tile on which of them the strut reaches.
        for (; b < b1; b += 2) {
            const Lanes2 ey = s.cy0 + Lanes2{double(b), double(b + 1)} * s.stepY - s.ay;
            const Lanes2 h = clampLanes(ex * s.ux + ey * s.uy + s.ez * s.uz, s.length);
            const Lanes2 rx = ex - h * s.ux, ry = ey - h * s.uy, rz = s.ez - h * s.uz;
            const Lanes2 dSqr = rx * rx + ry * ry + rz * rz;
            const auto inHalo = dSqr < s.farHaloSqr, within = dSqr < s.farSqr;
            for (int l = 0; l < 2; ++l) {
                if (inHalo[l]) reach.halo |= std::uint64_t(1) << (b + l);
                if (within[l] && dSqr[l] < s.innerSqr) reach.inner |= std::uint64_t(1) << (b + l);
            }
            if (!(within[0] || within[1])) continue;
            const Lanes2 d = sqrtLanes(dSqr);
            const Lanes2 spread = (s.halfX * (rx < 0.0 ? -rx : rx) + s.halfY * (ry < 0.0 ? -ry : ry)) / d;
            const Lanes2 root = d - (spread < s.halfDiagonal ? spread : Lanes2{} + s.halfDiagonal) - s.margin;
            const Lanes2 near = 0.0 < root ? root : Lanes2{};
            if (within[0]) add(b, near[0]);
            if (within[1]) add(b + 1, near[1]);
        }
        for (; b <= b1; ++b) {
            const double ey = s.cy0 + b * s.stepY - s.ay;
            // The centre's distance to the segment (its nearest point a + h u, h clamped):
            // rounding far below the margin.
            const double h = std::clamp(ex * s.ux + ey * s.uy + s.ez * s.uz, 0.0, s.length);
            const double rx = ex - h * s.ux, ry = ey - h * s.uy, rz = s.ez - h * s.uz;
            const double dSqr = rx * rx + ry * ry + rz * rz;
            if (dSqr < s.farHaloSqr) reach.halo |= std::uint64_t(1) << b;
            if (dSqr >= s.farSqr) continue;  // beyond the cut-off everywhere: nothing added there
            if (dSqr < s.innerSqr) reach.inner |= std::uint64_t(1) << b;
            // Every point of the footprint lies at least this far from the segment.
            const double d = std::sqrt(dSqr);
            const double spread = std::min(s.halfDiagonal, (s.halfX * std::abs(rx) + s.halfY * std::abs(ry)) / d);
            const double root = d - spread - s.margin;
            add(b, 0.0 < root ? root : 0.0);
        }
        reachOf[a - a0] = reach;
    }
}

}  // namespace voxlat
