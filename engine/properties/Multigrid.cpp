#include "engine/properties/Multigrid.h"

#include "engine/core/Errors.h"
#include "fields/core/HugePageAdvice.h"

#define VOXLAT_MG_ISA baseline
#include "engine/properties/MultigridKernels.h"
#undef VOXLAT_MG_ISA

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <new>
#include <stdexcept>
#include <type_traits>
#include <unordered_map>

namespace voxlat::homogenization {

#ifdef VOXLAT_MG_AVX2
// The same kernels built for AVX2 (MultigridAvx2.cpp, where they are instantiated).
namespace avx2 {
template <int D, class T, int St>
void elementBlocks(const std::int32_t* elemNodes, std::size_t e0, std::size_t e1, const T* blocks,
                   const typename Lanes<T>::type* columns, const T* xin, T* y, int R);
template <int D, class T, int St>
void elementDense(const std::int32_t* elemNodes, const std::int32_t* elemType, const T* table, bool single,
                  std::int32_t blockType, const T* blocks, const typename Lanes<T>::type* columns, std::size_t e0,
                  std::size_t e1, const T* xin, T* y, int R);
template <bool kT, bool kIn, bool kOut, bool kKeep>
void chebyshevNodes(const float* diagInv, std::size_t i0, std::size_t i1, int R, const float* b, const float* t,
                    const float* dIn, float* dOut, float* x, float c1, float c2);
}  // namespace avx2
#endif

namespace {

/// Whether the element products run their AVX2 build (the same bits, fewer instructions).
bool useAvx2()
{
#ifdef VOXLAT_MG_AVX2
    static const bool has = __builtin_cpu_supports("avx2");
    return has;
#else
    return false;
#endif
}

constexpr int kColours = 3;
constexpr std::size_t kDotBlock = 1 << 14;  // fixed blocks: the sum order never depends on threads
// Chebyshev degree on the finest grid and on the coarse ones: coarse smoothing is cheap, and a
// third step there saves iterations on thin walls (a 64^3 sheet gyroid: 23 instead of 28).
constexpr int kFineDegree = 2;
constexpr int kCoarseDegree = 3;
constexpr double kChebyshevRatio = 15.0;  // smoothed part of the spectrum: [hi / ratio, hi]
constexpr int kPowerIterations = 15;
constexpr std::size_t kCoarsestPoints = 64;

/// Colour of a coordinate along an axis of n voxels: its parity, and a third colour for the last
/// voxel of an odd axis (which shares nodes with voxel 0 through the periodic wrap).
inline int axisColour(int x, int n)
{
    return (n % 2 == 1 && x == n - 1) ? 2 : (x & 1);
}

/// Sums of K terms over i < n, in fixed blocks of kDotBlock added in block order (the same bits
/// for any number of threads, and the same as dot() for one term): @a f(i0, i1, s) adds to s[k]
/// the terms of [i0, i1) (s starts at zero), in order, and may do other work on those entries on
/// the way.
template <int K, class F>
std::array<double, K> blockedSums(std::size_t n, const F& f)
{
    const std::size_t blocks = (n + kDotBlock - 1) / kDotBlock;
    std::vector<std::array<double, K>> part(blocks);
    tbb::parallel_for(std::size_t(0), blocks, [&](std::size_t b) {
        std::array<double, K> s{};
        f(b * kDotBlock, std::min(n, (b + 1) * kDotBlock), s);
        part[b] = s;
    });
    std::array<double, K> total{};
    for (const auto& s : part)
        for (int k = 0; k < K; ++k) total[k] += s[k];
    return total;
}

template <class F>
void parallelRange(std::size_t begin, std::size_t end, std::size_t grain, const F& f)
{
    if (end <= begin) return;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(begin, end, grain),
                      [&](const tbb::blocked_range<std::size_t>& r) { f(r.begin(), r.end()); });
}

/// Right-hand sides the preconditioner takes at once (the elastic load cases; see
/// PeriodicSolver::solve).
constexpr int kMaxLanes = 6;

/// Allocates large blocks on 2 MB boundaries and asks Linux for transparent huge pages there
/// (adviseHugePages()): the preconditioner's work vectors, megabytes each, then take one page fault
/// and one TLB entry per 2 MB instead of per 4 kB.
template <class T>
struct HugePages {
    using value_type = T;
    HugePages() = default;
    template <class U>
    HugePages(const HugePages<U>&)
    {
    }
    static constexpr std::size_t kHuge = std::size_t(2) << 20;
    T* allocate(std::size_t n)
    {
        const std::size_t bytes = n * sizeof(T);
        if (bytes < kHuge) return static_cast<T*>(::operator new(bytes));
        const std::size_t rounded = (bytes + kHuge - 1) / kHuge * kHuge;
        void* p = ::operator new(rounded, std::align_val_t(kHuge));
        adviseHugePages(p, rounded);
        return static_cast<T*>(p);
    }
    void deallocate(T* p, std::size_t n)
    {
        if (n * sizeof(T) < kHuge)
            ::operator delete(p);
        else
            ::operator delete(p, std::align_val_t(kHuge));
    }
    template <class U>
    bool operator==(const HugePages<U>&) const
    {
        return true;
    }
    template <class U>
    bool operator!=(const HugePages<U>&) const
    {
        return false;
    }
};

/// Small dense symmetric D x D inverse (the nodal diagonal blocks are positive definite).
template <int D>
void invertBlock(const double* a, double* inv)
{
    if constexpr (D == 1) {
        inv[0] = 1.0 / a[0];
    } else {
        const double c00 = a[4] * a[8] - a[5] * a[7], c01 = a[5] * a[6] - a[3] * a[8], c02 = a[3] * a[7] - a[4] * a[6];
        const double det = a[0] * c00 + a[1] * c01 + a[2] * c02;
        const double s = 1.0 / det;
        inv[0] = c00 * s;
        inv[1] = (a[2] * a[7] - a[1] * a[8]) * s;
        inv[2] = (a[1] * a[5] - a[2] * a[4]) * s;
        inv[3] = c01 * s;
        inv[4] = (a[0] * a[8] - a[2] * a[6]) * s;
        inv[5] = (a[2] * a[3] - a[0] * a[5]) * s;
        inv[6] = c02 * s;
        inv[7] = (a[1] * a[6] - a[0] * a[7]) * s;
        inv[8] = (a[0] * a[4] - a[1] * a[3]) * s;
    }
}

/// Pseudo-random in [-1, 1) from an index: a start vector that does not depend on threads.
inline double hashUnit(std::uint64_t i)
{
    i += 0x9E3779B97F4A7C15ull;
    i = (i ^ (i >> 30)) * 0xBF58476D1CE4E5B9ull;
    i = (i ^ (i >> 27)) * 0x94D049BB133111EBull;
    i ^= i >> 31;
    return double(i >> 11) * (2.0 / 9007199254740992.0) - 1.0;
}

struct KeyHash {
    std::size_t operator()(const std::array<std::int32_t, 11>& k) const
    {
        std::uint64_t h = 1469598103934665603ull;
        for (std::int32_t v : k) h = (h ^ std::uint32_t(v)) * 1099511628211ull;
        return std::size_t(h);
    }
};

}  // namespace

