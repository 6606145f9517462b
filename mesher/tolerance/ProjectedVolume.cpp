#include "mesher/tolerance/ProjectedVolume.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <vector>

namespace voxlat {

namespace {

/// A corner of a clipped triangle: its place and its barycentric weights in the triangle.
struct ClippedCorner {
    Vec3d p;
    Vec3d w;
};

/// A convex polygon: a triangle clipped by up to six planes has at most nine corners.
struct Polygon {
    std::array<ClippedCorner, 12> c;
    int n = 0;
    bool cut = false;  ///< a face of the box cut the triangle
};

/// Sutherland-Hodgman against the half-space sign * (x[axis] - at) <= 0; new corners lie on the
/// plane exactly.
void clipAgainst(Polygon& poly, int axis, double at, double sign)
{
    Polygon out;
    out.cut = true;  // called only when a corner lies beyond the plane
    for (int i = 0; i < poly.n; ++i) {
        const ClippedCorner& a = poly.c[i];
        const ClippedCorner& b = poly.c[(i + 1) % poly.n];
        const double da = sign * (a.p[axis] - at), db = sign * (b.p[axis] - at);
        if (da <= 0.0) out.c[out.n++] = a;
        if ((da < 0.0 && db > 0.0) || (da > 0.0 && db < 0.0)) {
            const double t = da / (da - db);
            ClippedCorner m{a.p + t * (b.p - a.p), a.w + t * (b.w - a.w)};
            m.p[axis] = at;
            out.c[out.n++] = m;
        }
    }
    poly = out;
}

/// The triangle @a t within @a box (n = 0: none of it). Coordinates within @a snap of a face are
/// put on it, so that edges along a face are seen as on it.
Polygon clipToBox(const std::array<Vec3d, 3>& t, const Box3& box, double snap)
{
    Polygon poly;
    poly.n = 3;
    for (int k = 0; k < 3; ++k) {
        poly.c[k].p = t[k];
        poly.c[k].w = Vec3d(k == 0, k == 1, k == 2);
        for (int a = 0; a < 3; ++a) {
            if (std::abs(t[k][a] - box.min[a]) <= snap) poly.c[k].p[a] = box.min[a];
            if (std::abs(t[k][a] - box.max[a]) <= snap) poly.c[k].p[a] = box.max[a];
        }
    }
    for (int axis = 0; axis < 3 && poly.n > 0; ++axis) {
        double lo = poly.c[0].p[axis], hi = lo;
        for (int k = 1; k < poly.n; ++k) {
            lo = std::min(lo, poly.c[k].p[axis]);
            hi = std::max(hi, poly.c[k].p[axis]);
        }
        if (hi < box.min[axis] || lo > box.max[axis]) return {};
        if (lo < box.min[axis]) clipAgainst(poly, axis, box.min[axis], -1.0);
        if (poly.n > 0 && hi > box.max[axis]) clipAgainst(poly, axis, box.max[axis], 1.0);
    }
    if (poly.n < 3) poly.n = 0;
    return poly;
}

/// The three sums of the divergence theorem (see projectedVolumeInBox()).
struct BoxSums {
    double surface = 0.0;  ///< the integral of (x - x_min) n_x over the polygons
    double section = 0.0;  ///< the face x = x_max: the integral of (y - y_min) dz along its edges there
    double edge = 0.0;     ///< the box edge x = x_max, y = y_max: -(z - z_min) per jump of the solid
};

/// Adds polygon @a poly's terms to @a sums.
void addTerms(const Polygon& poly, const Box3& box, BoxSums& sums)
{
    const double x0 = box.min.x(), X = box.max.x(), Y = box.max.y(), y0 = box.min.y(), z0 = box.min.z();
    for (int i = 1; i + 1 < poly.n; ++i) {
        const Vec3d &a = poly.c[0].p, &b = poly.c[i].p, &c = poly.c[i + 1].p;
        const double nx = 0.5 * ((b.y() - a.y()) * (c.z() - a.z()) - (b.z() - a.z()) * (c.y() - a.y()));
        sums.surface += nx * ((a.x() + b.x() + c.x()) / 3.0 - x0);
    }
    for (int i = 0; i < poly.n; ++i) {
        const Vec3d& p = poly.c[i].p;
        const Vec3d& q = poly.c[(i + 1) % poly.n].p;
        if (p.x() != X || q.x() != X) continue;
        // The section's boundary runs this edge from q to p (the closed surface's other side).
        sums.section += (0.5 * (p.y() + q.y()) - y0) * (p.z() - q.z());
        if (p.y() == Y && q.y() == Y) continue;  // along the box's edge: no crossing
        // Reaching the box's edge at p, the boundary goes on along it upwards: the solid starts
        // there; leaving it at q, it came up along it: the solid ends there.
        if (p.y() == Y) sums.edge -= p.z() - z0;
        if (q.y() == Y) sums.edge += q.z() - z0;
    }
}

/// How far corner @a c of a clipped triangle moves when the triangle's corners move by @a d: the
/// weighted sum of their moves.
Vec3d move(const ClippedCorner& c, const std::array<Vec3d, 3>& d)
{
    return c.w[0] * d[0] + c.w[1] * d[1] + c.w[2] * d[2];
}

/// The volume @a poly sweeps as its triangle's corners move by @a d: ((N + N') / 2) . (mean
/// move) per fan triangle.
double swept(const Polygon& poly, const std::array<Vec3d, 3>& d)
{
    double sum = 0.0;
    for (int i = 1; i + 1 < poly.n; ++i) {
        const ClippedCorner &a = poly.c[0], &b = poly.c[i], &c = poly.c[i + 1];
        const Vec3d ma = move(a, d), mb = move(b, d), mc = move(c, d);
        const Vec3d before = 0.5 * (b.p - a.p).cross(c.p - a.p);
        const Vec3d after = 0.5 * ((b.p + mb) - (a.p + ma)).cross((c.p + mc) - (a.p + ma));
        sum += (0.5 * (before + after)).dot(ma + mb + mc) / 3.0;
    }
    return sum;
}

/// The area of @a poly with its corners moved as in swept().
double area(const Polygon& poly, const std::array<Vec3d, 3>& d)
{
    auto at = [&](const ClippedCorner& c) { return c.p + move(c, d); };
    Vec3d sum(0.0);
    for (int i = 1; i + 1 < poly.n; ++i)
        sum += 0.5 * (at(poly.c[i]) - at(poly.c[0])).cross(at(poly.c[i + 1]) - at(poly.c[0]));
    return sum.length();
}

/// A chunk's sums, kept in its slot until the chunk is written.
struct ChunkSums {
    BoxSums box;
    double cutSwept = 0.0;     ///< swept by every triangle the box cuts
    double sampleSwept = 0.0;  ///< swept by the sampled triangles inside the box
    double cutChord = 0.0;     ///< between the projected cut triangles and the surface
    double sampleChord = 0.0;  ///< between the projected sampled triangles and the surface
    std::uint64_t triangles = 0, cut = 0, inside = 0, sampled = 0;

