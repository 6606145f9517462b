/// @file HeldGridField.h
/// @brief A field read back from a grid already evaluated: trilinear between its leaves' voxels,
/// the field itself where the grid holds no leaf.
#pragma once

#include "fields/core/FieldNode.h"

#include <openvdb/openvdb.h>

namespace voxlat {

/// value(p) is the trilinear interpolation of @a grid's voxel values around p (voxel centres at
/// the grid's transform's index points) where all eight of those voxels lie in leaves of the
/// grid, and @a field's value elsewhere (tiles hold no values of the field, only its side).
/// For a coarse look at a result whose fine grid is held (report.html's picture of a streamed
/// mesh): the 50 mm wireframe's 63^3 picture took 0.18 s, where evaluating its struts again
/// took 0.55 s. The caller vouches that the grid's leaves hold @a field's values
/// (those a sparse evaluation of it made): bound(), support() and gradients() are the field's.
class HeldGridField final : public FieldNode {
public:
    HeldGridField(FieldPtr field, openvdb::FloatGrid::ConstPtr grid);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    /// As values(), the points no leaf covers taken in runs along z as batches of the field's.
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override
    {
        mField->gradients(points, out, grad);
    }
    Interval bound(const Box3& box) const override { return mField->bound(box); }
    /// True where two voxels of the grid's leaves with their centres in @a box prove it: one
    /// valued at least band.lo, one at most band.hi (a cull then takes no bound of the field's:
    /// they were most of the wireframe's picture).
    bool meets(const Box3& box, const Interval& band) const override;
    std::optional<Box3> support() const override { return mField->support(); }

private:
    FieldPtr mField;
    openvdb::FloatGrid::ConstPtr mGrid;
};

}  // namespace voxlat
