/// @file TriangleCheck.h
/// @brief Whether a triangle stays within a tolerance of a level set, from the signed distances
/// at its corners, edge midpoints and centre: the test decimation makes of every new triangle and
/// refinement of every triangle it keeps.
#pragma once

#include "fields/FieldNode.h"

#include <openvdb/Types.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <optional>

namespace voxlat {

/// A bound on |q| over a triangle, for the quadratic q through the corner values @a s and the
/// edge-midpoint values @a m (m[i] between corners i and i + 1). The decimation's check passes a
/// triangle on it and samples q only where it does not: a triangle the bound passes passes any
/// sampling of q.
double quadraticBound(const std::array<double, 3>& s, const std::array<double, 3>& m);

/// Whether coordinate @a x (of a mesh point, stored in float) lies on a face of @a box across axis
/// @a a: the face's plane as a float (a box at 5.6 mm has its faces' points at 5.5999999).
inline bool onBoxPlane(double x, const Box3& box, int a)
{
    return x == double(float(box.min[a])) || x == double(float(box.max[a]));
}

/// Whether every point of the triangle with corners @a p stays within @a tolerance of the solid:
/// the quadratic q through the field's signed distances at the corners @a s and edge midpoints
/// @a m (m[i] between corners i and i + 1) is bounded over the triangle (quadraticBound(), else
/// sampled on a 6-step grid), and the centre's miss of it (@a centre, the field's distance
/// there) is added as a margin. With @a box (the solid is also inside it; every corner is): a
/// triangle on one of its faces (all corners on the face's plane) is on the solid's boundary
/// wherever the field is inside: q goes through the positive parts of the distances there. Any other triangle is inside
/// the box, where the solid's distance max(q, box) is at most |q| and comes as close to it as one
/// likes next to a face (a crease): |q| counts, the box's distance never helps. (Decimation
/// sampled max(q, box) there before: 6 steps missed the kink where the two meet, and a triangle
/// along a crease strayed 0.0125 mm at a 0.01 mm tolerance.)
inline bool triangleWithin(const std::array<openvdb::Vec3d, 3>& p, std::array<double, 3> s, std::array<double, 3> m,
                           double centre, const std::optional<Box3>& box, double tolerance)
{
    bool onFace = false;
    if (box)
        for (int a = 0; a < 3 && !onFace; ++a)
            onFace = p[0][a] == p[1][a] && p[1][a] == p[2][a] && onBoxPlane(p[0][a], *box, a);
    if (onFace) {
        // The solid's distance there is max(f, 0): the quadratic goes through that (deep inside,
        // where the field is far from quadratic, it is 0).
        for (int i = 0; i < 3; ++i) {
            s[i] = std::max(s[i], 0.0);
            m[i] = std::max(m[i], 0.0);
        }
        centre = std::max(centre, 0.0);
    }
    // Quadratic through corners s_i and midpoints m_i (m_0 between corners 0 and 1).
    auto quadratic = [&](double l0, double l1, double l2) {
        return s[0] * l0 * (2 * l0 - 1) + s[1] * l1 * (2 * l1 - 1) + s[2] * l2 * (2 * l2 - 1) +
               4 * (m[0] * l0 * l1 + m[1] * l1 * l2 + m[2] * l2 * l0);
    };
    const double margin = std::abs(centre - quadratic(1.0 / 3, 1.0 / 3, 1.0 / 3));
    if (margin > tolerance) return false;
    if (quadraticBound(s, m) * (1.0 + 1e-12) + margin <= tolerance) return true;
    constexpr int kSteps = 6;
    double largest = 0.0;
    for (int i = 0; i <= kSteps; ++i)
        for (int j = 0; i + j <= kSteps; ++j)
            largest = std::max(
                largest, std::abs(quadratic(double(i) / kSteps, double(j) / kSteps, 1.0 - double(i + j) / kSteps)));
    return largest + margin <= tolerance;
}

}  // namespace voxlat
