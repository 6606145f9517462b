#pragma once
// The build's paths, defined in tests/TestPaths.cpp only: every other test source compiles to the
// same object in any checkout and hits a shared compiler cache.

#include <filesystem>
#include <string>

namespace voxlat::test {

/// The `voxlat` program of this build.
std::string voxlatBinary();
/// The checkout the tests read data from.
std::filesystem::path sourceDir();

}  // namespace voxlat::test
