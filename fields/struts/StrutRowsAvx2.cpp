/// @file StrutRowsAvx2.cpp
/// addStrutRowScalar (StrutRows.h) with four lanes. This file alone is compiled for AVX2, without
/// FMA and without contraction: each lane makes the scalar loop's IEEE operations in its order,
/// so both give the same doubles (tests/test_struts.cpp compares them bit for bit).

#include "fields/struts/StrutRows.h"

#include <limits>

#ifdef VOXLAT_AVX2_ROWS
#include <immintrin.h>
#endif

namespace voxlat {

#ifdef VOXLAT_AVX2_ROWS

namespace {

/// |x| and x's sign bit.
inline __m256d absOf(__m256d x)
{
    return _mm256_andnot_pd(_mm256_set1_pd(-0.0), x);
}
inline __m256d copySign(__m256d magnitude, __m256d sign)
{
    const __m256d bit = _mm256_set1_pd(-0.0);
    return _mm256_or_pd(_mm256_andnot_pd(bit, magnitude), _mm256_and_pd(bit, sign));
}

/// GaussianTable::evaluate (withGaussian) or erfIntegral in four lanes.
template <bool withGaussian>
inline void tableLanes(const double* nodes, __m256d y, __m256d& u, __m256d& g)
{
    const __m256d a = absOf(y);
    // Lanes at or beyond the table's end (or NaN) take U = sign * sqrt(pi / 2), g = 0; they
    // interpolate at 0 meanwhile so that every load stays inside the table.
    const __m256d inside = _mm256_cmp_pd(a, _mm256_set1_pd(GaussianTable::kEnd), _CMP_LT_OQ);
    const __m256d s = _mm256_mul_pd(_mm256_and_pd(inside, a), _mm256_set1_pd(double(GaussianTable::kPerUnit)));
    const __m128i i = _mm256_cvttpd_epi32(s);
    const __m256d t = _mm256_sub_pd(s, _mm256_cvtepi32_pd(i));
    const __m256d t2 = _mm256_mul_pd(t, t), t3 = _mm256_mul_pd(t2, t);
    const __m256d two = _mm256_set1_pd(2.0), three = _mm256_set1_pd(3.0), delta = _mm256_set1_pd(GaussianTable::kDelta);
    // span(): 2 t^3 - 3 t^2 + 1, (t^3 - 2 t^2 + t) delta, -2 t^3 + 3 t^2, (t^3 - t^2) delta.
    const __m256d h00 =
        _mm256_add_pd(_mm256_sub_pd(_mm256_mul_pd(two, t3), _mm256_mul_pd(three, t2)), _mm256_set1_pd(1.0));
    const __m256d h10 = _mm256_mul_pd(_mm256_add_pd(_mm256_sub_pd(t3, _mm256_mul_pd(two, t2)), t), delta);
    const __m256d h01 = _mm256_add_pd(_mm256_mul_pd(_mm256_set1_pd(-2.0), t3), _mm256_mul_pd(three, t2));
    const __m256d h11 = _mm256_mul_pd(_mm256_sub_pd(t3, t2), delta);
    // Node i is nodes[3 i .. 3 i + 2] = (U, g, g'); node i + 1 follows it. Each lane's two nodes
    // are six consecutive doubles, loaded as four and two and transposed into one vector per
    // value (four gathers of four cost more on the machines measured).
    alignas(16) int at[4];
    _mm_store_si128(reinterpret_cast<__m128i*>(at), _mm_mullo_epi32(i, _mm_set1_epi32(3)));
    const __m256d a0 = _mm256_loadu_pd(nodes + at[0]), a1 = _mm256_loadu_pd(nodes + at[1]);
    const __m256d a2 = _mm256_loadu_pd(nodes + at[2]), a3 = _mm256_loadu_pd(nodes + at[3]);
    const __m256d lo01 = _mm256_unpacklo_pd(a0, a1), hi01 = _mm256_unpackhi_pd(a0, a1);
    const __m256d lo23 = _mm256_unpacklo_pd(a2, a3), hi23 = _mm256_unpackhi_pd(a2, a3);
    const __m256d pu = _mm256_permute2f128_pd(lo01, lo23, 0x20), pg = _mm256_permute2f128_pd(hi01, hi23, 0x20);
    const __m256d qu = _mm256_permute2f128_pd(hi01, hi23, 0x31);
    const __m256d b02 = _mm256_set_m128d(_mm_loadu_pd(nodes + at[2] + 4), _mm_loadu_pd(nodes + at[0] + 4));
    const __m256d b13 = _mm256_set_m128d(_mm_loadu_pd(nodes + at[3] + 4), _mm_loadu_pd(nodes + at[1] + 4));
    const __m256d qg = _mm256_unpacklo_pd(b02, b13);
    const __m256d sum = _mm256_add_pd(
        _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(h00, pu), _mm256_mul_pd(h10, pg)), _mm256_mul_pd(h01, qu)),
        _mm256_mul_pd(h11, qg));
    u = copySign(_mm256_blendv_pd(_mm256_set1_pd(GaussianTable::kHalfRootTwoPi), sum, inside), y);
    if constexpr (withGaussian) {
        const __m256d pd = _mm256_permute2f128_pd(lo01, lo23, 0x31), qd = _mm256_unpackhi_pd(b02, b13);
        const __m256d gs = _mm256_add_pd(
            _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(h00, pg), _mm256_mul_pd(h10, pd)), _mm256_mul_pd(h01, qg)),
            _mm256_mul_pd(h11, qd));
        g = _mm256_and_pd(inside, gs);
    }
}

