#include "mesher/writers/MeshPreview.h"

#include "mesher/writers/SliceWriters.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace voxlat {

namespace {

using Vec3d = openvdb::Vec3d;

/// A depth sample: nearer is smaller; the triangle index breaks ties so merging is order-free.
struct Sample {
    float depth = std::numeric_limits<float>::max();
    std::uint32_t triangle = std::numeric_limits<std::uint32_t>::max();
    bool nearerThan(const Sample& o) const { return depth < o.depth || (depth == o.depth && triangle < o.triangle); }
};

struct View {
    Vec3d right, up, toward;  ///< camera axes; `toward` points at the viewer
    Vec3d center;
    double scale = 1.0;  ///< pixels per mm
    int size = 0;

    Vec3d project(const openvdb::Vec3f& p) const
    {
        const Vec3d d = Vec3d(p.x(), p.y(), p.z()) - center;
        return {0.5 * size + scale * d.dot(right), 0.5 * size - scale * d.dot(up), -d.dot(toward)};
    }
};

View makeView(const TriangleMesh& mesh, int size)
{
    View v;
    v.size = size;
    v.toward = Vec3d(1.0, -1.3, 0.9).unit();
    v.right = Vec3d(0, 0, 1).cross(v.toward).unit();
    v.up = v.toward.cross(v.right);
    const openvdb::BBoxd box = mesh.bounds();
    v.center = box.getCenter();
    // Fit the projected bounding box's corners with a 5 % margin.
    double extent = 1e-9;
    for (int c = 0; c < 8; ++c) {
        const Vec3d p(c & 1 ? box.max().x() : box.min().x(), c & 2 ? box.max().y() : box.min().y(),
                      c & 4 ? box.max().z() : box.min().z());
        const Vec3d d = p - v.center;
        extent = std::max({extent, std::abs(d.dot(v.right)), std::abs(d.dot(v.up))});
    }
    v.scale = 0.45 * size / extent;
    return v;
}

/// Rasterises triangles [begin, end) of @a mesh seen in @a view into @a buffer. The corners are
/// projected as each triangle is met, not into an array of every point first: a 50 mm lattice's
/// 9.4 million points made 226 MB of fresh pages for a picture.
void rasterise(const TriangleMesh& mesh, const View& view, std::size_t begin, std::size_t end,
               std::vector<Sample>& buffer)
{
    const int size = view.size;
    for (std::size_t t = begin; t < end; ++t) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        const Vec3d a = view.project(mesh.points[tri[0]]), b = view.project(mesh.points[tri[1]]),
                    c = view.project(mesh.points[tri[2]]);
        // Only pixel centres (x + 0.5) inside the triangle's bounds: most triangles of a fine
        // mesh are smaller than a pixel and cover no centre at all, so test that first.
        const int x0 = std::max(0, int(std::ceil(std::min({a.x(), b.x(), c.x()}) - 0.5)));
        const int x1 = std::min(size - 1, int(std::floor(std::max({a.x(), b.x(), c.x()}) - 0.5)));
        if (x0 > x1) continue;
        const int y0 = std::max(0, int(std::ceil(std::min({a.y(), b.y(), c.y()}) - 0.5)));
        const int y1 = std::min(size - 1, int(std::floor(std::max({a.y(), b.y(), c.y()}) - 0.5)));
        if (y0 > y1) continue;
        const double area = (b.x() - a.x()) * (c.y() - a.y()) - (b.y() - a.y()) * (c.x() - a.x());
        if (area == 0.0) continue;
        const double inverseArea = 1.0 / area;
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) {
                const double px = x + 0.5, py = y + 0.5;
                const double w0 = ((b.x() - px) * (c.y() - py) - (b.y() - py) * (c.x() - px)) * inverseArea;
                const double w1 = ((c.x() - px) * (a.y() - py) - (c.y() - py) * (a.x() - px)) * inverseArea;
                const double w2 = 1.0 - w0 - w1;
                if (w0 < 0 || w1 < 0 || w2 < 0) continue;
                const Sample s{float(w0 * a.z() + w1 * b.z() + w2 * c.z()), std::uint32_t(t)};
                Sample& dst = buffer[std::size_t(y) * size + x];
                if (s.nearerThan(dst)) dst = s;
            }
    }
}

}  // namespace

std::string renderMeshPreview(const TriangleMesh& mesh, int size)
{
    std::vector<Sample> depth(std::size_t(size) * size);
    if (!mesh.triangles.empty()) {
        const View view = makeView(mesh, size);
        // Fixed chunks, one depth buffer each, merged in chunk order: the same for any thread count.
        constexpr std::size_t kChunks = 4;
        std::vector<std::vector<Sample>> partial(kChunks);
        const std::size_t n = mesh.triangles.size();
        tbb::parallel_for(std::size_t(0), kChunks, [&](std::size_t c) {
            partial[c].assign(depth.size(), Sample{});
            rasterise(mesh, view, c * n / kChunks, (c + 1) * n / kChunks, partial[c]);
        });
        for (const auto& p : partial)
            for (std::size_t i = 0; i < depth.size(); ++i)
                if (p[i].nearerThan(depth[i])) depth[i] = p[i];
    }
    const View view = makeView(mesh, size);
    const Vec3d key = (view.toward + 0.6 * view.up - 0.3 * view.right).unit(), fill = (view.toward - view.up).unit();
    return encodePng(size, size, 4, [&](int y, std::uint8_t* row) {
        for (int x = 0; x < size; ++x) {
            const Sample& s = depth[std::size_t(y) * size + x];
            std::array<double, 3> rgb{1.0, 1.0, 1.0};
            if (s.triangle != std::numeric_limits<std::uint32_t>::max()) {
                const openvdb::Vec3I& tri = mesh.triangles[s.triangle];
                const openvdb::Vec3f e1 = mesh.points[tri[1]] - mesh.points[tri[0]];
                const openvdb::Vec3f e2 = mesh.points[tri[2]] - mesh.points[tri[0]];
                Vec3d normal = Vec3d(e1.x(), e1.y(), e1.z()).cross(Vec3d(e2.x(), e2.y(), e2.z()));
                normal = normal.length() > 0 ? normal.unit() : view.toward;
                // Outward normals face the viewer on visible faces; back faces are inner walls.
                const double light =
                    0.25 + 0.6 * std::max(0.0, normal.dot(key)) + 0.2 * std::max(0.0, normal.dot(fill));
                rgb = {0.55 * light, 0.68 * light, 0.85 * light};
            }
            for (int ch = 0; ch < 3; ++ch) row[4 * x + ch] = std::uint8_t(std::clamp(rgb[ch], 0.0, 1.0) * 255.0 + 0.5);
            row[4 * x + 3] = 255;
        }
    });
}

}  // namespace voxlat
