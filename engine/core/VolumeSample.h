/// @file VolumeSample.h
/// @brief The volume of a field's solid (value below zero) within a box, estimated from random
/// points, one in each cell of a grid over the box (jittered, stratified sampling), with the
/// standard error of the estimate.
#pragma once

#include "fields/core/FieldNode.h"

#include <cstdint>
#include <functional>

namespace voxlat {

/// An estimated share of a box and its sampling error.
struct VolumeSample {
    std::uint64_t points = 0;  ///< points taken (one per cell)
    std::uint64_t inside = 0;  ///< of them, with a value below zero
    int cells[3] = {0, 0, 0};  ///< the grid of cells over the box
    double fraction = 0.0;     ///< inside / points: the estimated share of the box
    /// The standard error of @a fraction: the collapsed-strata estimate (cells paired along x,
    /// sqrt(sum over pairs of (y1 - y2)^2) / points, y = 1 inside), which does not understate
    /// the error of one point per cell; at most about the error of as many independent points,
    /// sqrt(f (1 - f) / points), and far below it where most cells lie wholly on one side.
    double standardError = 0.0;
};

/// @a field's solid within @a box estimated from about @a points points: the box cut into
/// cells as near cubes as the count allows (an even number along x), one point at a uniform
/// random place in each (a counter-based generator seeded by @a seed and the cell's index, so
/// the points and the result are the same for any thread count), evaluated in batches in
/// parallel. @a interrupt, when set, is called between batches and throws to stop.
VolumeSample sampleVolume(const FieldNode& field, const Box3& box, std::uint64_t points, std::uint64_t seed = 1,
                          const std::function<void()>& interrupt = {});

}  // namespace voxlat