/// One grid of the hierarchy: its elements, nodes, element matrices and work vectors.
template <int D>
struct PeriodicSolver<D>::Level {
    static constexpr int kE = 8 * D;
    /// Values a node takes in the preconditioner's vectors: three unknowns are padded to four
    /// (the fourth always zero), so a node is one aligned lane vector, loaded and stored whole.
    static constexpr int S = D == 3 ? 4 : 1;
    /// A node's entries in diagInv: D rows of S (the padding zero).
    static constexpr int kDiag = D * S;
    /// Stride of a node in a vector of T: padded in the preconditioner's precision, not in CG's.
    template <class T>
    static constexpr int strideOf = std::is_same_v<T, Real> ? S : D;
    std::array<int, 3> n{};                 ///< voxels (= grid points) per axis
    std::vector<std::int32_t> nodeOfPoint;  ///< grid point -> node, -1 if no element touches it
    std::vector<std::int32_t> pointOfNode;
    std::vector<std::int32_t> elemVoxel;  ///< sorted by colour, then voxel index
    std::vector<std::int32_t> elemNodes;  ///< 8 per element
    std::vector<std::int32_t> elemType;   ///< per element, index into matrices
    std::vector<double> matrices;         ///< kE * kE per element type; dropped after set-up except on level 0
    std::vector<Real> realMatrices;       ///< the same in the preconditioner's precision
    /// Elements sorted by layer (z), layers by colour: colour c's layers are the ranks
    /// colourLayer[c] to colourLayer[c + 1] - 1, layer rank l's elements layerStart[l] to
    /// layerStart[l + 1] - 1.
    std::array<std::size_t, kColours + 1> colourLayer{};
    std::vector<std::size_t> layerStart;
    std::vector<double> diag;   ///< D x D nodal diagonal blocks (set-up only)
    std::vector<Real> diagInv;  ///< their inverses
    double hi = 0.0, lo = 0.0;  ///< Chebyshev interval of diag^-1 A
    /// Towards the next coarser level, per axis: fine coordinate -> (coarse coordinate, weight) x2,
    /// coarse coordinate -> (fine coordinate, weight) x3 (count -1 means unused).
    std::array<std::vector<std::array<std::pair<int, double>, 2>>, 3> prolong;
    std::array<std::vector<std::array<std::pair<int, double>, 3>>, 3> restrict;
    /// Work vectors of the preconditioner: node i's right-hand side q at (i * R + q) * S for R
    /// right-hand sides (sized for `lanes` of them).
    mutable std::vector<Real, HugePages<Real>> b, x, d, t;
    mutable int lanes = 1;
    void reserveLanes(int R) const
    {
        if (R <= lanes) return;
        for (auto* v : {&b, &x, &d, &t}) v->assign(nodes() * S * std::size_t(R), Real(0));
        lanes = R;
    }

    std::size_t nodes() const { return pointOfNode.size(); }
    std::size_t dofs() const { return pointOfNode.size() * D; }
    std::size_t points() const { return std::size_t(n[0]) * n[1] * n[2]; }
    std::int32_t pointIndex(int x, int y, int z) const
    {
        return std::int32_t(x + std::size_t(n[0]) * (y + std::size_t(n[1]) * z));
    }
    void coords(std::int32_t p, int c[3]) const
    {
        c[0] = int(p % n[0]);
        c[1] = int((p / n[0]) % n[1]);
        c[2] = int(p / (std::size_t(n[0]) * n[1]));
    }

    /// Elements from (voxel, type) pairs in voxel order: colour sort, node numbering, diagonal.
    void build(const std::vector<std::pair<std::int32_t, std::int32_t>>& voxels)
    {
        // Layers of voxels along z, coloured by the parity of z (see axisColour): layers of one
        // colour share no node. Ranked colour by colour, each colour's layers in z order.
        const int nz = n[2];
        std::vector<int> rank(nz);
        int next = 0;
        for (int c = 0; c < kColours; ++c) {
            colourLayer[c] = std::size_t(next);
            for (int z = 0; z < nz; ++z)
                if (axisColour(z, nz) == c) rank[z] = next++;
        }
        colourLayer[kColours] = std::size_t(next);
        const std::size_t perLayer = std::size_t(n[0]) * n[1];
        layerStart.assign(std::size_t(nz) + 1, 0);
        for (const auto& v : voxels) ++layerStart[rank[std::size_t(v.first) / perLayer] + 1];
        for (int l = 0; l < nz; ++l) layerStart[l + 1] += layerStart[l];
        std::vector<std::size_t> fill(layerStart.begin(), layerStart.end() - 1);
        elemVoxel.resize(voxels.size());
        elemType.resize(voxels.size());
        for (const auto& v : voxels) {  // in voxel order: each layer's elements stay in voxel order
            const std::size_t at = fill[rank[std::size_t(v.first) / perLayer]]++;
            elemVoxel[at] = v.first;
            elemType[at] = v.second;
        }
        nodeOfPoint.assign(points(), -1);
        for (std::int32_t v : elemVoxel) {
            int c[3];
            coords(v, c);
            for (int a = 0; a < 8; ++a) nodeOfPoint[corner(c, a)] = 0;
        }
        pointOfNode.clear();
        for (std::size_t p = 0; p < nodeOfPoint.size(); ++p)
            if (nodeOfPoint[p] == 0) {
                nodeOfPoint[p] = std::int32_t(pointOfNode.size());
                pointOfNode.push_back(std::int32_t(p));
            }
        elemNodes.resize(8 * elemVoxel.size());
        for (std::size_t e = 0; e < elemVoxel.size(); ++e) {
            int c[3];
            coords(elemVoxel[e], c);
            for (int a = 0; a < 8; ++a) elemNodes[8 * e + a] = nodeOfPoint[corner(c, a)];
        }
        for (auto* v : {&b, &x, &d, &t}) v->assign(nodes() * S, Real(0));
    }

    std::int32_t corner(const int c[3], int a) const
    {
        const int x = c[0] + (a & 1), y = c[1] + ((a >> 1) & 1), z = c[2] + ((a >> 2) & 1);
        return pointIndex(x == n[0] ? 0 : x, y == n[1] ? 0 : y, z == n[2] ? 0 : z);
    }

