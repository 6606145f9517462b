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

namespace {

/// The fastest form the build has and the CPU runs, chosen once.
const LeafStepForms& forms()
{
    static const LeafStepForms chosen = [] {
        if (hasAvx512Rows() && avx512LeafSteps()) return *avx512LeafSteps();
        if (hasAvx2Rows() && avx2LeafSteps()) return *avx2LeafSteps();
        return LeafStepForms{
            [](const LeafWithNeighbours& leaf, float* steps, float, float) { leafStepsLoop(leaf, steps); },
            leafStraddleLoop, leafWidestLoop, leafMeetsLoop};
    }();
    return chosen;
}

}  // namespace

void leafSteps(const LeafWithNeighbours& leaf, float* steps, float lo, float hi)
{
    forms().steps(leaf, steps, lo, hi);
}

LeafStraddle leafStraddle(const float* data, const float* steps, const StraddleBounds& s)
{
    return forms().straddle(data, steps, s);
}

float leafWidest(const float* data, const float* steps, float lo, float hi)
{
    return forms().widest(data, steps, lo, hi);
}

bool leafMeets(const float* data, float lo, float hi)
{
    return forms().meets(data, lo, hi);
}

}  // namespace voxlat::coverage
