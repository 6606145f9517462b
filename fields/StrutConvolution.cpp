#include "fields/StrutConvolution.h"

#include "fields/GaussianTable.h"

#include <algorithm>
#include <stdexcept>

namespace voxlat {

StrutConvolution::StrutConvolution(const std::vector<ConvolutionStrut>& struts, double eps) : mEps(eps)
{
    if (!(eps > 0.0 && eps < 1.0)) throw std::invalid_argument("the convolution cut-off eps must be in (0, 1)");
    std::vector<Vec3d> a, b;
    std::vector<double> reach;
    for (const ConvolutionStrut& s : struts) {
        if (!(s.sigma > 0.0)) throw std::invalid_argument("sigma must be greater than zero");
        if (!((s.b - s.a).length() > 0.0)) throw std::invalid_argument("a strut has zero length");
        if (!(s.w0 > 0.0 && s.w1 > 0.0)) throw std::invalid_argument("strut weights must be greater than zero");
        mSegments.emplace_back(s.a, s.b, s.sigma, s.w0, s.w1);
        mEnd.push_back(s.b);
        const double rc = gaussianCutoffRadius(s.sigma, eps);
        mCutoffSqr.push_back(rc * rc);
        mPeak.push_back(std::max(s.w0, s.w1) * s.sigma * kSqrtTwoPi);
        mWMin.push_back(std::min(s.w0, s.w1));
        a.push_back(s.a);
        b.push_back(s.b);
        reach.push_back(rc);
    }
    mIndex = StrutIndex(a, b, reach);
}

double StrutConvolution::pointValue(const Vec3d& p, const std::vector<std::uint32_t>& cand) const
{
    double sum = 0.0;
    for (const std::uint32_t j : cand) {
        const GaussianSegment& s = mSegments[j];
        double h, r2;
        if (s.distanceSqr(p, h, r2) >= mCutoffSqr[j]) continue;
        sum += s.value(h, r2);
    }
    return sum;
}

void StrutConvolution::values(std::span<const Vec3d> points, std::span<double> out) const
{
    std::vector<std::uint32_t> cand;
    for (std::size_t n = 0; n < points.size(); ++n) {
        mIndex.candidates(Box3{points[n], points[n]}, cand);
        out[n] = pointValue(points[n], cand);
    }
}

void StrutConvolution::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    std::vector<std::uint32_t> cand;
    for (std::size_t n = 0; n < points.size(); ++n) {
        mIndex.candidates(Box3{points[n], points[n]}, cand);
        double sum = 0.0;
        Vec3d g(0.0);
        for (const std::uint32_t j : cand) {
            const GaussianSegment& s = mSegments[j];
            double h, r2;
            if (s.distanceSqr(points[n], h, r2) >= mCutoffSqr[j]) continue;
            Vec3d gj;
            sum += s.valueAndGradient(points[n], gj);
            g += gj;
        }
        out[n] = sum;
        grad[n] = g;
    }
}

