#include "fields/StrutConvolution.h"

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
    // Strut-outer, point-inner: each point still sums its struts in ascending index order.
    for (const std::uint32_t j : cand) {
        const GaussianSegment& s = mSegments[j];
        const double rc2 = mCutoffSqr[j];
        std::size_t n = 0;
        for (int i = 0; i < batch.nx; ++i)
            for (int jj = 0; jj < batch.ny; ++jj)
                for (int k = 0; k < batch.nz; ++k, ++n) {
                    double h, r2;
                    if (s.distanceSqr(batch.point(i, jj, k), h, r2) >= rc2) continue;
                    out[n] += s.value(h, r2);
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
