/// @file DensityTable.h
/// @brief The relative density of a solid {g < level} as a function of the level, computed
/// numerically over one unit cell, and its monotone inverse.
#pragma once

#include "fields/core/FieldNode.h"

#include <vector>

namespace voxlat {

/// Samples an indicator field g on n^3 cell-centred points of one unit cell, sorts the values
/// and keeps the quantiles: the level at which the solid {g < level} fills a share rho of the
/// cell. Works for any field (TPMS network or sheet, shifted fields, user equations): no fitted
/// catalog curve is involved. Both directions are piecewise linear and monotone, so they are
/// exact inverses of each other between the table's entries.
class DensityTable {
public:
    /// @param indicator  the field whose sub-level set is the solid
    /// @param cell       one period of it (the table is exact for periodic fields)
    /// @param samplesPerAxis  n; the density resolution is 1 / n^3
    /// @param entries    quantiles kept (evenly spaced in density, both ends included)
    DensityTable(const FieldNode& indicator, const Box3& cell, int samplesPerAxis = 96, int entries = 4097);

    /// The level at which the solid fills @a density of the cell (clamped to the table).
    double levelAt(double density) const;
    /// d level / d density at @a density (the slope of the piece it falls in).
    double levelSlope(double density) const;
    /// The share of the cell below @a level (inverse of levelAt).
    double densityAt(double level) const;

    /// Densities the cell resolves: [1 / n^3, 1 - 1 / n^3].
    double minDensity() const { return mMinDensity; }
    double maxDensity() const { return 1.0 - mMinDensity; }
    std::size_t sampleCount() const { return mSamples; }
    const std::vector<double>& levels() const { return mLevels; }

private:
    std::vector<double> mLevels;  ///< level at density j / (entries - 1)
    double mMinDensity = 0.0;
    std::size_t mSamples = 0;
};

}  // namespace voxlat
