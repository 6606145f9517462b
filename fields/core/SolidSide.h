/// @file SolidSide.h
/// @brief Which side of a raw field's level is solid: shared by LevelSolid and the nodes that
/// apply a level while they evaluate (TpmsField::gridValuesAtLevel).
#pragma once

namespace voxlat {

/// Which side of the level is solid.
enum class SolidSide {
    Below,  ///< raw <= level (a TPMS network; value raw - level)
    Band,   ///< |raw| <= level (a TPMS sheet; value |raw| - level)
    Above,  ///< raw >= level (a convolution lattice; value level - raw)
};

}  // namespace voxlat
