/// @file Multigrid.h
/// @brief Matrix-free periodic voxel finite-element operator and its multigrid-preconditioned CG
/// solver (internal to properties).
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <utility>
#include <vector>

namespace voxlat::homogenization {

/// The periodic finite-element system of a voxel cell with D unknowns per node (3: displacement,
/// 1: temperature), one element per solid voxel, all elements sharing one element matrix.
///
/// Nodes are the grid points touched by a solid voxel, numbered in grid order; unknown d of node
/// i is entry i*D + d of a vector. The operator is applied element by element (gather, multiply,
/// scatter) layer by layer: the z layers of voxels are coloured by the parity of z (a third
/// colour for the last layer of an odd count, which touches the first one periodically), so
/// layers of one colour share no node and run in parallel without atomics, each layer's voxels
/// in order, and every node sums its contributions in the same order for any thread count. Dot
/// products sum fixed blocks in a fixed order. Every result is therefore bit-identical for any
/// number of threads.
///
/// On the finest grid the element product goes through the voxel's mirror symmetry: an 8-point
/// Walsh-Hadamard transform per unknown block-diagonalises the element matrix into 8 blocks of
/// D x D (Level::setReflectionBlocks), a quarter of the dense product's flops. The element
/// products (MultigridKernels.h) also have an AVX2 build, run where the CPU has AVX2: no FMA, the
/// same operations lane by lane, the same bits.
///
/// The preconditioner is a multigrid V-cycle, in single precision. Coarse grids halve each axis (ceil(n/2): an odd axis
/// ends with a one-voxel-wide coarse element); the coarse operators are Galerkin products P^T A P
/// with trilinear interpolation P, formed element by element: a coarse voxel's matrix is the sum
/// over its non-empty children of P_c^T K_child P_c. Coarse voxels with the same children share one
/// matrix (at the first coarse level at most 2048 kinds), so memory stays proportional to the
/// solid voxels. Smoothing is Chebyshev (degree 2, 3 on coarse grids) on the nodal block-Jacobi preconditioned
/// operator, its upper eigenvalue found by a few power iterations; the coarsest grid (<= 64
/// points) is solved by a dense Cholesky factorisation.
///
/// The system is singular: each connected component may translate rigidly (and a component that
/// wraps along one axis only may also rotate about it; components touching only along a voxel
/// edge or at a corner can hinge). Every such mode carries no strain, so a load built from a
/// macroscopic strain is orthogonal to all of them: the system is consistent, and CG converges in
/// the range of the operator. The coarsest factorisation drops pivots below 1e-10 of their
/// diagonal (a generalized inverse, symmetric), and component translations are projected out of
/// loads and solutions to keep rounding from accumulating there.
template <int D>
class PeriodicSolver {
public:
    using Vector = std::vector<double>;

    /// @a n: voxels per axis; @a label: per voxel, its component (>= 0) if it is a solid element,
    /// -1 otherwise; @a elementMatrix: the (8D)^2 row-major symmetric element matrix.
    PeriodicSolver(const std::array<int, 3>& n, const std::vector<std::int32_t>& label, int components,
                   const std::vector<double>& elementMatrix);
    ~PeriodicSolver();

    std::size_t dofs() const;
    std::size_t elements() const;
    int levels() const;

    /// y = A x.
    void apply(const Vector& x, Vector& y) const;
    /// f = the sum over elements of the element vector @a fe (8D values) at the element's nodes.
    void assemble(const std::vector<double>& fe, Vector& f) const;
    /// Deterministic dot product.
    double dot(const Vector& a, const Vector& b) const;
    /// Several dot products in one pass: entry k is dot(*pairs[k].first, *pairs[k].second), bit
    /// for bit.
    std::vector<double> dots(const std::vector<std::pair<const Vector*, const Vector*>>& pairs) const;
    /// Removes from @a v, per component and per unknown, its mean over the component's nodes.
    void removeTranslations(Vector& v) const;

    struct Stats {
        int iterations = 0;
        double relativeResidual = 0.0;  ///< of the CG recurrence; the caller checks the true one
    };
    /// Solves A x_k = f_k for several right-hand sides (at most 6; each x_k starts at 0), each
    /// until |r_k| <= tolerance |f_k|, by CG in lockstep: one V-cycle serves every system still
    /// iterating, each of them a right-hand side of its own that takes the same operations as
    /// alone, so every system's iterates are the bits it would get solved by itself. @a f is
    /// used up (it holds the residuals). @a progress receives the mean fraction of the way to
    /// the tolerance (log scale) after each iteration; false cancels (throws voxlat::Cancelled).
    std::vector<Stats> solve(std::vector<Vector>& f, std::vector<Vector>& x, double tolerance, int maxIterations,
                             const std::function<bool(double)>& progress) const;

private:
    /// Precision of the preconditioner. Single: twice the SIMD width and half the memory traffic
    /// of the dominant element loop. CG itself runs in double (residuals, iterates, the operator)
    /// with a flexible (Polak-Ribiere) beta that tolerates the preconditioner's rounding, so the
    /// final accuracy does not depend on it.
    using Real = float;
    struct Level;
    void buildHierarchy();
    // The preconditioner on R right-hand sides at once: right-hand side q of node i at
    // (i * R + q) * S (see Level).
    void vcycle(std::size_t level, const Real* b, Real* x, int R) const;
    void smooth(const Level& L, const Real* b, Real* x, bool zeroStart, int R) const;
    /// d = c1 dIn + c2 diag^-1 (b - t) (no dIn: c1 unused; no t: b), stored in dOut if given;
    /// x = x + d, or d without keepX.
    void chebyshevStep(const Level& L, const Real* b, const Real* t, Real* x, const Real* dIn, Real* dOut, Real c1,
                       Real c2, bool keepX, int R) const;
    void coarseSolve(const Level& L, const Real* b, Real* x, int R) const;
    /// The transfers with W values a node (every right-hand side): bc = P^T (b - t), x += P xc.
    template <int W>
    void restrictResidual(const Level& L, const Level& C, const Real* b, const Real* t, Real* bc) const;
    template <int W>
    void prolongAdd(const Level& L, const Level& C, const Real* xc, Real* x) const;

    std::vector<std::unique_ptr<Level>> mLevels;
    std::vector<std::int32_t> mNodeComponent;
    int mComponents = 0;
    std::vector<double> mCoarseFactor;         ///< dense lower-triangular factor of the coarsest level
    std::vector<std::uint8_t> mCoarseDropped;  ///< pivots treated as zero (null space)
};

extern template class PeriodicSolver<1>;
extern template class PeriodicSolver<3>;

}  // namespace voxlat::homogenization
