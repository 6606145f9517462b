#include "engine/properties/MemoryEstimate.h"

#include <array>
#include <cstddef>

namespace voxlat {

std::int64_t cellNodes(const VoxelCell& cell)
{
    // Point (x, y, z) is the corner shared by voxels (x - 1 .. x, y - 1 .. y, z - 1 .. z), modulo
    // the cell. Marked per point from each solid voxel's 8 corners.
    const std::array<int, 3> n{cell.nx, cell.ny, cell.nz};
    std::vector<std::uint8_t> touched(cell.solid.size(), 0);
    for (int z = 0; z < n[2]; ++z)
        for (int y = 0; y < n[1]; ++y)
            for (int x = 0; x < n[0]; ++x) {
                if (!cell.solid[std::size_t(x) + std::size_t(n[0]) * (std::size_t(y) + std::size_t(n[1]) * z)])
                    continue;
                for (int c = 0; c < 8; ++c) {
                    const int px = (x + (c & 1)) % n[0], py = (y + ((c >> 1) & 1)) % n[1], pz = (z + (c >> 2)) % n[2];
                    touched[std::size_t(px) + std::size_t(n[0]) * (std::size_t(py) + std::size_t(n[1]) * pz)] = 1;
                }
            }
    std::int64_t nodes = 0;
    for (const std::uint8_t t : touched) nodes += t;
    return nodes;
}

double homogenizationBytes(double voxels, double nodes)
{
    constexpr double kPerNode = 1450.0, kPerVoxel = 16.0, kFixed = 4.0 * 1048576.0;
    return kFixed + kPerNode * nodes + kPerVoxel * voxels;
}

double homogenizationBytes(const VoxelCell& cell)
{
    return homogenizationBytes(double(cell.solid.size()), double(cellNodes(cell)));
}

}  // namespace voxlat
