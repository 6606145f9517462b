/// @file Traps.h
/// @brief Closed cavities of a solid in 3D (resin traps), found on a lattice of samples.
#pragma once

#include "engine/core/JobContext.h"
#include "fields/core/FieldNode.h"

#include <cstdint>
#include <memory>
#include <vector>

namespace voxlat {

/// One closed cavity: void that reaches none of the searched box's faces.
struct Trap {
    double volumeMm3 = 0.0;  ///< samples times the sample's cell volume
    std::uint64_t samples = 0;
    /// The sample lowest along the build direction (ties: nearest the cavity's centroid across it).
    Vec3d lowest{0.0};
    Vec3d centroid{0.0};
};

/// The closed cavities of the solid {@a solid < 0} in @a box, sampled at the centres of cells of
/// @a spacing (min + (ijk + 1/2) spacing): void samples (value >= 0) 6-connected to each other and
/// not to a sample on the lattice's faces, so the box must hold the solid with a sample of void
/// around it. Largest first (ties in the order of their first sample, x-major, z fastest): the
/// same list for any thread count. Cavities narrower than the spacing may be missed or joined;
/// throws Cancelled when @a context is cancelled.
/// When @a openSpace is given it receives the void open to the outside as findTraps() sampled it:
/// a field positive on the void samples reached from the box's faces and beyond the box, negative
/// on solid samples and in closed cavities (the nearest sample's; gradients by central
/// differences of the samples). It tells where a channel from a cavity comes out when the solid
/// is no part with an outside of its own (`drain:` under `slices:`). @a up is the build direction
/// (a unit vector) along which Trap::lowest is lowest; @a lowestSolid, when given, receives the
/// lowest height along it of a solid sample (the part's bottom, within a sample; infinity when
/// there is none).
std::vector<Trap> findTraps(const FieldNode& solid, const Box3& box, double spacing,
                            const JobContext* context = nullptr, std::shared_ptr<const FieldNode>* openSpace = nullptr,
                            const Vec3d& up = Vec3d(0.0, 0.0, 1.0), double* lowestSolid = nullptr);

}  // namespace voxlat
