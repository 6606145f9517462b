/// @file PhotonWorkshopWriter.h
/// @brief Anycubic Photon Workshop's binary layout (`.pwmx`, `.pwma`, `.pwmb`, `.pm3`, `.pm4n`,
/// ...; shared/reference/anycubic-format.md), file versions 1, 515, 516, 517 and 518: the file
/// mark, the named tables (HEADER, PREVIEW, colour table, LAYERDEF, EXTRA, MACHINE, SOFTWARE,
/// MODEL, SUBIMGS, PREVIEW2) and the PW0 run-length layer code (`.pws` takes the bit planes of
/// BitPlanes.h instead). Every number is little-endian except PW0's run words.
#pragma once

#include "mesher/writers/GooWriter.h"

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace voxlat {

/// The fields of a Photon Workshop file a writer chooses. Speeds are in mm/min here (as the
/// printer profiles'); the file holds mm/s.
struct PhotonWorkshopHeader {
    std::uint32_t version = 516;     ///< 1, 515, 516, 517 or 518
    std::uint32_t antiAliasing = 1;  ///< HEADER's level: the bit planes of a `.pws` layer; 1 for PW0
    double pixelUm = 0, layerMm = 0, exposureS = 0, bottomExposureS = 0;
    std::uint32_t bottomLayers = 0, transitionLayers = 0;
    std::uint32_t resolutionX = 0, resolutionY = 0, layers = 0;
    std::uint32_t printTimeS = 0;
    double volumeMl = 0;
    GooMotion bottom, normal;
    std::string machineName, softwareVersion;
    double displayWidthMm = 0, displayHeightMm = 0, machineZMm = 0;
    std::array<double, 6> modelBox{};  ///< min x, y, z, max x, y, z (mm; x, y from the plate's centre)
    std::string preview;               ///< 224 x 168 RGB565 little-endian (75,264 bytes); empty = dark grey
    std::string preview2;              ///< version 518: 320 x 190 RGB565; empty = dark grey
};

/// One layer record of LAYERDEF.
struct PhotonWorkshopLayer {
    std::uint32_t address = 0, length = 0;
    double exposureS = 0;
    bool bottom = false;
    std::uint32_t exposedPixels = 0;  ///< pixels that are not black
};

constexpr int kPhotonPreviewW = 224, kPhotonPreviewH = 168, kPhotonPreview2W = 320, kPhotonPreview2H = 190;

/// The address of the first layer's data: the size of everything before it for @a layers
/// layers in file version @a version.
std::uint32_t photonWorkshopLayersStart(std::uint32_t version, std::uint32_t layers);

/// Everything before the first layer's data (photonWorkshopLayersStart() bytes).
std::string photonWorkshopHeadBytes(const PhotonWorkshopHeader& header, const std::vector<PhotonWorkshopLayer>& layers);

/// PW0 code of a layer: the display is @a width x @a height grey pixels, black except the window
/// of @a w x @a h bytes (row-major) at column @a col0, row @a row0; grey g is stored as g >> 4.
std::string encodePw0Layer(int width, int height, const std::uint8_t* window, int col0, int row0, int w, int h);

/// The pixels of a PW0 layer that are not black (LAYERDEF's count), read from its code.
std::uint32_t pw0ExposedPixels(const std::string& code);

/// An RGBA image (4 bytes a pixel) resampled to @a outW x @a outH RGB565 (PREVIEW: 224 x 168,
/// PREVIEW2: 320 x 190).
std::string photonWorkshopPreview(const std::uint8_t* rgba, int width, int height, int outW = kPhotonPreviewW,
                                  int outH = kPhotonPreviewH);

}  // namespace voxlat
