// The density solve's coverage samples: what solveDensity's coverage pass relies on when it walks
// the grid once per band instead of picking the bands' samples from the evaluated band's.
#include "engine/core/GridMeasure.h"
#include "engine/core/SparseEvaluator.h"
#include "engine/density/Coverage.h"
#include "engine/frames/StrutFrames.h"
#include "engine/frames/UnitCells.h"
#include "fields/struts/IsoRadius.h"
#include "fields/struts/StrutConvolution.h"

#include <gtest/gtest.h>

#include <cstring>

using namespace voxlat;
using namespace voxlat::coverage;

TEST(Coverage, ANarrowerBandsSamplesAreTheWiderBandsPickedInOrder)
{
    // A strut lattice's iso-radius evaluated over a band (leaves, inside and outside tiles), the
    // region past the domain by two voxels: the samples of a band within the evaluated one are
    // that band's picks from the evaluated band's samples, in the same order and the same bits
    // (a voxel's step does not depend on the band), and the voxels below its low end are those
    // below the evaluated band's plus the evaluated samples between the two low ends.
    const Frame f = boxFrame(presetUnitCell("bcc"), Vec3d(0.0), Vec3d(4.0), {2, 2, 2});
    std::vector<ConvolutionStrut> struts;
    for (const auto& e : f.struts) struts.push_back({f.nodes[e[0]], f.nodes[e[1]], 0.4, 1.0, 1.3});
    const auto raw = std::make_shared<StrutConvolution>(struts);
    const IsoRadius iso(raw, raw->peak(0), 0.4, 2.0 * raw->cutoffRadius(0));
    const Domain d = Domain::fromBox(Box3{Vec3d(-0.33, -0.27, -0.41), Vec3d(8.37, 8.21, 8.13)}, 0.1);
    SparseOptions options;
    options.band = Interval(0.3, 0.9);
    options.margin = 2;
    options.insideValue = -std::numeric_limits<float>::max();
    options.outsideValue = std::numeric_limits<float>::max();
    const auto grid = evaluateSparse(iso, d, options);
    const openvdb::CoordBBox region(openvdb::Coord(-2), d.dims - openvdb::Coord(-1));
    const float lo = 0.3f, hi = 0.9f;
    const std::vector<CoverageSample> wide = coverageSamples(*grid, region, lo, hi);
    ASSERT_GT(wide.size(), 10000u);
    for (const auto& [nlo, nhi] : {std::pair{0.45f, 0.62f}, std::pair{0.3f, 0.5f}, std::pair{0.61f, 0.9f}}) {
        const std::vector<CoverageSample> narrow = coverageSamples(*grid, region, nlo, nhi);
        std::vector<CoverageSample> picked;
        std::uint64_t between = 0;
        for (const CoverageSample& c : wide) {
            if (!(c.value < nlo || c.value > nhi)) picked.push_back(c);
            between += c.value < nlo;  // at or above lo: in the evaluated band
        }
        ASSERT_EQ(narrow.size(), picked.size()) << nlo;
        EXPECT_EQ(std::memcmp(narrow.data(), picked.data(), narrow.size() * sizeof(CoverageSample)), 0) << nlo;
        EXPECT_EQ(countBelow(*grid, region, nlo), countBelow(*grid, region, lo) + between) << nlo;
        EXPECT_GT(between + narrow.size(), 0u);
    }
}
