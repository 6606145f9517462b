#include "engine/core/HeldGridField.h"

#include <cmath>
#include <vector>

namespace voxlat {

namespace {

/// The trilinear value of @a grid at index point @a x when the eight voxels around it lie in
/// leaves; false otherwise.
bool heldValue(const openvdb::FloatGrid::ConstAccessor& acc, const openvdb::Vec3d& x, double& value)
{
    using openvdb::Coord;
    const Coord c0(int(std::floor(x.x())), int(std::floor(x.y())), int(std::floor(x.z())));
    const double t[3] = {x.x() - c0.x(), x.y() - c0.y(), x.z() - c0.z()};
    double corner[8];
    for (int c = 0; c < 8; ++c) {
        const Coord ijk = c0.offsetBy(c >> 2 & 1, c >> 1 & 1, c & 1);
        const auto* leaf = acc.probeConstLeaf(ijk);
        if (!leaf) return false;
        corner[c] = double(leaf->getValue(ijk));
    }
    // Along z, then y, then x.
    double yz[4];
    for (int c = 0; c < 4; ++c) yz[c] = corner[2 * c] + t[2] * (corner[2 * c + 1] - corner[2 * c]);
    const double x0 = yz[0] + t[1] * (yz[1] - yz[0]), x1 = yz[2] + t[1] * (yz[3] - yz[2]);
    value = x0 + t[0] * (x1 - x0);
    return true;
}

openvdb::Vec3d indexOf(const openvdb::math::Transform& xf, const Vec3d& p)
{
    return xf.worldToIndex(openvdb::Vec3d(p.x(), p.y(), p.z()));
}

}  // namespace

HeldGridField::HeldGridField(FieldPtr field, openvdb::FloatGrid::ConstPtr grid)
    : mField(std::move(field)), mGrid(std::move(grid))
{
}

void HeldGridField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    const auto acc = mGrid->getConstAccessor();
    // The points no leaf covers, evaluated by the field together.
    std::vector<std::size_t> missed;
    for (std::size_t n = 0; n < points.size(); ++n)
        if (!heldValue(acc, indexOf(mGrid->transform(), points[n]), out[n])) missed.push_back(n);
    if (missed.empty()) return;
    std::vector<Vec3d> missedPoints(missed.size());
    std::vector<double> missedValues(missed.size());
    for (std::size_t m = 0; m < missed.size(); ++m) missedPoints[m] = points[missed[m]];
    mField->values(missedPoints, missedValues);
    for (std::size_t m = 0; m < missed.size(); ++m) out[missed[m]] = missedValues[m];
}

bool HeldGridField::meets(const Box3& box, const Interval& band) const
{
    using openvdb::Coord;
    const openvdb::Vec3d lo = indexOf(mGrid->transform(), box.min), hi = indexOf(mGrid->transform(), box.max);
    const openvdb::CoordBBox voxels(Coord(int(std::ceil(lo.x())), int(std::ceil(lo.y())), int(std::ceil(lo.z()))),
                                    Coord(int(std::floor(hi.x())), int(std::floor(hi.y())), int(std::floor(hi.z()))));
    if (voxels.empty()) return false;
    const auto acc = mGrid->getConstAccessor();
    bool above = false, below = false;
    // Leaf by leaf (origins multiples of 8), each leaf's voxels within the box.
    const Coord first(voxels.min().x() & ~7, voxels.min().y() & ~7, voxels.min().z() & ~7);
    for (int x = first.x(); x <= voxels.max().x(); x += 8)
        for (int y = first.y(); y <= voxels.max().y(); y += 8)
            for (int z = first.z(); z <= voxels.max().z(); z += 8) {
                const auto* leaf = acc.probeConstLeaf(Coord(x, y, z));
                if (!leaf) continue;
                openvdb::CoordBBox part = leaf->getNodeBoundingBox();
                part.intersect(voxels);
                for (auto ijk = part.begin(); ijk; ++ijk) {
                    const double v = leaf->getValue(*ijk);
                    above = above || v >= band.lo;
                    below = below || v <= band.hi;
                    if (above && below) return true;
                }
            }
    return false;
}

void HeldGridField::gridValues(const GridBatch& batch, std::span<double> out) const
{
    const auto acc = mGrid->getConstAccessor();
    // Runs of points along z that no leaf covers, each a batch of the field's (a row's set-up
    // shared by its points: half the points of the wireframe's picture lie in the grid's tiles).
    std::vector<double> run;
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j) {
            const std::size_t row = (std::size_t(i) * batch.ny + j) * batch.nz;
            for (int k = 0; k < batch.nz;) {
                if (heldValue(acc, indexOf(mGrid->transform(), batch.point(i, j, k)), out[row + k])) {
                    ++k;
                    continue;
                }
                int e = k + 1;
                while (e < batch.nz && !heldValue(acc, indexOf(mGrid->transform(), batch.point(i, j, e)), out[row + e]))
                    ++e;
                GridBatch part;
                part.origin = batch.point(i, j, k);
                part.spacing = batch.spacing;
                part.nx = part.ny = 1;
                part.nz = e - k;
                run.resize(std::size_t(e - k));
                mField->gridValues(part, run);
                std::copy(run.begin(), run.end(), out.begin() + std::ptrdiff_t(row + k));
                k = e;
            }
        }
}

}  // namespace voxlat
