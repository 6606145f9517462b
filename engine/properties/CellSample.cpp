#include "engine/properties/CellSample.h"

#include "engine/core/Errors.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <span>
#include <stdexcept>
#include <vector>

namespace voxlat {

namespace {

/// Calls @a store(index, value) with the field's value at every voxel centre of the cell (index
/// x + nx * (y + ny * z)), in parallel. The cell is cut into blocks of 8 x 8 x 8 voxels, each
/// evaluated as one regular batch (FieldNode::gridValues: a strut lattice gathers its nearby
/// struts once a block instead of once a point; a TPMS shares its terms along the axes).
template <class Store>
void sampleBlocks(const FieldNode& field, const Vec3d& origin, const Vec3d& size, const std::array<int, 3>& counts,
                  const std::function<bool(double)>& progress, Store&& store)
{
    constexpr int kBlock = 8;
    const double h[3] = {size[0] / counts[0], size[1] / counts[1], size[2] / counts[2]};
    int blocks[3];
    for (int a = 0; a < 3; ++a) blocks[a] = (counts[a] + kBlock - 1) / kBlock;
    const int total = blocks[0] * blocks[1] * blocks[2];
    std::atomic<int> done{0};
    std::atomic<bool> cancelled{false};
    tbb::parallel_for(0, total, [&](int t) {
        if (cancelled.load()) return;
        const int b[3] = {t % blocks[0], (t / blocks[0]) % blocks[1], t / (blocks[0] * blocks[1])};
        GridBatch batch;
        int first[3], n[3];
        for (int a = 0; a < 3; ++a) {
            first[a] = b[a] * kBlock;
            n[a] = std::min(kBlock, counts[a] - first[a]);
        }
        batch.origin = Vec3d(origin[0] + (first[0] + 0.5) * h[0], origin[1] + (first[1] + 0.5) * h[1],
                             origin[2] + (first[2] + 0.5) * h[2]);
        batch.spacing = Vec3d(h[0], h[1], h[2]);
        batch.nx = n[0];
        batch.ny = n[1];
        batch.nz = n[2];
        batch.exact = true;  // a quantile of these values sets the cell's level
        double values[kBlock * kBlock * kBlock];
        field.gridValues(batch, std::span<double>(values, batch.size()));
        for (int i = 0; i < n[0]; ++i)
            for (int j = 0; j < n[1]; ++j)
                for (int k = 0; k < n[2]; ++k)
                    store(std::size_t(first[0] + i) +
                              std::size_t(counts[0]) *
                                  (std::size_t(first[1] + j) + std::size_t(counts[1]) * std::size_t(first[2] + k)),
                          values[(i * n[1] + j) * n[2] + k]);
        const int now = ++done;
        if (progress && !progress(double(now) / total)) cancelled = true;
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
    sampleBlocks(field, origin, size, counts, progress,
                 [&](std::size_t n, double value) { cell.solid[n] = value < 0.0 ? 1 : 0; });
    return cell;
}

std::vector<double> sampleCellValues(const FieldNode& field, const Vec3d& origin, const Vec3d& size,
                                     const std::array<int, 3>& counts, const std::function<bool(double)>& progress)
{
    std::vector<double> out(std::size_t(counts[0]) * counts[1] * counts[2]);
    sampleBlocks(field, origin, size, counts, progress, [&](std::size_t n, double value) { out[n] = value; });
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