/// out[0..3] += gauss[0..3] * j0 in the lanes @a within (the others keep their sums); lanes past
/// the row (@a lanes < 4) are neither read nor written. Whole groups take plain loads and stores:
/// a masked store is microcoded on the Zen 1 EPYC measured (about ten times a store), and most of
/// a row's groups are whole. The same doubles either way.
inline void accumulate(double* out, const double* gauss, __m256d j0, __m256d within, int lanes, __m256i live)
{
    if (lanes == 4) {
        const __m256d before = _mm256_loadu_pd(out);
        const __m256d added = _mm256_add_pd(before, _mm256_mul_pd(_mm256_loadu_pd(gauss), j0));
        _mm256_storeu_pd(out, _mm256_blendv_pd(before, added, within));
        return;
    }
    const __m256d before = _mm256_maskload_pd(out, live);
    const __m256d added = _mm256_add_pd(before, _mm256_mul_pd(_mm256_maskload_pd(gauss, live), j0));
    alignas(32) double sum[4];
    _mm256_store_pd(sum, _mm256_blendv_pd(before, added, within));
    for (int l = 0; l < lanes; ++l) out[l] = sum[l];
}

/// A row's points four at a time against the strut's cut-off: each group's position along the
/// axis (h) and the lanes within the cut-off, summed in the scalar loop's order.
struct RowCutoff {
    __m256d hxy, lxy, uz, az, z0, stepZ, length, cutoff, zero;
    RowCutoff(const StrutRowConstants& s, const StrutRow& row)
    {
        const double dxs = row.x - s.ax, dys = row.y - s.ay;
        // The parts of h and |d|^2 that do not change along the row, summed first as the scalar does.
        hxy = _mm256_set1_pd(dxs * s.ux + dys * s.uy);
        lxy = _mm256_set1_pd(dxs * dxs + dys * dys);
        uz = _mm256_set1_pd(s.uz);
        az = _mm256_set1_pd(s.az);
        z0 = _mm256_set1_pd(row.z0);
        stepZ = _mm256_set1_pd(row.dz);
        length = _mm256_set1_pd(s.length);
        cutoff = _mm256_set1_pd(s.cutoffSqr);
        zero = _mm256_setzero_pd();
    }
    /// The offset along z of points k..k + 3 from the strut's start.
    __m256d dz(int k) const
    {
        const __m256d kk = _mm256_setr_pd(double(k), double(k + 1), double(k + 2), double(k + 3));
        return _mm256_sub_pd(_mm256_add_pd(z0, _mm256_mul_pd(kk, stepZ)), az);
    }
    /// Points k..k + 3's h (the position along the axis).
    __m256d h(__m256d dz) const { return _mm256_add_pd(hxy, _mm256_mul_pd(dz, uz)); }
    /// The lanes of @a live whose points (offset @a dz, position @a h) are within the cut-off.
    __m256d within(__m256d dz, __m256d h, __m256i live) const
    {
        const __m256d r2 =
            _mm256_max_pd(_mm256_sub_pd(_mm256_add_pd(lxy, _mm256_mul_pd(dz, dz)), _mm256_mul_pd(h, h)), zero);
        // beyond = h < 0 ? h : (h > L ? h - L : 0)
        const __m256d beyond =
            _mm256_blendv_pd(_mm256_and_pd(_mm256_cmp_pd(h, length, _CMP_GT_OQ), _mm256_sub_pd(h, length)), h,
                             _mm256_cmp_pd(h, zero, _CMP_LT_OQ));
        const __m256d dist2 = _mm256_add_pd(r2, _mm256_mul_pd(beyond, beyond));
        return _mm256_and_pd(_mm256_castsi256_pd(live), _mm256_cmp_pd(dist2, cutoff, _CMP_LT_OQ));
    }
};

