/// @file SurfaceThickness.h
/// @brief The wall a surface point stands on: the chord from the point straight into the solid
/// (against the field's gradient) to where the solid ends. report.html colours a part whose
/// walls the recipe grades by it.
#pragma once

#include "fields/core/FieldNode.h"

#include <openvdb/openvdb.h>

#include <vector>

namespace voxlat {

/// For each of @a points (on, or near, the surface of the solid {@a solid <= 0}), the length (mm)
/// of the chord through the solid along minus the unit gradient of @a solid at the point: from
/// where the line enters the solid (a point inside already: the first-order distance back to the
/// surface) to where it first leaves it, marched in steps of @a step up to @a most, each end placed
/// between two samples by linear interpolation. A chord that does not close within @a most is
/// given as @a most. Deterministic (no threads; batches of all points).
std::vector<float> surfaceThickness(const FieldNode& solid, const std::vector<openvdb::Vec3f>& points, double step,
                                    double most);

}  // namespace voxlat