    /// Nodal diagonal blocks: every element's blocks between local nodes that are the same node
    /// (two local nodes coincide along an axis of one voxel).
    void buildDiagonal()
    {
        diag.assign(nodes() * D * D, 0.0);
        forEachColour([&](std::size_t e) {
            const std::int32_t* nd = &elemNodes[8 * e];
            const double* K = &matrices[std::size_t(elemType[e]) * kE * kE];
            for (int a = 0; a < 8; ++a)
                for (int a2 = 0; a2 < 8; ++a2) {
                    if (nd[a] != nd[a2]) continue;
                    double* blk = &diag[std::size_t(nd[a]) * D * D];
                    for (int i = 0; i < D; ++i)
                        for (int j = 0; j < D; ++j) blk[i * D + j] += K[(a * D + i) * kE + a2 * D + j];
                }
        });
        diagInv.assign(nodes() * kDiag, Real(0));  // rows padded as the work vectors
        parallelRange(0, nodes(), 4096, [&](std::size_t b0, std::size_t b1) {
            for (std::size_t i = b0; i < b1; ++i) {
                double inv[D * D];
                invertBlock<D>(&diag[i * D * D], inv);
                for (int r = 0; r < D; ++r)
                    for (int c = 0; c < D; ++c) diagInv[i * kDiag + r * S + c] = Real(inv[r * D + c]);
            }
        });
    }

    /// Runs f(e0, e1) over ranges of elements, colour after colour, each colour's layers in
    /// parallel; a range is one or more whole layers of a colour, its elements in order. So every
    /// node sums its elements' contributions in one order for any number of threads, and a
    /// thread's elements lie in a few neighbouring layers of nodes (one pass over the vectors
    /// per colour, in cache).
    template <class F>
    void forEachLayerRange(const F& f) const
    {
        for (int c = 0; c < kColours; ++c)
            parallelRange(colourLayer[c], colourLayer[c + 1], 1,
                          [&](std::size_t l0, std::size_t l1) { f(layerStart[l0], layerStart[l1]); });
    }
    /// Runs f(element) over all elements (see forEachLayerRange).
    template <class F>
    void forEachColour(const F& f) const
    {
        forEachLayerRange([&](std::size_t e0, std::size_t e1) {
            for (std::size_t e = e0; e < e1; ++e) f(e);
        });
    }

    /// The level's most common element type (on the finest level the only one; on a coarse level
    /// the voxel whose eight children are full, most of a solid's inside), in the basis that
    /// block-diagonalises its matrix, when it does (see setReflectionBlocks): its type, -1 if none.
    std::int32_t blockType = -1;
    std::vector<double> blocks;
    std::vector<Real> realBlocks;
    /// For D = 3: column j of block c as lanes, at c * 3 + j.
    std::vector<Double4> blockColumns;
    std::vector<Float4> realBlockColumns;

    /// An element matrix invariant under the voxel's three mirror reflections (a box of an
    /// isotropic or axis-aligned material) commutes with the group they generate, Z2^3, whose
    /// characters are one-dimensional. A Walsh-Hadamard transform over the 8 nodes, per unknown,
    /// takes node values to character components: value (k, d) has character k ^ e_d for
    /// displacements (a reflection along d also flips the d component) and k for a scalar. The
    /// matrix is then block diagonal: 8 blocks of D x D. The product K u = T M T u (T the
    /// transform, T^2 = 8) costs two 8-point transforms and 8 D x D blocks: about a quarter of the
    /// flops of the dense 24 x 24 product. Kept only if the matrix really is block diagonal.
    void setReflectionBlocks()
    {
        const std::size_t types = matrices.size() / std::size_t(kE * kE);
        if (types == 0) return;
        std::int32_t common = 0;
        if (types > 1) {
            std::vector<std::size_t> count(types, 0);
            for (std::int32_t t : elemType) ++count[std::size_t(t)];
            common = std::int32_t(std::max_element(count.begin(), count.end()) - count.begin());
        }
        const double* K = &matrices[std::size_t(common) * kE * kE];
        auto sign = [](int k, int a) { return (__builtin_popcount(unsigned(k & a)) & 1) ? -1.0 : 1.0; };
        // M = T K T / 64, entry ((k, d), (k2, d2)).
        std::vector<double> M(kE * kE, 0.0);
        double top = 0.0;
        for (int i = 0; i < kE * kE; ++i) top = std::max(top, std::abs(K[i]));
        for (int k = 0; k < 8; ++k)
            for (int d = 0; d < D; ++d)
                for (int k2 = 0; k2 < 8; ++k2)
                    for (int d2 = 0; d2 < D; ++d2) {
                        double s = 0.0;
                        for (int a = 0; a < 8; ++a)
                            for (int a2 = 0; a2 < 8; ++a2)
                                s += sign(k, a) * K[(a * D + d) * kE + a2 * D + d2] * sign(k2, a2);
                        M[(k * D + d) * kE + k2 * D + d2] = s / 64.0;
                    }
        auto character = [](int k, int d) { return D == 1 ? k : (k ^ (1 << d)); };
        blocks.assign(8 * D * D, 0.0);
        for (int k = 0; k < 8; ++k)
            for (int d = 0; d < D; ++d)
                for (int k2 = 0; k2 < 8; ++k2)
                    for (int d2 = 0; d2 < D; ++d2) {
                        const double v = M[(k * D + d) * kE + k2 * D + d2];
                        const int c = character(k, d);
                        if (c != character(k2, d2)) {
                            if (std::abs(v) > 1e-13 * top) {  // not symmetric: keep the dense product
                                blocks.clear();
                                return;
                            }
                            continue;
                        }
                        blocks[(c * D + d) * D + d2] = v;
                    }
        blockType = common;
        realBlocks.assign(blocks.begin(), blocks.end());
        if constexpr (D == 3) {
            for (int c = 0; c < 8; ++c)
                for (int j = 0; j < 3; ++j) {
                    const double* B = &blocks[c * 9];
                    blockColumns.push_back(Double4{B[j], B[3 + j], B[6 + j], 0.0});
                    realBlockColumns.push_back(Float4{Real(B[j]), Real(B[3 + j]), Real(B[6 + j]), 0.0f});
                }
        }
    }

    /// y = A x in double (the operator CG solves with; level 0 only).
    void apply(const double* xin, double* y) const
    {
        applyWith(matrices.data(), matrices.size(), blocks, blockColumns, xin, y, 1);
    }
    /// y = A x in the preconditioner's precision, for @a R right-hand sides at once.
    void apply(const Real* xin, Real* y, int R = 1) const
    {
        applyWith(realMatrices.data(), realMatrices.size(), realBlocks, realBlockColumns, xin, y, R);
    }

