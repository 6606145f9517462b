/// @file StrutRowsAvx512.cpp
/// addStrutRowTabledScalar (StrutRows.h) with eight lanes. This file alone is compiled for
/// AVX-512F, without contraction: each lane makes the scalar loop's IEEE operations in its order,
/// so all three forms give the same doubles (tests/test_struts.cpp compares them bit for bit).

#include "fields/struts/StrutRows.h"

#include <algorithm>
#include <cstdlib>

#ifdef VOXLAT_AVX512_ROWS
// GCC 12 takes _mm512_undefined_pd() inside the unmasked intrinsics for a read of an
// uninitialised value (-Wmaybe-uninitialized): a false positive of the headers, not of this file.
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include <immintrin.h>
#endif

namespace voxlat {

#ifdef VOXLAT_AVX512_ROWS

namespace {

/// withinCutoff's test of a row's points k..k + 7, eight lanes: the parts of h and |d|^2 that do
/// not change along the row summed first, as the scalar does.
struct RowCutoff8 {
    __m512d hxy, lxy, uz, az, z0, stepZ, length, cutoff, zero, lane;
    RowCutoff8(const StrutRowConstants& s, const StrutRow& row)
    {
        const double dxs = row.x - s.ax, dys = row.y - s.ay;
        hxy = _mm512_set1_pd(dxs * s.ux + dys * s.uy);
        lxy = _mm512_set1_pd(dxs * dxs + dys * dys);
        uz = _mm512_set1_pd(s.uz);
        az = _mm512_set1_pd(s.az);
        z0 = _mm512_set1_pd(row.z0);
        stepZ = _mm512_set1_pd(row.dz);
        length = _mm512_set1_pd(s.length);
        cutoff = _mm512_set1_pd(s.cutoffSqr);
        zero = _mm512_setzero_pd();
        lane = _mm512_setr_pd(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
    }
    /// The lanes of @a live whose points lie within the cut-off.
    __mmask8 within(int k, __mmask8 live) const
    {
        const __m512d kk = _mm512_add_pd(_mm512_set1_pd(double(k)), lane);
        const __m512d dz = _mm512_sub_pd(_mm512_add_pd(z0, _mm512_mul_pd(kk, stepZ)), az);
        const __m512d h = _mm512_add_pd(hxy, _mm512_mul_pd(dz, uz));
        const __m512d r2 =
            _mm512_max_pd(_mm512_sub_pd(_mm512_add_pd(lxy, _mm512_mul_pd(dz, dz)), _mm512_mul_pd(h, h)), zero);
        // beyond = h < 0 ? h : (h > L ? h - L : 0)
        const __m512d past = _mm512_maskz_sub_pd(_mm512_cmp_pd_mask(h, length, _CMP_GT_OQ), h, length);
        const __m512d beyond = _mm512_mask_blend_pd(_mm512_cmp_pd_mask(h, zero, _CMP_LT_OQ), past, h);
        const __m512d dist2 = _mm512_add_pd(r2, _mm512_mul_pd(beyond, beyond));
        return _mm512_mask_cmp_pd_mask(live, dist2, cutoff, _CMP_LT_OQ);
    }
};

/// A tabled row's J at points k..k + 7 (StrutRowTable::at): ((w00 v + w10 s) + w01 v1) + w11 s1,
/// its nodes read only in the lanes of @a add.
struct TabledLanes8 {
    const StrutRowTable& table;
    __m512d w00, w10, w01, w11;
    const double *nextValue, *nextSlope;
    explicit TabledLanes8(const StrutRowTable& t)
        : table(t),
          w00(_mm512_set1_pd(t.w00)),
          w10(_mm512_set1_pd(t.w10)),
          w01(_mm512_set1_pd(t.w01)),
          w11(_mm512_set1_pd(t.w11)),
          nextValue(t.nextValue ? t.nextValue : t.value + 1),
          nextSlope(t.nextSlope ? t.nextSlope : t.slope + 1)
    {
    }
    __m512d operator()(int k, __mmask8 add) const
    {
        const int n = table.n0 + k;
        return _mm512_add_pd(
            _mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(w00, _mm512_maskz_loadu_pd(add, table.value + n)),
                                        _mm512_mul_pd(w10, _mm512_maskz_loadu_pd(add, table.slope + n))),
                          _mm512_mul_pd(w01, _mm512_maskz_loadu_pd(add, nextValue + n))),
            _mm512_mul_pd(w11, _mm512_maskz_loadu_pd(add, nextSlope + n)));
    }
};

/// out[k + l] += gauss[l] j0[l] in the lanes of @a add.
inline void accumulate8(double* out, int k, __mmask8 add, __m512d gauss, __m512d j0)
{
    const __m512d before = _mm512_maskz_loadu_pd(add, out + k);
    _mm512_mask_storeu_pd(out + k, add, _mm512_add_pd(before, _mm512_mul_pd(gauss, j0)));
}

}  // namespace

void addStrutRowTabledAvx512(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                             const double* gauss, double* out)
{
    const RowCutoff8 cut(s, row);
    const TabledLanes8 tabled(table);
    const int inHi = std::min(row.inHi, row.kHi);
    for (int k = row.kLo; k <= row.kHi; k += 8) {
        // Lanes past the row are masked: neither the table nor the row is read or written there.
        const int count = std::min(8, row.kHi - k + 1);
        const __mmask8 live = __mmask8((1u << count) - 1u);
        __mmask8 add = live;
        // The cut-off test unless all eight points are proven within it.
        if (!(k >= row.inLo && k + 7 <= inHi)) {
            add = cut.within(k, live);
            if (add == 0) continue;
        }
        accumulate8(out, k, add, _mm512_maskz_loadu_pd(add, gauss + k), tabled(k, add));
    }
}