    ChunkSums& operator+=(const ChunkSums& s)
    {
        box.surface += s.box.surface;
        box.section += s.box.section;
        box.edge += s.box.edge;
        cutSwept += s.cutSwept;
        sampleSwept += s.sampleSwept;
        cutChord += s.cutChord;
        sampleChord += s.sampleChord;
        triangles += s.triangles;
        cut += s.cut;
        inside += s.inside;
        sampled += s.sampled;
        return *this;
    }
};

}  // namespace

ProjectedVolume projectedVolumeInBox(const openvdb::FloatGrid& grid, const FieldNode& field, const Box3& box,
                                     const ProjectionOptions& options, std::uint64_t sampleEvery, ProgressFn progress)
{
    sampleEvery = std::max<std::uint64_t>(1, sampleEvery);
    // Corners are floats: one on a face (a grid sample on it) is off it by up to an ulp of its
    // coordinate, more than a millionth of a voxel far from the origin.
    double far = 0.0;
    for (int a = 0; a < 3; ++a) far = std::max({far, std::abs(box.min[a]), std::abs(box.max[a])});
    const double snap =
        std::max(1e-6 * grid.transform().voxelSize()[0], 8.0 * double(std::numeric_limits<float>::epsilon()) * far);
    TriangleStream stream;
    std::vector<ChunkSums> slots(stream.slots);
    ChunkSums total;
    stream.format = [&](std::size_t, std::size_t slot, std::span<const TriangleCorners> triangles) {
        ChunkSums sums;
        TriangleMesh moved;  // the projected triangles, each with its own three corners
        std::vector<Polygon> polygons;
        std::vector<bool> isCut;
        for (const TriangleCorners& t : triangles) {
            const std::array<Vec3d, 3> corners{Vec3d(t[0]), Vec3d(t[1]), Vec3d(t[2])};
            const Polygon poly = clipToBox(corners, box, snap);
            if (poly.n == 0) continue;
            ++sums.triangles;
            addTerms(poly, box, sums.box);
            const bool cut = poly.cut;
            if (cut) {
                ++sums.cut;
            } else if (sums.inside++ % sampleEvery != 0) {
                continue;
            }
            const auto first = std::uint32_t(moved.points.size());
            moved.points.insert(moved.points.end(), t.begin(), t.end());
            moved.triangles.emplace_back(first, first + 1, first + 2);
            polygons.push_back(poly);
            isCut.push_back(cut);
        }
        sums.sampled = polygons.size() - sums.cut;
        if (!polygons.empty()) {
            // Moves in double from the float corners the mesh gives.
            std::vector<openvdb::Vec3f> before = moved.points;
            ProjectionOptions loose = options;
            loose.holdBackCrossings = false;  // a soup: its triangles share no corner
            projectToSurface(moved, field, loose);
            // Each projected triangle's centre: its distance to the surface along the gradient.
            std::vector<Vec3d> centres(polygons.size()), gradients(polygons.size());
            std::vector<double> values(polygons.size());
            for (std::size_t n = 0; n < polygons.size(); ++n)
                centres[n] =
                    (Vec3d(moved.points[3 * n]) + Vec3d(moved.points[3 * n + 1]) + Vec3d(moved.points[3 * n + 2])) /
                    3.0;
            field.gradients(centres, values, gradients);
            for (std::size_t n = 0; n < polygons.size(); ++n) {
                std::array<Vec3d, 3> d;
                for (int k = 0; k < 3; ++k) d[k] = Vec3d(moved.points[3 * n + k]) - Vec3d(before[3 * n + k]);
                (isCut[n] ? sums.cutSwept : sums.sampleSwept) += swept(polygons[n], d);
                // A surface through the three corners bends quadratically between them: its mean
                // distance from the flat triangle is 3/4 of that at the centre.
                const double g = gradients[n].length();
                if (!(g > 0.0)) continue;
                const double outwards = -(values[n] - options.level) / g;
                (isCut[n] ? sums.cutChord : sums.sampleChord) += 0.75 * outwards * area(polygons[n], d);
            }
        }
        slots[slot] = sums;
    };
    stream.write = [&](std::size_t, std::size_t slot) { total += slots[slot]; };
    marchingCubesStreamed(grid, 0.0f, stream, std::move(progress));
    // The corner (x_max, y_max, z_max): inside or not by the field there.
    const double corner = field.value(box.max) < options.level ? 1.0 : 0.0;
    const Vec3d e = box.extent();
    const double length = total.box.edge + e.z() * corner;
    ProjectedVolume result;
    result.capArea = total.box.section + e.y() * length;
    result.unprojected = total.box.surface + e.x() * result.capArea;
    const double scale = total.sampled > 0 ? double(total.inside) / double(total.sampled) : 0.0;
    result.volume = result.unprojected + total.cutSwept + total.sampleSwept * scale;
    result.surface = result.volume + total.cutChord + total.sampleChord * scale;
    result.triangles = total.triangles;
    result.cut = total.cut;
    result.sampled = total.sampled;
    return result;
}

}  // namespace voxlat
