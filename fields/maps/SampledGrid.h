/// @file SampledGrid.h
/// @brief Values given on a regular grid (from a file), interpolated linearly in between.
#pragma once

#include "fields/core/FieldNode.h"

#include <array>
#include <vector>

namespace voxlat {

/// A field known at the nodes of a rectilinear grid over one, two or three axes (an axis with a
/// single coordinate is constant along it), interpolated (tri)linearly; outside the grid the
/// nearest boundary value holds. Coordinates per axis are strictly increasing.
class SampledGridField final : public FieldNode {
public:
    /// @a coords[a] are the node coordinates along axis a (size 1 for an unused axis);
    /// @a values are laid out with z fastest: ((i * ny) + j) * nz + k.
    SampledGridField(std::array<std::vector<double>, 3> coords, std::vector<double> values);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    /// The range of the nodes of every cell the box touches.
    Interval bound(const Box3& box) const override;

    double minValue() const { return mMin; }
    double maxValue() const { return mMax; }

private:
    /// Cell index and fraction along axis a.
    void locate(int a, double u, std::size_t& i, double& t, bool& inside) const;
    double at(std::size_t i, std::size_t j, std::size_t k) const
    {
        return mValues[(i * mCoords[1].size() + j) * mCoords[2].size() + k];
    }

    std::array<std::vector<double>, 3> mCoords;
    std::vector<double> mValues;
    double mMin = 0.0, mMax = 0.0;
};

}  // namespace voxlat
