#include "fields/DensityTable.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace voxlat {

DensityTable::DensityTable(const FieldNode& indicator, const Box3& cell, int samplesPerAxis, int entries)
{
    if (samplesPerAxis < 8 || entries < 2) throw std::invalid_argument("density table: too few samples or entries");
    const int n = (samplesPerAxis + 7) / 8 * 8;  // whole 8^3 blocks
    const int blocks = n / 8;
    const Vec3d step = cell.extent() / double(n);
    std::vector<double> samples(std::size_t(n) * n * n);
    // Each block writes its own slice, so the sample set (and after sorting the table) is the
    // same for any number of threads.
    tbb::parallel_for(tbb::blocked_range<int>(0, blocks * blocks * blocks), [&](const auto& range) {
        for (int b = range.begin(); b != range.end(); ++b) {
            const int bx = b / (blocks * blocks), by = (b / blocks) % blocks, bz = b % blocks;
            GridBatch batch;
            batch.spacing = step;
            batch.origin =
                cell.min + Vec3d((8 * bx + 0.5) * step.x(), (8 * by + 0.5) * step.y(), (8 * bz + 0.5) * step.z());
            indicator.gridValues(batch, std::span<double>(samples.data() + std::size_t(b) * 512, 512));
        }
    });
    std::sort(samples.begin(), samples.end());
    mSamples = samples.size();
    mMinDensity = 1.0 / double(mSamples);
    // Sample i stands for the share (i + 1/2) / N of the cell: the quantile at density rho lies at
    // position rho N - 1/2, interpolated between neighbours.
    mLevels.resize(std::size_t(entries));
    const double count = double(mSamples);
    for (int j = 0; j < entries; ++j) {
        const double pos = std::clamp(double(j) / (entries - 1) * count - 0.5, 0.0, count - 1.0);
        const auto i = std::size_t(pos);
        const double t = pos - double(i);
        mLevels[j] = i + 1 < mSamples ? samples[i] + t * (samples[i + 1] - samples[i]) : samples[i];
    }
}

double DensityTable::levelAt(double density) const
{
    const double pos = std::clamp(density, 0.0, 1.0) * double(mLevels.size() - 1);
    const auto i = std::min(std::size_t(pos), mLevels.size() - 2);
    const double t = pos - double(i);
    return mLevels[i] + t * (mLevels[i + 1] - mLevels[i]);
}

double DensityTable::levelSlope(double density) const
{
    const double pos = std::clamp(density, 0.0, 1.0) * double(mLevels.size() - 1);
    const auto i = std::min(std::size_t(pos), mLevels.size() - 2);
    return (mLevels[i + 1] - mLevels[i]) * double(mLevels.size() - 1);
}

double DensityTable::densityAt(double level) const
{
    if (level <= mLevels.front()) return 0.0;
    if (level >= mLevels.back()) return 1.0;
    const auto it = std::upper_bound(mLevels.begin(), mLevels.end(), level);
    const auto i = std::size_t(it - mLevels.begin()) - 1;
    const double span = mLevels[i + 1] - mLevels[i];
    const double t = span > 0.0 ? (level - mLevels[i]) / span : 0.0;
    return (double(i) + t) / double(mLevels.size() - 1);
}

}  // namespace voxlat