/// The live lanes of a group of @a lanes points (at most 4).
inline __m256i liveLanes(int lanes)
{
    return _mm256_cmpgt_epi64(_mm256_set1_epi64x(lanes), _mm256_setr_epi64x(0, 1, 2, 3));
}

/// A tabled row's J0 at points k..k + 3: the two phases' nodes and slopes weighted (Hermite).
struct TabledLanes {
    // The table's rows from its n0 on, held here (the stores to a row's sums may alias anything:
    // the table's fields would be reloaded for each group).
    const double *value, *slope, *nextValue, *nextSlope;
    __m256d w00, w10, w01, w11;
    explicit TabledLanes(const StrutRowTable& t)
        : value(t.value + t.n0),
          slope(t.slope + t.n0),
          // Lanes past the row read nodes the table holds (its caller sizes it with a margin).
          nextValue((t.nextValue ? t.nextValue : t.value + 1) + t.n0),
          nextSlope((t.nextSlope ? t.nextSlope : t.slope + 1) + t.n0),
          w00(_mm256_set1_pd(t.w00)),
          w10(_mm256_set1_pd(t.w10)),
          w01(_mm256_set1_pd(t.w01)),
          w11(_mm256_set1_pd(t.w11))
    {
    }
    __m256d operator()(int k) const
    {
        return _mm256_add_pd(_mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(w00, _mm256_loadu_pd(value + k)),
                                                         _mm256_mul_pd(w10, _mm256_loadu_pd(slope + k))),
                                           _mm256_mul_pd(w01, _mm256_loadu_pd(nextValue + k))),
                             _mm256_mul_pd(w11, _mm256_loadu_pd(nextSlope + k)));
    }
};

template <bool graded>
void addRow(const StrutRowConstants& s, const StrutRow& row, const double* gauss, double* out)
{
    const double* nodes = GaussianTable::instance().nodeData();
    const RowCutoff cut(s, row);
    const __m256d length = cut.length, invSigma = _mm256_set1_pd(s.invSigma);
    const __m256d w0 = _mm256_set1_pd(s.w0), slope = _mm256_set1_pd(s.slope), sigma = _mm256_set1_pd(s.sigma);
    const __m256d w0Sigma = _mm256_set1_pd(s.w0 * s.sigma), slopeS2 = _mm256_set1_pd(s.slope * s.s2);
    for (int k = row.kLo; k <= row.kHi; k += 4) {
        const int lanes = std::min(4, row.kHi - k + 1);
        const __m256i live = liveLanes(lanes);
        const __m256d dz = cut.dz(k), h = cut.h(dz);
        const __m256d within = cut.within(dz, h, live);
        if (_mm256_movemask_pd(within) == 0) continue;
        __m256d uL, gL, uA, gA;
        tableLanes<graded>(nodes, _mm256_mul_pd(_mm256_sub_pd(length, h), invSigma), uL, gL);
        tableLanes<graded>(nodes, _mm256_mul_pd(h, invSigma), uA, gA);
        __m256d j0;
        if constexpr (graded) {
            const __m256d i0 = _mm256_mul_pd(sigma, _mm256_add_pd(uL, uA));
            j0 = _mm256_add_pd(_mm256_mul_pd(_mm256_add_pd(w0, _mm256_mul_pd(slope, h)), i0),
                               _mm256_mul_pd(slopeS2, _mm256_sub_pd(gA, gL)));
        } else {
            j0 = _mm256_mul_pd(w0Sigma, _mm256_add_pd(uL, uA));
        }
        accumulate(out + k, gauss + k, j0, within, lanes, live);
    }
}

}  // namespace