void addStrutRowTabledSeededAvx512(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                                   GaussianLanes& lanes, double* out)
{
    // The four recurrences stay four lanes wide (GaussianLanes::step, the same products in order);
    // each eight-point group of the row takes three of their groups: g(K), g(K + 4) and g(K + 8),
    // K the recurrences' group at or below the row's group, its points shift..shift + 7 of them.
    __m256d e = _mm256_loadu_pd(lanes.e), r = _mm256_loadu_pd(lanes.r);
    const __m256d q = _mm256_set1_pd(lanes.q16);
    // The row's bounds and the table's pointers in locals: the stores to @a out (doubles) might
    // alias the structs' doubles, so read from them they were loaded again in every group.
    const int kLo = row.kLo, kHi = row.kHi;
    int groupK = lanes.k;
    while (groupK + 4 <= kLo) {
        e = _mm256_mul_pd(e, r);
        r = _mm256_mul_pd(r, q);
        groupK += 4;
    }
    const int shift = kLo - groupK;
    const __m512i pick = _mm512_add_epi64(_mm512_set1_epi64(shift), _mm512_setr_epi64(0, 1, 2, 3, 4, 5, 6, 7));
    const RowCutoff8 cut(s, row);
    const __m512d w00 = _mm512_set1_pd(table.w00), w10 = _mm512_set1_pd(table.w10), w01 = _mm512_set1_pd(table.w01),
                  w11 = _mm512_set1_pd(table.w11);
    const double *value = table.value, *slope = table.slope;
    const double* nextValue = table.nextValue ? table.nextValue : table.value + 1;
    const double* nextSlope = table.nextSlope ? table.nextSlope : table.slope + 1;
    const int n0 = table.n0;
    const int inLo = row.inLo, inHi = std::min(row.inHi, kHi);
    // The groups whose eight points are all proven within the cut-off (inLo..inHi): no test, no
    // mask (TabledLanes8 and accumulate8 with every lane added: the same operations).
    const int provenFrom = kLo + std::max(0, (inLo - kLo + 7) / 8) * 8;
    const int provenTo = inLo <= inHi ? inHi - 7 : kLo - 1;  // groups k with k <= provenTo
    for (int k = kLo; k <= kHi; k += 8) {
        const __m256d e4 = _mm256_mul_pd(e, r), r4 = _mm256_mul_pd(r, q);
        const __m256d e8 = _mm256_mul_pd(e4, r4), r8 = _mm256_mul_pd(r4, q);
        const __m512d pair = _mm512_insertf64x4(_mm512_castpd256_pd512(e), e4, 1);
        const __m512d gauss = shift == 0 ? pair : _mm512_permutex2var_pd(pair, pick, _mm512_castpd256_pd512(e8));
        // Left at the group of the row's last group of eight (at or below its last point).
        if (k + 8 <= kHi) {
            e = e8;
            r = r8;
            groupK += 8;
        }
        const int n = n0 + k;
        if (k >= provenFrom && k <= provenTo) {
            const __m512d j0 =
                _mm512_add_pd(_mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(w00, _mm512_loadu_pd(value + n)),
                                                          _mm512_mul_pd(w10, _mm512_loadu_pd(slope + n))),
                                            _mm512_mul_pd(w01, _mm512_loadu_pd(nextValue + n))),
                              _mm512_mul_pd(w11, _mm512_loadu_pd(nextSlope + n)));
            _mm512_storeu_pd(out + k, _mm512_add_pd(_mm512_loadu_pd(out + k), _mm512_mul_pd(gauss, j0)));
            continue;
        }
        const int count = std::min(8, kHi - k + 1);
        const __mmask8 live = __mmask8((1u << count) - 1u);
        // The points proven within the cut-off (row.inLo..inHi) take no test, as in the scalar loop.
        const int provenLo = std::max(0, inLo - k), provenHi = std::min(7, inHi - k);
        const __mmask8 proven =
            live & (provenLo <= provenHi ? __mmask8(((2u << provenHi) - 1u) & ~((1u << provenLo) - 1u)) : 0);
        __mmask8 add = live;
        if (proven != live) {
            add = cut.within(k, live) | proven;
            if (add == 0) continue;
        }
        const __m512d j0 =
            _mm512_add_pd(_mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(w00, _mm512_maskz_loadu_pd(add, value + n)),
                                                      _mm512_mul_pd(w10, _mm512_maskz_loadu_pd(add, slope + n))),
                                        _mm512_mul_pd(w01, _mm512_maskz_loadu_pd(add, nextValue + n))),
                          _mm512_mul_pd(w11, _mm512_maskz_loadu_pd(add, nextSlope + n)));
        accumulate8(out, k, add, gauss, j0);
    }
    _mm256_storeu_pd(lanes.e, e);
    _mm256_storeu_pd(lanes.r, r);
    lanes.k = groupK;
}

bool hasAvx512Rows()
{
    // VOXLAT_NO_AVX512 keeps the four-lane form (to measure one against the other).
    static const bool has = __builtin_cpu_supports("avx512f") && !std::getenv("VOXLAT_NO_AVX512");
    return has;
}

#else

void addStrutRowTabledAvx512(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                             const double* gauss, double* out)
{
    addStrutRowTabledScalar(s, row, table, gauss, out);
}

void addStrutRowTabledSeededAvx512(const StrutRowConstants& s, const StrutRow& row, const StrutRowTable& table,
                                   GaussianLanes& lanes, double* out)
{
    addStrutRowTabledSeededScalar(s, row, table, lanes, out);
}

bool hasAvx512Rows()
{
    return false;
}

#endif

}  // namespace voxlat