    template <class T>
    void applyWith(const T* matrixTable, std::size_t tableSize, const std::vector<T>& scalarBlocks,
                   const std::vector<typename Lanes<T>::type>& columns, const T* xin, T* y, int R) const
    {
        constexpr int St = strideOf<T>;
        parallelRange(0, nodes() * St * std::size_t(R), 8192,
                      [&](std::size_t i0, std::size_t i1) { std::fill(y + i0, y + i1, T(0)); });
        const bool single = tableSize == std::size_t(kE * kE);
        const std::int32_t* nodes = elemNodes.data();
        const std::int32_t* types = elemType.data();
        const bool avx2 = useAvx2();
        const std::int32_t blocked = scalarBlocks.empty() ? -1 : blockType;
        const T* blockData = scalarBlocks.empty() ? nullptr : scalarBlocks.data();
        const typename Lanes<T>::type* columnData = columns.empty() ? nullptr : columns.data();
        forEachLayerRange([&](std::size_t e0, std::size_t e1) {
            if (single && blocked == 0) {  // every element through the blocks
#ifdef VOXLAT_MG_AVX2
                if (avx2) return avx2::elementBlocks<D, T, St>(nodes, e0, e1, blockData, columnData, xin, y, R);
#endif
                return baseline::elementBlocks<D, T, St>(nodes, e0, e1, blockData, columnData, xin, y, R);
            }
#ifdef VOXLAT_MG_AVX2
            if (avx2)
                return avx2::elementDense<D, T, St>(nodes, types, matrixTable, single, blocked, blockData, columnData,
                                                    e0, e1, xin, y, R);
#endif
            baseline::elementDense<D, T, St>(nodes, types, matrixTable, single, blocked, blockData, columnData, e0, e1,
                                             xin, y, R);
        });
        (void)avx2;
    }

    /// out = diag^-1 in, node by node.
    void applyDiagInv(const Real* in, Real* out, std::size_t i) const
    {
        const Real* m = &diagInv[i * kDiag];
        for (int r = 0; r < D; ++r) {
            Real s = 0;
            for (int c = 0; c < D; ++c) s += m[r * S + c] * in[i * S + c];
            out[i * S + r] = s;
        }
    }
};

template <int D>
PeriodicSolver<D>::PeriodicSolver(const std::array<int, 3>& n, const std::vector<std::int32_t>& label, int components,
                                  const std::vector<double>& elementMatrix)
    : mComponents(components)
{
    auto L = std::make_unique<Level>();
    L->n = n;
    std::vector<std::pair<std::int32_t, std::int32_t>> voxels;
    for (std::size_t v = 0; v < label.size(); ++v)
        if (label[v] >= 0) voxels.push_back({std::int32_t(v), 0});
    L->matrices = elementMatrix;
    L->setReflectionBlocks();
    L->build(voxels);
    // Nodes are shared only within a component (sharing a node is what connects voxels).
    mNodeComponent.assign(L->nodes(), -1);
    for (std::size_t e = 0; e < L->elemVoxel.size(); ++e)
        for (int a = 0; a < 8; ++a) mNodeComponent[L->elemNodes[8 * e + a]] = label[L->elemVoxel[e]];
    mLevels.push_back(std::move(L));
    buildHierarchy();
}

template <int D>
PeriodicSolver<D>::~PeriodicSolver() = default;

template <int D>
std::size_t PeriodicSolver<D>::dofs() const
{
    return mLevels[0]->dofs();
}

template <int D>
std::size_t PeriodicSolver<D>::elements() const
{
    return mLevels[0]->elemVoxel.size();
}

template <int D>
int PeriodicSolver<D>::levels() const
{
    return int(mLevels.size());
}

