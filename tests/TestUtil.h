// Helpers shared by the engine and command-line tests.
#pragma once

#include "TestPaths.h"
#include "engine/recipe/Recipe.h"
#include "mesher/extract/TriangleMesh.h"

#include <sys/wait.h>
#include <unistd.h>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <sstream>
#include <string>
#include <vector>

namespace voxlat::test {

/// A fresh, empty temporary folder, removed when the object goes away.
struct TempDir {
    std::filesystem::path path;
    TempDir()
    {
        path = std::filesystem::temp_directory_path() /
               ("voxlat-test-" + std::to_string(::getpid()) + "-" + std::to_string(counter()++));
        std::filesystem::remove_all(path);
        std::filesystem::create_directories(path);
    }
    ~TempDir() { std::filesystem::remove_all(path); }
    static int& counter()
    {
        static int c = 0;
        return c;
    }
    std::filesystem::path write(const std::string& name, const std::string& text) const
    {
        std::ofstream(path / name) << text;
        return path / name;
    }
    /// The path of @a name in the folder, as a string.
    std::string file(const std::string& name) const { return (path / name).string(); }
    /// How many files and folders the folder holds.
    std::size_t entries() const { return std::size_t(std::distance(std::filesystem::directory_iterator(path), {})); }
};

/// Runs a shell command, returning its exit status and capturing stdout+stderr.
inline int runCommand(const std::string& command, std::string* output = nullptr)
{
    std::string full = command + " 2>&1";
    FILE* pipe = ::popen(full.c_str(), "r");
    std::string text;
    char buf[4096];
    while (std::size_t n = std::fread(buf, 1, sizeof buf, pipe)) text.append(buf, n);
    const int status = ::pclose(pipe);
    if (output) *output = text;
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

/// Under the sanitizers (`make sanitize`: ASan + UBSan, most code at -O0, several times slower)
/// the heavy tests run smaller instances of the same code paths: coarser cells, fewer resolutions,
/// fewer trials. Assertions of numerical accuracy that need the full instance run in the Release
/// build only.
#ifdef VOXLAT_SANITIZE
inline constexpr bool kSanitized = true;
#else
inline constexpr bool kSanitized = false;
#endif

inline std::string readFile(const std::filesystem::path& p)
{
    std::ifstream in(p, std::ios::binary);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
}

/// Files in a folder (names only), to check nothing half-written is left.
inline std::vector<std::string> listFolder(const std::filesystem::path& p)
{
    std::vector<std::string> names;
    for (const auto& e : std::filesystem::directory_iterator(p)) names.push_back(e.path().filename().string());
    return names;
}

/// Every file or folder under @a folder (recursively) whose name holds ".tmp-": temporaries left
/// behind.
inline std::vector<std::string> temporariesUnder(const std::filesystem::path& folder)
{
    std::vector<std::string> left;
    for (const auto& f : std::filesystem::recursive_directory_iterator(folder))
        if (f.path().filename().string().find(".tmp-") != std::string::npos) left.push_back(f.path().string());
    return left;
}

/// A cube [lo, hi]^3 as 12 outward triangles.
inline TriangleMesh cubeMesh(double lo, double hi)
{
    TriangleMesh m;
    for (int i = 0; i < 8; ++i)
        m.points.emplace_back(float(i & 1 ? hi : lo), float(i & 2 ? hi : lo), float(i & 4 ? hi : lo));
    const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
    for (const auto& q : quads) {
        m.triangles.emplace_back(q[0], q[1], q[2]);
        m.triangles.emplace_back(q[0], q[2], q[3]);
    }
    return m;
}

/// The message of what @a fn throws, or "" if it returns.
inline std::string errorOf(const std::function<void()>& fn)
{
    try {
        fn();
    } catch (const std::exception& e) {
        return e.what();
    }
    return "";
}

}  // namespace voxlat::test
