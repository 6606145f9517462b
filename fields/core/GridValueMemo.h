/// @file GridValueMemo.h
/// @brief A field that can keep its operand's grid values for a while: the same batch asked
/// again (the job's evaluations of the grid at a moved level) is served from memory.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/core/MappedBlock.h"
#include "fields/core/PlaneBands.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <memory_resource>
#include <mutex>
#include <optional>
#include <span>
#include <unordered_map>
#include <vector>

namespace voxlat {

/// Whole leaves of a GridValueMemo's own grid values (8 x 8 x 8 points at a grid's spacing,
/// x-major, z fastest, as floats) held by someone else: a density solve's grid of the memo's
/// values (engine: KeptGridLeaves), handed over instead of freed. Its leaves' values are the
/// memo's for the batches they were evaluated in (a stack of leaves' own batch).
class KeptLeaves {
public:
    virtual ~KeptLeaves() = default;
    /// Per leaf m of @a batch (8 x 8 x 8n points on the grid the leaves were evaluated on; its
    /// points k in [8m, 8m + 8)), into @a values[m]: its 512 values, or null when not held. All
    /// null when @a batch is not on that grid.
    virtual void leaves(const GridBatch& batch, std::span<const float*> values) const = 0;
    /// Frees the leaves for which @a unread (the leaf's batch, its values) is true; @a unread is
    /// called from several threads.
    virtual void dropIf(const std::function<bool(const GridBatch&, const float*)>& unread) = 0;
    /// Frees the leaves m of @a batch with bit m of @a leaves set (each served by leaves() just
    /// before, by the thread that calls this): leaves() then gives null for them. Each batch's
    /// leaves are freed by one caller, while other threads read other batches' leaves.
    virtual void release(const GridBatch& batch, std::uint32_t leaves) = 0;
    /// FieldNode::meets() from the values held (none: false).
    virtual bool meets(const Box3& box, const Interval& band) const
    {
        (void)box;
        (void)band;
        return false;
    }
    /// FieldNode::heldRange() from the values held (none: std::nullopt).
    virtual std::optional<Interval> heldRange(const GridBatch& points) const
    {
        (void)points;
        return std::nullopt;
    }
};

/// Passes everything to its operand, except that gridValues() gives the operand's grid values
/// rounded to float (the precision of the grid they end in), keeping or not. While keeping
/// (keep(true)), each gridValues() batch's values are stored as floats, up to a byte budget, and
/// a batch equal to a stored one (same origin, spacing and size) is copied from the store instead
/// of evaluated: the same values, since an operand's gridValues gives the same values for the same
/// batch, and whether a batch was kept (the budget, the order threads came in) changes nothing. A
/// density-solved solid sits above it (LevelSolid(GridValueMemo(raw))): the job moves the level
/// between evaluations of the same leaves, and only the level's subtraction is redone. Kept as
/// floats, a 50 mm wireframe's values take 0.5 GB instead of 1 GB. values(), gradients(), the
/// slicer's planes and batches asked GridBatch::exact (a cell's quantile, where rounding merges
/// mirror images' values: a capsule X cell then missed its density at 34 voxels) are the
/// operand's own. The values are kept in large blocks, which
/// keep(false) frees whole.
class GridValueMemo final : public FieldNode, public PlaneBands {
public:
    explicit GridValueMemo(FieldPtr operand) : mOperand(std::move(operand)) {}
    /// The field whose values it keeps.
    const FieldPtr& operand() const { return mOperand; }

