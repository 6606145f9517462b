/// @file Drains.h
/// @brief Drain channels for the resin traps of a solid (`drain:` on an infill or a shell).
#pragma once

#include "engine/core/JobContext.h"
#include "engine/recipe/FieldBuilder.h"

#include <nlohmann/json.hpp>

namespace voxlat {

/// For each request, finds the closed cavities of its (solved) solid and gives the node one
/// channel per cavity, from the cavity's lowest point along the request's build direction
/// (DrainRequest::up, +z by default): straight down (against the build direction) where it comes
/// out above the build plate (the part's lowest extent along that direction, which closes a hole
/// there) and is no longer than a sideways way by a diameter; else sideways, the shortest of four
/// directions across the build direction (+-x, +-y for +z), a radius above the plate; else along
/// the part's outward normal (the thinnest wall). Then looks for cavities again in the drained
/// solid. Cavities of fewer than 8 samples are crumbs (listed, not drained). Returns report.json's
/// `drain` entry (per field: the build direction, the holes with position, direction and length,
/// the cavities found before and after); warns when a cavity is left. Deterministic: the same
/// channels for any thread count.
nlohmann::json planDrains(const std::vector<DrainRequest>& drains, double voxel, const JobContext* context);

}  // namespace voxlat
