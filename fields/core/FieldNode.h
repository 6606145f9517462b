/// @file FieldNode.h
/// @brief The one interface every field node implements.
///
/// Sign convention everywhere: a value is negative inside the solid and positive outside
/// (OpenVDB's level-set convention). Nodes are immutable once they can be evaluated and safe to
/// evaluate from many threads at once. The one node made before all its numbers are known, a
/// LevelSolid whose level a density solve finds, refuses to be evaluated until its level is given,
/// and takes it once (LevelSolid::unsolved, solve): build, solve, then evaluate.
#pragma once

#include "fields/core/Interval.h"

#include <openvdb/math/Vec3.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <span>
#include <utility>

namespace voxlat {

using Vec3d = openvdb::math::Vec3<double>;

/// An axis-aligned box in world units (millimetres).
struct Box3 {
    Vec3d min{0.0};
    Vec3d max{0.0};

    Vec3d center() const { return 0.5 * (min + max); }
    Vec3d extent() const { return max - min; }
    /// Half the length of the diagonal: the largest distance from the centre to the box.
    double radius() const { return 0.5 * extent().length(); }
};

/// Where a field that does not repeat everywhere still does: inside @a box its solid (value <= 0)
/// repeats with @a period, cells aligned with @a phase. A finite frame of identical cells is such
/// a field: deeper inside its box than the struts' reach, the box's faces are out of sight.
struct RepeatZone {
    Vec3d period{0.0};
    Box3 box;
    Vec3d phase{0.0};  ///< a corner of one cell (the frame's origin)
};

/// Where a field's values repeat along one axis, though perhaps not everywhere: value(p + period
/// e_axis) = value(p), up to rounding, for every p with lo <= p[axis] and p[axis] + period <= hi
/// (whatever its other coordinates). A box frame of identical cells repeats along an axis between
/// its faces' zones (the faces out of the kernel's reach), also when its radii are graded along
/// another axis.
struct AxisRepeat {
    double period = 0.0;  ///< 0: no repeat known
    double lo = -std::numeric_limits<double>::infinity();
    double hi = std::numeric_limits<double>::infinity();
};

/// A regular block of sample points origin + (i*spacing.x, j*spacing.y, k*spacing.z) for
/// i < nx, j < ny, k < nz. Values are laid out with k fastest: offset = (i*ny + j)*nz + k, which
/// is the linear voxel order of an OpenVDB leaf when the block is one 8x8x8 leaf.
struct GridBatch {
    Vec3d origin{0.0};
    Vec3d spacing{1.0};
    int nx = 8, ny = 8, nz = 8;
    /// A stack of leaves (8 x 8 x 8m points, SparseOptions::stackLeaves): bit m set when the
    /// caller will not read leaf m's values (the points with k in [8m, 8m + 8)); a node may leave
    /// them unset (GridValueMemo serves a stack from the leaves it kept). 0: every value is read.
    /// Nodes that pass the batch on pass this on; a batch of another layout made from it clears it.
    std::uint32_t unread = 0;
    /// The caller needs the values as exact as the nodes make them: a cell's quantile, where
    /// values that differ in their last bits (mirror images) must stay apart. GridValueMemo then
    /// passes the operand's doubles through unrounded and unkept. Passed on like unread.
    bool exact = false;
    /// The voxel lattice the points lie on, where the caller knows it (SparseEvaluator's leaves
    /// and stacks, the density solve's coarse pass): point (i, j, k) is voxel latticeIndex +
    /// latticeStride (i, j, k) of the lattice whose voxel c is centred at latticeMin + voxel (c +
    /// 0.5), spacing the same along every axis and latticeStride voxels (voxel: latticeVoxel, the
    /// spacing where 0, as at stride 1; spacing / stride need not give its bits). A node may share
    /// work between the batches of one lattice (StrutConvolution's coarse nodes); it checks that
    /// origin is that voxel's centre (within a billionth of a voxel), so a node that moves the
    /// batch need not clear it. A node that passes on a part of the batch moves the index.
    bool onLattice = false;
    Vec3d latticeMin{0.0};
    std::array<int, 3> latticeIndex{0, 0, 0};
    int latticeStride = 1;
    double latticeVoxel = 0.0;
    /// The lattice's voxel (onLattice).
    double voxel() const { return latticeVoxel > 0.0 ? latticeVoxel : spacing.x(); }

    std::size_t size() const { return std::size_t(nx) * ny * nz; }
    Vec3d point(int i, int j, int k) const
    {
        return {origin.x() + i * spacing.x(), origin.y() + j * spacing.y(), origin.z() + k * spacing.z()};
    }
    /// The box spanned by the sample points.
    Box3 bounds() const { return {origin, point(nx - 1, ny - 1, nz - 1)}; }
};

/// A scalar field that can be evaluated in batches, differentiated and bounded.
class FieldNode {
public:
    virtual ~FieldNode() = default;

    /// Values at @a points; @a out has the same size.
    virtual void values(std::span<const Vec3d> points, std::span<double> out) const = 0;

    /// Values and analytic gradients at @a points.
    virtual void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const = 0;

    /// Values on a regular block of points. The default expands the block into points; nodes
    /// that can share work along the axes (separable TPMS terms) override it.
    virtual void gridValues(const GridBatch& batch, std::span<double> out) const;

    /// Values and gradients on a regular block of points (same layout as gridValues). The
    /// default expands the block into points; separable nodes (TPMS) override it.
    virtual void gridGradients(const GridBatch& batch, std::span<double> out, std::span<Vec3d> grad) const;