template <int D>
void PeriodicSolver<D>::buildHierarchy()
{
    constexpr int kE = Level::kE;
    while (mLevels.back()->points() > kCoarsestPoints && mLevels.back()->nodes() > 0) {
        Level& F = *mLevels.back();
        if (F.n[0] == 1 && F.n[1] == 1 && F.n[2] == 1) break;
        auto C = std::make_unique<Level>();
        for (int k = 0; k < 3; ++k) C->n[k] = (F.n[k] + 1) / 2;
        // Transfer maps per axis (trilinear interpolation; see the class comment).
        for (int k = 0; k < 3; ++k) {
            const int nf = F.n[k], nc = C->n[k];
            F.prolong[k].assign(nf, {std::pair<int, double>{-1, 0.0}, std::pair<int, double>{-1, 0.0}});
            for (int i = 0; i < nf; ++i) {
                if (i % 2 == 0)
                    F.prolong[k][i][0] = {i / 2, 1.0};
                else
                    F.prolong[k][i] = {std::pair<int, double>{(i - 1) / 2, 0.5}, {((i + 1) / 2) % nc, 0.5}};
            }
            F.restrict[k].assign(nc, {std::pair<int, double>{-1, 0.0}, {-1, 0.0}, {-1, 0.0}});
            for (int I = 0; I < nc; ++I) {
                F.restrict[k][I][0] = {2 * I, 1.0};
                if (2 * I + 1 < nf) F.restrict[k][I][1] = {2 * I + 1, 0.5};
                const int J = (I - 1 + nc) % nc;
                if (2 * J + 1 < nf) F.restrict[k][I][2] = {2 * J + 1, 0.5};
            }
        }
        // Children of each coarse voxel: their element types (-1: empty) by position.
        const std::size_t coarsePoints = C->points();
        std::vector<std::int32_t> child(coarsePoints * 8, -1);
        for (std::size_t e = 0; e < F.elemVoxel.size(); ++e) {
            int c[3];
            F.coords(F.elemVoxel[e], c);
            const std::int32_t cv = C->pointIndex(c[0] / 2, c[1] / 2, c[2] / 2);
            child[std::size_t(cv) * 8 + (c[0] & 1) + 2 * (c[1] & 1) + 4 * (c[2] & 1)] = F.elemType[e];
        }
        // One matrix per distinct (children, widths): numbered in voxel order, deterministic.
        std::unordered_map<std::array<std::int32_t, 11>, std::int32_t, KeyHash> typeOf;
        std::vector<std::array<std::int32_t, 11>> keys;
        std::vector<std::pair<std::int32_t, std::int32_t>> voxels;
        for (std::size_t cv = 0; cv < coarsePoints; ++cv) {
            std::array<std::int32_t, 11> key;
            bool any = false;
            for (int p = 0; p < 8; ++p) {
                key[p] = child[cv * 8 + p];
                any = any || key[p] >= 0;
            }
            if (!any) continue;
            int c[3];
            C->coords(std::int32_t(cv), c);
            for (int k = 0; k < 3; ++k) key[8 + k] = (2 * c[k] + 1 < F.n[k]) ? 2 : 1;
            auto [it, inserted] = typeOf.try_emplace(key, std::int32_t(keys.size()));
            if (inserted) keys.push_back(key);
            voxels.push_back({std::int32_t(cv), it->second});
        }
        child.clear();
        child.shrink_to_fit();
        C->matrices.assign(keys.size() * kE * kE, 0.0);
        tbb::parallel_for(std::size_t(0), keys.size(), [&](std::size_t t) {
            const auto& key = keys[t];
            double* G = &C->matrices[t * kE * kE];
            for (int pos = 0; pos < 8; ++pos) {
                if (key[pos] < 0) continue;
                // 1D interpolation from the coarse voxel's two nodes to the child's two nodes.
                double w1[3][2][2];
                for (int k = 0; k < 3; ++k) {
                    const int p = (pos >> k) & 1;
                    if (key[8 + k] == 1) {
                        w1[k][0][0] = 1, w1[k][0][1] = 0, w1[k][1][0] = 0, w1[k][1][1] = 1;
                    } else if (p == 0) {
                        w1[k][0][0] = 1, w1[k][0][1] = 0, w1[k][1][0] = 0.5, w1[k][1][1] = 0.5;
                    } else {
                        w1[k][0][0] = 0.5, w1[k][0][1] = 0.5, w1[k][1][0] = 0, w1[k][1][1] = 1;
                    }
                }
                double P[8][8];  // [child node][coarse node]
                for (int a = 0; a < 8; ++a)
                    for (int bb = 0; bb < 8; ++bb)
                        P[a][bb] = w1[0][a & 1][bb & 1] * w1[1][(a >> 1) & 1][(bb >> 1) & 1] *
                                   w1[2][(a >> 2) & 1][(bb >> 2) & 1];
                const double* K = &F.matrices[std::size_t(key[pos]) * kE * kE];
                // T = K P (per unknown), then G += P^T T.
                double T[kE][kE];
                for (int i = 0; i < kE; ++i)
                    for (int bb = 0; bb < 8; ++bb)
                        for (int dj = 0; dj < D; ++dj) {
                            double s = 0.0;
                            for (int a = 0; a < 8; ++a)
                                if (P[a][bb] != 0.0) s += K[i * kE + a * D + dj] * P[a][bb];
                            T[i][bb * D + dj] = s;
                        }
                for (int bb = 0; bb < 8; ++bb)
                    for (int di = 0; di < D; ++di)
                        for (int j = 0; j < kE; ++j) {
                            double s = 0.0;
                            for (int a = 0; a < 8; ++a)
                                if (P[a][bb] != 0.0) s += P[a][bb] * T[a * D + di][j];
                            G[(bb * D + di) * kE + j] += s;
                        }
            }
            for (int i = 0; i < kE; ++i)
                for (int j = i + 1; j < kE; ++j) G[i * kE + j] = G[j * kE + i] = 0.5 * (G[i * kE + j] + G[j * kE + i]);
        });
        C->build(voxels);
        C->setReflectionBlocks();
        mLevels.push_back(std::move(C));
    }

    // Smoother set-up: diagonal blocks and the top of the spectrum of diag^-1 A per level.
    for (std::size_t l = 0; l + 1 < mLevels.size(); ++l) {
        Level& L = *mLevels[l];
        L.buildDiagonal();
        L.realMatrices.assign(L.matrices.begin(), L.matrices.end());
        constexpr int S = Level::S;
        auto& v = L.x;
        auto& w = L.t;
        for (std::size_t i = 0; i < L.nodes(); ++i)
            for (int r = 0; r < D; ++r) v[i * S + r] = Real(hashUnit(i * D + r));
        double lambda = 0.0;
        for (int it = 0; it < kPowerIterations; ++it) {
            L.apply(v.data(), w.data());
            // Rayleigh quotient v.Av / v.Dv, then v = D^-1 A v normalised.
            double vav = 0.0, vdv = 0.0;
            for (std::size_t i = 0; i < L.nodes(); ++i)
                for (int r = 0; r < D; ++r) {
                    double dv = 0.0;
                    for (int c = 0; c < D; ++c) dv += L.diag[i * D * D + r * D + c] * v[i * S + c];
                    vdv += v[i * S + r] * dv;
                    vav += v[i * S + r] * w[i * S + r];
                }
            lambda = vdv > 0.0 ? vav / vdv : 0.0;
            double norm = 0.0;
            for (std::size_t i = 0; i < L.nodes(); ++i) {
                L.applyDiagInv(w.data(), v.data(), i);
                for (int r = 0; r < D; ++r) norm += v[i * S + r] * v[i * S + r];
            }
            norm = std::sqrt(norm);
            if (norm == 0.0) break;
            for (Real& x : v) x = Real(x / norm);
        }
        // The Rayleigh quotient approaches the top from below: a margin keeps Chebyshev stable.
        L.hi = 1.1 * lambda;
        L.lo = L.hi / kChebyshevRatio;
        std::fill(v.begin(), v.end(), Real(0));
        L.diag.clear();
        L.diag.shrink_to_fit();
    }

    // Coarsest level: dense Cholesky, pivots below 1e-10 of their diagonal dropped (null space).
    Level& L = *mLevels.back();
    const std::size_t n = L.dofs();
    std::vector<double> A(n * n, 0.0);
    for (std::size_t e = 0; e < L.elemVoxel.size(); ++e) {
        const double* K = &L.matrices[std::size_t(L.elemType[e]) * kE * kE];
        for (int i = 0; i < kE; ++i)
            for (int j = 0; j < kE; ++j) {
                const std::size_t gi = std::size_t(L.elemNodes[8 * e + i / D]) * D + i % D;
                const std::size_t gj = std::size_t(L.elemNodes[8 * e + j / D]) * D + j % D;
                A[gi * n + gj] += K[i * kE + j];
            }
    }
    std::vector<double> original(n);
    for (std::size_t i = 0; i < n; ++i) original[i] = A[i * n + i];
    mCoarseDropped.assign(n, 0);
    for (std::size_t k = 0; k < n; ++k) {
        const double pivot = A[k * n + k];
        if (!(pivot > 1e-10 * original[k])) {
            mCoarseDropped[k] = 1;
            for (std::size_t i = k; i < n; ++i) A[i * n + k] = 0.0;
            continue;
        }
        const double s = std::sqrt(pivot);
        for (std::size_t i = k; i < n; ++i) A[i * n + k] /= s;
        for (std::size_t j = k + 1; j < n; ++j) {
            const double ljk = A[j * n + k];
            if (ljk == 0.0) continue;
            for (std::size_t i = j; i < n; ++i) A[i * n + j] -= A[i * n + k] * ljk;
        }
    }
    mCoarseFactor = std::move(A);
    for (std::size_t l = 1; l < mLevels.size(); ++l) {
        mLevels[l]->matrices.clear();
        mLevels[l]->matrices.shrink_to_fit();
    }
}

