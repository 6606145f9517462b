/// @file SignWords.h
/// @brief A leaf's values below a threshold as 512 bits, eight bytes at a time.
#pragma once

#include <cstdint>

#if defined(__SSE2__)
#include <immintrin.h>
#endif

namespace voxlat {

/// Bit z set when v[z] < threshold, for 8 consecutive values.
inline unsigned belowByte(const float* v, float threshold)
{
#if defined(__SSE2__)
    const __m128 t = _mm_set1_ps(threshold);
    return unsigned(_mm_movemask_ps(_mm_cmplt_ps(_mm_loadu_ps(v), t))) |
           (unsigned(_mm_movemask_ps(_mm_cmplt_ps(_mm_loadu_ps(v + 4), t))) << 4);
#else
    unsigned bits = 0;
    for (int z = 0; z < 8; ++z) bits |= unsigned(v[z] < threshold) << z;
    return bits;
#endif
}

/// The 512 values of an 8^3 leaf (offset x << 6 | y << 3 | z) below @a threshold as eight words:
/// word x, bit (y << 3) | z. "<", never "<=": a value exactly at the threshold is not below.
inline void belowWords(const float* values, float threshold, std::uint64_t* words)
{
    for (int x = 0; x < 8; ++x) {
        std::uint64_t word = 0;
        for (int y = 0; y < 8; ++y)
            word |= std::uint64_t(belowByte(values + (x << 6) + (y << 3), threshold)) << (8 * y);
        words[x] = word;
    }
}

}  // namespace voxlat
