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

/// The quadratic q through a triangle's signed distances at its corners @a s and edge midpoints
/// @a m (m[i] between corners i and i + 1), with the centre's miss of it (the field's distance
/// @a centre there against q's) as a margin. With @a box (the solid is also inside it; every corner
/// is): a triangle on one of its faces (all corners on the face's plane) is on the solid's boundary
/// wherever the field is inside: q goes through the positive parts of the distances there. Any
/// other triangle is inside the box, where the solid's distance max(q, box) is at most |q| and
/// comes as close to it as one likes next to a face (a crease): |q| counts, the box's distance
/// never helps. (Decimation sampled max(q, box) there before: 6 steps missed the kink where the two
/// meet, and a triangle along a crease strayed 0.0125 mm at a 0.01 mm tolerance.)
class TriangleQuadratic {
public:
    TriangleQuadratic(const std::array<openvdb::Vec3d, 3>& p, const std::array<double, 3>& s,
                      const std::array<double, 3>& m, double centre, const std::optional<Box3>& box)
        : mS(s), mM(m)
    {
        bool onFace = false;
        if (box)
            for (int a = 0; a < 3 && !onFace; ++a)
                onFace = p[0][a] == p[1][a] && p[1][a] == p[2][a] && onBoxPlane(p[0][a], *box, a);
        if (onFace) {
            // The solid's distance there is max(f, 0): the quadratic goes through that (deep
            // inside, where the field is far from quadratic, it is 0).
            for (int i = 0; i < 3; ++i) {
                mS[i] = std::max(mS[i], 0.0);
                mM[i] = std::max(mM[i], 0.0);
            }
            centre = std::max(centre, 0.0);
        }
        mMargin = std::abs(centre - at(1.0 / 3, 1.0 / 3, 1.0 / 3));
    }

    /// q at barycentric coordinates (l0, l1, l2).
    double at(double l0, double l1, double l2) const
    {
        return mS[0] * l0 * (2 * l0 - 1) + mS[1] * l1 * (2 * l1 - 1) + mS[2] * l2 * (2 * l2 - 1) +
               4 * (mM[0] * l0 * l1 + mM[1] * l1 * l2 + mM[2] * l2 * l0);
    }

    /// How far the centre's distance misses q.
    double margin() const { return mMargin; }

    /// How far q's value at the midpoint of edge @a i (corners i and i + 1) lies off the chord
    /// between its ends: the edge's bend (with the positive parts on a face).
    double bend(int i) const { return std::abs(mM[i] - 0.5 * (mS[i] + mS[(i + 1) % 3])); }

    /// A bound on |q| over the triangle (quadraticBound()).
    double bound() const { return quadraticBound(mS, mM); }

    /// The largest |q| over the triangle, exactly: at a corner, where q is stationary along an
    /// edge, or where it is stationary inside.
    double largest() const
    {
        // q(u, v) = a + b u + c v + d u^2 + e u v + f v^2 with u = l0, v = l1 (corner 2 at 0).
        const std::array<double, 3>&s = mS, &m = mM;
        const double a = s[2], b = 4 * m[2] - 3 * s[2] - s[0], c = 4 * m[1] - 3 * s[2] - s[1];
        const double d = 2 * (s[0] + s[2]) - 4 * m[2], f = 2 * (s[1] + s[2]) - 4 * m[1];
        const double e = 4 * (m[0] - a) - 2 * (b + c) - (d + f);
        double most = std::max({std::abs(s[0]), std::abs(s[1]), std::abs(s[2])});
        for (int i = 0; i < 3; ++i) {
            // Along edge i from corner i to i + 1: s_i + (4 m_i - 3 s_i - s_j) t + 2 (s_i + s_j - 2 m_i) t^2.
            const double linear = 4 * m[i] - 3 * s[i] - s[(i + 1) % 3];
            const double square = 2 * (s[i] + s[(i + 1) % 3] - 2 * m[i]);
            // The stationary point t = -linear / (2 square) lies on the edge only where the two
            // have opposite signs and |linear| < 2 |square|: divided only then (most are not).
            if (!(linear * square < 0.0 && std::abs(linear) < 2 * std::abs(square))) continue;
            const double t = -linear / (2 * square);
            if (t > 0.0 && t < 1.0) most = std::max(most, std::abs(s[i] + (linear + square * t) * t));
        }
        // Inside: [2d e; e 2f] (u, v) = -(b, c), u = U / det and v = V / det.
        const double det = 4 * d * f - e * e;
        const double numeratorU = -2 * f * b + e * c, numeratorV = -2 * d * c + e * b;
        const bool inside = det > 0.0 ? numeratorU > 0.0 && numeratorV > 0.0 && numeratorU + numeratorV < det
                                      : numeratorU < 0.0 && numeratorV < 0.0 && numeratorU + numeratorV > det;
        if (det != 0.0 && inside) {
            const double u = numeratorU / det, v = numeratorV / det;
            if (u > 0.0 && v > 0.0 && u + v < 1.0)
                most = std::max(most, std::abs(a + b * u + c * v + d * u * u + e * u * v + f * v * v));
        }
        return most;
    }

    /// The mean of q squared over the triangle: exact, by the quadratic element's mass matrix
    /// (corners 6, corner with corner -1, corner with the opposite midpoint -4, midpoint 32,
    /// midpoint with midpoint 16, over 180).
    double meanSquare() const
    {
        const std::array<double, 3>&s = mS, &m = mM;
        double corners = 0.0, midpoints = 0.0, mixed = 0.0;
        for (int i = 0; i < 3; ++i) {
            corners += 6.0 * s[i] * s[i] - 2.0 * s[i] * s[(i + 1) % 3];
            midpoints += 32.0 * m[i] * m[i] + 32.0 * m[i] * m[(i + 1) % 3];
            mixed -= 8.0 * s[i] * m[(i + 1) % 3];  // corner i faces the midpoint of edge (i + 1, i + 2)
        }
        return std::max(0.0, (corners + midpoints + mixed) / 180.0);
    }

private:
    std::array<double, 3> mS, mM;
    double mMargin = 0.0;
};

/// Whether every point of the triangle with corners @a p stays within @a tolerance of the solid:
/// the TriangleQuadratic through the distances @a s, @a m and @a centre is bounded over the
/// triangle (quadraticBound(), else its largest value), its margin added.
inline bool triangleWithin(const std::array<openvdb::Vec3d, 3>& p, const std::array<double, 3>& s,
                           const std::array<double, 3>& m, double centre, const std::optional<Box3>& box,
                           double tolerance)
{
    const TriangleQuadratic q(p, s, m, centre, box);
    if (q.margin() > tolerance) return false;
    if (q.bound() * (1.0 + 1e-12) + q.margin() <= tolerance) return true;
    return q.largest() + q.margin() <= tolerance;
}

}  // namespace voxlat
