/// @file Domain.h
/// @brief The box a job lives in and the voxel grid that samples it.
#pragma once

#include "fields/core/FieldNode.h"

#include <openvdb/math/Coord.h>
#include <openvdb/math/Transform.h>

#include <cstdint>
#include <optional>

namespace voxlat {

/// A box sampled at voxel centres: voxel (i, j, k) has its centre at
/// min + (i + 0.5, j + 0.5, k + 0.5) * voxel, for 0 <= i < dims.x and so on.
/// The most voxels a domain may have along one axis (OpenVDB indexes with 32-bit integers, and
/// the culling pass lists every 128^3 block).
inline constexpr int kMaxVoxelsPerAxis = 1 << 24;
/// The most voxels a job's domain may hold: past this even listing the 128^3 blocks to cull costs
/// gigabytes (a 1 m cube at 0.01 mm is 10^15).
inline constexpr double kMaxDomainVoxels = 1e13;
/// How far (in voxels) a domain may reach from the origin: 2^21, so single-precision vertices
/// (24 bits) still place points to an eighth of a voxel.
inline constexpr double kMaxVoxelsFromOrigin = 2097152.0;

struct Domain {
    Box3 box;
    double voxel = 0.1;
    openvdb::Coord dims{0, 0, 0};
    /// The lattice a sub-domain shares with the domain it was cut from (subDomain): that domain's
    /// box.min, and the index there of this domain's voxel 0. Unset: this domain's own.
    std::optional<Vec3d> latticeRoot{};
    openvdb::Coord latticeOffset{0, 0, 0};

    /// Snaps the box to a whole number of voxels per axis (round to nearest, at least one); the
    /// returned box is the one actually sampled.
    static Domain fromBox(const Box3& box, double voxel);

    Vec3d worldOf(const openvdb::Coord& ijk) const
    {
        return box.min + voxel * Vec3d(ijk.x() + 0.5, ijk.y() + 0.5, ijk.z() + 0.5);
    }
    /// The voxels of this domain whose centres lie in @a box, as a domain of its own (same voxel
    /// lattice). Throws std::invalid_argument if none do.
    Domain subDomain(const Box3& box) const;
    /// This domain with @a voxels more on every side, on the same voxel lattice.
    Domain grown(int voxels) const;

    /// The box.min of the domain whose voxel lattice this is (GridBatch::latticeMin): voxel c of
    /// this domain is that lattice's voxel c + latticeOffset.
    Vec3d latticeMin() const { return latticeRoot ? *latticeRoot : box.min; }

    /// Number of voxels inside the domain.
    std::uint64_t voxelCount() const { return std::uint64_t(dims.x()) * dims.y() * dims.z(); }
    /// Index-space box of the domain's voxels (inclusive).
    openvdb::CoordBBox indexBox() const { return {openvdb::Coord(0), dims - openvdb::Coord(1)}; }
    /// OpenVDB transform mapping voxel indices to voxel centres.
    openvdb::math::Transform::Ptr transform() const;
};

}  // namespace voxlat
