/// @file AnycubicZipWriter.h
/// @brief The binary members of Anycubic's zip layout (`.pm7`, `.pm7m`, `.pm4u`, `.pp1`, `.pp1m`;
/// docs/formats/anycubic-zip.md): `scene.slice` (a summary of every layer) and
/// `calc_layer_volumes.data` (the resin per slab of about 0.2 mm), and what they need to know of a
/// PW0 layer (its lit area, bounds and pieces). The JSON members and the zip itself are the
/// archive's (engine/jobs/SliceArchives.cpp); the layers are PW0 code (PhotonWorkshopWriter.h).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace voxlat {

/// What the scene summary states of one PW0 layer, in pixels of the stored image.
struct Pw0LayerShape {
    std::uint64_t litPixels = 0;  ///< pixels that are not black
    double coverage = 0;          ///< the pixels' summed grey, in whole pixels (a grey c of 15 counts c/15)
    int col0 = 0, row0 = 0, col1 = 0, row1 = 0;  ///< lit pixels' bounds, [col0, col1) x [row0, row1); empty: all 0
    std::uint32_t pieces = 0;                    ///< 8-connected pieces of lit pixels
    std::uint64_t largestPiecePixels = 0;        ///< lit pixels of the largest piece
};

/// The shape of the PW0 layer @a code of a @a width x @a height display (runs run on from row
/// to row). Throws std::invalid_argument if the code does not cover exactly width x height pixels.
Pw0LayerShape pw0LayerShape(const std::string& code, int width, int height);

/// One layer's record in `scene.slice` (64 bytes): millimetres, x and y from the display's centre.
struct AnycubicSceneLayer {
    double zMm = 0;               ///< the layer's middle
    double areaMm2 = 0;           ///< its lit area
    std::array<double, 4> box{};  ///< x min, y min, x max, y max (all 0 for an empty layer)
    std::uint32_t pieces = 0;
    double largestPieceMm2 = 0;
};

/// `scene.slice`: "ANYCUBIC-PWSZ", the software's name, the format's numbers, the layer count,
/// the part's box (x min, y min, z min, x max, y max, z max), then `<---`, the count again, the
/// layers' records and `--->`.
std::string anycubicSceneBytes(const std::string& software, const std::array<double, 6>& box,
                               const std::vector<AnycubicSceneLayer>& layers);

/// One slab of `calc_layer_volumes.data` (48 bytes).
struct AnycubicVolumeSlab {
    std::uint32_t layer = 0;  ///< the layer before the slab's first (0 for the first slab)
    double zMm = 0, thicknessMm = 0;
    double raw = 0;  ///< the slab's resin in the format's unit (0.0011 mL each)
};

/// The slabs of `calc_layer_volumes.data` for layers of @a thicknessMm with the lit areas
/// @a areasMm2 (one per layer): about 0.2 mm each (round(0.2 / thickness) layers), the top
/// round(0.1 / thickness) layers (at least one) left out, the raw volumes scaled so they add up to
/// @a totalMl (the job's volume) when that is > 0.
std::vector<AnycubicVolumeSlab> anycubicVolumeSlabs(const std::vector<double>& areasMm2, double thicknessMm,
                                                    double totalMl);

/// `calc_layer_volumes.data`: its magic 0x20251024, the slab height 0.2, 1, the count, the slabs.
std::string anycubicVolumesBytes(const std::vector<AnycubicVolumeSlab>& slabs);

/// mL per raw unit of `calc_layer_volumes.data`.
constexpr double kAnycubicRawVolumeMl = 0.0011;

}  // namespace voxlat
