#include "engine/properties/CellSample.h"

#include "engine/core/Errors.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace voxlat {

namespace {

/// Calls @a store(k, values) with the field's values on each z-slice k of the cell, in parallel.
template <class Store>
void sampleSlices(const FieldNode& field, const Vec3d& origin, const Vec3d& size, const std::array<int, 3>& counts,
                  const std::function<bool(double)>& progress, Store&& store)
{
    const double hx = size[0] / counts[0], hy = size[1] / counts[1], hz = size[2] / counts[2];
    std::atomic<int> done{0};
    std::atomic<bool> cancelled{false};
    // One z-slice per task: a batch of nx * ny points, written to its own part of the cell.
    tbb::parallel_for(0, counts[2], [&](int k) {
        if (cancelled.load()) return;
        std::vector<Vec3d> points(std::size_t(counts[0]) * counts[1]);
        std::vector<double> values(points.size());
        const double z = origin[2] + (k + 0.5) * hz;
        for (int j = 0; j < counts[1]; ++j)
            for (int i = 0; i < counts[0]; ++i)
                points[std::size_t(j) * counts[0] + i] =
                    Vec3d(origin[0] + (i + 0.5) * hx, origin[1] + (j + 0.5) * hy, z);
        field.values(points, values);
        store(k, values);
        const int now = ++done;
        if (progress && !progress(double(now) / counts[2])) cancelled = true;
    });
    if (cancelled.load()) throw Cancelled("cancelled while sampling the cell");
}

VoxelCell emptyCell(const Vec3d& size, const std::array<int, 3>& counts)
{
    VoxelCell cell;
    cell.nx = counts[0];
    cell.ny = counts[1];
    cell.nz = counts[2];
    cell.hx = size[0] / counts[0];
    cell.hy = size[1] / counts[1];
    cell.hz = size[2] / counts[2];
    cell.solid.assign(std::size_t(cell.nx) * cell.ny * cell.nz, 0);
    return cell;
}

}  // namespace

VoxelCell sampleCell(const FieldNode& field, const Vec3d& origin, const Vec3d& size, const std::array<int, 3>& counts,
                     const std::function<bool(double)>& progress)
{
    VoxelCell cell = emptyCell(size, counts);
    const std::size_t slice = std::size_t(cell.nx) * cell.ny;
    sampleSlices(field, origin, size, counts, progress, [&](int k, const std::vector<double>& values) {
        std::uint8_t* out = &cell.solid[std::size_t(k) * slice];
        for (std::size_t n = 0; n < values.size(); ++n) out[n] = values[n] < 0.0 ? 1 : 0;
    });
    return cell;
}

std::vector<double> sampleCellValues(const FieldNode& field, const Vec3d& origin, const Vec3d& size,
                                     const std::array<int, 3>& counts, const std::function<bool(double)>& progress)
{
    const std::size_t slice = std::size_t(counts[0]) * counts[1];
    std::vector<double> out(slice * counts[2]);
    sampleSlices(field, origin, size, counts, progress, [&](int k, const std::vector<double>& values) {
        std::copy(values.begin(), values.end(), out.begin() + std::ptrdiff_t(std::size_t(k) * slice));
    });
    return out;
}

double cellLevelShift(std::vector<double> values, double density)
{
    if (values.size() < 2 || !(density > 0.0 && density < 1.0))
        throw std::invalid_argument("cellLevelShift: needs two values and a density in (0, 1)");
    const std::size_t n = values.size();
    const std::size_t k = std::clamp<std::size_t>(std::size_t(std::llround(density * double(n))), 1, n - 1);
    // The k smallest values are solid: the shift lies between the k-th and the (k+1)-th.
    std::nth_element(values.begin(), values.begin() + std::ptrdiff_t(k), values.end());
    const double above = values[k];
    const double below = *std::max_element(values.begin(), values.begin() + std::ptrdiff_t(k));
    return 0.5 * (below + above);
}

VoxelCell cellAtShift(const std::vector<double>& values, const Vec3d& size, const std::array<int, 3>& counts,
                      double shift)
{
    VoxelCell cell = emptyCell(size, counts);
    if (values.size() != cell.solid.size()) throw std::invalid_argument("cellAtShift: values do not match the cell");
    for (std::size_t n = 0; n < values.size(); ++n) cell.solid[n] = values[n] < shift ? 1 : 0;
    return cell;
}

}  // namespace voxlat
