#include "engine/jobs/MeshOffset.h"

#include "fields/shapes/BoxField.h"
#include "mesher/extract/BoxVolumes.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

namespace voxlat {

namespace {

constexpr int kSide = 8;            ///< a box's cells per axis
constexpr int kPoints = kSide + 1;  ///< its points per axis
constexpr int kRing = kPoints + 2;  ///< its points and the ring around them (central differences)

/// A box's place mixed into 64 bits (splitmix64's finaliser): the sample does not follow a
/// lattice's period.
std::uint64_t placeHash(const openvdb::Coord& c)
{
    std::uint64_t x = (std::uint64_t(std::uint32_t(c.x())) << 42) ^ (std::uint64_t(std::uint32_t(c.y())) << 21) ^
                      std::uint64_t(std::uint32_t(c.z()));
    x += 0x9e3779b97f4a7c15ULL;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
    return x ^ (x >> 31);
}

int floorToSide(int v)
{
    return (v >= 0 ? v / kSide : -((-v + kSide - 1) / kSide)) * kSide;
}

std::size_t ringIndex(int i, int j, int k)
{
    return (std::size_t(i) * kRing + std::size_t(j)) * kRing + std::size_t(k);
}

}  // namespace

std::uint64_t meshOffsetBoxes(const Domain& domain)
{
    // Origins from floorToSide(-1) to dims - 1 on each axis (the cells of the points -1..dims).
    std::uint64_t count = 1;
    for (int a = 0; a < 3; ++a) count *= std::uint64_t((domain.dims[a] - 1 - floorToSide(-1)) / kSide + 1);
    return count;
}

MeshOffset estimateMeshOffset(const FieldNode& result, const Domain& domain, int every, bool coverage,
                              const std::function<void()>& interrupt)
{
    MeshOffset m;
    every = std::max(1, every);
    // The grid's points: the domain's voxels and one of margin; beyond them the background (1).
    const openvdb::CoordBBox region(openvdb::Coord(-1), domain.dims);
    const openvdb::CoordBBox deepInside(openvdb::Coord(1), domain.dims - openvdb::Coord(2));
    const openvdb::CoordBBox domainIndex = domain.indexBox();
    const BoxField clip(domain.box);
    // The boxes' origins: from floorToSide(-1) to dims - 1 on each axis (meshOffsetBoxes()).
    std::vector<openvdb::Coord> sample;
    const int first = floorToSide(-1);
    for (int x = first; x <= region.max().x() - 1; x += kSide)
        for (int y = first; y <= region.max().y() - 1; y += kSide)
            for (int z = first; z <= region.max().z() - 1; z += kSide)
                if (placeHash(openvdb::Coord(x, y, z)) % std::uint64_t(every) == 0) sample.emplace_back(x, y, z);
    m.boxes = meshOffsetBoxes(domain);
    m.sampled = sample.size();
    // Each sampled box's points as the grid would hold them (floats) with the ring around them:
    // the 9^3 for its mesh, and their sub-voxel coverage as the density solve measures it
    // (1/2 - value / step, the step the length of the central differences).
    std::vector<std::array<float, kPoints * kPoints * kPoints>> values(sample.size());
    std::vector<double> covered(sample.size(), 0.0);
    std::vector<char> crossed(sample.size(), 0), evaluated(sample.size(), 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, sample.size()), [&](const auto& range) {
        std::vector<double> v(std::size_t(kRing) * kRing * kRing), c(v.size());
        std::vector<float> f(v.size()), raw(v.size());
        for (std::size_t n = range.begin(); n != range.end(); ++n) {
            if (interrupt) interrupt();
            const openvdb::Coord o = sample[n];
            const openvdb::CoordBBox ring(o - openvdb::Coord(1), o + openvdb::Coord(kSide + 1));
            // A box of the domain's inside whose bound (over its ring) lies on one side of zero:
            // its mesh volume and its coverage are both all or nothing.
            if (deepInside.isInside(ring)) {
                const Interval b = result.bound(Box3{domain.worldOf(ring.min()), domain.worldOf(ring.max())});
                if (b.lo > 0.0 || b.hi < 0.0) continue;
            }
            evaluated[n] = 1;
            GridBatch batch;
            batch.origin = domain.worldOf(ring.min());
            batch.spacing = Vec3d(domain.voxel);
            batch.nx = batch.ny = batch.nz = kRing;
            batch.exact = true;  // not kept by a memo: the grid's floats are taken below
            result.gridValues(batch, v);
            clip.gridValues(batch, c);
            bool below = false, above = false;
            for (int i = 0; i < kRing; ++i)
                for (int j = 0; j < kRing; ++j)
                    for (int k = 0; k < kRing; ++k) {
                        const std::size_t at = ringIndex(i, j, k);
                        const openvdb::Coord p = ring.min().offsetBy(i, j, k);
                        float value = 1.0f;
                        if (region.isInside(p)) {
                            // The clip is the grid's only within its leaves near the box's faces.
                            const openvdb::Coord leaf(floorToSide(p.x()), floorToSide(p.y()), floorToSide(p.z()));
                            const bool clipped =
                                !deepInside.isInside(openvdb::CoordBBox(leaf, leaf + openvdb::Coord(kSide - 1)));
                            value = float(clipped ? std::max(v[at], c[at]) : v[at]);
                        }
                        f[at] = value;
                        raw[at] = float(v[at]);
                    }
            // The box's points: for its mesh, and their coverage, each weighted by its share of the
            // box as marchingCubesBoxVolumes() weighs the count (voxels whose cubes straddle the
            // box's faces paired with the cells they straddle: an offset per box a few voxels at
            // most, not a slab of the surface's).
            double sum = 0.0;
            for (int i = 1; i <= kPoints; ++i)
                for (int j = 1; j <= kPoints; ++j)
                    for (int k = 1; k <= kPoints; ++k) {
                        const float value = f[ringIndex(i, j, k)];
                        values[n][(std::size_t(i - 1) * kPoints + std::size_t(j - 1)) * kPoints + std::size_t(k - 1)] =
                            value;
                        below = below || value < 0.0f;
                        above = above || !(value < 0.0f);
                        // The solve measures the domain's voxels only (not the margin's).
                        if (!domainIndex.isInside(ring.min().offsetBy(i, j, k))) continue;
                        // The solve's field is not clipped by the domain's box (its faces' voxels
                        // whole where the field holds them, not half cut by the clip's margin).
                        const double dx = 0.5 * (double(raw[ringIndex(i + 1, j, k)]) - raw[ringIndex(i - 1, j, k)]);
                        const double dy = 0.5 * (double(raw[ringIndex(i, j + 1, k)]) - raw[ringIndex(i, j - 1, k)]);
                        const double dz = 0.5 * (double(raw[ringIndex(i, j, k + 1)]) - raw[ringIndex(i, j, k - 1)]);
                        const double step = std::sqrt(dx * dx + dy * dy + dz * dz);
                        const double own = raw[ringIndex(i, j, k)];
                        const double share =
                            coverage && step > 0.0 ? std::clamp(0.5 - own / step, 0.0, 1.0) : double(own < 0.0);
                        const int onFaces =
                            (i == 1 || i == kPoints) + (j == 1 || j == kPoints) + (k == 1 || k == kPoints);
                        sum += share / double(1 << onFaces);
                    }
            covered[n] = sum;
            crossed[n] = below && above;
        }
    });
    // The crossed boxes on one grid (their shared faces hold the same points), measured at once;
    // a box on one side has a mesh volume of 0 or 512, its coverage the same (the bound or the
    // values put every point on that side, at least half a step from zero or its coverage is cut).
    std::vector<openvdb::Coord> boxes;
    std::vector<std::size_t> of;
    const openvdb::FloatGrid::Ptr grid = openvdb::FloatGrid::create(1.0f);
    auto acc = grid->getAccessor();
    double offset = 0.0;
    for (std::size_t n = 0; n < sample.size(); ++n) {
        if (!evaluated[n]) continue;
        if (!crossed[n]) {
            const bool inside = values[n][0] < 0.0f;
            offset += (inside ? double(kSide * kSide * kSide) : 0.0) - covered[n];
            continue;
        }
        boxes.push_back(sample[n]);
        of.push_back(n);
        for (int i = 0; i < kPoints; ++i)
            for (int j = 0; j < kPoints; ++j)
                for (int k = 0; k < kPoints; ++k)
                    acc.setValue(sample[n].offsetBy(i, j, k), values[n][(std::size_t(i) * kPoints + j) * kPoints + k]);
    }
    m.crossed = boxes.size();
    if (m.sampled == 0) return m;
    const std::vector<BoxVolumes> volumes = marchingCubesBoxVolumes(*grid, boxes, kSide);
    for (std::size_t b = 0; b < boxes.size(); ++b) offset += volumes[b].mesh - covered[of[b]];
    m.volume = offset * double(m.boxes) / double(m.sampled) * std::pow(domain.voxel, 3);
    return m;
}

}  // namespace voxlat
