/// @file Version.h
/// @brief The version of voxlat, from CMake's project(), for --version, report.json and archives.
#pragma once

#include <string>

namespace voxlat {

/// "MAJOR.MINOR.PATCH" as set in the top CMakeLists.txt.
std::string versionString();

}  // namespace voxlat