    void values(std::span<const Vec3d> points, std::span<double> out) const override { mOperand->values(points, out); }
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override
    {
        mOperand->gradients(points, out, grad);
    }
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    void gridGradients(const GridBatch& batch, std::span<double> out, std::span<Vec3d> grad) const override
    {
        mOperand->gridGradients(batch, out, grad);
    }
    void gridValuesShifted(const GridBatch& batch, std::span<const Vec3d> shift, std::span<double> plus,
                           std::span<double> minus) const override
    {
        mOperand->gridValuesShifted(batch, shift, plus, minus);
    }
    /// The operand's bound; while keeping, each box's is kept too and a box asked again (the
    /// cull of every evaluation of the grid at a moved level: the same leaf boxes, bit for bit)
    /// is answered from memory, the same interval.
    Interval bound(const Box3& box) const override;
    /// From the leaves kept (keepLeaves()), when they hold values inside @a box that prove it.
    bool meets(const Box3& box, const Interval& band) const override;
    /// From the leaves kept (keepLeaves()), when they hold every point of @a points.
    std::optional<Interval> heldRange(const GridBatch& points) const override
    {
        return mLeaves ? mLeaves->heldRange(points) : std::nullopt;
    }
    /// The operand's planeValues (a slicer's planes are never kept); while keeping, gridValues
    /// with every tile 0.
    void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                     std::span<signed char> side, std::span<const TileNeed> need) const override
    {
        if (!mShards) {
            planeValuesOf(*mOperand, plane, tile, band, out, side, need);
            return;
        }
        gridValues(plane, out);
        std::fill(side.begin(), side.begin() + PlaneTiles::of(plane, tile).size(), static_cast<signed char>(0));
    }
    bool planeCheap() const override { return planeCheapOf(*mOperand); }
    std::optional<Box3> support() const override { return mOperand->support(); }
    double period(int axis) const override { return mOperand->period(axis); }
    AxisRepeat axisRepeat(int axis) const override { return mOperand->axisRepeat(axis); }
    std::optional<RepeatZone> repeatZone() const override { return mOperand->repeatZone(); }

    /// Starts keeping batches' values (at most @a maxBytes of them), or stops and frees them
    /// (and the leaves keepLeaves() gave). Called between evaluations, never during one.
    void keep(bool on, std::size_t maxBytes = 0) const;
    /// While keeping: serves batches from @a leaves as well (a batch whose every leaf read is
    /// held there takes those values), and keeps other batches' values up to @a maxBytes from
    /// now on. A density solve's grid of this memo's values, handed over (a 50 mm wireframe:
    /// 0.55 GB), so that the same values are not held twice while the solve measures them.
    /// Called between evaluations, never during one.
    void keepLeaves(std::unique_ptr<KeptLeaves> leaves, std::size_t maxBytes) const;
    /// The next evaluation is the last to read the leaves keepLeaves() gave (keep(false) follows
    /// it): the held leaves of each batch asked are freed once its values are given
    /// (KeptLeaves::release), so the grid that evaluation makes reuses their memory instead of
    /// pages fresh to the process. A batch asked again is served otherwise (the same values).
    /// Called between evaluations, never during one; keep() and keepLeaves() end it.
    void consumeLeaves() const { mConsume = mLeaves != nullptr; }
    /// Bytes of values kept now in the memo's own blocks (not counting keepLeaves()').
    std::size_t keptBytes() const;
    /// Bytes of memory mapped for them now (whole blocks).
    std::size_t mappedBytes() const;
    /// Drops the kept batches a grid of a level in @a levels would not read, and frees their
    /// memory: those whose operand bound over the batch's box grown by one spacing (as
    /// evaluateSparse() culls a leaf) misses @a levels. The batches kept and their values are
    /// unchanged; a dropped batch asked again is evaluated again (the same values). A stack of
    /// leaves (8 x 8 x 8m, SparseOptions::stackLeaves) is decided leaf by leaf: its leaves a grid
    /// in @a levels cannot read are dropped, and the stack is served from the others to a caller
    /// that reads none of the dropped ones (GridBatch::unread), else evaluated again. The values
    /// kept are moved to the front of their shard's blocks, in the order they lie there, and the
    /// blocks left empty are unmapped: no fresh pages are written. For a density solve that has
    /// bracketed its level (solveDensity()'s @a levelWithin): its band was evaluated wider.
    /// The leaves keepLeaves() gave are dropped by the same rule, leaf by leaf.
    /// Called between evaluations, never during one.
    void dropOutside(Interval levels) const;

private:
    struct Key {
        double ox, oy, oz, sx, sy, sz;
        int nx, ny, nz;
        bool operator==(const Key&) const = default;
    };
    struct KeyHash {
        std::size_t operator()(const Key& k) const;
    };
    static constexpr int kShards = 64;
    /// Values per block of kept values (2 MB, a huge page: 1024 leaves' batches).
    static constexpr std::size_t kBlockValues = MappedBlock::kHugePage / sizeof(float);
    /// A shard's values sit in blocks of kBlockDoubles and its map's nodes in a pool of large
    /// blocks, not one small allocation each: a batch's 4 KB and its node, allocated between the
    /// grid's leaves (evaluated in the same loop), left each leaf freed with the grid in a hole
    /// no page fits in, so the solve's freed grid could not go back to the system (a 50 mm
    /// frame: 0.4 GB). Blocks of one size, not growing ones: a shard's last block is partly
    /// used, and 64 of them growing past a megabyte held 0.1 GB more.
    /// A batch's kept values: all of them in its layout (dropped 0), or a stack's leaves not
    /// dropped (bit m of dropped: leaf m's values are gone), each as its 64 rows of 8 in turn.
    struct Kept {
        const float* values = nullptr;
        std::uint32_t dropped = 0;
    };
    struct BoxKey {
        double x0, y0, z0, x1, y1, z1;
        bool operator==(const BoxKey&) const = default;
    };
    struct BoxKeyHash {
        std::size_t operator()(const BoxKey& k) const;
    };
    struct Shard {
        std::mutex mutex;
        std::pmr::monotonic_buffer_resource nodes{std::size_t(1) << 16};
        std::pmr::unordered_map<Key, Kept, KeyHash> values{&nodes};            ///< into blocks
        std::pmr::unordered_map<BoxKey, Interval, BoxKeyHash> bounds{&nodes};  ///< the operand's bounds
        std::vector<MappedBlock> blocks;
        float* next = nullptr;  ///< the last block's first unused value
        std::size_t left = 0;   ///< values unused in the last block
    };

