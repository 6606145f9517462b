/// @file LittleEndian.h
/// @brief Appends little-endian numbers, fixed-width strings and padding to a byte string: the
/// binary slice formats (.ctb, Photon Workshop) lay their headers and tables out with it.
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>

namespace voxlat {

/// Appends to the string it is given; never shrinks it.
class LittleEndian {
public:
    explicit LittleEndian(std::string& out) : mOut(out) {}
    void u8(unsigned v) { mOut.push_back(char(v & 0xFF)); }
    void u16(unsigned v)
    {
        u8(v);
        u8(v >> 8);
    }
    void u32(std::uint32_t v)
    {
        u16(v & 0xFFFF);
        u16(v >> 16);
    }
    /// @a v as an IEEE single.
    void f32(double v)
    {
        const float f = float(v);
        std::uint32_t bits;
        std::memcpy(&bits, &f, 4);
        u32(bits);
    }
    /// @a s NUL-padded to @a width bytes (cut to width - 1 so a NUL always ends it).
    void text(const std::string& s, std::size_t width)
    {
        const std::size_t n = std::min(s.size(), width - 1);
        mOut.append(s, 0, n);
        mOut.append(width - n, '\0');
    }
    void zeros(std::size_t n) { mOut.append(n, '\0'); }
    void raw(const std::string& s) { mOut += s; }
    /// Pads with zeros up to absolute offset @a at (a section's start); a section already past
    /// it is a bug in the layout.
    void to(std::size_t at)
    {
        if (mOut.size() > at) throw std::logic_error("a slice archive's section overruns the next one");
        mOut.append(at - mOut.size(), '\0');
    }

private:
    std::string& mOut;
};

}  // namespace voxlat
