#include "fields/levels/GradedLevel.h"

#include <algorithm>
#include <vector>

namespace voxlat {

GradedLevel::GradedLevel(FieldPtr indicator, FieldPtr density, const Box3& cell, int samplesPerAxis)
    : mIndicator(std::move(indicator)),
      mDensity(std::move(density)),
      mTable(std::make_shared<DensityTable>(*mIndicator, cell, samplesPerAxis))
{
}

GradedLevel::GradedLevel(FieldPtr indicator, FieldPtr density, std::shared_ptr<const DensityTable> table)
    : mIndicator(std::move(indicator)), mDensity(std::move(density)), mTable(std::move(table))
{
}

double GradedLevel::clampDensity(double rho) const
{
    return std::clamp(rho, mTable->minDensity(), mTable->maxDensity());
}

void GradedLevel::values(std::span<const Vec3d> points, std::span<double> out) const
{
    mIndicator->values(points, out);
    forEachChunk(points.size(), [&](std::size_t begin, std::size_t count) {
        std::vector<double> rho(count);
        mDensity->values(points.subspan(begin, count), rho);
        for (std::size_t i = 0; i < count; ++i) out[begin + i] -= mTable->levelAt(clampDensity(rho[i]));
    });
}

void GradedLevel::gridValues(const GridBatch& batch, std::span<double> out) const
{
    mIndicator->gridValues(batch, out);
    std::vector<double> rho(batch.size());
    mDensity->gridValues(batch, rho);
    for (std::size_t i = 0; i < rho.size(); ++i) out[i] -= mTable->levelAt(clampDensity(rho[i]));
}

void GradedLevel::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    mIndicator->gradients(points, out, grad);
    forEachChunk(points.size(), [&](std::size_t begin, std::size_t count) {
        std::vector<double> rho(count);
        std::vector<Vec3d> rhoGrad(count);
        mDensity->gradients(points.subspan(begin, count), rho, rhoGrad);
        for (std::size_t i = 0; i < count; ++i) {
            const double r = rho[i], c = clampDensity(r);
            out[begin + i] -= mTable->levelAt(c);
            if (r == c) grad[begin + i] -= mTable->levelSlope(c) * rhoGrad[i];
        }
    });
}

double GradedLevel::period(int axis) const
{
    return commonPeriod(mIndicator->period(axis), mDensity->period(axis));
}

Interval GradedLevel::bound(const Box3& box) const
{
    const Interval rho = mDensity->bound(box);
    // level() is non-decreasing in the density.
    const Interval level(mTable->levelAt(clampDensity(rho.lo)), mTable->levelAt(clampDensity(rho.hi)));
    return mIndicator->bound(box) - level;
}

}  // namespace voxlat
