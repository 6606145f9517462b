// The build's paths, given to this source only (CMakeLists.txt): every other test source compiles
// to the same object in any checkout.
#include "TestUtil.h"

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
