#include "engine/core/InputFiles.h"

#include "engine/core/Errors.h"

#include <fstream>
#include <sstream>

namespace voxlat {

namespace fs = std::filesystem;

std::uintmax_t checkInputFile(const fs::path& path, std::uintmax_t maxBytes, const std::string& what)
{
    std::error_code ec;
    const fs::file_status status = fs::status(path, ec);
    if (!fs::exists(status)) throw InputError(path.string() + ": no such " + what + " (check the path)");
    if (!fs::is_regular_file(status))
        throw InputError(path.string() + ": the " + what + " is not a regular file (a folder, device or pipe)");
    const std::uintmax_t size = fs::file_size(path, ec);
    if (ec) throw InputError(path.string() + ": cannot read the " + what + ": " + ec.message());
    if (size > maxBytes)
        throw InputError(path.string() + ": the " + what + " is " + std::to_string(size >> 20) + " MB, more than the " +
                         std::to_string(maxBytes >> 20) + " MB a " + what + " may have");
    return size;
}

std::string readInputFile(const fs::path& path, std::uintmax_t maxBytes, const std::string& what)
{
    checkInputFile(path, maxBytes, what);
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path.string() + ": cannot open the " + what);
    std::ostringstream text;
    text << in.rdbuf();
    return text.str();
}

}  // namespace voxlat
