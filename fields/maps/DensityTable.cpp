#include "fields/maps/DensityTable.h"

#include "fields/core/BlockLattice.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace voxlat {

DensityTable::DensityTable(const FieldNode& indicator, const Box3& cell, int samplesPerAxis, int entries)
{
    if (samplesPerAxis < 8 || entries < 2) throw std::invalid_argument("density table: too few samples or entries");
    const int n = (samplesPerAxis + 7) / 8 * 8;  // whole 8^3 blocks
    BlockLattice lattice;                        // the cell's sample centres
    lattice.base = cell.min;
    lattice.step = cell.extent() / double(n);
    lattice.offset = Vec3d(0.5);
    lattice.count = {n, n, n};
    std::vector<double> samples(std::size_t(n) * n * n);
    // Each block writes its own slice, so the sample set (and after sorting the table) is the
    // same for any number of threads.
    sampleBlocks(indicator, lattice, [&](std::size_t b, const GridBatch&, auto, std::span<const double> values) {
        std::copy(values.begin(), values.end(), samples.begin() + std::ptrdiff_t(b * 512));
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
