// Built with -mavx2 -mfma where the compiler targets x86-64 (fields/CMakeLists.txt); runs only
// where the CPU has both (hasAvx2SinCos()).
#include "fields/core/SinCos.h"

#include <cmath>

#if defined(VOXLAT_SLEEF_AVX2)
#include <immintrin.h>
#include <sleef.h>
#endif

namespace voxlat {

#if defined(VOXLAT_SLEEF_AVX2)

void sinCosBatchAvx2(const double* x, double* s, double* c, std::size_t n)
{
    std::size_t i = 0;
    for (; i + 4 <= n; i += 4) {
        const Sleef___m256d_2 r = Sleef_sincosd4_u35avx2(_mm256_loadu_pd(x + i));
        _mm256_storeu_pd(s + i, r.x);
        _mm256_storeu_pd(c + i, r.y);
    }
    if (i < n) {
        // The last few through the same vector function (padded), so every angle gets the same
        // result wherever it falls in a batch.
        double in[4] = {0.0, 0.0, 0.0, 0.0}, outS[4], outC[4];
        for (std::size_t k = i; k < n; ++k) in[k - i] = x[k];
        const Sleef___m256d_2 r = Sleef_sincosd4_u35avx2(_mm256_loadu_pd(in));
        _mm256_storeu_pd(outS, r.x);
        _mm256_storeu_pd(outC, r.y);
        for (std::size_t k = i; k < n; ++k) s[k] = outS[k - i], c[k] = outC[k - i];
    }
}

bool hasAvx2SinCos()
{
    static const bool has = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    return has;
}

#else

void sinCosBatchAvx2(const double* x, double* s, double* c, std::size_t n)
{
    for (std::size_t i = 0; i < n; ++i) s[i] = std::sin(x[i]), c[i] = std::cos(x[i]);
}

bool hasAvx2SinCos()
{
    return false;
}

#endif

}  // namespace voxlat
