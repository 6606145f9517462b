#include "fields/shapes/Cylinder.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace voxlat {

Cylinder::Cylinder(const Vec3d& center, const Vec3d& axis, double radius, double height)
    : mCenter(center), mAxis(axis), mRadius(radius), mHalfHeight(0.5 * height)
{
    if (axis.length() <= 0.0) throw std::invalid_argument("cylinder axis has zero length");
    mAxis.normalize();
}

double Cylinder::distance(const Vec3d& p, Vec3d* gradient) const
{
    const Vec3d d = p - mCenter;
    const double h = d.dot(mAxis);
    const Vec3d radial = d - h * mAxis;
    const double r = radial.length();
    const Vec3d radialDir = r > 0 ? radial / r : Vec3d(0.0);
    const Vec3d axialDir = h < 0 ? -mAxis : mAxis;
    const double qr = r - mRadius, qh = std::abs(h) - mHalfHeight;
    if (qr > 0 && qh > 0) {
        const double len = std::sqrt(qr * qr + qh * qh);
        if (gradient) *gradient = (qr * radialDir + qh * axialDir) / len;
        return len;
    }
    if (qr > qh) {
        if (gradient) *gradient = radialDir;
        return qr;  // outside radially, or inside and nearer the mantle than a cap
    }
    if (gradient) *gradient = axialDir;
    return qh;
}

void Cylinder::values(std::span<const Vec3d> points, std::span<double> out) const
{
    for (std::size_t n = 0; n < points.size(); ++n) out[n] = distance(points[n], nullptr);
}

void Cylinder::gridValues(const GridBatch& batch, std::span<double> out) const
{
    int along = -1;
    for (int a = 0; a < 3; ++a)
        if (mAxis[a] == 1.0 && mAxis[(a + 1) % 3] == 0.0 && mAxis[(a + 2) % 3] == 0.0) along = a;
    if (along < 0) {
        FieldNode::gridValues(batch, out);
        return;
    }
    // distance() with a unit axis e_a: h = d . e_a is d_a (the other products are zeros), the
    // radial part is d with d_a replaced by 0, and its length sqrt(x x + y y + z z) adds that zero
    // in its place: the same doubles, from the same coordinates batch.point() gives.
    thread_local std::vector<double> d[3], qh, qr;
    const int n[3] = {batch.nx, batch.ny, batch.nz};
    for (int a = 0; a < 3; ++a) {
        d[a].resize(std::size_t(n[a]));
        for (int i = 0; i < n[a]; ++i) d[a][std::size_t(i)] = (batch.origin[a] + i * batch.spacing[a]) - mCenter[a];
    }
    qh.resize(std::size_t(n[along]));
    for (int i = 0; i < n[along]; ++i) qh[std::size_t(i)] = std::abs(d[along][std::size_t(i)]) - mHalfHeight;
    // The radial term over the plane of the two other axes (b < c), index b * n[c] + c.
    const int b = along == 0 ? 1 : 0, c = along == 2 ? 1 : 2;
    qr.resize(std::size_t(n[b]) * std::size_t(n[c]));
    for (int i = 0; i < n[b]; ++i)
        for (int j = 0; j < n[c]; ++j) {
            const double u = d[b][std::size_t(i)], v = d[c][std::size_t(j)];
            // (u u + 0) + v v, 0 + u u + v v and u u + v v + 0 are all u u + v v exactly.
            const double r = std::sqrt(u * u + v * v);
            qr[std::size_t(i) * std::size_t(n[c]) + std::size_t(j)] = r - mRadius;
        }
    // Per row (along z): either h changes along it (a cylinder along z) or q does (c is z).
    // q q + h h is never negative, so its square root is taken in every lane and kept where
    // both are positive (the same doubles): the rows vectorise.
    auto value = [](double q, double h) {
        const double corner = std::sqrt(q * q + h * h);
        return q > 0 && h > 0 ? corner : q > h ? q : h;
    };
    const std::size_t nz = std::size_t(batch.nz);
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j) {
            double* row = out.data() + (std::size_t(i) * std::size_t(batch.ny) + std::size_t(j)) * nz;
            const int idx[3] = {i, j, 0};
            if (along == 2) {
                const double q = qr[std::size_t(i) * std::size_t(n[c]) + std::size_t(j)];
                const double* h = qh.data();
                for (std::size_t k = 0; k < nz; ++k) row[k] = value(q, h[k]);
            } else {
                const double h = qh[std::size_t(idx[along])];
                const double* q = qr.data() + std::size_t(idx[b]) * std::size_t(n[c]);
                for (std::size_t k = 0; k < nz; ++k) row[k] = value(q[k], h);
            }
        }
}

void Cylinder::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    for (std::size_t n = 0; n < points.size(); ++n) out[n] = distance(points[n], &grad[n]);
}

Interval Cylinder::bound(const Box3& box) const
{
    return lipschitzBound(*this, box, 1.0);
}

std::optional<Box3> Cylinder::support() const
{
    // Per world axis: the caps' centres reach halfHeight * |a_i|, their rims radius * sin(angle).
    Vec3d half;
    for (int i = 0; i < 3; ++i)
        half[i] = mHalfHeight * std::abs(mAxis[i]) + mRadius * std::sqrt(std::max(0.0, 1.0 - mAxis[i] * mAxis[i]));
    return Box3{mCenter - half, mCenter + half};
}

}  // namespace voxlat
