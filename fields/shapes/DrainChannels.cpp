#include "fields/shapes/DrainChannels.h"

#include <algorithm>
#include <stdexcept>

namespace voxlat {

DrainedSolid::DrainedSolid(FieldPtr solid) : mSolid(std::move(solid)) {}

void DrainedSolid::setChannels(std::vector<DrainChannel> channels)
{
    if (mSet) throw std::logic_error("DrainedSolid::setChannels: the channels are already set (set once)");
    for (const DrainChannel& c : channels) {
        const Vec3d axis = c.to - c.from;
        if (!(axis.length() > 0.0) || !(c.diameter > 0.0))
            throw std::logic_error("DrainedSolid::setChannels: a channel needs a length and a diameter");
        mCylinders.emplace_back(0.5 * (c.from + c.to), axis, 0.5 * c.diameter, axis.length());
    }
    mChannels = std::move(channels);
    mSet = true;
}

void DrainedSolid::requireSet() const
{
    if (!mSet) [[unlikely]]
        throw std::logic_error("DrainedSolid: evaluated before its channels were set (plan the drains first)");
}

void DrainedSolid::cut(const Box3& box, std::span<const Vec3d> points, std::span<double> out,
                       std::span<Vec3d> grad) const
{
    if (mCylinders.empty() || points.empty()) return;
    const double lowest = *std::min_element(out.begin(), out.end());
    std::vector<double> d(points.size());
    std::vector<Vec3d> g(grad.empty() ? 0 : points.size());
    for (const Cylinder& c : mCylinders) {
        // -d > v somewhere needs d < -v <= -lowest.
        if (c.bound(box).lo >= -lowest) continue;
        if (grad.empty())
            c.values(points, d);
        else
            c.gradients(points, d, g);
        for (std::size_t n = 0; n < points.size(); ++n)
            if (-d[n] > out[n]) {
                out[n] = -d[n];
                if (!grad.empty()) grad[n] = -g[n];
            }
    }
}

namespace {
Box3 boundsOf(std::span<const Vec3d> points)
{
    Box3 b{points.empty() ? Vec3d(0.0) : points[0], points.empty() ? Vec3d(0.0) : points[0]};
    for (const Vec3d& p : points)
        for (int a = 0; a < 3; ++a) {
            b.min[a] = std::min(b.min[a], p[a]);
            b.max[a] = std::max(b.max[a], p[a]);
        }
    return b;
}
}  // namespace

void DrainedSolid::values(std::span<const Vec3d> points, std::span<double> out) const
{
    requireSet();
    mSolid->values(points, out);
    cut(boundsOf(points), points, out, {});
}

void DrainedSolid::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    requireSet();
    mSolid->gradients(points, out, grad);
    cut(boundsOf(points), points, out, grad);
}

void DrainedSolid::gridValues(const GridBatch& batch, std::span<double> out) const
{
    requireSet();
    mSolid->gridValues(batch, out);
    cutGrid(batch, out);
}

void DrainedSolid::planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                               std::span<signed char> side, std::span<const TileNeed> need) const
{
    requireSet();
    const PlaneTiles tiles = PlaneTiles::of(plane, tile);
    planeValuesOf(*mSolid, plane, tile, band, out, side, need);
    // max(solid, -channel) is below band.lo where the solid is and every channel is above -lo.
    const double slack = 1e-12 * (finiteScale(band) + 1.0);
    std::vector<TileNeed> again;
    for (std::size_t t = 0; t < tiles.size(); ++t) {
        if (side[t] >= 0 || mCylinders.empty()) continue;
        const Box3 foot = tiles.footprint(plane, int(t / tiles.ny), int(t % tiles.ny));
        if (std::all_of(mCylinders.begin(), mCylinders.end(),
                        [&](const Cylinder& c) { return c.bound(foot).lo > slack - band.lo; }))
            continue;
        if (again.empty()) again.assign(tiles.size(), TileNeed::Skip);
        again[t] = TileNeed::Exact;
        side[t] = 0;
    }
    if (!again.empty()) {
        std::vector<double> redone(plane.size());
        std::vector<signed char> ignored(tiles.size());
        planeValuesOf(*mSolid, plane, tile, band, redone, ignored, again);
        for (std::size_t t = 0; t < tiles.size(); ++t)
            if (again[t] == TileNeed::Exact)
                copyTileWithHalo(plane, tile, int(t / tiles.ny), int(t % tiles.ny), redone.data(), out.data());
    }
    cutGrid(plane, out);
}

void DrainedSolid::cutGrid(const GridBatch& batch, std::span<double> out) const
{
    if (mCylinders.empty()) return;
    const Box3 box = batch.bounds();
    const double lowest = *std::min_element(out.begin(), out.begin() + std::ptrdiff_t(batch.size()));
    if (std::all_of(mCylinders.begin(), mCylinders.end(),
                    [&](const Cylinder& c) { return c.bound(box).lo >= -lowest; }))
        return;
    std::vector<Vec3d> points;
    points.reserve(batch.size());
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j)
            for (int k = 0; k < batch.nz; ++k) points.push_back(batch.point(i, j, k));
    cut(box, points, out.first(batch.size()), {});
}

Interval DrainedSolid::bound(const Box3& box) const
{
    requireSet();
    Interval b = mSolid->bound(box);
    for (const Cylinder& c : mCylinders) {
        const Interval d = c.bound(box);
        b = {std::max(b.lo, -d.hi), std::max(b.hi, -d.lo)};
    }
    return b;
}

}  // namespace voxlat
