/// @file GaussianSegment.h
/// @brief The Gaussian kernel integrated along a segment (closed form with erf), its gradient
/// and its cut-off radius.
///
/// Kernel f(p) = exp(-|p|^2 / (2 sigma^2)) (a = 1, seed 002). For the segment from A to B
/// (length L, unit direction u), a point P with h = (P - A).u and r^2 = |P - A|^2 - h^2, and a
/// weight varying linearly from w0 at A to w1 at B, the convolution is
///
///   F(P) = exp(-r^2 / (2 sigma^2)) * (w0 * I0(h) + k * I1(h)),   k = (w1 - w0) / L
///   I0(h) = int_0^L exp(-(s - h)^2 / (2 sigma^2)) ds
///         = sigma * sqrt(pi/2) * [erf((L - h) / (sigma sqrt 2)) + erf(h / (sigma sqrt 2))]
///   I1(h) = int_0^L s exp(-(s - h)^2 / (2 sigma^2)) ds = sigma^2 (e0 - eL) + h I0(h)
///
/// with e0 = exp(-h^2 / (2 sigma^2)), eL = exp(-(L - h)^2 / (2 sigma^2)).
///
/// Cut-off. Let d be the distance from P to the segment and wMax = max(w0, w1). Then
///   F(P) <= wMax * sigma * sqrt(2 pi) * exp(-d^2 / (2 sigma^2))
/// (inside the slab 0 <= h <= L, d = r and I0 <= sigma sqrt(2 pi); beyond an end, say h < 0,
/// (s - h)^2 >= s^2 + h^2 so I0 <= exp(-h^2 / (2 sigma^2)) sigma sqrt(pi / 2) and d^2 = r^2 + h^2).
/// sigma * sqrt(2 pi) * wMax is the peak of an infinite strut of weight wMax, so beyond
///   r_c = sigma * sqrt(2 ln(1 / eps))
/// every dropped contribution is below eps times that peak (eps = 1e-4: r_c = 4.29 sigma).
#pragma once

#include "fields/core/FieldNode.h"

#include <cmath>
#include <numbers>

namespace voxlat {

/// sqrt(2 pi): the integral of the kernel along an infinite line through P (per unit weight).
inline constexpr double kSqrtTwoPi = 2.5066282746310002;

/// The cut-off radius beyond which one strut's contribution is below eps of its peak.
inline double gaussianCutoffRadius(double sigma, double eps)
{
    return sigma * std::sqrt(2.0 * std::log(1.0 / eps));
}

/// Upper bound of one strut's contribution at distance @a d from its segment (see the file).
inline double gaussianSegmentUpperBound(double d, double sigma, double wMax)
{
    return wMax * sigma * kSqrtTwoPi * std::exp(-d * d / (2.0 * sigma * sigma));
}

/// Radius of an isolated infinite strut of weight @a w at iso-value @a t (0 if w's peak < t):
/// r = sigma sqrt(2 ln(w sigma sqrt(2 pi) / t)).
inline double gaussianStrutRadius(double w, double sigma, double t)
{
    const double q = w * sigma * kSqrtTwoPi / t;
    return q > 1.0 ? sigma * std::sqrt(2.0 * std::log(q)) : 0.0;
}

/// The weight that gives an isolated infinite strut radius @a r at iso-value @a t.
inline double gaussianStrutWeight(double r, double sigma, double t)
{
    return t * std::exp(r * r / (2.0 * sigma * sigma)) / (sigma * kSqrtTwoPi);
}

/// erf(x1) + erf(x2) for x1 + x2 > 0, through erfc when one is negative, so that points beyond
/// an end (where the two nearly cancel) keep their relative precision.
inline double erfSum(double x1, double x2)
{
    if (x2 < 0.0) return std::erfc(-x2) - std::erfc(x1);
    if (x1 < 0.0) return std::erfc(-x1) - std::erfc(x2);
    return std::erf(x1) + std::erf(x2);
}

/// One segment prepared for evaluation.
struct GaussianSegment {
    Vec3d a{0.0};      ///< start A
    Vec3d u{1, 0, 0};  ///< unit direction
    double length = 0.0;
    double sigma = 1.0;
    double w0 = 1.0;     ///< weight at A
    double slope = 0.0;  ///< (w1 - w0) / L

    GaussianSegment() = default;
    GaussianSegment(const Vec3d& start, const Vec3d& end, double sigma_, double wStart, double wEnd)
        : a(start), length((end - start).length()), sigma(sigma_), w0(wStart)
    {
        u = (end - start) / length;
        slope = (wEnd - wStart) / length;
    }

    /// Squared distance from @a p to the segment, and h, r^2 on the way.
    double distanceSqr(const Vec3d& p, double& h, double& r2) const
    {
        const Vec3d d = p - a;
        h = d.dot(u);
        r2 = std::max(0.0, d.lengthSqr() - h * h);
        const double beyond = h < 0.0 ? h : (h > length ? h - length : 0.0);
        return r2 + beyond * beyond;
    }

    /// F at a point given its h and r^2 (the closed form above).
    double value(double h, double r2) const
    {
        const double inv2s2 = 0.5 / (sigma * sigma);
        const double invS2 = 1.0 / (sigma * std::numbers::sqrt2);
        const double i0 = sigma * std::sqrt(std::numbers::pi / 2.0) * erfSum((length - h) * invS2, h * invS2);
        double j = w0 * i0;
        if (slope != 0.0) {
            const double e0 = std::exp(-h * h * inv2s2), eL = std::exp(-(length - h) * (length - h) * inv2s2);
            j += slope * (sigma * sigma * (e0 - eL) + h * i0);
        }
        return std::exp(-r2 * inv2s2) * j;
    }

    /// F and its gradient at @a p:
    /// grad F = E * (-J / sigma^2 * (P - A - h u) + J'(h) u),
    /// J' = w0 (e0 - eL) + k (I0 - L eL)   (dI0/dh = e0 - eL, dI1/dh = I0 - L eL).
    double valueAndGradient(const Vec3d& p, Vec3d& grad) const
    {
        const double inv2s2 = 0.5 / (sigma * sigma);
        const double invS2 = 1.0 / (sigma * std::numbers::sqrt2);
        const Vec3d d = p - a;
        const double h = d.dot(u);
        const Vec3d perp = d - h * u;
        const double r2 = std::max(0.0, d.lengthSqr() - h * h);  // as in distanceSqr: same bits as value()
        const double i0 = sigma * std::sqrt(std::numbers::pi / 2.0) * erfSum((length - h) * invS2, h * invS2);
        const double e0 = std::exp(-h * h * inv2s2), eL = std::exp(-(length - h) * (length - h) * inv2s2);
        double j = w0 * i0, dj = w0 * (e0 - eL);
        if (slope != 0.0) {
            j += slope * (sigma * sigma * (e0 - eL) + h * i0);
            dj += slope * (i0 - length * eL);
        }
        const double e = std::exp(-r2 * inv2s2);
        grad = e * (-j / (sigma * sigma) * perp + dj * u);
        return e * j;
    }
};

}  // namespace voxlat
