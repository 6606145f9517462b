/// @file MultigridKernels.h
/// @brief The element products of the periodic multigrid solver (internal to Multigrid.cpp).
///
/// Included twice, in namespaces named by VOXLAT_MG_ISA: by Multigrid.cpp for the baseline
/// instruction set, and by MultigridAvx2.cpp, the one file built for AVX2 (without FMA and
/// without contraction), which the solver calls where the CPU has AVX2. Each lane makes the
/// same IEEE operations in the same order in both, so both give the same bits; the wider
/// registers only take fewer instructions (the double lane vectors and the dense coarse
/// products). Raw pointers and lane vectors only: no inline library function is instantiated
/// here that the two builds could share.
///
/// No include guard on purpose: each including file defines VOXLAT_MG_ISA first.

#include <cstddef>
#include <cstdint>
#include <cstring>

#ifndef VOXLAT_MG_ISA
#error "define VOXLAT_MG_ISA (the kernels' namespace) before including MultigridKernels.h"
#endif

namespace voxlat::homogenization {

/// Four lanes of float or double (GCC/Clang vector extensions; with SSE, double takes two
/// registers). Lane d holds unknown d of a node; lane 3 is padding.
typedef float Float4 __attribute__((vector_size(16)));
typedef double Double4 __attribute__((vector_size(32)));

template <class T>
struct Lanes;
template <>
struct Lanes<float> {
    using type = Float4;
};
template <>
struct Lanes<double> {
    using type = Double4;
};

/// Eight lanes of float or double: a dense element product's element vector, whole.
typedef float Float8 __attribute__((vector_size(32)));
typedef double Double8 __attribute__((vector_size(64)));
template <class T>
struct Lanes8;
template <>
struct Lanes8<float> {
    using type = Float8;
};
template <>
struct Lanes8<double> {
    using type = Double8;
};

namespace VOXLAT_MG_ISA {

/// In place: v[k] = sum_a (-1)^popcount(k & a) v[a], a fixed sequence of butterflies.
template <class V>
inline void hadamard(V* v)
{
#pragma GCC unroll 8
    for (int bit = 1; bit < 8; bit <<= 1)
#pragma GCC unroll 8
        for (int a = 0; a < 8; ++a)
            if (!(a & bit)) {
                const V p = v[a], q = v[a | bit];
                v[a] = p + q;
                v[a | bit] = p - q;
            }
}

/// One element's product through the reflection blocks (see Level::setReflectionBlocks in
/// Multigrid.cpp): @a blocks, 8 scalars for D = 1; @a columns, column j of block c at c * 3 + j
/// for D = 3. The vectors hold R right-hand sides: right-hand side q of a node at
/// node * St * R + q * St. Every right-hand side takes the same operations in the same order as
/// alone (R = 1); two at a time for single precision with three unknowns, in one eight-lane
/// vector (two nodes' four lanes), lane by lane the four-lane product. Made once per range of
/// elements (a local: its lane vectors stay in registers).
template <int D, class T, int St>
struct BlockProduct {
    using V = typename Lanes<T>::type;
    using P = typename Lanes8<T>::type;
    static constexpr bool kPairs = D == 3 && St == 4 && sizeof(T) == 4;
    T B1[8];
    V sign[8], B[24];
    P sign2[8], B2[24];

    /// Null @a blocks (D = 1) or @a columns (D = 3): not used (no element goes through blocks).
    BlockProduct(const T* blocks, const V* columns)
    {
        if constexpr (D == 1) {
            if (!blocks) return;
            for (int c = 0; c < 8; ++c) B1[c] = blocks[c];
        } else {
            if (!columns) return;
            for (int a = 0; a < 8; ++a)
                sign[a] = V{T((a & 1) ? -1 : 1), T((a & 2) ? -1 : 1), T((a & 4) ? -1 : 1), T(0)};
            for (int k = 0; k < 24; ++k) B[k] = columns[k];
            if constexpr (kPairs) {
                for (int a = 0; a < 8; ++a)
                    sign2[a] = P{sign[a][0], sign[a][1], sign[a][2], sign[a][3],
                                 sign[a][0], sign[a][1], sign[a][2], sign[a][3]};
                for (int k = 0; k < 24; ++k)
                    B2[k] = P{B[k][0], B[k][1], B[k][2], B[k][3], B[k][0], B[k][1], B[k][2], B[k][3]};
            }
        }
    }