    /// Whether a grid at a level in @a levels may read the batch @a k (kept @a values): its
    /// values or else its bound over the box evaluateSparse() culls it by meet @a levels.
    bool readAt(const Key& k, const float* values, Interval levels) const;
    /// The leaves of stack @a k whose values no grid at a level in @a levels reads (bit m: leaf
    /// m; readAt() of each leaf, its values gathered from @a kept), @a kept's dropped among them.
    std::uint32_t unreadLeaves(const Key& k, const Kept& kept, Interval levels) const;
    /// Row @a ij (its 8 values along z) of leaf @a m of stack @a k as @a kept holds it (leaf m not
    /// dropped): in the batch's layout, or among the kept leaves' rows in turn once some are dropped.
    static const float* keptRow(const Key& k, const Kept& kept, int m, std::size_t ij)
    {
        if (kept.dropped == 0) return kept.values + ij * std::size_t(k.nz) + 8 * std::size_t(m);
        const int before = std::popcount(kept.dropped & ((std::uint32_t(1) << m) - 1u));
        return kept.values + (std::size_t(m - before) * 64 + ij) * 8;
    }
    /// The bits of a stack's @a count leaves (bit m: leaf m), @a count from 1 to 32.
    static std::uint32_t allLeaves(int count)
    {
        return count == 32 ? ~std::uint32_t(0) : (std::uint32_t(1) << count) - 1u;
    }
    /// Whether @a k is a stack of leaves (8 x 8 x 8m points, m from 2 to 32).
    static bool isStack(const Key& k) { return k.nx == 8 && k.ny == 8 && k.nz % 8 == 0 && k.nz >= 16 && k.nz <= 256; }
    /// Room for @a n values in @a shard's blocks (its mutex held).
    static float* place(Shard& shard, std::size_t n);
    /// Copies @a batch's values from mLeaves when it holds every leaf of the batch its caller
    /// reads; false (nothing written) otherwise.
    bool fromLeaves(const GridBatch& batch, std::span<double> out) const;
    /// The key of @a batch's values.
    static Key keyOf(const GridBatch& batch)
    {
        return {batch.origin.x(),  batch.origin.y(), batch.origin.z(), batch.spacing.x(), batch.spacing.y(),
                batch.spacing.z(), batch.nx,         batch.ny,         batch.nz};
    }
    /// Writes leaf @a m of a stack @a nz points tall into @a out (the stack's layout), its rows
    /// of 8 values row(ij) for ij in [0, 64).
    template <class Row>
    static void putLeaf(std::span<double> out, int nz, int m, Row row)
    {
        for (std::size_t ij = 0; ij < 64; ++ij) {
            const float* r = row(ij);
            std::copy(r, r + 8, out.begin() + std::ptrdiff_t(ij * std::size_t(nz) + 8 * std::size_t(m)));
        }
    }

    FieldPtr mOperand;
    mutable std::unique_ptr<std::array<Shard, kShards>> mShards;  ///< set while keeping
    mutable std::unique_ptr<KeptLeaves> mLeaves;                  ///< keepLeaves()', while keeping
    mutable bool mConsume = false;                                ///< consumeLeaves()
    mutable std::size_t mMaxBytes = 0;
    mutable std::atomic<std::size_t> mBytes{0};
};

}  // namespace voxlat
