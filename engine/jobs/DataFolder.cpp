#include "engine/jobs/DataFolder.h"

#include <mutex>

#ifndef VOXLAT_DATA_DIR
#define VOXLAT_DATA_DIR "data"
#endif

namespace voxlat {

namespace {
std::mutex gMutex;
std::string gFolder = VOXLAT_DATA_DIR;
}  // namespace

std::string dataFolder()
{
    std::lock_guard<std::mutex> lock(gMutex);
    return gFolder;
}

void setDataFolder(const std::string& folder)
{
    std::lock_guard<std::mutex> lock(gMutex);
    gFolder = folder;
}

std::string installedDataFolder(const std::filesystem::path& executable)
{
    std::error_code ec;
    const std::filesystem::path exe = std::filesystem::weakly_canonical(executable, ec);
    if (ec || exe.empty()) return {};
    const std::filesystem::path share = exe.parent_path().parent_path() / "share" / "voxlat";
    if (!std::filesystem::is_directory(share / "printers", ec)) return {};
    return share.lexically_normal().string();
}

}  // namespace voxlat
