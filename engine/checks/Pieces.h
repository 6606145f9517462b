/// @file Pieces.h
/// @brief The connected pieces of a solid on its grid: a result that falls apart is found, not printed.
#pragma once

#include "engine/core/Domain.h"

#include <openvdb/openvdb.h>

#include <array>
#include <cstdint>
#include <functional>
#include <vector>

namespace voxlat {

/// One connected piece of solid voxels.
struct Piece {
    std::uint64_t voxels = 0;
    openvdb::CoordBBox bounds;  ///< index bounds of its voxels
};

/// The pieces of a solid, largest first (ties: the lower first voxel).
struct PieceCount {
    std::vector<Piece> pieces;
    std::uint64_t solidVoxels = 0;
};

/// The connected components of the voxels of @a grid below zero (inside tiles included), two voxels
/// being connected when they share a face (6-connectivity: a piece touching another only along an
/// edge or at a corner is separate, as it would be in print). Splits each leaf's voxels into their
/// connected parts by flood fills on the leaf's 512 bits held in eight words, in parallel, then
/// joins parts across leaf faces with a union-find; the result does not depend on the thread count.
PieceCount countPieces(const openvdb::FloatGrid& grid);

/// The solid voxels of an 8^3 block: bit (y << 3) | z of word x for the voxel at origin + (x, y, z)
/// (belowWords() of a leaf's values).
struct SolidBlock {
    openvdb::Coord origin;
    std::array<std::uint64_t, 8> bits;
};

/// The solid of @a grid as blocks, sorted by origin, none empty: each leaf's voxels below zero and
/// every 8^3 block of its tiles below zero, with @a leaves (blocks of leaves evaluated but not
/// kept in the grid, in any order; empty ones are dropped) in place of leaves of its own.
/// @a interrupt, when given, is called every few thousand blocks and may throw to stop.
std::vector<SolidBlock> solidBlocks(const openvdb::FloatGrid& grid, std::vector<SolidBlock> leaves = {},
                                    const std::function<void()>& interrupt = {});

/// countPieces() of a solid given as solidBlocks() returns it. @a interrupt, when given, is called
/// every few thousand blocks or parts (from any thread) and may throw to stop.
PieceCount countPieces(const std::vector<SolidBlock>& blocks, const std::function<void()>& interrupt = {});

}  // namespace voxlat
