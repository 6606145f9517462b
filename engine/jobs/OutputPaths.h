/// @file OutputPaths.h
/// @brief Where outputs may go: inside the output folder, onto nothing but regular files.
#pragma once

#include <filesystem>
#include <string>

namespace voxlat {

/// The path of output @a name inside @a outDir. Throws InputError (naming @a where) when it
/// resolves outside @a outDir (a symlink out) or onto something that is not a regular file (a
/// device, a folder, a FIFO): an output never replaces what it did not make.
std::filesystem::path outputPathIn(const std::filesystem::path& outDir, const std::string& name,
                                   const std::string& where);

/// Throws InputError (naming @a where) when @a path exists and is not a regular file (`-o /dev/null`
/// would otherwise replace the device node) or is a symlink.
void checkReplaceable(const std::filesystem::path& path, const std::string& where);

}  // namespace voxlat
