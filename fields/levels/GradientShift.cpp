#include "fields/levels/GradientShift.h"

#include "fields/core/Constant.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace voxlat {

namespace {

/// The constant value of a field, if it is a ConstantField.
bool constantOf(const FieldPtr& f, double& value)
{
    if (const auto* c = dynamic_cast<const ConstantField*>(f.get())) {
        value = c->value();
        return true;
    }
    return false;
}

double upperMagnitude(const FieldPtr& f, const Box3& box, double scale)
{
    return std::max(0.0, scale * abs(f->bound(box)).hi);
}

}  // namespace

GradientShift::GradientShift(FieldPtr field, ShiftSpec spec) : mField(std::move(field)), mSpec(std::move(spec))
{
    if (!mSpec.uniform && !(mSpec.wall && mSpec.layer))
        throw std::invalid_argument("a gradient shift needs a uniform magnitude or both wall and layer");
    const bool directionConstant = !mSpec.directionGradient && !mSpec.directionComponents[0];
    if (directionConstant) {
        const double len = mSpec.direction.length();
        if (!(len > 0.0)) throw std::invalid_argument(mSpec.label + ": the build direction has zero length");
        mDirection = mSpec.direction / len;
    }
    if (mSpec.oneSided && !mSpec.uniform)
        throw std::invalid_argument("a one-sided gradient shift (an offset) takes a uniform magnitude");
    if (mSpec.uniform) {
        mConstantMagnitudes = constantOf(mSpec.uniform, mConstantUniform);
        mConstantUniform =
            mSpec.oneSided ? mConstantUniform * mSpec.scale : std::max(0.0, mConstantUniform * mSpec.scale);
    } else {
        mConstantMagnitudes =
            directionConstant && constantOf(mSpec.wall, mConstantD) && constantOf(mSpec.layer, mConstantL);
        mConstantD = std::max(0.0, mConstantD * mSpec.scale);
        mConstantL = std::max(0.0, mConstantL * mSpec.scale);
        if (mConstantMagnitudes) mConstantM = rotatedMagnitudes(mDirection, mConstantD, mConstantL);
    }
}

Vec3d GradientShift::rotatedMagnitudes(const Vec3d& b, double d, double l)
{
    const Vec3d m(d, d, l);
    // b = +z: v = 0, R = I. b = -z: R is a half-turn about an axis in the xy-plane; about x it is
    // diag(1, -1, -1), and |R m| = m. Both exact, with no division.
    if (b.x() == 0.0 && b.y() == 0.0) return m;
    const double c = b.z();
    const Vec3d v(-b.y(), b.x(), 0.0);                // z x b
    const double vv = b.x() * b.x() + b.y() * b.y();  // |v|^2 = 1 - c^2 = (1 - c)(1 + c)
    // 1 / (1 + c), written as (1 - c) / |v|^2 below the equator so that it stays exact near c = -1.
    const double k = c >= 0.0 ? 1.0 / (1.0 + c) : (1.0 - c) / vv;
    // R m = m + v x m + v x (v x m) / (1 + c) = c m + v x m + v (v.m) / (1 + c), using |v|^2 = 1 - c^2.
    const Vec3d r = c * m + v.cross(m) + v * (v.dot(m) * k);
    return {std::abs(r.x()), std::abs(r.y()), std::abs(r.z())};
}

Vec3d GradientShift::anisotropicShift(const Vec3d& n, const Vec3d& b, double d, double l, ShiftRotation rotation)
{
    if (rotation == ShiftRotation::Tensor) return d * n + ((l - d) * n.dot(b)) * b;
    const Vec3d m = rotatedMagnitudes(b, d, l);
    return {m.x() * n.x(), m.y() * n.y(), m.z() * n.z()};
}

