#include "fields/struts/IsoRadius.h"

#include <cmath>
#include <stdexcept>
#include <vector>

namespace voxlat {

IsoRadius::IsoRadius(FieldPtr convolution, double peak, double sigma, double rhoMax)
    : mF(std::move(convolution)), mPeak(peak), mSigma(sigma), mRhoMax(rhoMax)
{
    if (!(peak > 0.0 && sigma > 0.0 && rhoMax > 0.0))
        throw std::invalid_argument("IsoRadius needs positive parameters");
    mFMin = valueOf(rhoMax);
}

double IsoRadius::radiusOf(double f) const
{
    if (f <= mFMin) return mRhoMax;
    // Where joints sum above P the radius continues negative (signed root): monotone, no ties.
    const double u = std::log(mPeak / f);
    return std::min(mRhoMax, std::copysign(mSigma * std::sqrt(2.0 * std::abs(u)), u));
}

double IsoRadius::valueOf(double rho) const
{
    return mPeak * std::exp(-std::copysign(rho * rho, rho) / (2.0 * mSigma * mSigma));
}

void IsoRadius::values(std::span<const Vec3d> points, std::span<double> out) const
{
    mF->values(points, out);
    for (double& v : out) v = radiusOf(v);
}

void IsoRadius::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    mF->gradients(points, out, grad);
    for (std::size_t n = 0; n < out.size(); ++n) {
        const double f = out[n];
        out[n] = radiusOf(f);
        // d rho / dF = -sigma^2 / (F |rho|); flat where capped, unbounded at F = P.
        const bool flat = f <= mFMin || out[n] >= mRhoMax || out[n] == 0.0;
        grad[n] *= flat ? 0.0 : -mSigma * mSigma / (f * std::abs(out[n]));
    }
}

void IsoRadius::gridValues(const GridBatch& batch, std::span<double> out) const
{
    mF->gridValues(batch, out);
    for (std::size_t n = 0; n < batch.size(); ++n) out[n] = radiusOf(out[n]);
}

Interval IsoRadius::bound(const Box3& box) const
{
    const Interval f = mF->bound(box);
    return {radiusOf(f.hi), radiusOf(f.lo)};
}

}  // namespace voxlat
