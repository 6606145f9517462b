/// @file BitPlanes.h
/// @brief The RLE1 bit-plane layer code of Chitubox's `.cbddlp` / `.photon` and Anycubic's `.pws`
/// (shared/reference/ctb-format.md §5.2, anycubic-format.md §9.2): a grey layer as @a planes
/// bilevel images, each a stream of one-byte runs (bit 7 = on, bits 6–0 = 1 to 125 pixels) over
/// the whole display. A reader counts the planes a pixel is on in, n, and shows grey
/// n·(256/planes) − 1 (0 for none); the writer sets the planes that give the nearest such grey.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace voxlat {

/// The grey a reader shows for a pixel on in @a n of @a planes planes.
int bitPlanesGrey(int n, int planes);

/// The planes of a layer, concatenated (plane 1 first; a pixel is on in planes 1..n): the display
/// is @a width x @a height grey pixels, black except the window of @a w x @a h bytes (row-major)
/// at column @a col0, row @a row0. @a planes is 1, 2, 4, 8 or 16.
std::string encodeBitPlanes(int planes, int width, int height, const std::uint8_t* window, int col0, int row0, int w,
                            int h);

/// The byte length of each plane of @a code (encodeBitPlanes()) for a display of @a pixels.
std::vector<std::size_t> bitPlaneLengths(const std::string& code, int planes, std::uint64_t pixels);

/// The pixels that are not black: those on in the first plane.
std::uint32_t bitPlanesExposed(const std::string& code, std::uint64_t pixels);

}  // namespace voxlat
