#include "engine/jobs/OutputPaths.h"

#include "engine/core/Errors.h"

namespace voxlat {

namespace fs = std::filesystem;

void checkReplaceable(const fs::path& path, const std::string& where)
{
    std::error_code ec;
    const fs::file_status status = fs::symlink_status(path, ec);
    if (!fs::exists(status)) return;
    if (fs::is_symlink(status))
        throw InputError(
            where + ": `" + path.string() +
            "` is a symbolic link; an output replaces only a regular file it can own: choose another name");
    if (!fs::is_regular_file(status))
        throw InputError(where + ": `" + path.string() +
                         "` exists and is not a regular file (a device, folder or pipe); outputs never replace those: "
                         "choose a file name");
}

fs::path outputPathIn(const fs::path& outDir, const std::string& name, const std::string& where)
{
    const fs::path path = outDir / name;
    // Resolve what exists of both (symlinks included) and compare: the output must stay below.
    const fs::path root = fs::weakly_canonical(fs::absolute(outDir));
    const fs::path resolved = fs::weakly_canonical(fs::absolute(path).parent_path()) / path.filename();
    const auto [rootEnd, unused] = std::mismatch(root.begin(), root.end(), resolved.begin(), resolved.end());
    if (rootEnd != root.end())
        throw InputError(where + ": the output `" + name + "` resolves to `" + resolved.string() +
                         "`, outside the output folder `" + root.string() + "` (a symbolic link out?)");
    checkReplaceable(path, where);
    return path;
}

}  // namespace voxlat