    /// Values at the block's points moved both ways by a per-point shift (same layout):
    /// plus[n] = value(p_n + shift[n]), minus[n] = value(p_n - shift[n]). The default forms the
    /// 2N points; a TPMS reuses its per-axis terms through the angle-addition formulas.
    virtual void gridValuesShifted(const GridBatch& batch, std::span<const Vec3d> shift, std::span<double> plus,
                                   std::span<double> minus) const;

    /// A conservative bound of the value over @a box: every value inside lies in the interval.
    virtual Interval bound(const Box3& box) const = 0;

    /// True only when values the node already holds prove that any bound over @a box meets
    /// @a band: a point of the box valued at least band.lo and one valued at most band.hi (the
    /// same or two). The sparse cull then takes the box as straddling without its bound. False:
    /// nothing known (the default).
    virtual bool meets(const Box3& box, const Interval& band) const
    {
        (void)box;
        (void)band;
        return false;
    }

    /// An interval holding every value a grid would hold at the points of @a points (a box of
    /// lattice points: origin, spacing, nx x ny x nz), when values the node already holds give
    /// all of them (a density solve's grid of its own values kept for the grids at its level;
    /// their range, or wider): the sparse cull then decides a leaf from it, not from a bound
    /// over the box between the points (a grid reads the field at its points alone). None: not
    /// all held (the default).
    virtual std::optional<Interval> heldRange(const GridBatch& points) const
    {
        (void)points;
        return std::nullopt;
    }

    /// A box outside which the field is positive (the solid lies inside it), or none when the
    /// solid is unbounded (a bare lattice). The engine uses it for the domain when none is given.
    virtual std::optional<Box3> support() const { return std::nullopt; }

    /// The field's translation period along @a axis (0, 1, 2 for x, y, z): a length P with
    /// value(p + P e_axis) = value(p) for every p; kNoPeriod when the node does not know one,
    /// kInvariant when the value never changes along the axis. Composite nodes derive it from
    /// their operands (commonPeriod()); the slicer copies layers one z-period apart.
    virtual double period(int axis) const
    {
        (void)axis;
        return kNoPeriod;
    }
    static constexpr double kNoPeriod = 0.0;

    /// Where the values repeat along @a axis (AxisRepeat): by default everywhere with period()
    /// when that is a finite length, else nowhere. The slicer copies pixel rows a whole number of
    /// periods apart within a layer.
    virtual AxisRepeat axisRepeat(int axis) const
    {
        const double p = period(axis);
        return p > 0.0 && std::isfinite(p) ? AxisRepeat{p} : AxisRepeat{};
    }

    /// Where the solid repeats though the field has no period (RepeatZone); none by default.
    /// Lattice properties take their cell from it when period() gives none.
    virtual std::optional<RepeatZone> repeatZone() const { return std::nullopt; }
    static constexpr double kInvariant = std::numeric_limits<double>::infinity();

    /// Convenience single-point queries (slow path; batches are the fast path).
    double value(const Vec3d& p) const;
    std::pair<double, Vec3d> valueAndGradient(const Vec3d& p) const;
};

using FieldPtr = std::shared_ptr<const FieldNode>;

/// Largest batch composite nodes process at once (one VDB leaf).
inline constexpr std::size_t kBatchSize = 512;

/// Calls fn(begin, count) over [0, n) in chunks of at most kBatchSize.
template <typename Fn>
void forEachChunk(std::size_t n, Fn&& fn)
{
    for (std::size_t b = 0; b < n; b += kBatchSize) fn(b, std::min(kBatchSize, n - b));
}

/// A batch's values point by point from the elements near it: gather(box) once per run of its
/// points along z (the points of the run in @a box), then out[n] = value(point) for the run's
/// points. A stack of leaves (nz = 8m, SparseOptions::stackLeaves) runs leaf by leaf, and its
/// leaves GridBatch::unread names are set to zero without a value; any other batch is one run.
/// For nodes that scan what they gather for each point: a stack's box is m leaves tall, so
/// each of its points would scan m leaves' worth.
template <typename Gather, typename Value>
void pointValuesBySlab(const GridBatch& batch, std::span<double> out, Gather&& gather, Value&& value)
{
    const int slab = batch.nz > 8 && batch.nz % 8 == 0 ? 8 : batch.nz;
    for (int k0 = 0; k0 < batch.nz; k0 += slab) {
        const bool unread = slab == 8 && k0 / 8 < 32 && ((batch.unread >> (k0 / 8)) & 1u) != 0;
        if (!unread) {
            GridBatch run = batch;  // the run's points as a batch of their own (the whole batch: itself)
            run.origin = batch.point(0, 0, k0);
            run.nz = slab;
            gather(run.bounds());
        }
        for (int i = 0; i < batch.nx; ++i)
            for (int j = 0; j < batch.ny; ++j) {
                const std::size_t row = (std::size_t(i) * batch.ny + j) * batch.nz;
                for (int k = k0; k < k0 + slab; ++k) out[row + k] = unread ? 0.0 : value(batch.point(i, j, k));
            }
    }
}

/// A period shared by two fields that repeat with periods @a a and @a b (FieldNode::period()):
/// the other one where either is invariant, the larger where it is a whole multiple of the
/// smaller (to 1e-9 relative), otherwise kNoPeriod.
double commonPeriod(double a, double b);

/// A bound from a Lipschitz constant: value(centre) +- lipschitz * radius.
Interval lipschitzBound(const FieldNode& node, const Box3& box, double lipschitz);

}  // namespace voxlat
