/// @file DataFolder.h
/// @brief Where voxlat's shipped data is read from: printer profiles, example recipes and unit
/// cells, sample meshes, scripts and the page's JavaScript.
///
/// A build reads the source tree's `data/`; an installed copy (`cmake --install`, `pip install`)
/// reads `<prefix>/share/voxlat`, found from the running program: the front ends set it
/// (`setDataFolder`) before any job runs.
#pragma once

#include <filesystem>
#include <string>

namespace voxlat {

/// The data folder: the one set by setDataFolder(), else the source tree's `data/` of the build.
std::string dataFolder();

/// Sets the data folder for the whole process (front ends, at start-up).
void setDataFolder(const std::string& folder);

/// `<folder of executable>/../share/voxlat` when it holds `printers/` (an installed copy), else
/// empty (a build folder, which reads the source tree's data).
std::string installedDataFolder(const std::filesystem::path& executable);

}  // namespace voxlat
