#include "fields/core/SinCos.h"

#include <cmath>

#if defined(VOXLAT_SLEEF_SSE2)
#include <emmintrin.h>
#include <sleef.h>
#endif

namespace voxlat {

void sinCosBatch(const double* x, double* s, double* c, std::size_t n)
{
    if (hasAvx2SinCos()) {
        sinCosBatchAvx2(x, s, c, n);
        return;
    }
    std::size_t i = 0;
#if defined(VOXLAT_SLEEF_SSE2)
    for (; i + 2 <= n; i += 2) {
        const Sleef___m128d_2 r = Sleef_sincosd2_u35sse2(_mm_loadu_pd(x + i));
        _mm_storeu_pd(s + i, r.x);
        _mm_storeu_pd(c + i, r.y);
    }
    if (i < n) {  // the last one through the same function (padded): the same result anywhere
        const Sleef___m128d_2 r = Sleef_sincosd2_u35sse2(_mm_set_pd(0.0, x[i]));
        s[i] = _mm_cvtsd_f64(r.x);
        c[i] = _mm_cvtsd_f64(r.y);
        return;
    }
#endif
    for (; i < n; ++i) {
        s[i] = std::sin(x[i]);
        c[i] = std::cos(x[i]);
    }
}

}  // namespace voxlat
