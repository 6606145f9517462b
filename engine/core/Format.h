/// @file Format.h
/// @brief Numbers in messages, written as a stream writes them (six significant digits).
#pragma once

#include <sstream>
#include <string>

namespace voxlat {

inline std::string formatNumber(double v)
{
    std::ostringstream s;
    s << v;
    return s.str();
}

}  // namespace voxlat
