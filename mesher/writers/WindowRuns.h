/// @file WindowRuns.h
/// @brief The runs of a layer over the whole display, row after row (runs continue across rows),
/// from its stored window: what every run-length layer code of the native resin formats walks.
#pragma once

#include <cstdint>

namespace voxlat {

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
            int e = c + 1;
            while (e < w && key(row[e]) == v) ++e;
            add(v, std::uint64_t(e - c));
            c = e;
        }
        add(black, std::uint64_t(width - col0 - w));
    }
    add(black, std::uint64_t(height - row0 - h) * width);
    if (length > 0) emit(value, length);
}

}  // namespace voxlat
