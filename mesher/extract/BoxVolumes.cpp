#include "mesher/extract/BoxVolumes.h"

#include "mesher/extract/MarchingCubes.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <stdexcept>

namespace voxlat {

namespace {

/// The mesher's point on the edge from its lower corner (value @a lower) to its upper one, as a
/// share of the edge (MarchingCubes.cpp's edgePoint, kept off the corners).
double edgeShare(double iso, double lower, double upper)
{
    return std::clamp((iso - lower) / (upper - lower), 1e-3, 1.0 - 1e-3);
}

/// The shoelace area of a polygon of @a n points.
double polygonArea(const std::array<double, 16>& u, const std::array<double, 16>& v, int n)
{
    double twice = 0.0;
    for (int k = 0; k < n; ++k) {
        const int next = (k + 1) % n;
        twice += u[k] * v[next] - u[next] * v[k];
    }
    return 0.5 * std::abs(twice);
}

/// The inside (value below @a iso) of a unit square with corner values @a f at (0, 0), (1, 0),
/// (1, 1), (0, 1), as the mesher's cubes trace it on their faces: the edges' points from their
/// lower corners, and where the inside corners lie on one diagonal, the asymptotic decider of
/// Mesher::decisions (the diagonals' products of value - iso).
double squareInside(const std::array<float, 4>& f, float iso)
{
    const double level = double(iso);
    const double g[4] = {double(f[0]) - level, double(f[1]) - level, double(f[2]) - level, double(f[3]) - level};
    const bool in[4] = {f[0] < iso, f[1] < iso, f[2] < iso, f[3] < iso};
    const int count = int(in[0]) + int(in[1]) + int(in[2]) + int(in[3]);
    if (count == 0) return 0.0;
    if (count == 4) return 1.0;
    // Each edge's point: edges (0, 1) and (3, 2) along u from u = 0, (0, 3) and (1, 2) along v.
    const double s01 = edgeShare(level, f[0], f[1]), s32 = edgeShare(level, f[3], f[2]);
    const double s03 = edgeShare(level, f[0], f[3]), s12 = edgeShare(level, f[1], f[2]);
    const double cu[4] = {0.0, 1.0, 1.0, 0.0}, cv[4] = {0.0, 0.0, 1.0, 1.0};
    // The crossing on the edge from corner k to corner k + 1 (cyclic).
    auto crossing = [&](int k, double& pu, double& pv) {
        switch (k) {
            case 0:
                pu = s01, pv = 0.0;
                break;
            case 1:
                pu = 1.0, pv = s12;
                break;
            case 2:
                pu = s32, pv = 1.0;
                break;
            default:
                pu = 0.0, pv = s03;
                break;
        }
    };
    const bool diagonal = count == 2 && in[0] == in[2];
    if (diagonal) {
        const bool firstInside = in[0];
        const double d02 = g[0] * g[2], d13 = g[1] * g[3];
        const bool connectInside = firstInside ? d02 > d13 : d13 > d02;
        if (!connectInside) {
            // Two corners of their own: a triangle at each inside corner.
            double area = 0.0;
            for (int k = 0; k < 4; ++k) {
                if (!in[k]) continue;
                std::array<double, 16> u{}, v{};
                u[0] = cu[k];
                v[0] = cv[k];
                crossing(k, u[1], v[1]);
                crossing((k + 3) % 4, u[2], v[2]);
                area += polygonArea(u, v, 3);
            }
            return area;
        }
    }
    // One region: the inside corners and the crossings, walked around the square.
    std::array<double, 16> u{}, v{};
    int n = 0;
    for (int k = 0; k < 4; ++k) {
        if (in[k]) {
            u[n] = cu[k];
            v[n] = cv[k];
            ++n;
        }
        if (in[k] != in[(k + 1) % 4]) {
            crossing(k, u[n], v[n]);
            ++n;
        }
    }
    return polygonArea(u, v, n);
}

}  // namespace

std::vector<BoxVolumes> marchingCubesBoxVolumes(const openvdb::FloatGrid& grid, std::span<const openvdb::Coord> boxes,
                                                int side, float iso)
{
    if (side < 1) throw std::invalid_argument("marchingCubesBoxVolumes: a box needs a side of at least one cell");
    std::vector<BoxVolumes> out(boxes.size());
    std::map<openvdb::Coord, std::size_t> index;
    for (std::size_t b = 0; b < boxes.size(); ++b) index.emplace(boxes[b], b);
    const double half = 0.5 * side;
    const int points = side + 1;
    // Each box alone (its own slot): its points read once, then its count and its faces.
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, boxes.size()), [&](const auto& range) {
        auto acc = grid.getConstAccessor();
        std::vector<float> f(std::size_t(points) * points * points);
        auto at = [&](int x, int y, int z) -> float& {
            return f[(std::size_t(x) * points + std::size_t(y)) * points + std::size_t(z)];
        };
        for (std::size_t b = range.begin(); b != range.end(); ++b) {
            const openvdb::Coord o = boxes[b];
            for (int x = 0; x <= side; ++x)
                for (int y = 0; y <= side; ++y)
                    for (int z = 0; z <= side; ++z) at(x, y, z) = acc.getValue(o.offsetBy(x, y, z));
            // The points' count, each weighted by its share of the box.
            double voxels = 0.0;
            for (int x = 0; x <= side; ++x)
                for (int y = 0; y <= side; ++y)
                    for (int z = 0; z <= side; ++z) {
                        if (!(at(x, y, z) < iso)) continue;
                        const int onFaces = (x == 0 || x == side) + (y == 0 || y == side) + (z == 0 || z == side);
                        voxels += 1.0 / double(1 << onFaces);
                    }
            // The faces: the inside of each, at side / 2 from the centre along its outward normal.
            double faces = 0.0;
            for (int axis = 0; axis < 3; ++axis) {
                const int ua = (axis + 1) % 3, va = (axis + 2) % 3;
                for (const int plane : {0, side})
                    for (int i = 0; i < side; ++i)
                        for (int j = 0; j < side; ++j) {
                            std::array<float, 4> corner{};
                            const int du[4] = {0, 1, 1, 0}, dv[4] = {0, 0, 1, 1};
                            for (int k = 0; k < 4; ++k) {
                                int c[3];
                                c[axis] = plane;
                                c[ua] = i + du[k];
                                c[va] = j + dv[k];
                                corner[std::size_t(k)] = at(c[0], c[1], c[2]);
                            }
                            faces += squareInside(corner, iso);
                        }
            }
            out[b].voxels = voxels;
            out[b].mesh = faces * half / 3.0;
        }
    });
    // The triangles, each in the box of the cell holding its centroid: its signed tetrahedron
    // about the box's centre (the mesh is outward oriented), in the mesh's order.
    const TriangleMesh mesh = marchingCubes(grid, iso);
    const openvdb::math::Transform& xform = grid.transform();
    for (const openvdb::Vec3I& t : mesh.triangles) {
        const openvdb::Vec3d a = xform.worldToIndex(openvdb::Vec3d(mesh.points[t[0]]));
        const openvdb::Vec3d p = xform.worldToIndex(openvdb::Vec3d(mesh.points[t[1]]));
        const openvdb::Vec3d q = xform.worldToIndex(openvdb::Vec3d(mesh.points[t[2]]));
        const openvdb::Vec3d centroid = (a + p + q) / 3.0;
        openvdb::Coord box;
        for (int axis = 0; axis < 3; ++axis) box[axis] = int(std::floor(std::floor(centroid[axis]) / side)) * side;
        const auto found = index.find(box);
        if (found == index.end()) continue;
        const openvdb::Vec3d centre(box.x() + half, box.y() + half, box.z() + half);
        out[found->second].mesh += (a - centre).dot((p - centre).cross(q - centre)) / 6.0;
    }
    return out;
}

}  // namespace voxlat
