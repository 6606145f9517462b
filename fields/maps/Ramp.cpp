#include "fields/maps/Ramp.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace voxlat {

RampField::RampField(int axis, double start, double end, double from, double to)
    : mAxis(axis), mStart(start), mEnd(end), mFrom(from), mTo(to)
{
    if (axis < 0 || axis > 2 || !(end != start)) throw std::invalid_argument("ramp: bad axis or empty range");
}

RampField::RampField(FieldPtr source, double start, double end, double from, double to)
    : mSource(std::move(source)), mStart(start), mEnd(end), mFrom(from), mTo(to)
{
    if (!(end != start)) throw std::invalid_argument("ramp: empty range");
}

double RampField::map(double u) const
{
    const double t = std::clamp((u - mStart) / (mEnd - mStart), 0.0, 1.0);
    return mFrom + (mTo - mFrom) * t;
}

double RampField::slope(double u) const
{
    const double t = (u - mStart) / (mEnd - mStart);
    return t > 0.0 && t < 1.0 ? (mTo - mFrom) / (mEnd - mStart) : 0.0;
}

void RampField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    if (mSource) {
        mSource->values(points, out);
        for (double& v : out) v = map(std::abs(v));
        return;
    }
    for (std::size_t i = 0; i < points.size(); ++i) out[i] = map(points[i][mAxis]);
}

void RampField::gridValues(const GridBatch& batch, std::span<double> out) const
{
    if (mSource) {
        mSource->gridValues(batch, out);
        for (double& v : out) v = map(std::abs(v));
        return;
    }
    std::size_t n = 0;
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j)
            for (int k = 0; k < batch.nz; ++k) out[n++] = map(batch.point(i, j, k)[mAxis]);
}

void RampField::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    if (mSource) {
        mSource->gradients(points, out, grad);
        for (std::size_t i = 0; i < points.size(); ++i) {
            const double u = std::abs(out[i]);
            grad[i] *= slope(u) * (out[i] < 0.0 ? -1.0 : 1.0);
            out[i] = map(u);
        }
        return;
    }
    for (std::size_t i = 0; i < points.size(); ++i) {
        const double u = points[i][mAxis];
        out[i] = map(u);
        grad[i] = Vec3d(0.0);
        grad[i][mAxis] = slope(u);
    }
}

double RampField::period(int axis) const
{
    if (mSource) return mSource->period(axis);
    return axis == mAxis ? kNoPeriod : kInvariant;
}

Interval RampField::bound(const Box3& box) const
{
    const Interval u = mSource ? abs(mSource->bound(box)) : Interval(box.min[mAxis], box.max[mAxis]);
    const double a = map(u.lo), b = map(u.hi);  // map is monotone
    return {std::min(a, b), std::max(a, b)};
}

}  // namespace voxlat