void addStrutRowTabledAvx2(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                           const double* gauss, double* out)
{
    const RowCutoff cut(s, row);
    const TabledLanes tabled(table);
    const int inHi = std::min(row.inHi, row.kHi);
    for (int k = row.kLo; k <= row.kHi; k += 4) {
        if (k >= row.inLo && k + 3 <= inHi) {
            // Four points proven within the cut-off: no test (the same sums).
            const __m256d before = _mm256_loadu_pd(out + k);
            _mm256_storeu_pd(out + k, _mm256_add_pd(before, _mm256_mul_pd(_mm256_loadu_pd(gauss + k), tabled(k))));
            continue;
        }
        const int lanes = std::min(4, row.kHi - k + 1);
        const __m256i live = liveLanes(lanes);
        const __m256d dz = cut.dz(k);
        const __m256d within = cut.within(dz, cut.h(dz), live);
        if (_mm256_movemask_pd(within) == 0) continue;
        accumulate(out + k, gauss + k, tabled(k), within, lanes, live);
    }
}

void addStrutRowTabledSeededAvx2(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                                 GaussianLanes& lanes, double* out)
{
    __m256d e = _mm256_loadu_pd(lanes.e), r = _mm256_loadu_pd(lanes.r);
    const __m256d q = _mm256_set1_pd(lanes.q16);
    while (lanes.k + 4 <= row.kLo) {  // GaussianLanes::step in lanes
        e = _mm256_mul_pd(e, r);
        r = _mm256_mul_pd(r, q);
        lanes.k += 4;
    }
    const RowCutoff cut(s, row);
    const TabledLanes tabled(table);
    // The row's groups start at kLo, the recurrences' groups at lanes.k: a row's group k holds
    // lanes shift..3 of the recurrences' group and lanes 0..shift-1 of the next one (the same
    // bits, moved: the doubles fillGaussians writes at k..k + 3).
    alignas(32) static constexpr int kRotate[4][8] = {
        {0, 1, 2, 3, 4, 5, 6, 7}, {2, 3, 4, 5, 6, 7, 0, 1}, {4, 5, 6, 7, 0, 1, 2, 3}, {6, 7, 0, 1, 2, 3, 4, 5}};
    const int shift = row.kLo - lanes.k;
    const __m256i rotate = _mm256_load_si256(reinterpret_cast<const __m256i*>(kRotate[shift]));
    const __m256d fromThis =
        _mm256_castsi256_pd(_mm256_cmpgt_epi64(_mm256_set1_epi64x(4 - shift), _mm256_setr_epi64x(0, 1, 2, 3)));
    // The row's bounds and the recurrences' group in locals (the stores to out may alias them).
    const int kHi = row.kHi, inLo = row.inLo, inHi = std::min(row.inHi, row.kHi);
    int lanesK = lanes.k;
    for (int k = row.kLo; k <= kHi; k += 4) {
        const __m256d next = _mm256_mul_pd(e, r);
        const __m256d gauss =
            _mm256_blendv_pd(_mm256_castps_pd(_mm256_permutevar8x32_ps(_mm256_castpd_ps(next), rotate)),
                             _mm256_castps_pd(_mm256_permutevar8x32_ps(_mm256_castpd_ps(e), rotate)), fromThis);
        if (k + 4 <= kHi) {
            e = next;
            r = _mm256_mul_pd(r, q);
            lanesK += 4;
        }
        if (k >= inLo && k + 3 <= inHi) {
            // Four points proven within the cut-off: no test (the same sums).
            const __m256d before = _mm256_loadu_pd(out + k);
            _mm256_storeu_pd(out + k, _mm256_add_pd(before, _mm256_mul_pd(gauss, tabled(k))));
            continue;
        }
        const int count = std::min(4, kHi - k + 1);
        const __m256i live = liveLanes(count);
        const __m256d dz = cut.dz(k);
        const __m256d within = cut.within(dz, cut.h(dz), live);
        if (_mm256_movemask_pd(within) == 0) continue;
        const __m256d j0 = tabled(k);
        if (count == 4) {
            const __m256d before = _mm256_loadu_pd(out + k);
            _mm256_storeu_pd(out + k,
                             _mm256_blendv_pd(before, _mm256_add_pd(before, _mm256_mul_pd(gauss, j0)), within));
        } else {
            const __m256d before = _mm256_maskload_pd(out + k, live);
            alignas(32) double sum[4];
            _mm256_store_pd(sum, _mm256_blendv_pd(before, _mm256_add_pd(before, _mm256_mul_pd(gauss, j0)), within));
            for (int l = 0; l < count; ++l) out[k + l] = sum[l];
        }
    }
    lanes.k = lanesK;
    _mm256_storeu_pd(lanes.e, e);
    _mm256_storeu_pd(lanes.r, r);
}