void StrutConvolution::gridValues(const GridBatch& batch, std::span<double> out) const
{
    thread_local std::vector<std::uint32_t> cand;
    mIndex.gather(batch.bounds(), cand);
    std::fill(out.begin(), out.begin() + batch.size(), 0.0);
    const GaussianTable& table = GaussianTable::instance();
    const double dx = batch.spacing.x(), dy = batch.spacing.y(), dz = batch.spacing.z();
    const double rowHalf = 0.5 * (batch.nz - 1) * dz;
    // Strut-outer, point-inner: each point still sums its struts in ascending index order. Along
    // a row (k) h is linear and r^2 quadratic in k, so exp(-r^2 / 2 sigma^2) follows from two
    // exponentials per row by the recurrence E(k+1) = E(k) R(k), R(k+1) = R(k) Q (a few ulps of
    // drift over a row); the erf sum comes from GaussianTable (error below 1e-10 of a peak).
    for (const std::uint32_t j : cand) {
        const GaussianSegment& s = mSegments[j];
        const double rc2 = mCutoffSqr[j], rc = std::sqrt(rc2);
        const double sigma = s.sigma, invSigma = 1.0 / sigma, inv2s2 = 0.5 / (sigma * sigma);
        const double length = s.length, w0 = s.w0, slope = s.slope, s2 = sigma * sigma;
        const Vec3d& u = s.u;
        const Vec3d d0 = batch.origin - s.a;
        const double hz = dz * u.z();
        // r^2(k) = r0 + b k + c k^2 along a row; Q = exp(-2 c / 2 sigma^2).
        const double c = dz * dz - hz * hz;
        const double q = std::exp(-2.0 * c * inv2s2);
        std::size_t n = 0;
        for (int i = 0; i < batch.nx; ++i) {
            const double px = d0.x() + i * dx;
            for (int jj = 0; jj < batch.ny; ++jj, n += batch.nz) {
                const double py = d0.y() + jj * dy;
                // Skip rows whose every point is beyond the cut-off (centre distance test).
                const Vec3d mid(px, py, d0.z() + rowHalf);
                const double hm = std::clamp(mid.dot(u), 0.0, length);
                if ((mid - hm * u).length() - rowHalf >= rc) continue;
                const double hRow = px * u.x() + py * u.y() + d0.z() * u.z();
                const double qRow = px * px + py * py;
                const double r0 = qRow + d0.z() * d0.z() - hRow * hRow;
                const double b = 2.0 * (d0.z() * dz - hRow * hz) + c;  // r^2(1) - r^2(0)
                // The recurrence's factors stay well inside double range for ordinary batches;
                // otherwise every point takes its own exponential.
                const bool recur = std::abs(b * inv2s2) < 200.0 && std::abs(c * inv2s2) * batch.nz < 200.0;
                double e = recur ? std::exp(-r0 * inv2s2) : 0.0;
                double ratio = recur ? std::exp(-b * inv2s2) : 0.0;
                for (int k = 0; k < batch.nz; ++k) {
                    // The cut-off test exactly as values() makes it (same h and r^2 bits).
                    double h, r2;
                    const double dist2 = s.distanceSqr(batch.point(i, jj, k), h, r2);
                    const double gauss = recur ? e : std::exp(-r2 * inv2s2);
                    e *= ratio;
                    ratio *= q;
                    if (dist2 >= rc2) continue;
                    double j0;
                    if (slope == 0.0) {
                        j0 =
                            w0 * sigma * (table.erfIntegral((length - h) * invSigma) + table.erfIntegral(h * invSigma));
                    } else {
                        double uL, gL, uA, gA;
                        table.evaluate((length - h) * invSigma, uL, gL);
                        table.evaluate(h * invSigma, uA, gA);
                        const double i0 = sigma * (uL + uA);
                        j0 = (w0 + slope * h) * i0 + slope * s2 * (gA - gL);
                    }
                    out[n + k] += gauss * j0;
                }
            }
        }
    }
}

Interval StrutConvolution::bound(const Box3& box) const
{
    thread_local std::vector<std::uint32_t> cand;
    mIndex.gather(box, cand);
    double lo = 0.0, hi = 0.0;
    const Vec3d c = box.center();
    const double radius = box.radius();
    for (const std::uint32_t j : cand) {
        const GaussianSegment& s = mSegments[j];
        const double sigma = s.sigma;
        const double dMin = segmentBoxDistance(s.a, mEnd[j], box);
        hi += gaussianSegmentUpperBound(dMin, sigma, mPeak[j] / (sigma * kSqrtTwoPi));
        // A positive lower bound only where the whole box lies within the cut-off.
        double h, r2;
        const double dc = std::sqrt(s.distanceSqr(c, h, r2));
        if (dc + radius >= std::sqrt(mCutoffSqr[j])) continue;
        const double rMax = std::sqrt(r2) + radius;
        const double hLo = h - radius, hHi = h + radius;
        // I0(h) is symmetric about L/2 and falls away from it: its minimum over [hLo, hHi] is
        // at the end farther from L/2.
        const double hFar = std::abs(hLo - 0.5 * s.length) > std::abs(hHi - 0.5 * s.length) ? hLo : hHi;
        GaussianSegment unit = s;
        unit.w0 = 1.0;
        unit.slope = 0.0;
        lo += mWMin[j] * unit.value(hFar, rMax * rMax);
    }
    // Rounding: the sums above and the evaluation's sums may differ in the last bits.
    const double slack = 1e-12 * (hi + 1e-300);
    return {std::max(0.0, lo * (1.0 - 1e-12)), hi + slack};
}

}  // namespace voxlat
