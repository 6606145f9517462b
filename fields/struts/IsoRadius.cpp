#include "fields/struts/IsoRadius.h"

#include "fields/struts/IsoRadiusAvx2.h"
#include "fields/struts/IsoRadiusSingle.h"
#include "fields/struts/StrutRows.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
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

void IsoRadius::radii(std::span<double> values) const
{
    // radiusOf()'s operations in its order, the same doubles, in three loops over a chunk: the
    // divisions and the square roots run in loops of their own (the file is built with
    // -fno-math-errno) and only the logarithm is a call per value; point by point the call held
    // up every division and root behind it. On W10's plate radiusOf and its log were 12.6 % of
    // slicing, this map and its log 11.5 %: the log calls are most of what is left.
    // Four values at a time where the CPU has AVX2 and FMA and the lanes' logarithm is the
    // library's (hasIsoRadiiAvx2): the same doubles, the log no longer a call per value.
    // Eight at a time where the CPU has AVX-512F (the same doubles again).
    if (hasIsoRadiiAvx512()) {
        isoRadiiAvx512(values.data(), values.size(), mPeak, mFMin, mSigma, mRhoMax);
        return;
    }
    if (hasIsoRadiiAvx2()) {
        isoRadiiAvx2(values.data(), values.size(), mPeak, mFMin, mSigma, mRhoMax);
        return;
    }
    constexpr std::size_t kChunk = 256;
    double u[kChunk];
    for (std::size_t start = 0; start < values.size(); start += kChunk) {
        const std::size_t n = std::min(kChunk, values.size() - start);
        double* f = values.data() + start;
        for (std::size_t k = 0; k < n; ++k) u[k] = mPeak / (f[k] <= mFMin ? mPeak : f[k]);  // 1 where capped
        // log(1) = 0 exactly: capped values (F = 0 far from the struts, or left out by
        // planeValues) take no call.
        for (std::size_t k = 0; k < n; ++k) u[k] = u[k] == 1.0 ? 0.0 : std::log(u[k]);
        for (std::size_t k = 0; k < n; ++k) {
            const double rho = std::min(mRhoMax, std::copysign(mSigma * std::sqrt(2.0 * std::abs(u[k])), u[k]));
            f[k] = f[k] <= mFMin ? mRhoMax : rho;
        }
    }
}

void IsoRadius::radiiSingle(std::span<double> values) const
{
    const SingleRadii m{float(std::log(mPeak)), float(mSigma), mFMin, mRhoMax};
    if (hasAvx512Rows())
        isoRadiiSingleAvx512(values.data(), values.size(), m);
    else if (hasAvx2Rows())
        isoRadiiSingleAvx2(values.data(), values.size(), m);
    else
        isoRadiiSingleLoop(values.data(), values.size(), m);
}

bool IsoRadius::planeSingle() const
{
    // Single precision holds its 1e-7 of sigma only for values within its range (fMin at or above
    // 1e-30: rhoMax within about 11.6 sigma of the peak).
    const auto* bands = dynamic_cast<const PlaneBands*>(mF.get());
    return bands && bands->planeTolerance() > 0.0 && mFMin >= 1e-30;
}

void IsoRadius::values(std::span<const Vec3d> points, std::span<double> out) const
{
    mF->values(points, out);
    radii(out.first(points.size()));
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
    radii(out.first(batch.size()));
}

void IsoRadius::planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                            std::span<signed char> side, std::span<const TileNeed> need) const
{
    const auto* bands = dynamic_cast<const PlaneBands*>(mF.get());
    const std::size_t tiles = PlaneTiles::of(plane, tile).size();
    if (!bands || !(band.lo <= band.hi)) {
        gridValues(plane, out);
        std::fill(side.begin(), side.begin() + tiles, static_cast<signed char>(0));
        return;
    }
    // rho > hi where F < F(hi + d) (never for hi at or past the cap: rho stops there), rho < lo
    // where F > F(lo - d) (F(-inf) = inf: never).
    const double d = 1e-9 * (mSigma + finiteScale(band));
    const double fLo = band.hi < mRhoMax ? valueOf(band.hi + d) : -std::numeric_limits<double>::infinity();
    bands->planeValues(plane, tile, Interval{fLo, valueOf(band.lo - d)}, out, side, need);
    const bool single = planeSingle();
    auto map = [&](std::span<double> values) {
        if (single)
            radiiSingle(values);
        else
            radii(values);
    };
    for (std::size_t t = 0; t < tiles; ++t) side[t] = static_cast<signed char>(-side[t]);
    // Only the points the open tiles read are mapped (each open tile's points and its one-point
    // halo: runs of tiles along each column); the others mean nothing and take rhoMax.
    const PlaneTiles grid = PlaneTiles::of(plane, tile);
    if (grid.nx == 0 || grid.ny > 64 || plane.ny < 2) {
        map(out.first(plane.size()));
        return;
    }
    for (int i = 0; i < plane.nx; ++i) {
        std::uint64_t open = 0;
        for (int a = std::max(0, (i - 1) / tile - 1); a <= std::min(grid.nx - 1, i / tile); ++a)
            if (i >= a * tile && i <= (a + 1) * tile + 1)
                for (int b = 0; b < grid.ny; ++b) {
                    const std::size_t t = std::size_t(a) * grid.ny + b;
                    open |= std::uint64_t(side[t] == 0 && needOf(need, t) != TileNeed::Skip) << b;
                }
        double* column = out.data() + std::size_t(i) * plane.ny;
        int done = 0;  // points below this are mapped or filled
        forEachTileRun(open, [&](int b0, int b1) {
            const int lo = b0 * tile, hi = std::min(plane.ny - 1, (b1 + 1) * tile + 1);
            std::fill(column + done, column + std::max(done, lo), mRhoMax);
            if (hi >= std::max(done, lo)) map(std::span<double>(column + std::max(done, lo), column + hi + 1));
            done = std::max(done, hi + 1);
        });
        std::fill(column + done, column + plane.ny, mRhoMax);
    }
}

Interval IsoRadius::bound(const Box3& box) const
{
    const Interval f = mF->bound(box);
    return {radiusOf(f.hi), radiusOf(f.lo)};
}

}  // namespace voxlat