template <int D>
void PeriodicSolver<D>::coarseSolve(const Level& L, const Real* b, Real* xOut, int R) const
{
    const std::size_t n = L.dofs();
    const double* A = mCoarseFactor.data();
    constexpr int S = Level::S;
    // Right-hand side q's unknown i at (i / D) * S * R + q * S + i % D.
    auto at = [&](std::size_t i, int q) { return (i / D) * S * std::size_t(R) + std::size_t(q) * S + i % D; };
    std::vector<double> x(n);
    for (int q = 0; q < R; ++q) {
        for (std::size_t i = 0; i < n; ++i) {  // L y = b
            if (mCoarseDropped[i]) {
                x[i] = 0.0;
                continue;
            }
            double s = b[at(i, q)];
            for (std::size_t k = 0; k < i; ++k) s -= A[i * n + k] * x[k];
            x[i] = s / A[i * n + i];
        }
        for (std::size_t i = n; i-- > 0;) {  // L^T x = y
            if (mCoarseDropped[i]) continue;
            double s = x[i];
            for (std::size_t k = i + 1; k < n; ++k) s -= A[k * n + i] * x[k];
            x[i] = s / A[i * n + i];
        }
        for (std::size_t i = 0; i < n; ++i) xOut[at(i, q)] = Real(x[i]);
    }
}

template <int D>
void PeriodicSolver<D>::smooth(const Level& L, const Real* b, Real* x, bool zeroStart, int R) const
{
    // Chebyshev iteration on diag^-1 A over [lo, hi] (Saad, Iterative Methods, alg. 12.1). With a
    // zero start it is a fixed symmetric polynomial in diag^-1 A times diag^-1: the same operator
    // before and after the coarse correction, so the V-cycle is symmetric, as CG needs.
    const double theta = 0.5 * (L.hi + L.lo), delta = 0.5 * (L.hi - L.lo);
    const double sigma = theta / delta;
    double rho = 1.0 / sigma;
    Real* t = L.t.data();
    Real* d = L.d.data();
    const int degree = &L == mLevels[0].get() ? kFineDegree : kCoarseDegree;
    if (!zeroStart) L.apply(x, t, R);
    // d = c1 d + c2 diag^-1 (b - t), x = x + d (t and the old x, d are zero on a zero start).
    // The direction is stored only for a next step; after a zero start it is x itself.
    chebyshevStep(L, b, zeroStart ? nullptr : t, x, nullptr, zeroStart || degree == 1 ? nullptr : d, Real(0),
                  Real(1.0 / theta), !zeroStart, R);
    for (int step = 1; step < degree; ++step) {
        L.apply(x, t, R);
        const double rhoNew = 1.0 / (2.0 * sigma - rho);
        chebyshevStep(L, b, t, x, step == 1 && zeroStart ? x : d, step + 1 < degree ? d : nullptr, Real(rhoNew * rho),
                      Real(2.0 * rhoNew / delta), true, R);
        rho = rhoNew;
    }
}

namespace {

/// Calls f with std::bool_constant for each flag.
template <class F>
void withFlags(bool a, bool b, bool c, bool d, const F& f)
{
    auto pick = [](bool v, const auto& g) {
        if (v)
            g(std::true_type{});
        else
            g(std::false_type{});
    };
    pick(a,
         [&](auto A) { pick(b, [&](auto B) { pick(c, [&](auto C) { pick(d, [&](auto E) { f(A, B, C, E); }); }); }); });
}

/// Calls f with std::integral_constant<int, R> for R = 1 .. kMaxLanes.
template <class F>
void withLanes(int R, const F& f)
{
    switch (R) {
        case 1:
            return f(std::integral_constant<int, 1>{});
        case 2:
            return f(std::integral_constant<int, 2>{});
        case 3:
            return f(std::integral_constant<int, 3>{});
        case 4:
            return f(std::integral_constant<int, 4>{});
        case 5:
            return f(std::integral_constant<int, 5>{});
        case 6:
            return f(std::integral_constant<int, 6>{});
        default:
            throw std::logic_error("PeriodicSolver: more right-hand sides than kMaxLanes");
    }
}
static_assert(kMaxLanes == 6, "withLanes covers 1 .. kMaxLanes");

}  // namespace

template <int D>
void PeriodicSolver<D>::chebyshevStep(const Level& L, const Real* b, const Real* t, Real* x, const Real* dIn,
                                      Real* dOut, Real c1, Real c2, bool keepX, int R) const
{
    const Real* diagInv = L.diagInv.data();
    const bool avx2 = useAvx2();
    (void)avx2;
    withFlags(t != nullptr, dIn != nullptr, dOut != nullptr, keepX, [&](auto kT, auto kIn, auto kOut, auto kKeep) {
        parallelRange(0, L.nodes(), 2048, [=](std::size_t i0, std::size_t i1) {
            if constexpr (D == 3) {
                constexpr bool T_ = decltype(kT)::value, In = decltype(kIn)::value, Out = decltype(kOut)::value,
                               Keep = decltype(kKeep)::value;
#ifdef VOXLAT_MG_AVX2
                if (avx2)
                    return avx2::chebyshevNodes<T_, In, Out, Keep>(diagInv, i0, i1, R, b, t, dIn, dOut, x, c1, c2);
#endif
                baseline::chebyshevNodes<T_, In, Out, Keep>(diagInv, i0, i1, R, b, t, dIn, dOut, x, c1, c2);
            } else {
                for (std::size_t i = i0; i < i1; ++i)
                    for (int q = 0; q < R; ++q) {
                        const std::size_t o = i * R + q;
                        Real r = b[o];
                        if constexpr (kT) r = b[o] - t[o];
                        Real dn = c2 * (diagInv[i] * r);
                        if constexpr (kIn) dn += c1 * dIn[o];
                        if constexpr (kOut) dOut[o] = dn;
                        if constexpr (kKeep)
                            x[o] = x[o] + dn;
                        else
                            x[o] = dn;
                    }
            }
        });
    });
}