void GradientShift::shiftsFromGradients(std::span<const Vec3d> points, const Vec3d* grad, Vec3d* out,
                                        std::size_t n) const
{
    auto unit = [](const Vec3d& g) {
        const double len = g.length();
        return len > 0.0 ? g / len : Vec3d(0.0);
    };
    if (mConstantMagnitudes) {
        if (mSpec.uniform) {
            for (std::size_t i = 0; i < n; ++i) {
                const double len2 = grad[i].lengthSqr();
                out[i] = grad[i] * (len2 > 0.0 ? mConstantUniform / std::sqrt(len2) : 0.0);
            }
        } else if (mSpec.rotation == ShiftRotation::Rodrigues) {
            for (std::size_t i = 0; i < n; ++i) {
                const Vec3d u = unit(grad[i]);
                out[i] = Vec3d(mConstantM.x() * u.x(), mConstantM.y() * u.y(), mConstantM.z() * u.z());
            }
        } else {
            for (std::size_t i = 0; i < n; ++i)
                out[i] = anisotropicShift(unit(grad[i]), mDirection, mConstantD, mConstantL, mSpec.rotation);
        }
        return;
    }
    std::vector<double> a(n), b(n);
    if (mSpec.uniform) {
        mSpec.uniform->values(points, a);
        for (std::size_t i = 0; i < n; ++i)
            out[i] = (mSpec.oneSided ? mSpec.scale * a[i] : std::max(0.0, mSpec.scale * a[i])) * unit(grad[i]);
        return;
    }
    mSpec.wall->values(points, a);
    mSpec.layer->values(points, b);
    std::vector<Vec3d> dir(n, mDirection);
    if (mSpec.directionGradient) {
        std::vector<double> unused(n);
        mSpec.directionGradient->gradients(points, unused, dir);
    } else if (mSpec.directionComponents[0]) {
        std::vector<double> c(n);
        for (int axis = 0; axis < 3; ++axis) {
            mSpec.directionComponents[axis]->values(points, c);
            for (std::size_t i = 0; i < n; ++i) dir[i][axis] = c[i];
        }
    }
    for (std::size_t i = 0; i < n; ++i) {
        const double len = dir[i].length();
        if (!(len > 0.0)) {
            std::ostringstream msg;
            msg << mSpec.label << ": the build direction is zero (or not finite) at (" << points[i][0] << ", "
                << points[i][1] << ", " << points[i][2]
                << "): give a direction field that is non-zero everywhere in the domain";
            throw std::domain_error(msg.str());
        }
        out[i] = anisotropicShift(unit(grad[i]), dir[i] / len, std::max(0.0, mSpec.scale * a[i]),
                                  std::max(0.0, mSpec.scale * b[i]), mSpec.rotation);
    }
}

void GradientShift::sheetValues(std::span<const Vec3d> points, const Vec3d* shift, double* out, double* fPlus,
                                double* fMinus) const
{
    const std::size_t n = points.size();
    std::vector<Vec3d> shifted(2 * n);
    for (std::size_t i = 0; i < n; ++i) {
        shifted[i] = points[i] + shift[i];
        shifted[n + i] = points[i] - shift[i];
    }
    std::vector<double> f(2 * n);
    mField->values(shifted, f);
    for (std::size_t i = 0; i < n; ++i) {
        out[i] = mSpec.oneSided ? f[n + i] : std::max(f[n + i], -f[i]);
        if (fPlus) fPlus[i] = f[i];
        if (fMinus) fMinus[i] = f[n + i];
    }
}

void GradientShift::shifts(std::span<const Vec3d> points, std::span<Vec3d> out) const
{
    forEachChunk(points.size(), [&](std::size_t begin, std::size_t count) {
        const auto p = points.subspan(begin, count);
        std::vector<double> f(count);
        std::vector<Vec3d> g(count);
        mField->gradients(p, f, g);
        shiftsFromGradients(p, g.data(), out.data() + begin, count);
    });
}

void GradientShift::values(std::span<const Vec3d> points, std::span<double> out) const
{
    forEachChunk(points.size(), [&](std::size_t begin, std::size_t count) {
        const auto p = points.subspan(begin, count);
        std::vector<double> f(count);
        std::vector<Vec3d> g(count), s(count);
        mField->gradients(p, f, g);
        shiftsFromGradients(p, g.data(), s.data(), count);
        sheetValues(p, s.data(), out.data() + begin, nullptr, nullptr);
    });
}

void GradientShift::gridValues(const GridBatch& batch, std::span<double> out) const
{
    const std::size_t n = batch.size();
    std::vector<double> f(n), minus(n);
    std::vector<Vec3d> g(n), s(n), points;
    if (!mConstantMagnitudes) {  // the points are only needed to evaluate magnitude fields
        points.reserve(n);
        for (int i = 0; i < batch.nx; ++i)
            for (int j = 0; j < batch.ny; ++j)
                for (int k = 0; k < batch.nz; ++k) points.push_back(batch.point(i, j, k));
    }
    mField->gridGradients(batch, f, g);
    shiftsFromGradients(points, g.data(), s.data(), n);
    // f is no longer needed: it receives f+.
    mField->gridValuesShifted(batch, s, f, minus);
    for (std::size_t i = 0; i < n; ++i) out[i] = mSpec.oneSided ? minus[i] : std::max(minus[i], -f[i]);
}

