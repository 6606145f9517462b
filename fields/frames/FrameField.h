/// @file FrameField.h
/// @brief A frame field: a full orientation (three orthonormal axes) at every point (Aether's
/// frame fields), built from a direction field for the z axis and a reference for x.
#pragma once

#include "fields/maps/VectorField.h"

#include <openvdb/math/Mat3.h>

#include <array>
#include <memory>
#include <optional>
#include <string>

namespace voxlat {

using Mat3d = openvdb::math::Mat3<double>;

/// Bounds of a frame's entries over a box: entry[row][axis] bounds component `row` of `axis`.
using FrameBound = std::array<std::array<Interval, 3>, 3>;

/// R(p) = [ex ey ez] (columns) with ez = z(p)/|z(p)| and ex the reference x(p) made orthogonal
/// to ez (Gram-Schmidt), ey = ez x ex: a right-handed rotation at every point.
///
/// Without a reference the world x axis is used, or the world y axis where |ez . x| > 0.9 (ez
/// near x). Where a given reference is parallel to ez (|x - (x.ez) ez| <= 1e-6 |x|) that default
/// is used too. Both switches make the frame jump (a frame field on a sphere of directions
/// cannot be continuous everywhere); give a reference that stays away from z to avoid them. A z
/// direction that is zero or not finite at an evaluated point throws std::domain_error naming
/// the point.
class FrameField {
public:
    /// @a z: the direction of the frame's z axis; @a x: the reference for its x axis, or null
    /// for the default. @a label names the frame in errors ("field `twisted`").
    FrameField(std::shared_ptr<const VectorField> z, std::shared_ptr<const VectorField> x, std::string label);

    /// Frames at @a points; out[n](row, axis) is component `row` of axis `axis`.
    void frames(std::span<const Vec3d> points, std::span<Mat3d> out) const;
    /// Frames on a regular block (GridBatch layout); direction components use their grid fast path.
    void gridFrames(const GridBatch& batch, std::span<Mat3d> out) const;
    /// Frames and their exact partial derivatives: derivative[n][k] = dR/dp_k at points[n].
    void frameDerivatives(std::span<const Vec3d> points, std::span<Mat3d> out,
                          std::span<std::array<Mat3d, 3>> derivative) const;
    /// Conservative bounds of every entry of R over @a box, or none where the z direction (or
    /// the reference's part orthogonal to it) may vanish in the box.
    std::optional<FrameBound> bound(const Box3& box) const;

    const std::shared_ptr<const VectorField>& z() const { return mZ; }
    const std::shared_ptr<const VectorField>& x() const { return mX; }

private:
    /// Frames from the direction vectors (and reference vectors, may be null) of @a n points.
    void framesFromVectors(std::size_t n, const Vec3d* z, const Vec3d* x, const Vec3d* points, Mat3d* out) const;
    [[noreturn]] void zeroDirection(const Vec3d& p) const;

    std::shared_ptr<const VectorField> mZ, mX;
    std::string mLabel;
};

}  // namespace voxlat