template <int D>
template <int W>
void PeriodicSolver<D>::restrictResidual(const Level& L, const Level& C, const Real* b, const Real* t, Real* bc) const
{
    // bc = P^T (b - t), node by node on the coarse grid; W values a node (every right-hand side).
    parallelRange(0, C.nodes(), 1024, [&](std::size_t i0, std::size_t i1) {
        for (std::size_t i = i0; i < i1; ++i) {
            int c[3];
            C.coords(C.pointOfNode[i], c);
            Real s[W] = {};
            for (const auto& [fz, wz] : L.restrict[2][c[2]]) {
                if (fz < 0) continue;
                for (const auto& [fy, wy] : L.restrict[1][c[1]]) {
                    if (fy < 0) continue;
                    for (const auto& [fx, wx] : L.restrict[0][c[0]]) {
                        if (fx < 0) continue;
                        const std::int32_t node = L.nodeOfPoint[L.pointIndex(fx, fy, fz)];
                        if (node < 0) continue;
                        const Real w = Real(wx * wy * wz);
                        const Real* bv = b + std::size_t(node) * W;
                        const Real* tv = t + std::size_t(node) * W;
                        for (int j = 0; j < W; ++j) s[j] += w * (bv[j] - tv[j]);
                    }
                }
            }
            std::memcpy(bc + i * W, s, sizeof s);
        }
    });
}

template <int D>
template <int W>
void PeriodicSolver<D>::prolongAdd(const Level& L, const Level& C, const Real* xc, Real* x) const
{
    // x += P xc, node by node on the fine grid; W values a node.
    parallelRange(0, L.nodes(), 1024, [&](std::size_t i0, std::size_t i1) {
        for (std::size_t i = i0; i < i1; ++i) {
            int c[3];
            L.coords(L.pointOfNode[i], c);
            Real s[W] = {};
            for (const auto& [cz, wz] : L.prolong[2][c[2]]) {
                if (cz < 0) continue;
                for (const auto& [cy, wy] : L.prolong[1][c[1]]) {
                    if (cy < 0) continue;
                    for (const auto& [cx, wx] : L.prolong[0][c[0]]) {
                        if (cx < 0) continue;
                        const std::int32_t node = C.nodeOfPoint[C.pointIndex(cx, cy, cz)];
                        const Real w = Real(wx * wy * wz);
                        const Real* v = xc + std::size_t(node) * W;
                        for (int j = 0; j < W; ++j) s[j] += w * v[j];
                    }
                }
            }
            Real* out = x + i * W;
            for (int j = 0; j < W; ++j) out[j] += s[j];
        }
    });
}

template <int D>
void PeriodicSolver<D>::vcycle(std::size_t level, const Real* b, Real* x, int R) const
{
    const Level& L = *mLevels[level];
    if (level + 1 == mLevels.size()) {
        coarseSolve(L, b, x, R);
        return;
    }
    const Level& C = *mLevels[level + 1];
    smooth(L, b, x, true, R);
    // r = b - A x, then restricted to the coarse level (P^T, node by node on the coarse grid).
    L.apply(x, L.t.data(), R);
    // r = b - t, per value, is formed where the restriction reads it (the same float rounding).
    // A node's weighted sums, per value: s[j] += w v[j] from zero, in the order of the terms.
    const Real* t = L.t.data();
    Real* bc = C.b.data();
    withLanes(R, [&](auto lanes) { restrictResidual<decltype(lanes)::value * Level::S>(L, C, b, t, bc); });
    Real* xc = C.x.data();
    vcycle(level + 1, bc, xc, R);
    withLanes(R, [&](auto lanes) { prolongAdd<decltype(lanes)::value * Level::S>(L, C, xc, x); });
    smooth(L, b, x, false, R);
}

template <int D>
void PeriodicSolver<D>::apply(const Vector& x, Vector& y) const
{
    y.resize(dofs());
    mLevels[0]->apply(x.data(), y.data());
}

template <int D>
void PeriodicSolver<D>::assemble(const std::vector<double>& fe, Vector& f) const
{
    const Level& L = *mLevels[0];
    f.assign(dofs(), 0.0);
    L.forEachColour([&](std::size_t e) {
        for (int a = 0; a < 8; ++a)
            for (int k = 0; k < D; ++k) f[std::size_t(L.elemNodes[8 * e + a]) * D + k] += fe[a * D + k];
    });
}

template <int D>
double PeriodicSolver<D>::dot(const Vector& a, const Vector& b) const
{
    return blockedSums<1>(a.size(), [&](std::size_t i0, std::size_t i1, std::array<double, 1>& s) {
        double acc = 0.0;
        for (std::size_t i = i0; i < i1; ++i) acc += a[i] * b[i];
        s[0] = acc;
    })[0];
}

template <int D>
std::vector<double> PeriodicSolver<D>::dots(const std::vector<std::pair<const Vector*, const Vector*>>& pairs) const
{
    std::vector<double> total(pairs.size(), 0.0);
    if (pairs.empty()) return total;
    const std::size_t n = pairs[0].first->size();
    // Four sums at a time, each its own chain in dot()'s order and blocks (independent chains
    // overlap where one chain waits on its additions).
    constexpr int kChains = 4;
    for (std::size_t k0 = 0; k0 < pairs.size(); k0 += kChains) {
        const double* a[kChains];
        const double* b[kChains];
        for (int c = 0; c < kChains; ++c) {
            const auto& pr = pairs[std::min(k0 + c, pairs.size() - 1)];
            a[c] = pr.first->data();
            b[c] = pr.second->data();
        }
        const std::array<double, kChains> sums =
            blockedSums<kChains>(n, [&](std::size_t i0, std::size_t i1, std::array<double, kChains>& s) {
                double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
                for (std::size_t i = i0; i < i1; ++i) {
                    s0 += a[0][i] * b[0][i];
                    s1 += a[1][i] * b[1][i];
                    s2 += a[2][i] * b[2][i];
                    s3 += a[3][i] * b[3][i];
                }
                s = {s0, s1, s2, s3};
            });
        for (int c = 0; c < kChains && k0 + c < pairs.size(); ++c) total[k0 + c] = sums[c];
    }
    return total;
}

template <int D>
void PeriodicSolver<D>::removeTranslations(Vector& v) const
{
    std::vector<double> sum(std::size_t(mComponents) * D, 0.0);
    std::vector<std::int64_t> count(mComponents, 0);
    for (std::size_t i = 0; i < mNodeComponent.size(); ++i) {
        const std::int32_t c = mNodeComponent[i];
        ++count[c];
        for (int k = 0; k < D; ++k) sum[std::size_t(c) * D + k] += v[i * D + k];
    }
    for (int c = 0; c < mComponents; ++c)
        for (int k = 0; k < D; ++k)
            if (count[c] > 0) sum[std::size_t(c) * D + k] /= double(count[c]);
    for (std::size_t i = 0; i < mNodeComponent.size(); ++i)
        for (int k = 0; k < D; ++k) v[i * D + k] -= sum[std::size_t(mNodeComponent[i]) * D + k];
}

