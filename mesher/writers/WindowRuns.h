/// @file WindowRuns.h
/// @brief The runs of a layer over the whole display, row after row (runs continue across rows),
/// from its stored window: what every run-length layer code of the native resin formats walks.
#pragma once

#include <bit>
#include <cstdint>
#include <cstring>

namespace voxlat {

/// The first index in [@a from, @a end) whose byte of @a row differs from @a v, or @a end: eight
/// bytes at a time (the layers' runs of black and full exposure are tens to thousands long).
inline int sameBytesEnd(const std::uint8_t* row, int from, int end, std::uint8_t v)
{
    int e = from;
    if constexpr (std::endian::native == std::endian::little) {
        const std::uint64_t broadcast = 0x0101010101010101ull * v;
        for (; e + 8 <= end; e += 8) {
            std::uint64_t word;
            std::memcpy(&word, row + e, 8);
            if (const std::uint64_t diff = word ^ broadcast) return e + std::countr_zero(diff) / 8;
        }
    }
    while (e < end && row[e] == v) ++e;
    return e;
}

/// Calls @a emit(value, length) for each maximal run of equal @a key(grey) over a display of
/// @a width x @a height pixels that are black (grey 0) except the window of @a w x @a h bytes
/// (row-major) at column @a col0, row @a row0; runs are in raster order, top row first, and never
/// empty. The codes split long runs in @a emit.
template <class Key, class Emit>
void windowRuns(int width, int height, const std::uint8_t* window, int col0, int row0, int w, int h, Key key, Emit emit)
{
    const auto black = key(std::uint8_t(0));
    auto value = black;
    std::uint64_t length = 0;
    auto add = [&](decltype(black) v, std::uint64_t n) {
        if (n == 0) return;
        if (v != value && length > 0) {
            emit(value, length);
            length = 0;
        }
        value = v;
        length += n;
    };
    add(black, std::uint64_t(row0) * width);
    for (int r = 0; r < h; ++r) {
        add(black, std::uint64_t(col0));
        const std::uint8_t* row = window + std::size_t(r) * w;
        for (int c = 0; c < w;) {
            const auto v = key(row[c]);
            // Equal bytes share their key: skipped a word at a time, then bytes of another grey
            // with the same key one by one.
            int e = sameBytesEnd(row, c + 1, w, row[c]);
            while (e < w && key(row[e]) == v) e = sameBytesEnd(row, e + 1, w, row[e]);
            add(v, std::uint64_t(e - c));
            c = e;
        }
        add(black, std::uint64_t(width - col0 - w));
    }
    add(black, std::uint64_t(height - row0 - h) * width);
    if (length > 0) emit(value, length);
}

}  // namespace voxlat
