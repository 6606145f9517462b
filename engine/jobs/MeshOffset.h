/// @file MeshOffset.h
/// @brief How far the volume of the marching-cubes mesh of a job's grid lies from what the
/// density solve measures on its voxels, estimated on a sample of the grid's 8^3 boxes before the
/// grid is made.
#pragma once

#include "engine/core/Domain.h"
#include "fields/core/FieldNode.h"

#include <cstdint>
#include <functional>

namespace voxlat {

/// What estimateMeshOffset() measured.
struct MeshOffset {
    double volume = 0.0;        ///< mm^3: the mesh's volume less the solve's measure (estimated)
    std::uint64_t boxes = 0;    ///< 8^3 boxes of cells the grid's mesh spans
    std::uint64_t sampled = 0;  ///< boxes of the sample
    std::uint64_t crossed = 0;  ///< sampled boxes the surface crosses
};

/// The 8^3 boxes of cells the grid of a job on @a domain spans (MeshOffset::boxes).
std::uint64_t meshOffsetBoxes(const Domain& domain);

/// The grid Job::evaluateResult() makes of @a result on @a domain (one voxel of margin, the
/// domain's box clipped in, 1 outside) meshed by marchingCubes() encloses what the density solve
/// measures on the domain's voxels (@a coverage: each voxel's sub-voxel coverage, 1/2 - value /
/// step with the step the length of its central differences; else its count, value below zero;
/// of the field's own values, not clipped) plus an offset: marching cubes' chords and the
/// sampling of the surface. The offset is a sum over the 8^3 boxes of cells that tile the grid,
/// each box's own (its mesh volume, marchingCubesBoxVolumes(), less its points' measure, each
/// weighted by its share of the box), so it is estimated on a fixed sample of about one box in
/// @a every (chosen by a hash of the box's place: the same boxes for any thread count), each
/// evaluated alone on its 9^3 points and the ring around them, scaled to all boxes. Boxes whose
/// bound proves every point on one side add nothing and are not evaluated. @a interrupt, when
/// set, is called between boxes and throws to stop.
MeshOffset estimateMeshOffset(const FieldNode& result, const Domain& domain, int every, bool coverage = true,
                              const std::function<void()>& interrupt = {});

}  // namespace voxlat
