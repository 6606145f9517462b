#include "mesher/TriangleMesh.h"

namespace voxlat {

namespace {

openvdb::Vec3d toDouble(const openvdb::Vec3f& p)
{
    return {p.x(), p.y(), p.z()};
}

}  // namespace

double TriangleMesh::volume() const
{
    if (triangles.empty()) return 0.0;
    // Measuring the tetrahedra from a point on the mesh instead of the world origin keeps the
    // terms small for a part far from the origin, so they do not cancel catastrophically.
    const openvdb::Vec3d ref = toDouble(points[triangles.front()[0]]);
    double sum = 0.0;
    for (const openvdb::Vec3I& t : triangles) {
        const openvdb::Vec3d a = toDouble(points[t[0]]) - ref;
        const openvdb::Vec3d b = toDouble(points[t[1]]) - ref;
        const openvdb::Vec3d c = toDouble(points[t[2]]) - ref;
        sum += a.dot(b.cross(c));
    }
    return sum / 6.0;
}

double TriangleMesh::area() const
{
    double sum = 0.0;
    for (const openvdb::Vec3I& t : triangles) {
        const openvdb::Vec3d a = toDouble(points[t[0]]);
        sum += (toDouble(points[t[1]]) - a).cross(toDouble(points[t[2]]) - a).length();
    }
    return 0.5 * sum;
}

openvdb::BBoxd TriangleMesh::bounds() const
{
    openvdb::BBoxd box;  // default-constructed: min = +max, max = -max, i.e. empty
    for (const openvdb::Vec3f& p : points) box.expand(toDouble(p));
    return box;
}

}  // namespace voxlat
