/// @file FuzzUtil.h
/// @brief Shared pieces of the libFuzzer harnesses: inputs written to a private temporary file
/// (the readers under test take paths), and the rule that a clear error is a pass.
#pragma once

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

namespace voxlat::fuzz {

/// A file holding the fuzzer's bytes, removed when it goes out of scope.
class InputFile {
public:
    InputFile(const std::uint8_t* data, std::size_t size, const std::string& extension)
        : mPath(std::filesystem::temp_directory_path() / ("voxlat-fuzz-" + std::to_string(::getpid()) + extension))
    {
        std::ofstream(mPath, std::ios::binary).write(reinterpret_cast<const char*>(data), std::streamsize(size));
    }
    ~InputFile()
    {
        std::error_code ec;
        std::filesystem::remove(mPath, ec);
    }
    InputFile(const InputFile&) = delete;
    InputFile& operator=(const InputFile&) = delete;
    const std::filesystem::path& path() const { return mPath; }

private:
    std::filesystem::path mPath;
};

}  // namespace voxlat::fuzz
