/// @file TriangleMesh.h
/// @brief The indexed triangle mesh every mesher stage produces and every writer consumes.
#pragma once

#include <openvdb/Types.h>

#include <vector>

namespace voxlat {

/// An indexed triangle mesh in world units (millimetres).
///
/// Triangles are counter-clockwise when seen from outside, so normals computed with the right-hand
/// rule point from the solid (negative field values) into the void (positive values).
struct TriangleMesh {
    std::vector<openvdb::Vec3f> points;
    std::vector<openvdb::Vec3I> triangles;

    /// Signed enclosed volume by the divergence theorem, accumulated in double. Positive for a
    /// closed, outward-oriented mesh; meaningless for an open one.
    double volume() const;

    /// Total surface area, accumulated in double.
    double area() const;

    struct Measures {
        double volume = 0.0;
        double area = 0.0;
    };
    /// volume() and area() in one pass over the triangles (the same sums, bit for bit).
    Measures measure() const;

    /// Axis-aligned bounds of all points (an empty box, min > max, when there are none).
    openvdb::BBoxd bounds() const;

    bool empty() const { return triangles.empty(); }
};

/// A mesh point in double, for the stages that compute with it (projection, creases, decimation).
inline openvdb::Vec3d toDouble(const openvdb::Vec3f& p)
{
    return {p.x(), p.y(), p.z()};
}

/// A point computed in double, stored back as a mesh point.
inline openvdb::Vec3f toFloat(const openvdb::Vec3d& p)
{
    return {float(p.x()), float(p.y()), float(p.z())};
}

/// @a x rounded to single precision, as a mesh stores it. GCC 12.2 at -O2 and above drops the
/// rounding of double(float(x)) when it vectorises two such components together (x and y of a
/// point: toDouble(toFloat(p)) gave p back unrounded); the empty asm keeps the float.
inline double roundedToFloat(double x)
{
    float f = float(x);
    asm("" : "+x"(f));
    return double(f);
}

/// @a p as a mesh stores it (each component rounded to single precision), in double: what the
/// checks of a point about to be stored must see.
inline openvdb::Vec3d asStored(const openvdb::Vec3d& p)
{
    return {roundedToFloat(p.x()), roundedToFloat(p.y()), roundedToFloat(p.z())};
}

}  // namespace voxlat
