/// @file Format.h
/// @brief Numbers in messages (six significant digits, as a stream writes them) and in files
/// (ten, as PrusaSlicer's config files carry them).
#pragma once

#include <cstdio>
#include <sstream>
#include <string>

namespace voxlat {

inline std::string formatNumber(double v)
{
    std::ostringstream s;
    s << v;
    return s.str();
}

/// @a v with ten significant digits ("%.10g"): archive metadata and messages about printers.
inline std::string formatNumber10(double v)
{
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.10g", v);
    return buf;
}

}  // namespace voxlat
