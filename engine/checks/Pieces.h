/// @file Pieces.h
/// @brief The connected pieces of a solid on its grid: a result that falls apart is found, not printed.
#pragma once

#include "engine/core/Domain.h"

#include <openvdb/openvdb.h>

#include <cstdint>
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

}  // namespace voxlat
