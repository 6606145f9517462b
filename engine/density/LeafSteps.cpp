#include "engine/density/LeafSteps.h"

#include "fields/struts/StrutRows.h"

#include <array>

namespace voxlat::coverage {

const float* leafNoNeighbours()
{
    static const std::array<float, 512> none = [] {
        std::array<float, 512> values{};
        values.fill(kNoNeighbour);
        return values;
    }();
    return none.data();
}

void leafSteps(const LeafWithNeighbours& leaf, float* steps, float lo, float hi)
{
    if (hasAvx512Rows()) return avx512::leafSteps(leaf, steps, lo, hi);
    if (hasAvx2Rows()) return avx2::leafSteps(leaf, steps, lo, hi);
    leafStepsLoop(leaf, steps);
}

LeafStraddle leafStraddle(const float* data, const float* steps, const StraddleBounds& s)
{
    if (hasAvx512Rows()) return avx512::leafStraddle(data, steps, s);
    if (hasAvx2Rows()) return avx2::leafStraddle(data, steps, s);
    return leafStraddleLoop(data, steps, s);
}

float leafWidest(const float* data, const float* steps, float lo, float hi)
{
    if (hasAvx512Rows()) return avx512::leafWidest(data, steps, lo, hi);
    if (hasAvx2Rows()) return avx2::leafWidest(data, steps, lo, hi);
    return leafWidestLoop(data, steps, lo, hi);
}

bool leafMeets(const float* data, float lo, float hi)
{
    if (hasAvx512Rows()) return avx512::leafMeets(data, lo, hi);
    if (hasAvx2Rows()) return avx2::leafMeets(data, lo, hi);
    return leafMeetsLoop(data, lo, hi);
}

}  // namespace voxlat::coverage
