// voxlat_homogenize_cell: the homogenization core on a raw voxel cell, for the reference test
// (tests/scripts/homogenization_reference.py) and the W8 benchmark.
//
//   voxlat_homogenize_cell [--thermal] [--threads N] [--tolerance T] CELL
//
// CELL: a header line "nx ny nz h E nu", then nx*ny*nz characters '0' or '1' in the order
// x + nx*(y + ny*z) (whitespace ignored). Prints the effective stiffness C (or, with --thermal,
// the conductivity K for conductivity E; nu is then ignored) and the bookkeeping as JSON, with the
// solve's peak memory above what the process held before it (peak_growth_bytes).
#include "engine/properties/Homogenization.h"

#include <tbb/global_control.h>

#include <cctype>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <memory>
#include <stdexcept>
#include <string>

namespace {

voxlat::VoxelCell readCell(const std::string& path, double& E, double& nu)
{
    std::ifstream in(path);
    if (!in) throw std::runtime_error("cannot open " + path);
    voxlat::VoxelCell cell;
    double h = 0.0;
    if (!(in >> cell.nx >> cell.ny >> cell.nz >> h >> E >> nu)) throw std::runtime_error("bad header in " + path);
    if (cell.nx < 1 || cell.ny < 1 || cell.nz < 1) throw std::runtime_error("bad size in " + path);
    cell.hx = cell.hy = cell.hz = h;
    cell.solid.resize(std::size_t(cell.nx) * cell.ny * cell.nz);
    std::size_t i = 0;
    char c;
    while (i < cell.solid.size() && in.get(c)) {
        if (c == '0' || c == '1')
            cell.solid[i++] = std::uint8_t(c == '1');
        else if (!std::isspace(static_cast<unsigned char>(c)))
            throw std::runtime_error("bad voxel character in " + path);
    }
    if (i != cell.solid.size()) throw std::runtime_error("too few voxels in " + path);
    return cell;
}

template <std::size_t N>
void printMatrix(const char* name, const std::array<std::array<double, N>, N>& m)
{
    std::printf("  \"%s\": [", name);
    for (std::size_t i = 0; i < N; ++i) {
        std::printf("%s[", i ? ", " : "");
        for (std::size_t j = 0; j < N; ++j) std::printf("%s%.17g", j ? ", " : "", m[i][j]);
        std::printf("]");
    }
    std::printf("],\n");
}

template <class Result, std::size_t N>
void printCommon(const Result& r, const std::array<int, N>& iterations, const std::array<double, N>& residual)
{
    std::printf("  \"relative_density\": %.17g,\n  \"solid_voxels\": %lld,\n", r.relativeDensity,
                static_cast<long long>(r.solidVoxels));
    std::printf("  \"island_voxels_removed\": %lld,\n  \"islands_removed\": %d,\n",
                static_cast<long long>(r.islandVoxelsRemoved), r.islandsRemoved);
    std::printf("  \"percolates\": [%s, %s, %s],\n", r.percolates[0] ? "true" : "false",
                r.percolates[1] ? "true" : "false", r.percolates[2] ? "true" : "false");
    std::printf("  \"iterations\": [");
    for (std::size_t i = 0; i < N; ++i) std::printf("%s%d", i ? ", " : "", iterations[i]);
    std::printf("],\n  \"residual\": [");
    for (std::size_t i = 0; i < N; ++i) std::printf("%s%.3g", i ? ", " : "", residual[i]);
    std::printf("],\n");
}

/// Reads "Key:   123 kB" from /proc/self/status, in bytes (0 if absent).
long long statusBytes(const char* key)
{
    std::ifstream in("/proc/self/status");
    std::string line;
    const std::string k = key;
    while (std::getline(in, line))
        if (line.compare(0, k.size(), k) == 0) return std::atoll(line.c_str() + k.size()) * 1024;
    return 0;
}

/// Resets the peak resident size to the current one (Linux 4.0 and later), and returns the
/// current one: the solve's own peak is then VmHWM minus it.
long long resetPeak()
{
    std::ofstream("/proc/self/clear_refs") << "5";
    return statusBytes("VmRSS:");
}

}  // namespace

int main(int argc, char** argv)
{
    bool thermal = false;
    int threads = 0;
    voxlat::HomogenizationSettings settings;
    std::string path;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--thermal")
            thermal = true;
        else if (a == "--threads" && i + 1 < argc)
            threads = std::atoi(argv[++i]);
        else if (a == "--tolerance" && i + 1 < argc)
            settings.tolerance = std::atof(argv[++i]);
        else if (!a.empty() && a[0] != '-' && path.empty())
            path = a;
        else {
            std::fprintf(stderr, "usage: %s [--thermal] [--threads N] [--tolerance T] CELL\n", argv[0]);
            return 2;
        }
    }
    if (path.empty()) {
        std::fprintf(stderr, "usage: %s [--thermal] [--threads N] [--tolerance T] CELL\n", argv[0]);
        return 2;
    }
    std::unique_ptr<tbb::global_control> limit;
    if (threads > 0)
        limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, threads);
    try {
        double E = 0.0, nu = 0.0;
        const voxlat::VoxelCell cell = readCell(path, E, nu);
        const long long resident = resetPeak();
        const auto start = std::chrono::steady_clock::now();
        std::printf("{\n");
        if (thermal) {
            const voxlat::ConductivityResult r = voxlat::homogenizeConductivity(cell, E, settings);
            const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
            printMatrix("K", r.K);
            printCommon(r, r.iterations, r.residual);
            std::printf("  \"peak_growth_bytes\": %lld,\n", statusBytes("VmHWM:") - resident);
            std::printf("  \"seconds\": %.3f\n}\n", seconds);
        } else {
            const voxlat::ElasticityResult r = voxlat::homogenizeElasticity(cell, {E, nu}, settings);
            const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
            printMatrix("C", r.C);
            printCommon(r, r.iterations, r.residual);
            std::printf("  \"peak_growth_bytes\": %lld,\n", statusBytes("VmHWM:") - resident);
            std::printf("  \"seconds\": %.3f\n}\n", seconds);
        }
    } catch (const std::exception& e) {
        std::fprintf(stderr, "voxlat_homogenize_cell: %s\n", e.what());
        return 1;
    }
    return 0;
}
