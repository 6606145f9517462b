/// @file IsoRadiusSingleAvx2.cpp
/// isoRadiiSingleLoop built for AVX2 without FMA or contraction, for CPUs without AVX-512F: the
/// baseline build's doubles.
#include "fields/struts/IsoRadiusSingle.h"

namespace voxlat {

void isoRadiiSingleAvx2(double* values, std::size_t n, const SingleRadii& m)
{
    isoRadiiSingleLoop(values, n, m);
}

}  // namespace voxlat
