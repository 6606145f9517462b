/// @file LayerThumbnail.h
/// @brief A layer image averaged over square cells of pixels: the slices' contact sheet and
/// report.html's layer view.
#pragma once

#include "mesher/slice/Slicer.h"

#include <cstdint>
#include <vector>

namespace voxlat {

/// Cells of @a step x @a step pixels across a layer of @a pixels pixels: ceil(pixels / step) (the
/// last one may be short).
inline int cellsAcross(int pixels, int step)
{
    return (pixels + step - 1) / step;
}

/// The sums of @a image's pixels over cells of @a step x @a step pixels (row-major,
/// cellsAcross(nx) by cellsAcross(ny), row 0 at the image's row 0), into @a sums. Of each cell's
/// rows every @a rowStride-th is read, the first rowStride / 2 into the cell (or its last row, where
/// the cell is shorter); 1 reads every pixel, and the sums are then exact whatever the order.
/// Rows are summed into one row of column sums first, so the pass streams the image once.
void layerCellSums(const LayerImage& image, int step, int rowStride, std::vector<std::uint32_t>& sums);

/// @a image averaged over cells of @a step x @a step pixels (layerCellSums with @a rowStride; each
/// cell divided by the pixels it read, rounded): a grey value per cell, row 0 at the image's row 0.
std::vector<std::uint8_t> layerThumbnail(const LayerImage& image, int step, int rowStride);

/// Layers of a slices output kept as thumbnails (layerThumbnail) for report.html's layer view:
/// at most kMaxLayers of them and kMaxBytes of cells in all, spread evenly from the first layer to
/// the last (every layer where they fit), in cells of at most kLongSide along the window's longer
/// side, four rows of each cell read.
struct LayerThumbnails {
    static constexpr int kLongSide = 320;
    static constexpr int kMaxLayers = 64;
    static constexpr std::size_t kMaxBytes = std::size_t(2) << 20;

    int step = 1;               ///< pixels per cell along each axis
    int rowStride = 1;          ///< rows of a cell read: every rowStride-th
    int width = 0, height = 0;  ///< cells across (x) and down (y)
    /// Cell (0, 0)'s corner at the least x and y, and a cell's size, in the part's coordinates (mm).
    double originMm[2] = {0.0, 0.0}, cellMm[2] = {0.0, 0.0};
    std::vector<int> layers;                        ///< the kept layers, ascending
    std::vector<std::vector<std::uint8_t>> images;  ///< per kept layer: width x height cells, row 0 at the least y

    /// Chooses the layers and cells for @a count layers of windows of @a nx x @a ny pixels.
    void choose(int count, int nx, int ny);
    /// The position of @a layer in layers, or -1 where it is not kept.
    int indexOf(int layer) const;
};

}  // namespace voxlat
