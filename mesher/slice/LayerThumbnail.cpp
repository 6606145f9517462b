#include "mesher/slice/LayerThumbnail.h"

#include <algorithm>
#include <cmath>

namespace voxlat {

namespace {

/// The first row read of the cell starting at row @a first of @a rows rows.
int firstRowRead(int first, int rows, int rowStride)
{
    return first + std::min(rowStride / 2, rows - 1);
}

}  // namespace

void layerCellSums(const LayerImage& image, int step, int rowStride, std::vector<std::uint32_t>& sums)
{
    const int nx = image.nx, ny = image.ny, across = cellsAcross(nx, step), down = cellsAcross(ny, step);
    sums.assign(std::size_t(across) * std::size_t(down), 0);
    if (nx <= 0 || ny <= 0) return;
    // Locals, not members: the column sums' stores would otherwise reload the image's fields.
    std::vector<std::uint32_t> columns(static_cast<std::size_t>(nx));
    std::uint32_t* const column = columns.data();
    const std::uint8_t* const pixels = image.pixels.data();
    const std::size_t pitch = std::size_t(nx);
    const int whole = nx / step;  // cells of `step` columns; the last one may be short
    for (int b = 0; b < down; ++b) {
        const int first = b * step, rows = std::min(step, ny - first);
        std::fill(columns.begin(), columns.end(), 0u);
        for (int j = firstRowRead(first, rows, rowStride); j < first + rows; j += rowStride) {
            const std::uint8_t* const src = pixels + std::size_t(j) * pitch;
            for (int i = 0; i < nx; ++i) column[i] += src[i];
        }
        std::uint32_t* const target = &sums[std::size_t(b) * across];
        for (int c = 0; c < whole; ++c) {
            std::uint32_t s = 0;
            for (int k = 0; k < step; ++k) s += column[c * step + k];
            target[c] = s;
        }
        for (int i = whole * step; i < nx; ++i) target[whole] += column[i];
    }
}

std::vector<std::uint8_t> layerThumbnail(const LayerImage& image, int step, int rowStride)
{
    std::vector<std::uint32_t> sums;
    layerCellSums(image, step, rowStride, sums);
    const int across = cellsAcross(image.nx, step), down = cellsAcross(image.ny, step);
    std::vector<std::uint8_t> cells(sums.size());
    for (int b = 0; b < down; ++b) {
        const int first = b * step, rows = std::min(step, image.ny - first);
        const int read = (first + rows - firstRowRead(first, rows, rowStride) + rowStride - 1) / rowStride;
        for (int c = 0; c < across; ++c) {
            const int columns = std::min(step, image.nx - c * step);
            const std::uint64_t count = std::uint64_t(read) * std::uint64_t(columns);
            const std::size_t k = std::size_t(b) * across + c;
            cells[k] = std::uint8_t((2 * std::uint64_t(sums[k]) + count) / (2 * count));
        }
    }
    return cells;
}

void LayerThumbnails::choose(int count, int nx, int ny)
{
    step = std::max(1, cellsAcross(std::max(nx, ny), kLongSide));
    rowStride = std::max(1, step / 4);
    width = cellsAcross(nx, step);
    height = cellsAcross(ny, step);
    const std::size_t bytes = std::max<std::size_t>(1, std::size_t(width) * std::size_t(height));
    const int n = int(std::min<std::size_t>(
        {std::size_t(std::max(count, 0)), std::size_t(kMaxLayers), std::max<std::size_t>(2, kMaxBytes / bytes)}));
    layers.clear();
    for (int k = 0; k < n; ++k)
        layers.push_back(n == count ? k : int(std::lround(double(k) * double(count - 1) / double(n - 1))));
    images.assign(layers.size(), {});
}

int LayerThumbnails::indexOf(int layer) const
{
    const auto at = std::lower_bound(layers.begin(), layers.end(), layer);
    return at != layers.end() && *at == layer ? int(at - layers.begin()) : -1;
}

}  // namespace voxlat
