/// @file CellTopology.h
/// @brief Connected components of a periodic voxel cell and how they wrap (internal to properties).
#pragma once

#include <array>
#include <cstdint>
#include <vector>

namespace voxlat::homogenization {

/// The solid voxels that carry load, labelled by connected component.
struct CellTopology {
    /// Per voxel: the component (0-based, in order of each component's first voxel) of a kept
    /// solid voxel, -1 for void and for removed island voxels.
    std::vector<std::int32_t> label;
    int components = 0;  ///< kept components
    std::int64_t keptVoxels = 0;
    std::int64_t islandVoxels = 0;
    int islands = 0;
    /// Per kept component: the rank (1..3) of its lattice of wrap vectors (translations, in
    /// cells, that map it onto itself through solid), and whether that lattice spans each axis.
    std::vector<int> rank;
    std::array<bool, 3> percolates{};  ///< some kept component spans the axis
};

/// Components of the solid voxels of an n[0] x n[1] x n[2] periodic cell (index x + n0*(y + n1*z)),
/// two voxels being connected when they share a node (26-neighbours on the torus). Each component
/// is followed into the infinite periodic tiling: a union-find records, per voxel, which periodic
/// copy of it the component's root reaches, and an edge that closes a loop through a different
/// copy yields a wrap vector. Components without wrap vectors are finite in the tiling (islands)
/// and are removed. Serial and deterministic.
CellTopology analyzeCell(const std::array<int, 3>& n, const std::vector<std::uint8_t>& solid);

}  // namespace voxlat::homogenization
