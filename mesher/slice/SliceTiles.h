#pragma once
/// @file SliceTiles.h
/// The slicer's whole-tile pass (decideFullTile) and the edge coverage formula, written once for
/// any vector width. Slicer.cpp instantiates them with four-lane vectors (SSE on x86-64, NEON
/// elsewhere); SliceTilesAvx2.cpp, compiled for AVX2, with eight lanes. Every lane runs the same
/// IEEE operations in the same order at either width (no FMA: AVX2 does not bring it), so both
/// write the same bytes.
///
/// Internal to the mesher. Everything here has internal linkage (an unnamed namespace) on
/// purpose: the two files are compiled for different instruction sets, and an inline function
/// or template shared between them by name would let the linker keep the AVX2 copy for both.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace voxlat {
namespace {  // NOLINT(cert-dcl59-cpp,google-build-namespaces): see the file comment

/// Tile side of the vectorised path for whole tiles (the slicer's default tile).
constexpr int kLanes = 8;

/// Four floats and their comparison masks (GCC/Clang vector extensions), written out because the
/// compilers do not vectorise the eight-lane loops below. The tile tests run in single precision:
/// they only decide which pixels are sure (a rounding there moves a pixel between the sure and
/// the exact path, both of which give it the same grey but in a razor-thin case), and more lanes
/// per vector cut their cost.
using Quad = float __attribute__((vector_size(16)));
using QuadMask = int __attribute__((vector_size(16)));

/// What the width-generic code needs of a vector type: its lanes and an unaligned load here; the
/// lane bits of a mask (`bits`) and the square root (`sqrt`) in each width's own traits.
template <class Vector, class Mask>
struct LanesBase {
    using V = Vector;
    using M = Mask;
    static constexpr int kWidth = int(sizeof(V) / sizeof(float));
    static V load(const float* p)
    {
        V v;
        std::memcpy(&v, p, sizeof v);
        return v;
    }
};

/// Four lanes: SSE on x86-64, NEON elsewhere.
struct QuadLanes : LanesBase<Quad, QuadMask> {
    /// Bit k set where lane k of @a m is true.
    static unsigned bits(M m)
    {
#if defined(__SSE2__)
        return unsigned(_mm_movemask_ps(__m128(m)));
#else
        return unsigned(m[0] & 1) | unsigned(m[1] & 1) << 1 | unsigned(m[2] & 1) << 2 | unsigned(m[3] & 1) << 3;
#endif
    }
    /// Writes the lanes of @a v whose bit is set in @a mask to @a out, in order (whole vector stored).
    static void compress(V v, unsigned mask, float* out)
    {
        for (int k = 0; k < kWidth; ++k) {
            *out = v[k];
            out += (mask >> k) & 1u;
        }
    }
    static V sqrt(V v)
    {
#if defined(__SSE2__)
        return V(_mm_sqrt_ps(__m128(v)));
#else
        return V{std::sqrt(v[0]), std::sqrt(v[1]), std::sqrt(v[2]), std::sqrt(v[3])};
#endif
    }
};

template <class V>
inline V absLanes(V v)
{
    using M = decltype(v < v);
    return V(M(v) & 0x7fffffff);
}
/// |v| per lane, and for the scalar path's doubles.
template <class V>
inline V absOf(V v)
{
    return absLanes(v);
}
inline double absOf(double v)
{
    return std::abs(v);
}
/// std::max and std::min per lane.
template <class V>
inline V maxLanes(V a, V b)
{
    return a < b ? b : a;
}
template <class V>
inline V minLanes(V a, V b)
{
    return b < a ? b : a;
}

/// Transposes an 8 x 8 bit matrix (byte r of @a m is row r, bit c its column c).
inline std::uint64_t transposeBits8x8(std::uint64_t m)
{
    std::uint64_t t = (m ^ (m >> 7)) & 0x00AA00AA00AA00AAull;
    m ^= t ^ (t << 7);
    t = (m ^ (m >> 14)) & 0x0000CCCC0000CCCCull;
    m ^= t ^ (t << 14);
    t = (m ^ (m >> 28)) & 0x00000000F0F0F0F0ull;
    return m ^ t ^ (t << 28);
}

/// Eight bytes, 0xFF where bit k of @a bits is set (byte k).
inline std::uint64_t bytesOfBits(unsigned bits)
{
    std::uint64_t spread = ((bits * 0x8040201008040201ull) >> 7) & 0x0101010101010101ull;  // bit k -> byte 7 - k
    spread = __builtin_bswap64(spread);                                                    // byte k
    return spread * 0xFF;
}

/// The share of each lane's pixel inside the boundary of a field that is f + g.p + p'Hp/2 over it
/// (p in pixels from its centre; g = (gx, gy), H = [hxx hxy; hxy hyy]), clamped to [0, 1], with
/// selects for branches so the lanes stay in vectors.
/// - The straight edge f + g.p = 0: with a <= b the sorted |gx|, |gy| and c = (a + b)/2 - f, the
///   area of {u, v in [0, 1]: a u + b v < c} is exact, piecewise quadratic in c (c / b where the
///   edge runs along a pixel side).
/// - Its curvature: the boundary moves off the chord by -p'Hp / (2|g|); integrated along the
///   chord inside the pixel (midpoint m, vector d, length L) the area changes by
///   -L (m'Hm + d'Hd / 12) / (2|g|). The chord's ends are the first side crossing and the crossing
///   farthest from it (a chord through a corner is reported by both of its sides).
template <class L>
inline typename L::V edgeCoverage(typename L::V f, typename L::V gx, typename L::V gy, typename L::V hxx,
                                  typename L::V hyy, typename L::V hxy)
{
    using V = typename L::V;
    using M = typename L::M;
    const V zero{}, one = zero + 1.0f, half = zero + 0.5f;
    const V ax = absLanes(gx), ay = absLanes(gy);
    const V a = minLanes(ax, ay), b = maxLanes(ax, ay), c = 0.5f * (ax + ay) - f;
    auto ramp = [&](V x) {
        const V p = maxLanes(x, zero);
        return p * p;
    };
    const V ab2 = 2.0f * a * b;
    V area = (ramp(c) - ramp(c - a) - ramp(c - b) + ramp(c - a - b)) / (ab2 > zero ? ab2 : one);
    area = a < 1e-4f * b ? c / (b > zero ? b : one) : area;  // an edge along a pixel side
    area = b <= zero ? (c > zero ? one : zero) : area;
    area = minLanes(maxLanes(area, zero), one);

    const M hasY = gy != zero, hasX = gx != zero;
    const V invY = one / (hasY ? gy : one), invX = one / (hasX ? gx : one);
    const V v0 = (0.5f * gx - f) * invY, v1 = (-0.5f * gx - f) * invY;  // at u = -1/2, +1/2
    const V u0 = (0.5f * gy - f) * invX, u1 = (-0.5f * gy - f) * invX;  // at v = -1/2, +1/2
    const V px[4] = {-half, half, u0, u1}, py[4] = {v0, v1, -half, half};
    const M valid[4] = {hasY & (absLanes(v0) <= half), hasY & (absLanes(v1) <= half), hasX & (absLanes(u0) <= half),
                        hasX & (absLanes(u1) <= half)};
    V sx = px[3], sy = py[3];
    for (int k = 2; k >= 0; --k) sx = valid[k] ? px[k] : sx, sy = valid[k] ? py[k] : sy;
    V ex = sx, ey = sy, best = zero;
    for (int k = 0; k < 4; ++k) {
        const V d = (px[k] - sx) * (px[k] - sx) + (py[k] - sy) * (py[k] - sy);
        const M take = valid[k] & (d > best);
        best = take ? d : best, ex = take ? px[k] : ex, ey = take ? py[k] : ey;
    }
    const V mx = 0.5f * (sx + ex), my = 0.5f * (sy + ey), dx = ex - sx, dy = ey - sy;
    const V mHm = hxx * mx * mx + 2.0f * hxy * mx * my + hyy * my * my;
    const V dHd = hxx * dx * dx + 2.0f * hxy * dx * dy + hyy * dy * dy;
    const V g2 = gx * gx + gy * gy;
    const V bend = -0.5f * L::sqrt(best / (g2 > zero ? g2 : one)) * (mHm + dHd / 12.0f);
    const V coverage = area + (best > zero ? bend : zero);
    return minLanes(maxLanes(coverage, zero), one);
}

/// Whether the field's edge bends little over a pixel (central differences in pixel units,
/// @a gm = |(gx, gy)| > 0): its second difference across the edge (along the gradient) and along
/// it (the edge's curvature times |g|) are each at most @a tolerance |g|. Both are taken times
/// |g|^2, so nothing is divided; a flat pixel (|g| = 0) does not bend little. Where this holds and
/// the linearised edge misses the pixel, the pixel is on one side. One template for the tile
/// passes' lanes and the scalar path's doubles.
template <class V, class S>
inline auto bendsLittle(V gx, V gy, V dxx, V dyy, V dxy, V gm, S tolerance)
{
    const V gxx = gx * gx, gyy = gy * gy, gxy = gx * gy;
    const V across = dxx * gxx + 2 * dxy * gxy + dyy * gyy;  // (n . H n) |g|^2, n along the gradient
    const V along = dxx * gyy - 2 * dxy * gxy + dyy * gxx;   // (t . H t) |g|^2, t the edge's direction
    const V limit = tolerance * (gxx + gyy) * gm;
    return (limit > 0) & (absOf(across) <= limit) & (absOf(along) <= limit);
}

/// How far the 3 x 3 values around a pixel are from a quadratic (l, ld, lu: the column at x - 1
/// at y, y - 1, y + 1; f, down, up at x; r, rd, ru at x + 1): the changes of the second
/// differences across the stencil (its x^2 y, x y^2 and x^2 y^2 terms), which a smooth field has
/// at third order in the pixel and a crease within the stencil (two surfaces meeting at an angle:
/// a boolean, a box's edge, a sheet's mid-surface) at first. edgeCoverage's curvature correction
/// is a quadratic's: the slicer uses it where bendsLittle() holds and this is at most the same
/// tolerance times |g|, else it counts sub-samples (measured on creases, struts, gyroids and
/// balls of 1.5 pixels: Slices.EdgePixelsLinearisedWhereTheFieldIsNearlyQuadratic).
template <class V>
inline V beyondQuadratic(V l, V ld, V lu, V f, V down, V up, V r, V rd, V ru)
{
    const V xxDown = rd + ld - 2 * down, xxUp = ru + lu - 2 * up, xx = r + l - 2 * f;
    const V yyLeft = lu + ld - 2 * l, yyRight = ru + rd - 2 * r;
    return 0.5f * absOf(xxUp - xxDown) + 0.5f * absOf(yyRight - yyLeft) + absOf(xxUp + xxDown - 2 * xx);
}

/// A vector of as many doubles as a float vector of @a Bytes has floats (for the conversion).
template <std::size_t Bytes>
struct DoubleLanes;
template <>
struct DoubleLanes<16> {
    using type = double __attribute__((vector_size(32)));
};
template <>
struct DoubleLanes<32> {
    using type = double __attribute__((vector_size(64)));
};

/// The slicer's pass over a block's grid of values (@a nx columns of @a ny, column-major) before
/// its tiles are decided: @a single gets the values in single precision, @a cells ((nx - 1)
/// columns of ny - 1) the largest difference between the four corners of each grid cell (both
/// axes and both diagonals) and @a cellMax the largest of those (meaningful when every value is
/// finite). Returns whether every value is finite (x * 0 is NaN for NaN and infinities, 0
/// otherwise). The same floats at any vector width.
template <class L>
inline bool prepareTileBlock(const double* values, int nx, int ny, float* single, float* cells, float& cellMax)
{
    using V = typename L::V;
    using Doubles = typename DoubleLanes<sizeof(V)>::type;
    // One pass: each column converted (and its finiteness summed) just before the cells between
    // it and the column before are taken, while both are in registers or L1 (three passes over
    // the block before).
    V poison{};
    float rest = 0.0f;
    auto convert = [&](int a) {
        const double* from = values + std::size_t(a) * ny;
        float* to = single + std::size_t(a) * ny;
        int b = 0;
        for (; b + L::kWidth <= ny; b += L::kWidth) {
            Doubles d;
            std::memcpy(&d, from + b, sizeof d);
            const V v = __builtin_convertvector(d, V);
            std::memcpy(to + b, &v, sizeof v);
            poison += v * 0.0f;
        }
        for (; b < ny; ++b) {
            to[b] = float(from[b]);
            rest += to[b] * 0.0f;
        }
    };
    const int cy = ny - 1;
    V largest{};
    cellMax = 0.0f;
    convert(0);
    for (int a = 0; a + 1 < nx; ++a) {
        convert(a + 1);
        const float* c0 = single + std::size_t(a) * ny;
        const float* c1 = c0 + ny;
        float* e = cells + std::size_t(a) * cy;
        int b = 0;
        for (; b + L::kWidth <= cy; b += L::kWidth) {
            const V p00 = L::load(c0 + b), p01 = L::load(c0 + b + 1), p10 = L::load(c1 + b), p11 = L::load(c1 + b + 1);
            const V d = maxLanes(maxLanes(absLanes(p10 - p00), absLanes(p01 - p00)),
                                 maxLanes(absLanes(p11 - p00), absLanes(p10 - p01)));
            std::memcpy(e + b, &d, sizeof d);
            largest = maxLanes(largest, d);
        }
        for (; b < cy; ++b) {
            const float d0 = std::abs(c1[b] - c0[b]), d1 = std::abs(c0[b + 1] - c0[b]);
            const float d2 = std::abs(c1[b + 1] - c0[b]), d3 = std::abs(c1[b] - c0[b + 1]);
            e[b] = std::max(std::max(d0, d1), std::max(d2, d3));
            cellMax = std::max(cellMax, e[b]);
        }
    }
    for (int l = 0; l < L::kWidth; ++l) cellMax = std::max(cellMax, largest[l]);
    for (int l = 0; l < L::kWidth; ++l) rest += poison[l];
    return rest == 0.0f;
}

/// Decides the pixels of a kLanes x kLanes tile that lies wholly inside the part's box as
/// Slicer::edgeTile's per-pixel tests would, L::kWidth lanes at a time. A pixel is decided when it
/// is sure (|f| above the largest corner difference of its four cells: no sign change and no
/// boundary within its 3x3 neighbourhood) or far (the field is locally linear and its linearised
/// edge misses the pixel: the slow path's first exit). The whole tile is tried first: min |f| over
/// its pixels above the largest difference of every cell around them, with one sign, makes every
/// pixel sure. Decided pixels are written (255 inside, 0 outside); the others are listed in
/// @a slowList as a * kLanes + b. With @a greyEdges (anti-aliasing with gamma 1) the pixels the
/// boundary may pass through get the slow path's next tests here too: the 3x3 neighbourhood, then
/// the coverage of the linearised edge with its curvature correction (edgeCoverage); only pixels
/// where the field bends too much for that (sub-sampled) are listed. @a values and @a cells as in
/// edgeTile, in single precision; every value must be finite (NaN and infinities take the general
/// path). @a blockCell is at least every cell of the tile (the largest of its block; infinity
/// when not known). Returns the number of pixels decided as sure plus 65536 times the sure inside ones.
template <class L>
inline int decideFullTile(const float* values, int stride, const float* cells, float blockCell, float linearTolerance,
                          bool greyEdges, std::uint8_t* pixels, std::size_t rowStride, std::uint16_t* slowList,
                          int& slowCount)
{
    using V = typename L::V;
    using M = typename L::M;
    constexpr int kVectors = kLanes / L::kWidth;
    constexpr float kInf = std::numeric_limits<float>::infinity();
    V lo[kVectors], hi[kVectors], cellMax[kVectors];
    for (int q = 0; q < kVectors; ++q) lo[q] = V{} + kInf, hi[q] = -lo[q], cellMax[q] = V{};
    for (int a = 0; a < kLanes; ++a) {
        const float* f = values + std::size_t(a + 1) * stride + 1;
        for (int q = 0; q < kVectors; ++q) {
            lo[q] = minLanes(lo[q], L::load(f + L::kWidth * q));
            hi[q] = maxLanes(hi[q], L::load(f + L::kWidth * q));
        }
    }
    // Against @a blockCell first, lane by lane (no reductions across lanes): a tile whose values
    // all clear it clears its own cells, which are no larger, and is decided as below.
    {
        V lowest = lo[0], highest = hi[0];
        for (int q = 1; q < kVectors; ++q) lowest = minLanes(lowest, lo[q]), highest = maxLanes(highest, hi[q]);
        constexpr unsigned kAll = (1u << L::kWidth) - 1;
        const bool outside = L::bits(lowest > blockCell) == kAll;
        if (outside || L::bits(highest < -blockCell) == kAll) {
            const std::uint8_t grey = outside ? 0 : 255;
            for (int b = 0; b < kLanes; ++b) std::memset(pixels + std::size_t(b) * rowStride, grey, kLanes);
            return kLanes * kLanes * (grey ? 65537 : 1);
        }
    }
    float cell = 0.0f;
    for (int a = 0; a <= kLanes; ++a) {
        const float* c = cells + std::size_t(a) * (stride - 1);
        for (int q = 0; q < kVectors; ++q) cellMax[q] = maxLanes(cellMax[q], L::load(c + L::kWidth * q));
        cell = std::max(cell, c[kLanes]);
    }
    float low = kInf, high = -kInf;
    for (int q = 0; q < kVectors; ++q)
        for (int k = 0; k < L::kWidth; ++k) {
            low = std::min(low, lo[q][k]);
            high = std::max(high, hi[q][k]);
            cell = std::max(cell, cellMax[q][k]);
        }
    if (low > cell || high < -cell) {
        const std::uint8_t grey = high < 0.0f ? 255 : 0;
        for (int b = 0; b < kLanes; ++b) std::memset(pixels + std::size_t(b) * rowStride, grey, kLanes);
        return kLanes * kLanes * (grey ? 65537 : 1);
    }

    // The slow path's margin of 1e-9 is below float's resolution: 1e-6 keeps its intent.
    const float margin = 0.5f * (1.0f + 1e-6f);
    constexpr unsigned kAllLanes = (1u << L::kWidth) - 1;
    std::uint64_t insideBits = 0;  // byte a, bit b: pixel (a, b) decided inside
    int decided = 0, inside = 0, edgeCount = 0;
    std::uint8_t edgeIndex[kLanes * kLanes];  // grey edge pixels, a * kLanes + b
    // Their edgeCoverage inputs, packed (a vector's worth of slack: compress writes whole vectors).
    constexpr int kEdgeRoom = kLanes * kLanes + L::kWidth;
    float edgeF[kEdgeRoom], edgeGx[kEdgeRoom], edgeGy[kEdgeRoom], edgeDxx[kEdgeRoom], edgeDyy[kEdgeRoom],
        edgeDxy[kEdgeRoom];
    for (int a = 0; a < kLanes; ++a) {
        const float* left = values + std::size_t(a) * stride + 1;  // left[b] = v(a, b + 1)
        const float* centre = left + stride;
        const float* right = centre + stride;
        const float* c0 = cells + std::size_t(a) * (stride - 1);
        const float* c1 = c0 + (stride - 1);
        unsigned open = 0, in = 0, covered = 0;
        for (int q = 0; q < kVectors; ++q) {
            const int b = L::kWidth * q;
            const V f = L::load(centre + b);
            const V bound = maxLanes(maxLanes(L::load(c0 + b), L::load(c0 + b + 1)),
                                     maxLanes(L::load(c1 + b), L::load(c1 + b + 1)));
            const M boundSure = absLanes(f) > bound;
            if (L::bits(boundSure) == kAllLanes) {  // every pixel sure: no derivatives needed
                in |= L::bits(f < 0.0f) << b;
                continue;
            }
            const V up = L::load(centre + b + 1), down = L::load(centre + b - 1);
            const V l = L::load(left + b), r = L::load(right + b);
            const V gx = 0.5f * (r - l), gy = 0.5f * (up - down);
            const V dxx = r + l - 2.0f * f, dyy = up + down - 2.0f * f;
            const V dxy = 0.25f * (L::load(right + b + 1) - L::load(right + b - 1) - L::load(left + b + 1) +
                                   L::load(left + b - 1));
            const V gradient = absLanes(gx) + absLanes(gy);
            const V gm = L::sqrt(gx * gx + gy * gy);
            const M bends = bendsLittle(gx, gy, dxx, dyy, dxy, gm, linearTolerance);
            const M far = bends & (absLanes(f) > margin * gradient);
            M sure = boundSure | far;
            if (greyEdges && L::bits(~sure) != 0) {
                // The 3x3 test: no sign change and |f| above every difference to a neighbour.
                const V lu = L::load(left + b + 1), ld = L::load(left + b - 1);
                const V ru = L::load(right + b + 1), rd = L::load(right + b - 1);
                const V maxDiff = maxLanes(maxLanes(maxLanes(absLanes(l - f), absLanes(r - f)),
                                                    maxLanes(absLanes(up - f), absLanes(down - f))),
                                           maxLanes(maxLanes(absLanes(lu - f), absLanes(ld - f)),
                                                    maxLanes(absLanes(ru - f), absLanes(rd - f))));
                const M negative = f < 0.0f;
                const M sameSign = ~(((l < 0.0f) ^ negative) | ((r < 0.0f) ^ negative) | ((up < 0.0f) ^ negative) |
                                     ((down < 0.0f) ^ negative) | ((lu < 0.0f) ^ negative) | ((ld < 0.0f) ^ negative) |
                                     ((ru < 0.0f) ^ negative) | ((rd < 0.0f) ^ negative));
                sure |= sameSign & (absLanes(f) > maxDiff);
                const M linear = bends & (beyondQuadratic(l, ld, lu, f, down, up, r, rd, ru) <= linearTolerance * gm);
                const unsigned grey = L::bits(~sure & linear);
                if (grey != 0) {
                    // Packed for edgeCoverage below, so its vectors are full (a row holds a few).
                    L::compress(f, grey, edgeF + edgeCount);
                    L::compress(gx, grey, edgeGx + edgeCount);
                    L::compress(gy, grey, edgeGy + edgeCount);
                    L::compress(dxx, grey, edgeDxx + edgeCount);
                    L::compress(dyy, grey, edgeDyy + edgeCount);
                    L::compress(dxy, grey, edgeDxy + edgeCount);
                    for (unsigned m = grey; m != 0; m &= m - 1)
                        edgeIndex[edgeCount++] = std::uint8_t(a * kLanes + b + __builtin_ctz(m));
                }
                covered |= grey << b;
            }
            open |= L::bits(~sure) << b;
            in |= L::bits(sure & (f < 0.0f)) << b;
        }
        open &= ~covered;
        insideBits |= std::uint64_t(in) << (8 * a);
        inside += __builtin_popcount(in);
        decided += kLanes - __builtin_popcount(open | covered);
        for (; open != 0; open &= open - 1) slowList[slowCount++] = std::uint16_t(a * kLanes + __builtin_ctz(open));
    }
    const std::uint64_t rowBits = transposeBits8x8(insideBits);  // byte b, bit a
    for (int b = 0; b < kLanes; ++b) {
        const std::uint64_t row = bytesOfBits(unsigned(rowBits >> (8 * b)) & 0xFF);
        std::memcpy(pixels + std::size_t(b) * rowStride, &row, kLanes);
    }
    constexpr float zeros[L::kWidth] = {};
    // Zeros past the last one, so the last vector's spare lanes compute a harmless coverage (dropped).
    for (float* packed : {edgeF, edgeGx, edgeGy, edgeDxx, edgeDyy, edgeDxy})
        std::memcpy(packed + edgeCount, zeros, sizeof zeros);
    for (int e = 0; e < edgeCount; e += L::kWidth) {
        const V coverage = edgeCoverage<L>(L::load(edgeF + e), L::load(edgeGx + e), L::load(edgeGy + e),
                                           L::load(edgeDxx + e), L::load(edgeDyy + e), L::load(edgeDxy + e));
        for (int k = 0; k < L::kWidth && e + k < edgeCount; ++k)
            // coverage >= 0, so adding 1/2 rounds to nearest.
            pixels[std::size_t(edgeIndex[e + k] % kLanes) * rowStride + edgeIndex[e + k] / kLanes] =
                std::uint8_t(255.0f * coverage[k] + 0.5f);  // NOLINT(bugprone-incorrect-roundings)
    }
    return decided + 65536 * inside;
}

}  // namespace
}  // namespace voxlat