    /// y += the product of the element with nodes @a nd, every right-hand side.
    [[gnu::always_inline]] inline void operator()(const std::int32_t* nd, const T* xin, T* y, std::size_t stride,
                                                  int R) const
    {
        if constexpr (D == 1) {
            for (int q = 0; q < R; ++q) {
                T v[8];
#pragma GCC unroll 8
                for (int a = 0; a < 8; ++a) v[a] = xin[std::size_t(nd[a]) * stride + q];
                hadamard(v);
#pragma GCC unroll 8
                for (int c = 0; c < 8; ++c) v[c] *= B1[c];
                hadamard(v);
#pragma GCC unroll 8
                for (int a = 0; a < 8; ++a) y[std::size_t(nd[a]) * stride + q] += v[a];
            }
        } else {
            // Character c's component d is, in the transform of the node values, component d at
            // index c ^ e_d (a reflection along d also flips component d); each character's block
            // takes its three components from three lane vectors. The inverse: component d of
            // node a is the transform of the block products times (-1)^(bit d of a), the same
            // signs undoing the same permutation.
            int q = 0;
            if constexpr (kPairs) {
                // Two right-hand sides: lanes 0-3 and 4-7, each the four-lane product below (a
                // component broadcast within its half).
                for (; q + 2 <= R; q += 2) {
                    P v[8];
#pragma GCC unroll 8
                    for (int a = 0; a < 8; ++a)
                        std::memcpy(&v[a], xin + std::size_t(nd[a]) * stride + q * 4, sizeof(P));
                    hadamard(v);
                    P w[8];
#pragma GCC unroll 8
                    for (int c = 0; c < 8; ++c) {
                        const P x0 = __builtin_shufflevector(v[c ^ 1], v[c ^ 1], 0, 0, 0, 0, 4, 4, 4, 4);
                        const P x1 = __builtin_shufflevector(v[c ^ 2], v[c ^ 2], 1, 1, 1, 1, 5, 5, 5, 5);
                        const P x2 = __builtin_shufflevector(v[c ^ 4], v[c ^ 4], 2, 2, 2, 2, 6, 6, 6, 6);
                        w[c] = B2[3 * c] * x0 + B2[3 * c + 1] * x1 + B2[3 * c + 2] * x2;
                    }
                    hadamard(w);
#pragma GCC unroll 8
                    for (int a = 0; a < 8; ++a) {
                        const P r = w[a] * sign2[a];
                        T* out = y + std::size_t(nd[a]) * stride + q * 4;
                        P o;
                        std::memcpy(&o, out, sizeof o);
                        o += r;
                        std::memcpy(out, &o, sizeof o);
                    }
                }
            }
            for (; q < R; ++q) {
                V v[8];
#pragma GCC unroll 8
                for (int a = 0; a < 8; ++a) {
                    const T* p = xin + std::size_t(nd[a]) * stride + q * St;
                    if constexpr (St == 4)
                        std::memcpy(&v[a], p, sizeof(V));  // the padding lane is zero
                    else
                        v[a] = V{p[0], p[1], p[2], T(0)};
                }
                hadamard(v);
                V w[8];
#pragma GCC unroll 8
                for (int c = 0; c < 8; ++c)
                    w[c] = B[3 * c] * v[c ^ 1][0] + B[3 * c + 1] * v[c ^ 2][1] + B[3 * c + 2] * v[c ^ 4][2];
                hadamard(w);
#pragma GCC unroll 8
                for (int a = 0; a < 8; ++a) {
                    const V r = w[a] * sign[a];
                    T* out = y + std::size_t(nd[a]) * stride + q * St;
                    if constexpr (St == 4) {
                        V o;
                        std::memcpy(&o, out, sizeof(V));
                        o += r;  // lane 3: 0 + 0 (the blocks' columns are zero there)
                        std::memcpy(out, &o, sizeof(V));
                    } else {
                        out[0] += r[0];
                        out[1] += r[1];
                        out[2] += r[2];
                    }
                }
            }
        }
    }
};

/// y += the element products of elements e0..e1-1 through the reflection blocks (BlockProduct),
/// for @a R right-hand sides.
template <int D, class T, int St>
void elementBlocks(const std::int32_t* elemNodes, std::size_t e0, std::size_t e1, const T* blocks,
                   const typename Lanes<T>::type* columns, const T* xin, T* y, int R)
{
    const BlockProduct<D, T, St> product(blocks, columns);
    const std::size_t stride = std::size_t(St) * std::size_t(R);
    for (std::size_t e = e0; e < e1; ++e) product(&elemNodes[8 * e], xin, y, stride, R);
}

/// y += one element's dense product @a K for right-hand sides q .. q + M - 1 (see elementDense):
/// each column of K loaded once for all M.
template <int M, int D, class T, int St>
inline void denseProduct(const std::int32_t* nd, const T* K, const T* xin, T* y, std::size_t stride, int q)
{
    constexpr int kE = 8 * D;
    // The element vector as whole lane vectors of eight (kE = 8 or 24), the loops unrolled: lane
    // by lane the scalar axpy (the same bits), and no index left for the sanitizers' build to
    // check per scalar, which kept it from vectorising (the dense coarse product was 56 % of a
    // search test's time under ASan/UBSan).
    using W = typename Lanes8<T>::type;
    constexpr int kW = kE / 8;
    T ue[M][kE];
#pragma GCC unroll 2
    for (int h = 0; h < M; ++h)
#pragma GCC unroll 8
        for (int a = 0; a < 8; ++a)
#pragma GCC unroll 3
            for (int k = 0; k < D; ++k) ue[h][a * D + k] = xin[std::size_t(nd[a]) * stride + (q + h) * St + k];
    W ye[M][kW];
#pragma GCC unroll 2
    for (int h = 0; h < M; ++h)
#pragma GCC unroll 3
        for (int i = 0; i < kW; ++i) ye[h][i] = W{};
            // Column by column (K is symmetric): each step an axpy on whole lane vectors.
#pragma GCC unroll 24
    for (int j = 0; j < kE; ++j) {
        const T* col = K + j * kE;
        W c[kW];
#pragma GCC unroll 3
        for (int i = 0; i < kW; ++i) std::memcpy(&c[i], col + 8 * i, sizeof(W));
#pragma GCC unroll 2
        for (int h = 0; h < M; ++h) {
            const T u = ue[h][j];
#pragma GCC unroll 3
            for (int i = 0; i < kW; ++i) ye[h][i] += c[i] * u;
        }
    }
#pragma GCC unroll 2
    for (int h = 0; h < M; ++h)
#pragma GCC unroll 8
        for (int a = 0; a < 8; ++a)
#pragma GCC unroll 3
            for (int k = 0; k < D; ++k)
                y[std::size_t(nd[a]) * stride + (q + h) * St + k] += ye[h][(a * D + k) / 8][(a * D + k) % 8];
}

/// y += the element products of elements e0..e1-1 with their dense (8D)^2 matrices: @a table
/// holds one per element type (elemType), or the only one when @a single; elements of type
/// @a blockType (none if negative) go through its reflection blocks @a blocks / @a columns
/// instead (BlockProduct). @a R right-hand sides, laid out as in BlockProduct; a column of a
/// matrix is loaded once for two of them.
template <int D, class T, int St>
void elementDense(const std::int32_t* elemNodes, const std::int32_t* elemType, const T* table, bool single,
                  std::int32_t blockType, const T* blocks, const typename Lanes<T>::type* columns, std::size_t e0,
                  std::size_t e1, const T* xin, T* y, int R)
{
    constexpr int kE = 8 * D;
    const std::size_t stride = std::size_t(St) * std::size_t(R);
    const BlockProduct<D, T, St> product(blockType >= 0 ? blocks : nullptr, blockType >= 0 ? columns : nullptr);
    for (std::size_t e = e0; e < e1; ++e) {
        const std::int32_t* nd = &elemNodes[8 * e];
        const std::int32_t type = single ? 0 : elemType[e];
        if (type == blockType) {
            product(nd, xin, y, stride, R);
            continue;
        }
        const T* K = table + std::size_t(type) * kE * kE;
        int q = 0;
        for (; q + 2 <= R; q += 2) denseProduct<2, D, T, St>(nd, K, xin, y, stride, q);
        if (q < R) denseProduct<1, D, T, St>(nd, K, xin, y, stride, q);
    }
}

/// The Chebyshev update of nodes i0..i1-1 with three unknowns (PeriodicSolver::chebyshevStep):
/// per right-hand side, d = c1 dIn + c2 diag^-1 (b - t) (without kIn: no c1 term; without kT:
/// b), stored in dOut with kOut; x = x + d with kKeep, else d. Nodes hold R right-hand sides of
/// four lanes (the fourth zero), diagInv a node's three padded rows (its symmetric block: rows
/// are columns). Two right-hand sides at a time in eight lanes, each half lane by lane the four-
/// lane update.
template <bool kT, bool kIn, bool kOut, bool kKeep>
void chebyshevNodes(const float* diagInv, std::size_t i0, std::size_t i1, int R, const float* b, const float* t,
                    const float* dIn, float* dOut, float* x, float c1, float c2)
{
    auto load4 = [](const float* p) {
        Float4 v;
        std::memcpy(&v, p, sizeof v);
        return v;
    };
    auto load8 = [](const float* p) {
        Float8 v;
        std::memcpy(&v, p, sizeof v);
        return v;
    };
    for (std::size_t i = i0; i < i1; ++i) {
        const float* m = diagInv + 12 * i;
        const Float4 m0 = load4(m), m1 = load4(m + 4), m2 = load4(m + 8);
        const Float8 M0 = __builtin_shufflevector(m0, m0, 0, 1, 2, 3, 0, 1, 2, 3);
        const Float8 M1 = __builtin_shufflevector(m1, m1, 0, 1, 2, 3, 0, 1, 2, 3);
        const Float8 M2 = __builtin_shufflevector(m2, m2, 0, 1, 2, 3, 0, 1, 2, 3);
        int q = 0;
        for (; q + 2 <= R; q += 2) {
            const std::size_t o = 4 * (i * std::size_t(R) + std::size_t(q));
            Float8 r = load8(b + o);
            if constexpr (kT) r -= load8(t + o);
            const Float8 r0 = __builtin_shufflevector(r, r, 0, 0, 0, 0, 4, 4, 4, 4);
            const Float8 r1 = __builtin_shufflevector(r, r, 1, 1, 1, 1, 5, 5, 5, 5);
            const Float8 r2 = __builtin_shufflevector(r, r, 2, 2, 2, 2, 6, 6, 6, 6);
            Float8 dn = c2 * (M0 * r0 + M1 * r1 + M2 * r2);
            if constexpr (kIn) dn += c1 * load8(dIn + o);
            if constexpr (kOut) std::memcpy(dOut + o, &dn, sizeof dn);
            if constexpr (kKeep) {
                const Float8 xn = load8(x + o) + dn;
                std::memcpy(x + o, &xn, sizeof xn);
            } else {
                std::memcpy(x + o, &dn, sizeof dn);
            }
        }
        for (; q < R; ++q) {
            const std::size_t o = 4 * (i * std::size_t(R) + std::size_t(q));
            Float4 r = load4(b + o);
            if constexpr (kT) r -= load4(t + o);
            Float4 dn = c2 * (m0 * r[0] + m1 * r[1] + m2 * r[2]);
            if constexpr (kIn) dn += c1 * load4(dIn + o);
            if constexpr (kOut) std::memcpy(dOut + o, &dn, sizeof dn);
            if constexpr (kKeep) {
                const Float4 xn = load4(x + o) + dn;
                std::memcpy(x + o, &xn, sizeof xn);
            } else {
                std::memcpy(x + o, &dn, sizeof dn);
            }
        }
    }
}

}  // namespace VOXLAT_MG_ISA
}  // namespace voxlat::homogenization
