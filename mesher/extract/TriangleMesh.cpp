#include "mesher/extract/TriangleMesh.h"

#include <tbb/parallel_reduce.h>

#include <functional>

namespace voxlat {

namespace {

/// Sums term(triangle) over all triangles in parallel. The deterministic reduce splits the range
/// the same way for any thread count, so the floating-point sum is reproducible bit for bit.
template <typename Term>
double sumOverTriangles(const std::vector<openvdb::Vec3I>& triangles, Term term)
{
    return tbb::parallel_deterministic_reduce(
        tbb::blocked_range<std::size_t>(0, triangles.size(), 1 << 14), 0.0,
        [&](const tbb::blocked_range<std::size_t>& r, double sum) {
            for (std::size_t n = r.begin(); n != r.end(); ++n) sum += term(triangles[n]);
            return sum;
        },
        std::plus<>());
}

}  // namespace

double TriangleMesh::volume() const
{
    if (triangles.empty()) return 0.0;
    // Measuring the tetrahedra from a point on the mesh instead of the world origin keeps the
    // terms small for a part far from the origin, so they do not cancel catastrophically.
    const openvdb::Vec3d ref = toDouble(points[triangles.front()[0]]);
    return sumOverTriangles(triangles,
                            [&](const openvdb::Vec3I& t) {
                                const openvdb::Vec3d a = toDouble(points[t[0]]) - ref;
                                const openvdb::Vec3d b = toDouble(points[t[1]]) - ref;
                                const openvdb::Vec3d c = toDouble(points[t[2]]) - ref;
                                return a.dot(b.cross(c));
                            }) /
           6.0;
}

double TriangleMesh::area() const
{
    return 0.5 * sumOverTriangles(triangles, [&](const openvdb::Vec3I& t) {
               const openvdb::Vec3d a = toDouble(points[t[0]]);
               return (toDouble(points[t[1]]) - a).cross(toDouble(points[t[2]]) - a).length();
           });
}

TriangleMesh::Measures TriangleMesh::measure() const
{
    if (triangles.empty()) return {};
    // The terms of volume() and area(), summed over the same deterministic split.
    const openvdb::Vec3d ref = toDouble(points[triangles.front()[0]]);
    const Measures sums = tbb::parallel_deterministic_reduce(
        tbb::blocked_range<std::size_t>(0, triangles.size(), 1 << 14), Measures{},
        [&](const tbb::blocked_range<std::size_t>& r, Measures sum) {
            for (std::size_t n = r.begin(); n != r.end(); ++n) {
                const openvdb::Vec3I& t = triangles[n];
                const openvdb::Vec3d p0 = toDouble(points[t[0]]), p1 = toDouble(points[t[1]]),
                                     p2 = toDouble(points[t[2]]);
                sum.volume += (p0 - ref).dot((p1 - ref).cross(p2 - ref));
                sum.area += (p1 - p0).cross(p2 - p0).length();
            }
            return sum;
        },
        [](const Measures& a, const Measures& b) {
            return Measures{a.volume + b.volume, a.area + b.area};
        });
    return {sums.volume / 6.0, 0.5 * sums.area};
}

openvdb::BBoxd TriangleMesh::bounds() const
{
    openvdb::BBoxd box;  // default-constructed: min = +max, max = -max, i.e. empty
    for (const openvdb::Vec3f& p : points) box.expand(toDouble(p));
    return box;
}

}  // namespace voxlat
