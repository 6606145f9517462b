/// @file ScalarMaps.h
/// @brief Recipe values that may vary in space (densities, thicknesses): a number, a field, a
/// linear ramp, a ramp with distance from a surface, or a grid of values from a file.
#pragma once

#include "engine/recipe/FieldBuilder.h"

#include <optional>
#include <string>

namespace voxlat {

/// A spatially varying number read from a recipe key.
struct ScalarMap {
    FieldPtr field;
    std::optional<double> constant;  ///< set when the value is a plain number
    std::optional<int> axis;         ///< the axis a `ramp` runs along
    std::string description;         ///< e.g. "ramp along z from 0.1 to 0.4"
};

/// Reads @a node as one of
///   0.3                                    a number
///   rho                                    a field by name (its values are used as they are)
///   {field: rho} / {field: {sphere: ...}}  a field by name or inline
///   {ramp: {axis: z, from: 0.1, to: 0.4, range: [0, 30]}}   linear along an axis; range
///                                          defaults to the domain's extent along it
///   {distance: {field: part, from: 0.4, to: 0.1, over: 5}}  linear in |value of the field|
///                                          (its distance from the surface) from 0 to `over` mm
///   {file: rho.csv}                        a regular grid of values (columns x, y, z, value)
/// @a name labels inline fields.
ScalarMap readScalarMap(FieldBuilder& builder, const RecipeNode& node, const std::string& name);

/// `{ramp: {axis, from, to, range}}`, `{distance: {field, from, to, over}}` on their own.
ScalarMap readRamp(FieldBuilder& builder, const RecipeNode& ramp);
ScalarMap readDistanceRamp(FieldBuilder& builder, const RecipeNode& distance, const std::string& name);

/// Node types `ramp`, `distance-ramp` and `value-grid`: the same maps as fields of their own, so
/// that a density or thickness field can be named and reused.
void addScalarMapNodeTypes(std::vector<NodeType>& types);

/// The smallest and largest value of a field found by sampling a box (32^3 points), with where.
struct SampledRange {
    double lo = 0.0, hi = 0.0;
    Vec3d where_lo{0.0}, where_hi{0.0};
};
SampledRange sampleRange(const FieldNode& field, const Box3& box, int samplesPerAxis = 32);

/// Checks that @a map stays within [lo, hi] over the recipe's domain (exactly for numbers and
/// ramps, by sampling for other fields); fails on @a node with the value and the place.
void checkScalarRange(const FieldBuilder& builder, const ScalarMap& map, const RecipeNode& node, double lo, double hi,
                      bool openInterval, const std::string& what, const std::string& fix);

/// Reads a value grid from a text file: a header naming the columns (some of x, y, z, and one
/// value column), then one row per grid node; separators are commas, semicolons or blanks;
/// lines starting with # are comments. Throws InputError naming the file and line.
FieldPtr readValueGrid(const std::filesystem::path& path, const std::string& shownPath);

}  // namespace voxlat
