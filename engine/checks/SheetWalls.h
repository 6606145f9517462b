/// @file SheetWalls.h
/// @brief The wall thickness a sheet really has, measured across its mid-surface.
#pragma once

#include "fields/core/FieldNode.h"

#include <cstddef>

namespace voxlat {

/// Walls measured at points of a sheet's mid-surface.
struct SheetWallStats {
    std::size_t samples = 0;  ///< mid-surface points measured
    double mean = 0.0;        ///< mm
    double p01 = 0.0;         ///< the thinnest 1 % are thinner than this (mm)
    double min = 0.0;
    double max = 0.0;
};

/// Measures the walls of the sheet {@a sheet <= 0} built around the zero set of @a mid in @a box:
/// mid-surface points are found by bisection on @a lines x @a lines lines along z through the box
/// (sign changes of @a mid sampled 64 times along each), and at each the wall is the chord along
/// the unit gradient of @a mid between the sheet's two faces (each found by marching in steps of
/// @a expected / 16 up to 4 @a expected, then bisection to 1e-6 mm). Points whose chord does not
/// close within the march are left out. Deterministic (no threads, fixed lines).
SheetWallStats measureSheetWalls(const FieldNode& mid, const FieldNode& sheet, const Box3& box, double expected,
                                 int lines = 24);

}  // namespace voxlat
