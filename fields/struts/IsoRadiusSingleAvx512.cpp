/// @file IsoRadiusSingleAvx512.cpp
/// isoRadiiSingleLoop built for AVX-512F without contraction: the baseline build's doubles.
#include "fields/struts/IsoRadiusSingle.h"

namespace voxlat {

void isoRadiiSingleAvx512(double* values, std::size_t n, const SingleRadii& m)
{
    isoRadiiSingleLoop(values, n, m);
}

}  // namespace voxlat
