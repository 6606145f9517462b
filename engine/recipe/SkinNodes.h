/// @file SkinNodes.h
/// @brief The recipe side of skin-following frames: `skin:` under `struts:` and under a tpms's
/// `frame:` (SkinNodes.cpp).
#pragma once

#include "engine/frames/StrutFrames.h"
#include "engine/recipe/FieldBuilder.h"

namespace voxlat {

/// `struts: {cell: C, size: S, skin: {part, depth, layers}}`: the frame of @a cell mapped into
/// the skin cells; @a region receives the field of the cells' space (negative inside), where the
/// lattice's density is measured.
Frame buildSkinStrutFrame(FieldBuilder& builder, const RecipeNode& struts, const UnitCell& cell,
                          const std::string& name, FieldPtr& region);

/// `frame: {skin: {part, depth, layers}}` on a tpms: @a raw (cell size @a cell) evaluated in the
/// skin cells' local coordinates.
FieldPtr applySkinFrame(FieldBuilder& builder, const RecipeNode& frame, FieldPtr raw, const Vec3d& cell,
                        const std::string& name);

/// The cells' region of a skin-mapped field (negative inside the cells), or null for any other.
FieldPtr skinRegionOf(const FieldPtr& raw);

}  // namespace voxlat
