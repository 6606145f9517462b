#include "engine/core/Version.h"

namespace voxlat {

std::string versionString()
{
    return VOXLAT_VERSION;
}

}  // namespace voxlat