void addStrutRowTaylorAvx2(const StrutRowConstants& s, const StrutRow& row, const double c[4], double hc,
                           const double* gauss, double* out)
{
    const RowCutoff cut(s, row);
    const __m256d c0 = _mm256_set1_pd(c[0]), c1 = _mm256_set1_pd(c[1]), c2 = _mm256_set1_pd(c[2]),
                  c3 = _mm256_set1_pd(c[3]), centre = _mm256_set1_pd(hc);
    auto taylor = [&](__m256d h) {
        const __m256d d = _mm256_sub_pd(h, centre);
        return _mm256_add_pd(
            c0, _mm256_mul_pd(d, _mm256_add_pd(c1, _mm256_mul_pd(d, _mm256_add_pd(c2, _mm256_mul_pd(d, c3))))));
    };
    const int inHi = std::min(row.inHi, row.kHi);
    for (int k = row.kLo; k <= row.kHi; k += 4) {
        if (k >= row.inLo && k + 3 <= inHi) {
            // Four points proven within the cut-off: no test (the same sums).
            const __m256d before = _mm256_loadu_pd(out + k);
            const __m256d j0 = taylor(cut.h(cut.dz(k)));
            _mm256_storeu_pd(out + k, _mm256_add_pd(before, _mm256_mul_pd(_mm256_loadu_pd(gauss + k), j0)));
            continue;
        }
        const int lanes = std::min(4, row.kHi - k + 1);
        const __m256i live = liveLanes(lanes);
        const __m256d dz = cut.dz(k), h = cut.h(dz);
        const __m256d within = cut.within(dz, h, live);
        if (_mm256_movemask_pd(within) == 0) continue;
        accumulate(out + k, gauss + k, taylor(h), within, lanes, live);
    }
}

void fillGaussiansAvx2(const double lanes[4], const double steps[4], double q16, int count, double* gauss, int from)
{
    __m256d e = _mm256_loadu_pd(lanes), r = _mm256_loadu_pd(steps);
    const __m256d q = _mm256_set1_pd(q16);
    int k = 0;
    for (; k < count && k + 4 <= from; k += 4) {
        e = _mm256_mul_pd(e, r);
        r = _mm256_mul_pd(r, q);
    }
    for (; k < count; k += 4) {
        _mm256_storeu_pd(gauss + k, e);
        e = _mm256_mul_pd(e, r);
        r = _mm256_mul_pd(r, q);
    }
}

