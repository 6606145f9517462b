#include "engine/properties/CellSample.h"

#include "engine/core/Errors.h"

#include <tbb/parallel_for.h>

#include <atomic>
#include <vector>

namespace voxlat {

VoxelCell sampleCell(const FieldNode& field, const Vec3d& origin, const Vec3d& size, const std::array<int, 3>& counts,
                     const std::function<bool(double)>& progress)
{
    VoxelCell cell;
    cell.nx = counts[0];
    cell.ny = counts[1];
    cell.nz = counts[2];
    cell.hx = size[0] / counts[0];
    cell.hy = size[1] / counts[1];
    cell.hz = size[2] / counts[2];
    cell.solid.assign(std::size_t(cell.nx) * cell.ny * cell.nz, 0);
    std::atomic<int> done{0};
    std::atomic<bool> cancelled{false};
    // One z-slice per task: a batch of nx * ny points, written to its own part of the cell.
    tbb::parallel_for(0, cell.nz, [&](int k) {
        if (cancelled.load()) return;
        std::vector<Vec3d> points(std::size_t(cell.nx) * cell.ny);
        std::vector<double> values(points.size());
        const double z = origin[2] + (k + 0.5) * cell.hz;
        for (int j = 0; j < cell.ny; ++j)
            for (int i = 0; i < cell.nx; ++i)
                points[std::size_t(j) * cell.nx + i] =
                    Vec3d(origin[0] + (i + 0.5) * cell.hx, origin[1] + (j + 0.5) * cell.hy, z);
        field.values(points, values);
        std::uint8_t* out = &cell.solid[std::size_t(k) * cell.nx * cell.ny];
        for (std::size_t n = 0; n < values.size(); ++n) out[n] = values[n] < 0.0 ? 1 : 0;
        const int now = ++done;
        if (progress && !progress(double(now) / cell.nz)) cancelled = true;
    });
    if (cancelled.load()) throw Cancelled("cancelled while sampling the cell");
    return cell;
}

}  // namespace voxlat
