#include "fields/shapes/Unary.h"

#include <cmath>

namespace voxlat {

UnaryField::UnaryField(FieldPtr child, UnaryOp op, double offset) : mChild(std::move(child)), mOp(op), mOffset(offset)
{
}

double UnaryField::apply(double v, double& slope) const
{
    switch (mOp) {
        case UnaryOp::Negate:
            slope = -1.0;
            return -v;
        case UnaryOp::Abs:
            slope = v < 0 ? -1.0 : 1.0;
            return std::abs(v);
        case UnaryOp::Offset:
            slope = 1.0;
            return v + mOffset;
    }
    slope = 1.0;
    return v;
}

void UnaryField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    mChild->values(points, out);
    double slope;
    for (double& v : out) v = apply(v, slope);
}

void UnaryField::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    mChild->gradients(points, out, grad);
    for (std::size_t n = 0; n < out.size(); ++n) {
        double slope;
        out[n] = apply(out[n], slope);
        grad[n] *= slope;
    }
}

void UnaryField::gridValues(const GridBatch& batch, std::span<double> out) const
{
    mChild->gridValues(batch, out);
    // apply() with its case chosen once per batch.
    switch (mOp) {
        case UnaryOp::Negate:
            for (double& v : out) v = -v;
            return;
        case UnaryOp::Abs:
            for (double& v : out) v = std::abs(v);
            return;
        case UnaryOp::Offset:
            for (double& v : out) v += mOffset;
            return;
    }
}

void UnaryField::planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                             std::span<signed char> side, std::span<const TileNeed> need) const
{
    const std::size_t tiles = PlaneTiles::of(plane, tile).size();
    if (mOp == UnaryOp::Abs) {
        gridValues(plane, out);
        std::fill(side.begin(), side.begin() + tiles, static_cast<signed char>(0));
        return;
    }
    if (mOp == UnaryOp::Negate) {
        planeValuesOf(*mChild, plane, tile, Interval{-band.hi, -band.lo}, out, side, need);
        for (std::size_t t = 0; t < tiles; ++t) side[t] = static_cast<signed char>(-side[t]);
        for (double& v : out.first(plane.size())) v = -v;
        return;
    }
    // v + offset > hi where v > hi - offset, with a margin for the addition's rounding.
    const double slack = 1e-12 * (std::abs(mOffset) + finiteScale(band) + 1.0);
    planeValuesOf(*mChild, plane, tile, Interval{band.lo - mOffset - slack, band.hi - mOffset + slack}, out, side,
                  need);
    for (double& v : out.first(plane.size())) v += mOffset;
}

Interval UnaryField::bound(const Box3& box) const
{
    const Interval b = mChild->bound(box);
    switch (mOp) {
        case UnaryOp::Negate:
            return -b;
        case UnaryOp::Abs:
            return abs(b);
        case UnaryOp::Offset:
            return b + mOffset;
    }
    return b;
}

std::optional<Box3> UnaryField::support() const
{
    if (mOp == UnaryOp::Offset && mOffset >= 0.0) return mChild->support();
    return std::nullopt;
}

}  // namespace voxlat
