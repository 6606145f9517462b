/// @file FieldEdits.h
/// @brief A field's spec changed by typed values (a trial's density or sigma, a solved design
/// target, a frame grown around its cell), and what trial jobs need to know of a spec, read once
/// when the recipe loads. Jobs build their trial recipes from these types and read no YAML; the
/// YAML copy a trial still needs (the node builders of engine/recipe read YAML) is made here.
#pragma once

#include "fields/core/FieldNode.h"

#include <yaml-cpp/yaml.h>

#include <array>
#include <optional>
#include <string>

namespace voxlat {

/// A change to one field's spec. The design keys (`stiffness:`, `optimize:`) are always removed:
/// an edited field is one whose property targets are resolved.
struct FieldEdit {
    std::optional<double> density;                ///< `density:` set to this number (replacing a graded map)
    std::optional<double> sigma;                  ///< `kernel: {gaussian: {sigma}}` set to this number
    bool capsule = false;                         ///< `kernel: capsule` in place of the kernel, `radius:` removed
    std::optional<std::array<int, 3>> count;      ///< `struts: {count}`
    std::optional<std::array<double, 3>> origin;  ///< `struts: {origin}` (mm)
};

/// What jobs need to know of a field's spec, read once when the recipe loads (and again by
/// editField for an edited spec); never throws: what does not read is absent.
struct FieldFacts {
    bool hasDensity = false;     ///< the spec is a map with `density:` (a number or a graded map)
    bool densityScalar = false;  ///< `density:` is one scalar
    /// `kernel: {gaussian: {sigma: S}}` with S one number.
    std::optional<double> sigma;
    /// `struts:` a map with `cell:` and `size:` and none of within, skin, between, cylinder,
    /// sphere, wireframe: a box frame laid out by keys a trial can change (count, origin).
    bool boxFrame = false;
    /// `struts:` with only `cell`, `size` and `origin`: its box cell (mm), when size and origin
    /// read as numbers.
    std::optional<Vec3d> plainBoxCell;
    std::optional<Vec3d> plainBoxOrigin;  ///< that frame's `origin:`, when given
};

/// Reads @a spec's facts.
FieldFacts readFieldFacts(const YAML::Node& spec);

/// @a spec with @a edit applied: a new map on every path that changes, every other child shared
/// (so it keeps its recipe line, its `--set` and `$param` labels); @a spec is not changed.
YAML::Node editedSpec(const YAML::Node& spec, const FieldEdit& edit);

/// A number as YAML text that reads back to the same double.
YAML::Node exactNumber(double v);

}  // namespace voxlat
