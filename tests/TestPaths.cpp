// The build's paths, given to this source only (CMakeLists.txt): every other test source compiles
// to the same object in any checkout. It includes nothing heavy (it compiled in 25 s with
// TestUtil.h's engine headers).
#include "TestPaths.h"

namespace voxlat::test {

std::string voxlatBinary()
{
    return VOXLAT_BINARY;
}

std::filesystem::path sourceDir()
{
    return VOXLAT_SOURCE_DIR;
}

}  // namespace voxlat::test
