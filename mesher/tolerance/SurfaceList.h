/// @file SurfaceList.h
/// @brief The surfaces that bound a solid (CreaseSurfaces: fields and the domain box's six faces)
/// as one indexed list, evaluated in batches; shared by crease splitting and refinement.
#pragma once

#include "mesher/tolerance/CreaseSplit.h"

#include <array>
#include <cmath>
#include <limits>
#include <optional>
#include <span>
#include <vector>

namespace voxlat {

/// The surfaces as one list: the fields first, then the box's faces (-x, +x, -y, +y, -z, +z),
/// each with a value that is negative inside (minus the level for the fields) and its gradient.
class SurfaceList {
public:
    SurfaceList(const CreaseSurfaces& s, double level) : mFields(s.fields), mBox(s.box), mLevel(level) {}

    int size() const { return int(mFields.size()) + (mBox ? 6 : 0); }

    /// Values (minus the level) and gradients of surface @a i at @a points, in batches.
    void evaluate(int i, std::span<const Vec3d> points, std::span<double> values, std::span<Vec3d> gradients) const
    {
        if (i < int(mFields.size())) {
            forEachChunk(points.size(), [&](std::size_t begin, std::size_t count) {
                mFields[i]->gradients(points.subspan(begin, count), values.subspan(begin, count),
                                      gradients.subspan(begin, count));
            });
            for (double& v : values) v -= mLevel;
            return;
        }
        const int face = i - int(mFields.size()), axis = face / 2;
        const bool upper = face % 2 == 1;
        Vec3d g(0.0);
        g[axis] = upper ? 1.0 : -1.0;
        for (std::size_t k = 0; k < points.size(); ++k) {
            values[k] = upper ? points[k][axis] - mBox->max[axis] : mBox->min[axis] - points[k][axis];
            gradients[k] = g;
        }
    }

private:
    std::vector<const FieldNode*> mFields;
    std::optional<Box3> mBox;
    double mLevel;
};

/// First-order distance |r| / |g| (infinite at a flat spot off the level).
inline double firstOrderDistance(double r, const Vec3d& g)
{
    const double length = g.length();
    if (length > 0.0) return std::abs(r) / length;
    return r == 0.0 ? 0.0 : std::numeric_limits<double>::infinity();
}

/// Solves the k x k system (k <= 3) A y = r by Cramer's rule; false when singular.
inline bool solveSmall(int k, const std::array<std::array<double, 3>, 3>& a, const std::array<double, 3>& r,
                       std::array<double, 3>& y)
{
    if (k == 1) {
        if (!(std::abs(a[0][0]) > 0.0)) return false;
        y[0] = r[0] / a[0][0];
        return true;
    }
    if (k == 2) {
        const double det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
        if (!(std::abs(det) > 1e-12 * std::abs(a[0][0] * a[1][1]))) return false;
        y[0] = (a[1][1] * r[0] - a[0][1] * r[1]) / det;
        y[1] = (a[0][0] * r[1] - a[1][0] * r[0]) / det;
        return true;
    }
    const double det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) -
                       a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0]) +
                       a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    if (!(std::abs(det) > 1e-12 * std::abs(a[0][0] * a[1][1] * a[2][2]))) return false;
    for (int c = 0; c < 3; ++c) {
        auto m = a;
        for (int row = 0; row < 3; ++row) m[row][c] = r[row];
        y[c] = (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])) /
               det;
    }
    return true;
}

}  // namespace voxlat