void GradientShift::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    forEachChunk(points.size(), [&](std::size_t begin, std::size_t count) {
        const auto p = points.subspan(begin, count);
        std::vector<Vec3d> s(count);
        shifts(p, s);
        std::vector<double> fPlus(count), fMinus(count);
        sheetValues(p, s.data(), out.data() + begin, fPlus.data(), fMinus.data());

        // The Jacobian of s by central differences: s at x +- h e_a, six points per point.
        std::vector<Vec3d> probe(6 * count), probeShift(6 * count);
        std::vector<double> h(count);
        for (std::size_t i = 0; i < count; ++i) {
            const double scale = std::max({1.0, std::abs(p[i][0]), std::abs(p[i][1]), std::abs(p[i][2])});
            h[i] = 1e-5 * std::sqrt(scale);
            for (int a = 0; a < 3; ++a) {
                Vec3d up = p[i], down = p[i];
                up[a] += h[i];
                down[a] -= h[i];
                probe[6 * i + 2 * a] = up;
                probe[6 * i + 2 * a + 1] = down;
            }
        }
        shifts(probe, probeShift);

        // grad f at whichever shifted point decides the value.
        std::vector<Vec3d> decisive(count);
        std::vector<bool> minusSide(count);
        for (std::size_t i = 0; i < count; ++i) {
            minusSide[i] = mSpec.oneSided || fMinus[i] >= -fPlus[i];
            decisive[i] = minusSide[i] ? p[i] - s[i] : p[i] + s[i];
        }
        std::vector<double> unused(count);
        std::vector<Vec3d> gf(count);
        mField->gradients(decisive, unused, gf);
        for (std::size_t i = 0; i < count; ++i) {
            // F = f(x - s) : grad = (I - J)^T gf ;  F = -f(x + s) : grad = -(I + J)^T gf.
            const double sign = minusSide[i] ? -1.0 : 1.0;
            Vec3d g = gf[i];
            for (int a = 0; a < 3; ++a) {
                const Vec3d column = (probeShift[6 * i + 2 * a] - probeShift[6 * i + 2 * a + 1]) / (2.0 * h[i]);
                g[a] += sign * column.dot(gf[i]);  // (J^T gf)_a = sum_b J_ba gf_b, J_ba = d s_b / d x_a
            }
            grad[begin + i] = minusSide[i] ? g : -g;
        }
    });
}

double GradientShift::maxShift(const Box3& box) const
{
    if (mSpec.uniform)
        return mConstantMagnitudes ? std::abs(mConstantUniform) : upperMagnitude(mSpec.uniform, box, mSpec.scale);
    if (mConstantMagnitudes) {
        if (mSpec.rotation == ShiftRotation::Tensor) return std::max(mConstantD, mConstantL);
        return std::max({mConstantM.x(), mConstantM.y(), mConstantM.z()});
    }
    const double d = upperMagnitude(mSpec.wall, box, mSpec.scale), l = upperMagnitude(mSpec.layer, box, mSpec.scale);
    // |M' (.) n| <= max_i M'_i <= |M'| = |M| = sqrt(2 d^2 + l^2) for any rotation.
    if (mSpec.rotation == ShiftRotation::Tensor) return std::max(d, l);
    return std::sqrt(2.0 * d * d + l * l);
}

double GradientShift::period(int axis) const
{
    double p = mField->period(axis);
    for (const FieldPtr& f : {mSpec.uniform, mSpec.wall, mSpec.layer, mSpec.directionGradient,
                              mSpec.directionComponents[0], mSpec.directionComponents[1], mSpec.directionComponents[2]})
        if (f) p = commonPeriod(p, f->period(axis));
    return p;
}

Interval GradientShift::bound(const Box3& box) const
{
    const double grow = maxShift(box);
    const Box3 grown{box.min - Vec3d(grow), box.max + Vec3d(grow)};
    const Interval b = mField->bound(grown);
    if (mSpec.oneSided) return b;  // F = f- lies in b
    // f+ and f- both lie in b; F = max(f-, -f+).
    return {std::max(b.lo, -b.hi), std::max(b.hi, -b.lo)};
}

}  // namespace voxlat