void strutRowNodesAvx2(const StrutRowConstants& s, double h0, double step, int first, int count, double* value,
                       double* slope)
{
    const double* nodes = GaussianTable::instance().nodeData();
    const __m256d h0v = _mm256_set1_pd(h0), stepv = _mm256_set1_pd(step), length = _mm256_set1_pd(s.length),
                  invSigma = _mm256_set1_pd(s.invSigma), sigma = _mm256_set1_pd(s.sigma), w0 = _mm256_set1_pd(s.w0),
                  slopeK = _mm256_set1_pd(s.slope), s2 = _mm256_set1_pd(s.s2);
    for (int m = 0; m < count; m += 4) {
        const __m256d mm =
            _mm256_setr_pd(double(m + first), double(m + 1 + first), double(m + 2 + first), double(m + 3 + first));
        const __m256d h = _mm256_add_pd(h0v, _mm256_mul_pd(mm, stepv));
        __m256d uL, gL, uA, gA;
        tableLanes<true>(nodes, _mm256_mul_pd(_mm256_sub_pd(length, h), invSigma), uL, gL);
        tableLanes<true>(nodes, _mm256_mul_pd(h, invSigma), uA, gA);
        const __m256d i0 = _mm256_mul_pd(sigma, _mm256_add_pd(uL, uA));
        const __m256d dg = _mm256_sub_pd(gA, gL);
        const __m256d j = _mm256_add_pd(_mm256_mul_pd(_mm256_add_pd(w0, _mm256_mul_pd(slopeK, h)), i0),
                                        _mm256_mul_pd(_mm256_mul_pd(slopeK, s2), dg));
        const __m256d dj = _mm256_mul_pd(
            _mm256_add_pd(_mm256_mul_pd(w0, dg), _mm256_mul_pd(slopeK, _mm256_sub_pd(i0, _mm256_mul_pd(length, gL)))),
            stepv);
        _mm256_storeu_pd(value + m, j);
        _mm256_storeu_pd(slope + m, dj);
    }
}

void capsuleRowRangesAvx2(const CapsuleRows& k, const double x[4], double y, double z, double lo[4], double hi[4])
{
    const __m256d xs = _mm256_loadu_pd(x), ys = _mm256_set1_pd(y), zs = _mm256_set1_pd(z), zero = _mm256_setzero_pd();
    const __m256d ux = _mm256_set1_pd(k.ux), uy = _mm256_set1_pd(k.uy), uz = _mm256_set1_pd(k.uz);
    const __m256d rc2 = _mm256_set1_pd(k.rc2), invDz = _mm256_set1_pd(k.invDz);
    __m256d low = _mm256_set1_pd(std::numeric_limits<double>::infinity());
    __m256d high = _mm256_set1_pd(-std::numeric_limits<double>::infinity());
    // End balls (lanes where w > 0 merge their interval).
    for (const double h : {0.0, k.length}) {
        const __m256d hv = _mm256_set1_pd(h);
        const __m256d dx = _mm256_sub_pd(xs, _mm256_mul_pd(hv, ux)), dy = _mm256_sub_pd(ys, _mm256_mul_pd(hv, uy)),
                      dz = _mm256_sub_pd(zs, _mm256_mul_pd(hv, uz));
        const __m256d w = _mm256_sub_pd(_mm256_sub_pd(rc2, _mm256_mul_pd(dx, dx)), _mm256_mul_pd(dy, dy));
        const __m256d inside = _mm256_cmp_pd(w, zero, _CMP_GT_OQ);
        if (_mm256_movemask_pd(inside) == 0) continue;
        const __m256d root = _mm256_sqrt_pd(_mm256_max_pd(w, zero));
        const __m256d negDz = _mm256_sub_pd(zero, dz);
        const __m256d a = _mm256_mul_pd(_mm256_sub_pd(negDz, root), invDz),
                      b = _mm256_mul_pd(_mm256_add_pd(negDz, root), invDz);
        // std::min(lo, std::min(a, b)): min(x, y) = y < x ? y : x, as _mm256_min_pd(y, x) gives.
        const __m256d ab0 = _mm256_min_pd(b, a), ab1 = _mm256_max_pd(b, a);
        low = _mm256_blendv_pd(low, _mm256_min_pd(ab0, low), inside);
        high = _mm256_blendv_pd(high, _mm256_max_pd(ab1, high), inside);
    }
    // Cylinder.
    const __m256d h0 =
        _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(xs, ux), _mm256_mul_pd(ys, uy)), _mm256_mul_pd(zs, uz));
    const __m256d B = _mm256_mul_pd(_mm256_set1_pd(2.0), _mm256_sub_pd(_mm256_mul_pd(zs, _mm256_set1_pd(k.dz)),
                                                                       _mm256_mul_pd(h0, _mm256_set1_pd(k.hz))));
    const __m256d C = _mm256_sub_pd(
        _mm256_sub_pd(_mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(xs, xs), _mm256_mul_pd(ys, ys)), _mm256_mul_pd(zs, zs)),
                      _mm256_mul_pd(h0, h0)),
        rc2);
    const __m256d disc = _mm256_sub_pd(_mm256_mul_pd(B, B), _mm256_mul_pd(_mm256_set1_pd(4.0 * k.cc), C));
    __m256d valid = _mm256_cmp_pd(disc, zero, _CMP_GT_OQ);
    if (_mm256_movemask_pd(valid) != 0) {
        const __m256d root = _mm256_sqrt_pd(_mm256_max_pd(disc, zero)), half = _mm256_set1_pd(k.halfInvCc);
        const __m256d negB = _mm256_sub_pd(zero, B);
        __m256d a = _mm256_mul_pd(_mm256_sub_pd(negB, root), half), b = _mm256_mul_pd(_mm256_add_pd(negB, root), half);
        if (k.hz != 0.0) {
            const __m256d invHz = _mm256_set1_pd(k.invHz);
            const __m256d s0 = _mm256_mul_pd(_mm256_sub_pd(zero, h0), invHz),
                          s1 = _mm256_mul_pd(_mm256_sub_pd(_mm256_set1_pd(k.length), h0), invHz);
            // if (s0 > s1) swap: the lesser and the greater.
            const __m256d swap = _mm256_cmp_pd(s0, s1, _CMP_GT_OQ);
            const __m256d first = _mm256_blendv_pd(s0, s1, swap), second = _mm256_blendv_pd(s1, s0, swap);
            a = _mm256_max_pd(first, a);   // std::max(a, first)
            b = _mm256_min_pd(second, b);  // std::min(b, second)
        } else {
            valid = _mm256_and_pd(valid, _mm256_and_pd(_mm256_cmp_pd(h0, zero, _CMP_GE_OQ),
                                                       _mm256_cmp_pd(h0, _mm256_set1_pd(k.length), _CMP_LE_OQ)));
        }
        valid = _mm256_and_pd(valid, _mm256_cmp_pd(a, b, _CMP_LE_OQ));
        low = _mm256_blendv_pd(low, _mm256_min_pd(a, low), valid);
        high = _mm256_blendv_pd(high, _mm256_max_pd(b, high), valid);
    }
    _mm256_storeu_pd(lo, low);
    _mm256_storeu_pd(hi, high);
}

