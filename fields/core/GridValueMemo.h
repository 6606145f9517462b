/// @file GridValueMemo.h
/// @brief A field that can keep its operand's grid values for a while: the same batch asked
/// again (the job's evaluations of the grid at a moved level) is served from memory.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/core/PlaneBands.h"

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <unordered_map>
#include <vector>

namespace voxlat {

/// Passes everything to its operand. While keeping (keep(true)), each gridValues() batch's
/// values are stored, up to a byte budget, and a batch equal to a stored one (same origin,
/// spacing and size) is copied from the store instead of evaluated: the same doubles, since an
/// operand's gridValues gives the same values for the same batch. A density-solved solid sits
/// above it (LevelSolid(GridValueMemo(raw))): the job moves the level between evaluations of the
/// same leaves, and only the level's subtraction is redone. Off, it is a plain pass-through.
class GridValueMemo final : public FieldNode, public PlaneBands {
public:
    explicit GridValueMemo(FieldPtr operand) : mOperand(std::move(operand)) {}

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
    Interval bound(const Box3& box) const override { return mOperand->bound(box); }
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
    std::optional<RepeatZone> repeatZone() const override { return mOperand->repeatZone(); }

    /// Starts keeping batches' values (at most @a maxBytes of them), or stops and frees them.
    /// Called between evaluations, never during one.
    void keep(bool on, std::size_t maxBytes = 0) const;
    /// Bytes of values kept now.
    std::size_t keptBytes() const;

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
    struct Shard {
        std::mutex mutex;
        std::unordered_map<Key, std::vector<double>, KeyHash> values;
    };

    FieldPtr mOperand;
    mutable std::unique_ptr<std::array<Shard, kShards>> mShards;  ///< set while keeping
    mutable std::size_t mMaxBytes = 0;
    mutable std::atomic<std::size_t> mBytes{0};
};

}  // namespace voxlat
