/// @file ExprNodes.h
/// @brief Equations and direction fields written in recipes, for node types that take them.
#pragma once

#include "engine/recipe/FieldBuilder.h"
#include "fields/frames/OrientField.h"
#include "fields/maps/VectorField.h"

namespace voxlat {

/// Compiles the equation in the scalar @a text (x, y, z, `$params`, field names, `name.x`
/// components of vector fields). Errors name the place and show the equation with a caret.
FieldPtr equationField(FieldBuilder& builder, const RecipeNode& text);

/// A direction field wherever a node expects a direction: the name of a `vector:` node, an
/// inline `{vector: [...]}`, or a constant `[x, y, z]`.
std::shared_ptr<const VectorField> directionField(FieldBuilder& builder, const RecipeNode& spec,
                                                  const std::string& name);

/// Orients @a child by the frame in @a orientation, a map `{along: DIRECTION, x: DIRECTION,
/// origin: [x, y, z]}` (the `orient` node's value and the `axes:` key of `tpms`): the child's z
/// axis follows `along`, its x axis the reference `x` (Gram-Schmidt), rotating about `origin`.
FieldPtr orientedField(FieldBuilder& builder, const RecipeNode& orientation, FieldPtr child, const std::string& name);

}  // namespace voxlat
