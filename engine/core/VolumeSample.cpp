#include "engine/core/VolumeSample.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace voxlat {

namespace {

/// SplitMix64: a counter-based generator (a hash of the counter), so a cell's point depends on
/// its index alone.
std::uint64_t splitMix64(std::uint64_t x)
{
    x += 0x9e3779b97f4a7c15ull;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
    return x ^ (x >> 31);
}

/// A uniform double in [0, 1) from 53 bits of @a bits.
double unit(std::uint64_t bits)
{
    return double(bits >> 11) * 0x1.0p-53;
}

}  // namespace

VolumeSample sampleVolume(const FieldNode& field, const Box3& box, std::uint64_t points, std::uint64_t seed,
                          const std::function<void()>& interrupt)
{
    VolumeSample s;
    const Vec3d extent = box.extent();
    if (points == 0 || !(extent.x() > 0.0 && extent.y() > 0.0 && extent.z() > 0.0)) return s;
    // Cells of side about cbrt(V / points), an even count along x (cells pair along x).
    const double side = std::cbrt(extent.x() * extent.y() * extent.z() / double(points));
    for (int a = 0; a < 3; ++a) s.cells[a] = std::max(1, int(std::lround(extent[a] / side)));
    s.cells[0] += s.cells[0] % 2;
    const std::uint64_t ny = std::uint64_t(s.cells[1]), nz = std::uint64_t(s.cells[2]);
    s.points = std::uint64_t(s.cells[0]) * ny * nz;
    const Vec3d cell(extent.x() / s.cells[0], extent.y() / s.cells[1], extent.z() / s.cells[2]);
    // One batch per pair of x columns (i = 2 m, 2 m + 1): its cells y, z in order, both columns.
    const int pairs = s.cells[0] / 2;
    std::vector<std::uint64_t> inside(std::size_t(pairs), 0), differ(std::size_t(pairs), 0);
    const std::uint64_t key = splitMix64(seed);
    tbb::parallel_for(tbb::blocked_range<int>(0, pairs, 1), [&](const tbb::blocked_range<int>& range) {
        std::vector<Vec3d> p;
        std::vector<double> v;
        for (int m = range.begin(); m < range.end(); ++m) {
            if (interrupt) interrupt();
            p.clear();
            for (int i = 2 * m; i <= 2 * m + 1; ++i)
                for (std::uint64_t j = 0; j < ny; ++j)
                    for (std::uint64_t k = 0; k < nz; ++k) {
                        const std::uint64_t index = (std::uint64_t(i) * ny + j) * nz + k;
                        const std::uint64_t r0 = splitMix64(key ^ (3 * index)), r1 = splitMix64(key ^ (3 * index + 1)),
                                            r2 = splitMix64(key ^ (3 * index + 2));
                        p.emplace_back(box.min.x() + (double(i) + unit(r0)) * cell.x(),
                                       box.min.y() + (double(j) + unit(r1)) * cell.y(),
                                       box.min.z() + (double(k) + unit(r2)) * cell.z());
                    }
            v.resize(p.size());
            field.values(p, v);
            const std::size_t column = std::size_t(ny * nz);
            std::uint64_t in = 0, d = 0;
            for (std::size_t n = 0; n < column; ++n) {
                const bool a = v[n] < 0.0, b = v[column + n] < 0.0;
                in += std::uint64_t(a) + std::uint64_t(b);
                d += a != b;
            }
            inside[std::size_t(m)] = in;
            differ[std::size_t(m)] = d;
        }
    });
    std::uint64_t differing = 0;
    for (int m = 0; m < pairs; ++m) {
        s.inside += inside[std::size_t(m)];
        differing += differ[std::size_t(m)];
    }
    s.fraction = double(s.inside) / double(s.points);
    // Collapsed strata: each pair of cells (h, h') with one point each gives (y_h - y_h')^2, 1
    // where they differ; the sum estimates the variance of the count from above.
    s.standardError = std::sqrt(double(differing)) / double(s.points);
    return s;
}

}  // namespace voxlat