template <int D>
std::vector<typename PeriodicSolver<D>::Stats> PeriodicSolver<D>::solve(
    std::vector<Vector>& f, std::vector<Vector>& x, double tolerance, int maxIterations,
    const std::function<bool(double)>& progress) const
{
    const std::size_t n = dofs();
    const std::size_t systems = f.size();
    if (systems > std::size_t(kMaxLanes)) throw std::logic_error("PeriodicSolver::solve: too many right-hand sides");
    std::vector<Stats> stats(systems);
    x.assign(systems, Vector());
    // Per system: r (f itself), p, q, rz, |f|, |r|; active while it iterates. z = M^-1 r is read
    // where the V-cycle left it (doubles of floats: exact), right-hand side lane[k] of lanes.
    std::vector<Vector>& r = f;
    std::vector<Vector> p(systems), q(systems);
    std::vector<int> lane(systems, 0);
    int lanes = 0;
    std::vector<double> rz(systems, 0.0), alpha(systems, 0.0), fnorm(systems, 0.0), rnorm(systems, 0.0);
    std::vector<double> fraction(systems, 1.0);  // of the way to the tolerance (log scale); 1 when stopped
    std::vector<std::size_t> active;
    for (std::size_t k = 0; k < systems; ++k) {
        x[k].assign(n, 0.0);
        fnorm[k] = std::sqrt(dot(f[k], f[k]));
        if (fnorm[k] == 0.0) continue;
        rnorm[k] = fnorm[k];
        fraction[k] = 0.0;
        p[k].assign(n, 0.0);
        q[k].assign(n, 0.0);
        active.push_back(k);
    }
    const Level& L0 = *mLevels[0];
    // z = M^-1 r for every active system at once: system active[q] is right-hand side q of the
    // V-cycle, which gives each the bits it gives alone.
    constexpr int S = Level::S;
    auto precondition = [&]() {
        const int R = lanes = int(active.size());
        for (int h = 0; h < R; ++h) lane[active[h]] = h;
        for (const auto& level : mLevels) level->reserveLanes(R);
        parallelRange(0, L0.nodes(), 4096, [&](std::size_t i0, std::size_t i1) {
            for (int h = 0; h < R; ++h) {
                const double* rk = r[active[h]].data();
                for (std::size_t i = i0; i < i1; ++i)
                    for (int k = 0; k < D; ++k) L0.b[(i * R + h) * S + k] = Real(rk[i * D + k]);
            }
        });
        vcycle(0, L0.b.data(), L0.x.data(), R);
        // No projection of z onto the complement of translations: its null-space part is
        // harmless (A p ignores it) and the caller projects the solution.
    };
    // Runs f(i, z_i) over entries i0 .. i1 - 1 of system k's z, in order.
    auto forZ = [&](std::size_t k, std::size_t i0, std::size_t i1, const auto& f) {
        const Real* z = L0.x.data() + std::size_t(lane[k]) * S;
        const std::size_t stride = std::size_t(lanes) * S;
        std::size_t node = i0 / D;
        int d = int(i0 % D);
        for (std::size_t i = i0; i < i1; ++i) {
            f(i, double(z[node * stride + std::size_t(d)]));
            if (++d == D) {
                d = 0;
                ++node;
            }
        }
    };
    if (active.empty()) return stats;
    precondition();
    for (std::size_t k : active) {
        // p = z, and rz = dot(r, z).
        Vector &pk = p[k], &rk = r[k];
        rz[k] = blockedSums<1>(n, [&](std::size_t i0, std::size_t i1, std::array<double, 1>& s) {
            double acc = 0.0;
            forZ(k, i0, i1, [&](std::size_t i, double zi) {
                pk[i] = zi;
                acc += rk[i] * zi;
            });
            s[0] = acc;
        })[0];
    }
    const double logTarget = std::log(std::max(tolerance, 1e-300));
    while (!active.empty() && maxIterations > 0) {
        std::vector<std::size_t> going;
        for (std::size_t k : active) {
            Vector &xk = x[k], &rk = r[k], &pk = p[k], &qk = q[k];
            apply(pk, qk);
            const double pq = dot(pk, qk);
            fraction[k] = 1.0;
            if (!(pq > 0.0)) continue;  // breakdown: r is (numerically) in the null space
            const double a = alpha[k] = rz[k] / pq;
            // The update and |r|^2 in one pass (the same sum as dot(r, r)).
            rnorm[k] = std::sqrt(blockedSums<1>(n, [&](std::size_t i0, std::size_t i1, std::array<double, 1>& s) {
                double acc = 0.0;
                for (std::size_t i = i0; i < i1; ++i) {
                    xk[i] += a * pk[i];
                    rk[i] -= a * qk[i];
                    acc += rk[i] * rk[i];
                }
                s[0] = acc;
            })[0]);
            ++stats[k].iterations;
            if (rnorm[k] <= tolerance * fnorm[k] || stats[k].iterations >= maxIterations) continue;
            fraction[k] = std::clamp(std::log(std::max(rnorm[k] / fnorm[k], 1e-300)) / logTarget, 0.0, 1.0);
            going.push_back(k);
        }
        if (progress) {
            double sum = 0.0;
            for (const double v : fraction) sum += v;
            if (!progress(sum / double(systems))) throw Cancelled("homogenization cancelled");
        }
        active = std::move(going);
        if (active.empty()) break;
        precondition();
        for (std::size_t k : active) {
            const Vector &rk = r[k], &qk = q[k];
            Vector& pk = p[k];
            // Flexible (Polak-Ribiere) beta = z.(r_new - r_old) / rz_old, r_new - r_old = -alpha q:
            // robust to a preconditioner that is not exactly linear (single precision rounding).
            // dot(r, z) and dot(z, q) in one pass.
            const std::array<double, 2> sums =
                blockedSums<2>(n, [&](std::size_t i0, std::size_t i1, std::array<double, 2>& s) {
                    double rzs = 0.0, zq = 0.0;
                    forZ(k, i0, i1, [&](std::size_t i, double zi) {
                        rzs += rk[i] * zi;
                        zq += zi * qk[i];
                    });
                    s = {rzs, zq};
                });
            const double beta = std::max(0.0, -alpha[k] * sums[1] / rz[k]);
            rz[k] = sums[0];
            parallelRange(0, n, 8192, [&](std::size_t i0, std::size_t i1) {
                forZ(k, i0, i1, [&](std::size_t i, double zi) { pk[i] = zi + beta * pk[i]; });
            });
        }
    }
    for (std::size_t k = 0; k < systems; ++k) stats[k].relativeResidual = fnorm[k] > 0.0 ? rnorm[k] / fnorm[k] : 0.0;
    return stats;
}

template class PeriodicSolver<1>;
template class PeriodicSolver<3>;

}  // namespace voxlat::homogenization
