/// @file TriangleCheck.h
/// @brief Whether a triangle stays within a tolerance of a level set, from the signed distances
/// at its corners, edge midpoints and centre: the test decimation makes of every new triangle and
/// refinement of every triangle it keeps.
#pragma once

#include "fields/core/FieldNode.h"
#include "mesher/extract/TriangleMesh.h"

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
    return x == roundedToFloat(box.min[a]) || x == roundedToFloat(box.max[a]);
}

/// Whether the triangle with corners @a p lies on a face of @a box (every corner on the face's
/// plane): there the solid's distance is max(f, 0), and TriangleQuadratic takes the positive parts.
inline bool onBoxFace(const std::array<openvdb::Vec3d, 3>& p, const std::optional<Box3>& box)
{
    bool onFace = false;
    if (box)
        for (int a = 0; a < 3 && !onFace; ++a)
            onFace = p[0][a] == p[1][a] && p[1][a] == p[2][a] && onBoxPlane(p[0][a], *box, a);
    return onFace;
}

/// TriangleQuadratic's arithmetic on plain numbers, without branches: the refinement runs it over
/// structure-of-arrays batches, which the compiler then takes two triangles at a time (the same
/// operations in the same order: the same bits as one at a time).
namespace quadratic {

/// q at the centre, for corner values @a s0.. and edge-midpoint values @a m0.. (m0 between
/// corners 0 and 1).
inline double atCentre(double s0, double s1, double s2, double m0, double m1, double m2)
{
    constexpr double l = 1.0 / 3;
    return s0 * l * (2 * l - 1) + s1 * l * (2 * l - 1) + s2 * l * (2 * l - 1) +
           4 * (m0 * l * l + m1 * l * l + m2 * l * l);
}

/// How far the midpoint value @a mi of the edge from corner value @a si to @a sj lies off the
/// chord between its ends: the edge's bend.
inline double bend(double si, double sj, double mi)
{
    return std::abs(mi - 0.5 * (si + sj));
}

/// |q| at its stationary point along the edge from corner value @a si to @a sj (midpoint @a mi)
/// where that lies inside the edge, else 0.
inline double edgeExtremum(double si, double sj, double mi)
{
    // Along the edge: si + (4 mi - 3 si - sj) t + 2 (si + sj - 2 mi) t^2.
    const double linear = 4 * mi - 3 * si - sj;
    const double square = 2 * (si + sj - 2 * mi);
    const double t = -linear / (2 * square);  // not finite where square is 0: not inside
    const double value = std::abs(si + (linear + square * t) * t);
    return t > 0.0 && t < 1.0 ? value : 0.0;
}

/// The largest |q| over the triangle: at a corner, where q is stationary along an edge, or where
/// it is stationary inside.
inline double largest(double s0, double s1, double s2, double m0, double m1, double m2)
{
    // q(u, v) = a + b u + c v + d u^2 + e u v + f v^2 with u = l0, v = l1 (corner 2 at 0).
    const double a = s2, b = 4 * m2 - 3 * s2 - s0, c = 4 * m1 - 3 * s2 - s1;
    const double d = 2 * (s0 + s2) - 4 * m2, f = 2 * (s1 + s2) - 4 * m1;
    const double e = 4 * (m0 - a) - 2 * (b + c) - (d + f);
    double most = std::max(std::max(std::abs(s0), std::abs(s1)), std::abs(s2));
    most = std::max(most, edgeExtremum(s0, s1, m0));
    most = std::max(most, edgeExtremum(s1, s2, m1));
    most = std::max(most, edgeExtremum(s2, s0, m2));
    // Inside: [2d e; e 2f] (u, v) = -(b, c).
    const double det = 4 * d * f - e * e;
    const double u = (-2 * f * b + e * c) / det, v = (-2 * d * c + e * b) / det;  // not finite where det is 0
    const double inside = std::abs(a + b * u + c * v + d * u * u + e * u * v + f * v * v);
    return u > 0.0 && v > 0.0 && u + v < 1.0 ? std::max(most, inside) : most;
}

/// The mean of q squared over the triangle: exact, by the quadratic element's mass matrix
/// (corners 6, corner with corner -1, corner with the opposite midpoint -4, midpoint 32,
/// midpoint with midpoint 16, over 180).
inline double meanSquare(double s0, double s1, double s2, double m0, double m1, double m2)
{
    const double corners = 6.0 * (s0 * s0 + s1 * s1 + s2 * s2) - 2.0 * (s0 * s1 + s1 * s2 + s2 * s0);
    const double midpoints = 32.0 * (m0 * m0 + m1 * m1 + m2 * m2) + 32.0 * (m0 * m1 + m1 * m2 + m2 * m0);
    const double mixed = -8.0 * (s0 * m1 + s1 * m2 + s2 * m0);  // corner i faces the midpoint of edge (i + 1, i + 2)
    return std::max(0.0, (corners + midpoints + mixed) / 180.0);
}

}  // namespace quadratic

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
        if (onBoxFace(p, box)) {
            // The solid's distance there is max(f, 0): the quadratic goes through that (deep
            // inside, where the field is far from quadratic, it is 0).
            for (int i = 0; i < 3; ++i) {
                mS[i] = std::max(mS[i], 0.0);
                mM[i] = std::max(mM[i], 0.0);
            }
            centre = std::max(centre, 0.0);
        }
        mMargin = std::abs(centre - quadratic::atCentre(mS[0], mS[1], mS[2], mM[0], mM[1], mM[2]));
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
    double bend(int i) const { return quadratic::bend(mS[i], mS[(i + 1) % 3], mM[i]); }

    /// A bound on |q| over the triangle (quadraticBound()).
    double bound() const { return quadraticBound(mS, mM); }

    /// The largest |q| over the triangle, exactly: at a corner, where q is stationary along an
    /// edge, or where it is stationary inside.
    double largest() const { return quadratic::largest(mS[0], mS[1], mS[2], mM[0], mM[1], mM[2]); }

    /// The mean of q squared over the triangle (quadratic::meanSquare()).
    double meanSquare() const { return quadratic::meanSquare(mS[0], mS[1], mS[2], mM[0], mM[1], mM[2]); }

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
