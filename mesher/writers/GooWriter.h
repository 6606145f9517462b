/// @file GooWriter.h
/// @brief Elegoo's `.goo` resin-slice format, V3 layout (shared/reference/goo-format.md): the
/// 195,477-byte header, per-layer definitions and the run-length image code Elegoo's own slicer
/// writes (no "difference" chunks). Every number is big-endian.
#pragma once

#include <array>
#include <cstdint>
#include <string>

namespace voxlat {

/// Two-stage moves and waits of one kind of layer (bottom or normal).
struct GooMotion {
    std::array<double, 2> liftDistance{3, 4};  ///< mm, stage 1 (slow, off the film) and stage 2
    std::array<double, 2> liftSpeed{75, 230};  ///< mm/min
    std::array<double, 2> retractDistance{5.5, 1.5};
    std::array<double, 2> retractSpeed{230, 75};
    double waitBeforeLift = 0;    ///< s, after curing
    double waitAfterLift = 0;     ///< s
    double waitAfterRetract = 1;  ///< s, before curing
    int lightPwm = 255;           ///< 0..255
};

/// The header fields a writer chooses (the rest are fixed by the format).
struct GooHeader {
    std::string softwareName, softwareVersion, created, printerName, printerType, resinName;
    int antiAliasing = 8, greyLevel = 0, blurLevel = 0;
    std::string smallPreview;  ///< 116 x 116 RGB565 big-endian (26,912 bytes); empty = dark grey
    std::string bigPreview;    ///< 290 x 290 (168,200 bytes)
    std::uint32_t layers = 0;
    int resolutionX = 0, resolutionY = 0;
    bool mirrorX = false, mirrorY = false;
    double displayWidthMm = 0, displayHeightMm = 0, machineZMm = 0, layerMm = 0;
    double exposureS = 0, bottomExposureS = 0;
    std::uint32_t bottomLayers = 0, transitionLayers = 0;
    GooMotion bottom, normal;
    std::uint32_t printTimeS = 0;
    double volumeMm3 = 0, weightG = 0, price = 0;
    std::string priceUnit = "$";
};

/// One layer's definition (66 bytes in the file).
struct GooLayerDefinition {
    double zMm = 0, exposureS = 0;
    GooMotion motion;
};

constexpr std::size_t kGooHeaderBytes = 195477;
constexpr int kGooSmallPreview = 116, kGooBigPreview = 290;

/// The header, exactly kGooHeaderBytes long.
std::string gooHeaderBytes(const GooHeader& header);

/// An RGBA image (@a width x @a height, 4 bytes per pixel) resampled to @a side x @a side RGB565
/// big-endian, as the header's previews.
std::string gooPreview(const std::uint8_t* rgba, int width, int height, int side);

/// A layer image coded as `.goo` image data (0x55, chunks, checksum): the display is @a width x
/// @a height grey pixels, black except for the window of @a w x @a h bytes (row-major) at column
/// @a col0, row @a row0. Runs continue across rows, as the format reads one pixel stream.
std::string encodeGooLayer(int width, int height, const std::uint8_t* window, int col0, int row0, int w, int h);

/// One layer block: definition, data size, @a image (from encodeGooLayer()) and the delimiter.
std::string gooLayerBytes(const GooLayerDefinition& definition, const std::string& image);

/// The 11 bytes that end a file.
std::string gooEnding();

}  // namespace voxlat
