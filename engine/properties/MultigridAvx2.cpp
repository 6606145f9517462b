/// @file MultigridAvx2.cpp
/// The multigrid solver's element products (MultigridKernels.h) built for AVX2, without FMA and
/// without contraction: the same bits as the baseline build, in fewer instructions. This file
/// alone is compiled with -mavx2 (engine/CMakeLists.txt); Multigrid.cpp calls it only where the
/// CPU has AVX2.

#define VOXLAT_MG_ISA avx2
#include "engine/properties/MultigridKernels.h"

namespace voxlat::homogenization::avx2 {

template void elementBlocks<1, float, 1>(const std::int32_t*, std::size_t, std::size_t, const float*, const Float4*,
                                         const float*, float*, int);
template void elementBlocks<1, double, 1>(const std::int32_t*, std::size_t, std::size_t, const double*, const Double4*,
                                          const double*, double*, int);
template void elementBlocks<3, float, 4>(const std::int32_t*, std::size_t, std::size_t, const float*, const Float4*,
                                         const float*, float*, int);
template void elementBlocks<3, double, 3>(const std::int32_t*, std::size_t, std::size_t, const double*, const Double4*,
                                          const double*, double*, int);
template void elementDense<1, float, 1>(const std::int32_t*, const std::int32_t*, const float*, bool, std::int32_t,
                                        const float*, const Float4*, std::size_t, std::size_t, const float*, float*,
                                        int);
template void elementDense<1, double, 1>(const std::int32_t*, const std::int32_t*, const double*, bool, std::int32_t,
                                         const double*, const Double4*, std::size_t, std::size_t, const double*,
                                         double*, int);
template void elementDense<3, float, 4>(const std::int32_t*, const std::int32_t*, const float*, bool, std::int32_t,
                                        const float*, const Float4*, std::size_t, std::size_t, const float*, float*,
                                        int);
template void elementDense<3, double, 3>(const std::int32_t*, const std::int32_t*, const double*, bool, std::int32_t,
                                         const double*, const Double4*, std::size_t, std::size_t, const double*,
                                         double*, int);

// Every combination of chebyshevNodes' flags.
#define VOXLAT_CHEBYSHEV(a, b, c, d)                                                                                  \
    template void chebyshevNodes<a, b, c, d>(const float*, std::size_t, std::size_t, int, const float*, const float*, \
                                             const float*, float*, float*, float, float);
VOXLAT_CHEBYSHEV(false, false, false, false)
VOXLAT_CHEBYSHEV(false, false, false, true)
VOXLAT_CHEBYSHEV(false, false, true, false)
VOXLAT_CHEBYSHEV(false, false, true, true)
VOXLAT_CHEBYSHEV(false, true, false, false)
VOXLAT_CHEBYSHEV(false, true, false, true)
VOXLAT_CHEBYSHEV(false, true, true, false)
VOXLAT_CHEBYSHEV(false, true, true, true)
VOXLAT_CHEBYSHEV(true, false, false, false)
VOXLAT_CHEBYSHEV(true, false, false, true)
VOXLAT_CHEBYSHEV(true, false, true, false)
VOXLAT_CHEBYSHEV(true, false, true, true)
VOXLAT_CHEBYSHEV(true, true, false, false)
VOXLAT_CHEBYSHEV(true, true, false, true)
VOXLAT_CHEBYSHEV(true, true, true, false)
VOXLAT_CHEBYSHEV(true, true, true, true)
#undef VOXLAT_CHEBYSHEV

}  // namespace voxlat::homogenization::avx2