void addStrutRowAvx2(const StrutRowConstants& s, const StrutRow& row, const double* gauss, double* out)
{
    if (s.slope == 0.0)
        addRow<false>(s, row, gauss, out);
    else
        addRow<true>(s, row, gauss, out);
}

bool hasAvx2Rows()
{
    static const bool has = __builtin_cpu_supports("avx2");
    return has;
}

#else

void addStrutRowTaylorAvx2(const StrutRowConstants& s, const StrutRow& row, const double c[4], double hc,
                           const double* gauss, double* out)
{
    addStrutRowTaylorScalar(s, row, c, hc, gauss, out);
}

void fillGaussiansAvx2(const double lanes[4], const double steps[4], double q16, int count, double* gauss, int from)
{
    fillGaussiansScalar(lanes, steps, q16, count, gauss, from);
}

void strutRowNodesAvx2(const StrutRowConstants& s, double h0, double step, int first, int count, double* value,
                       double* slope)
{
    strutRowNodesScalar(s, h0, step, first, count, value, slope);
}

void addStrutRowTabledSeededAvx2(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                                 GaussianLanes& lanes, double* out)
{
    addStrutRowTabledSeededScalar(s, row, table, lanes, out);
}

void addStrutRowTabledAvx2(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                           const double* gauss, double* out)
{
    addStrutRowTabledScalar(s, row, table, gauss, out);
}

void addStrutRowAvx2(const StrutRowConstants& s, const StrutRow& row, const double* gauss, double* out)
{
    addStrutRowScalar(s, row, gauss, out);
}

void capsuleRowRangesAvx2(const CapsuleRows& k, const double x[4], double y, double z, double lo[4], double hi[4])
{
    for (int l = 0; l < 4; ++l) capsuleRowRange(k, x[l], y, z, lo[l], hi[l]);
}

bool hasAvx2Rows()
{
    return false;
}

#endif

}  // namespace voxlat
