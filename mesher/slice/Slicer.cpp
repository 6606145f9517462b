#include "mesher/slice/Slicer.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <type_traits>

#if defined(__SSSE3__)
#include <tmmintrin.h>
#endif

#include "fields/core/PlaneBands.h"
#include "mesher/slice/SliceTiles.h"
#include "mesher/slice/SliceTilesAvx2.h"

namespace voxlat {

namespace {

/// Transposes the 8 x 8 byte matrix held one row per word (little-endian: byte c of r[k] is column c).
inline void transpose8x8(std::uint64_t r[8])
{
    auto swap = [](std::uint64_t& a, std::uint64_t& b, int shift, std::uint64_t mask) {
        const std::uint64_t t = ((a >> shift) ^ b) & mask;
        b ^= t;
        a ^= t << shift;
    };
    for (int k : {0, 2, 4, 6}) swap(r[k], r[k + 1], 8, 0x00FF00FF00FF00FFull);
    for (int k : {0, 1, 4, 5}) swap(r[k], r[k + 2], 16, 0x0000FFFF0000FFFFull);
    for (int k : {0, 1, 2, 3}) swap(r[k], r[k + 4], 32, 0x00000000FFFFFFFFull);
}

#if defined(__SSSE3__)
/// Loads the 16 x 16 bytes at @a src (rows @a pitch apart) transposed: x[c] byte k is src row k,
/// column c. Four rounds of interleaving rows k and k + 8 rotate the bits (row, column) of each
/// byte's place by one, so four transpose it.
inline void transpose16x16(const std::uint8_t* src, std::size_t pitch, __m128i x[16])
{
    __m128i t[16];
    for (int k = 0; k < 16; ++k) x[k] = _mm_loadu_si128(reinterpret_cast<const __m128i*>(src + std::size_t(k) * pitch));
    for (int round = 0; round < 2; ++round) {
        for (int k = 0; k < 8; ++k) {
            t[2 * k] = _mm_unpacklo_epi8(x[k], x[k + 8]);
            t[2 * k + 1] = _mm_unpackhi_epi8(x[k], x[k + 8]);
        }
        for (int k = 0; k < 8; ++k) {
            x[2 * k] = _mm_unpacklo_epi8(t[k], t[k + 8]);
            x[2 * k + 1] = _mm_unpackhi_epi8(t[k], t[k + 8]);
        }
    }
}

/// Stores 16 bytes at @a dst, or reversed ending at @a dst (the bytes at dst - 15 .. dst).
inline void store16(std::uint8_t* dst, __m128i x, bool reversed)
{
    if (!reversed) {
        _mm_storeu_si128(reinterpret_cast<__m128i*>(dst), x);
        return;
    }
    const __m128i reverse = _mm_setr_epi8(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(dst - 15), _mm_shuffle_epi8(x, reverse));
}
#endif

/// True when this build has the eight-lane tile pass and the CPU running it has AVX2 (a check
/// made here, outside the file built for AVX2, so it runs on any x86-64 CPU).
bool avx2TilesAvailable()
{
#if defined(VOXLAT_AVX2_TILES)
    return __builtin_cpu_supports("avx2");
#else
    return false;
#endif
}

}  // namespace

double LayerImage::exposedPixels() const
{
    // 32-bit partial sums over chunks that cannot overflow them, so the inner loop vectorises.
    constexpr std::size_t kChunk = std::size_t(1) << 16;
    std::uint64_t sum = 0;
    for (std::size_t start = 0; start < pixels.size(); start += kChunk) {
        const std::uint8_t* p = pixels.data() + start;
        const std::size_t n = std::min(kChunk, pixels.size() - start);
        std::uint32_t part = 0;
        for (std::size_t k = 0; k < n; ++k) part += p[k];
        sum += part;
    }
    return double(sum) / 255.0;
}

void LayerImage::storedRow(const Display& display, int row, std::uint8_t* out) const
{
    const int width = display.storedWidth();
    std::fill(out, out + width, std::uint8_t(0));
    int i, j, i1, j1;
    display.landscapeOf(0, row, i, j);
    display.landscapeOf(width - 1, row, i1, j1);
    if (display.portrait) {  // the row is a column of the landscape grid (fixed i)
        if (i < i0 || i >= i0 + nx) return;
        const int step = j1 >= j ? 1 : -1;
        for (int c = 0; c < width; ++c) {
            const int jj = j + step * c;
            if (jj >= j0 && jj < j0 + ny) out[c] = pixels[std::size_t(jj - j0) * nx + (i - i0)];
        }
    } else {  // the row is a row of the landscape grid (fixed j)
        if (j < j0 || j >= j0 + ny) return;
        const int step = i1 >= i ? 1 : -1;
        const std::uint8_t* src = &pixels[std::size_t(j - j0) * nx];
        for (int c = 0; c < width; ++c) {
            const int ii = i + step * c;
            if (ii >= i0 && ii < i0 + nx) out[c] = src[ii - i0];
        }
    }
}

void LayerImage::storedWindow(const Display& display, std::vector<std::uint8_t>& out, int& col0, int& row0, int& w,
                              int& h) const
{
    w = display.portrait ? ny : nx;
    h = display.portrait ? nx : ny;
    out.resize(std::size_t(w) * h);  // every byte is written below (no clearing)
    if (nx == 0 || ny == 0) return;
    // Stored corners of the window's first and last pixels give its placement and directions.
    const bool mx = display.portrait ? !display.mirrorX : display.mirrorX, my = !display.mirrorY;
    const int W = display.storedWidth(), H = display.storedHeight();
    auto colOf = [&](int i, int j) {
        const int u = display.portrait ? j : i;
        return mx ? W - 1 - u : u;
    };
    auto rowOf = [&](int i, int j) {
        const int v = display.portrait ? i : j;
        return my ? H - 1 - v : v;
    };
    col0 = std::min(colOf(i0, j0), colOf(i0 + nx - 1, j0 + ny - 1));
    row0 = std::min(rowOf(i0, j0), rowOf(i0 + nx - 1, j0 + ny - 1));
    // Stored row and column are each a function of one landscape axis: rows of the source map
    // to a fixed stored column (portrait) or row (landscape) with a constant step along the other.
    const std::ptrdiff_t di = display.portrait ? (my ? -1 : 1) * std::ptrdiff_t(w) : (mx ? -1 : 1);
    const std::ptrdiff_t dj = display.portrait ? (mx ? -1 : 1) : (my ? -1 : 1) * std::ptrdiff_t(w);
    const std::ptrdiff_t origin = std::ptrdiff_t(rowOf(i0, j0) - row0) * w + (colOf(i0, j0) - col0);
    // Portrait: each source row becomes a stored column. Transpose 8 x 8 pixel blocks in 64-bit
    // words (a byte reversal where the stored column runs backwards), so stores are whole words;
    // the ragged right and bottom edges take the plain loop below.
    int iDone = 0, jDone = 0;
#if defined(__SSSE3__)
    // 16 x 16 blocks in SSE registers where available.
    if (display.portrait && (dj == 1 || dj == -1)) {
        iDone = nx / 16 * 16;
        jDone = ny / 16 * 16;
        for (int jb = 0; jb < jDone; jb += 16)
            for (int ib = 0; ib < iDone; ib += 16) {
                __m128i x[16];
                transpose16x16(&pixels[std::size_t(jb) * nx + ib], std::size_t(nx), x);
                // x[c] byte k: source row jb + k, column ib + c.
                for (int c = 0; c < 16; ++c) store16(out.data() + origin + di * (ib + c) + dj * jb, x[c], dj != 1);
            }
    }
#else
    if (display.portrait && (dj == 1 || dj == -1)) {
        iDone = nx / 8 * 8;
        jDone = ny / 8 * 8;
        for (int jb = 0; jb < jDone; jb += 8)
            for (int ib = 0; ib < iDone; ib += 8) {
                std::uint64_t r[8];
                for (int k = 0; k < 8; ++k) std::memcpy(&r[k], &pixels[std::size_t(jb + k) * nx + ib], 8);
                transpose8x8(r);  // r[c] byte k: source row jb + k, column ib + c
                for (int c = 0; c < 8; ++c) {
                    std::uint8_t* dst = out.data() + origin + di * (ib + c) + dj * jb;
                    if (dj == 1) {
                        std::memcpy(dst, &r[c], 8);
                    } else {
                        const std::uint64_t reversed = __builtin_bswap64(r[c]);
                        std::memcpy(dst - 7, &reversed, 8);
                    }
                }
            }
    }
#endif
    auto copy = [&](int iBegin, int iEnd, int jBegin, int jEnd) {
        for (int j = jBegin; j < jEnd; ++j) {
            const std::uint8_t* src = &pixels[std::size_t(j) * nx];
            std::uint8_t* dst = out.data() + origin + dj * j;
            for (int i = iBegin; i < iEnd; ++i) dst[di * i] = src[i];
        }
    };
    if (iDone > 0 || jDone > 0) {
        copy(iDone, nx, 0, ny);     // right strip
        copy(0, iDone, jDone, ny);  // bottom strip
        return;
    }
    // Landscape: each source row is a stored row, copied whole or reversed (mirrored x: the
    // Saturn 4), 16 bytes at a time where SSSE3 is there (a byte loop with a step of -1 ran at
    // about 0.4 GB/s: 13 % of slicing W10's plate once most rows were copied a period apart).
    if (!display.portrait && (di == 1 || di == -1)) {
        for (int j = 0; j < ny; ++j) {
            const std::uint8_t* src = &pixels[std::size_t(j) * nx];
            std::uint8_t* dst = out.data() + origin + dj * j;
            if (di == 1) {
                std::memcpy(dst, src, std::size_t(nx));
                continue;
            }
            int i = 0;
#if defined(__SSSE3__)
            for (; i + 16 <= nx; i += 16)
                store16(dst - i, _mm_loadu_si128(reinterpret_cast<const __m128i*>(src + i)), true);
#endif
            for (; i < nx; ++i) dst[-i] = src[i];
        }
        return;
    }
    constexpr int kBlock = 64;
    for (int jb0 = 0; jb0 < ny; jb0 += kBlock)
        for (int ib0 = 0; ib0 < nx; ib0 += kBlock)
            for (int j = jb0; j < std::min(ny, jb0 + kBlock); ++j) {
                const std::uint8_t* src = &pixels[std::size_t(j) * nx];
                std::uint8_t* dst = out.data() + origin + dj * j;
                for (int i = ib0; i < std::min(nx, ib0 + kBlock); ++i) dst[di * i] = src[i];
            }
}

StoredRows::StoredRows(const LayerImage& image, const Display& display, std::vector<std::uint8_t>& buffer)
    : mImage(image), mBuffer(buffer)
{
#if defined(__SSSE3__)
    mStrips = display.portrait && image.nx > 0 && image.ny > 0;
#endif
    if (!mStrips) {
        image.storedWindow(display, mBuffer, mCol0, mRow0, mW, mH);
        return;
    }
    // As storedWindow(): portrait, the stored row from i, reversed unless mirror_y, the column
    // from j, reversed unless mirror_x (portrait toggles the x mirror).
    mReverseI = !display.mirrorY;
    mReverseJ = !display.mirrorX;
    mW = image.ny;
    mH = image.nx;
    const int W = display.storedWidth(), H = display.storedHeight();
    const int firstCol = mReverseJ ? W - 1 - image.j0 : image.j0,
              lastCol = mReverseJ ? W - image.j0 - mW : image.j0 + mW - 1;
    const int firstRow = mReverseI ? H - 1 - image.i0 : image.i0,
              lastRow = mReverseI ? H - image.i0 - mH : image.i0 + mH - 1;
    mCol0 = std::min(firstCol, lastCol);
    mRow0 = std::min(firstRow, lastRow);
    mBuffer.resize(std::size_t(kStripRows) * mW);
}

const std::uint8_t* StoredRows::row(int r)
{
    if (!mStrips) return mBuffer.data() + std::size_t(r) * mW;
    if (r / kStripRows != mStrip) makeStrip(r / kStripRows);
    return mBuffer.data() + std::size_t(r % kStripRows) * mW;
}

void StoredRows::makeStrip(int strip)
{
    mStrip = strip;
    const int nx = mImage.nx, ny = mW;
    const std::uint8_t* pixels = mImage.pixels.data();
    // Stored window row r shows source column a = r (nx - 1 - r reversed), its column c source
    // row b = c (ny - 1 - c reversed). The strip holds rows kStripRows strip and on: source
    // columns aLo and on, in 16 x 16 blocks.
    const int first = kStripRows * strip, rows = std::min(kStripRows, mH - first);
    const int aLo = mReverseI ? nx - first - rows : first;
    auto rowOf = [&](int a) { return mReverseI ? nx - 1 - a - first : a - first; };
    int aDone = aLo;  // columns aLo .. aDone - 1 are done for rows 0 .. bDone - 1
    int bDone = 0;
#if defined(__SSSE3__)
    aDone = aLo + rows / 16 * 16;
    bDone = ny / 16 * 16;
    // Locals, not members: the byte stores may alias any member, which would be reloaded.
    std::uint8_t* const buffer = mBuffer.data();
    const std::ptrdiff_t pitch = mW, rowStep = mReverseI ? -pitch : pitch;
    // Column blocks outer, row blocks inner: each load walks down the image at a constant stride,
    // which the prefetchers follow (the other way round the loads waited for memory); a source
    // line's later three visits find it in L2.
    auto transpose = [&](auto reverseJ) {
        for (int ab = aLo; ab < aDone; ab += 16) {
            std::uint8_t* const top = buffer + std::ptrdiff_t(rowOf(ab)) * pitch;  // the row of column ab
            for (int bb = 0; bb < bDone; bb += 16) {
                __m128i x[16];
                transpose16x16(pixels + std::size_t(bb) * nx + ab, std::size_t(nx), x);
                // x[c] byte k: source row bb + k, column ab + c.
                std::uint8_t* const dst = top + (reverseJ ? ny - 1 - bb : bb);
                for (int c = 0; c < 16; ++c) store16(dst + c * rowStep, x[c], reverseJ);
            }
        }
    };
    if (mReverseJ)
        transpose(std::true_type{});
    else
        transpose(std::false_type{});
#endif
    for (int a = aDone; a < aLo + rows; ++a) {  // columns left over: every row
        std::uint8_t* dst = mBuffer.data() + std::size_t(rowOf(a)) * mW;
        for (int b = 0; b < ny; ++b) dst[mReverseJ ? ny - 1 - b : b] = pixels[std::size_t(b) * nx + a];
    }
    for (int a = aLo; a < aDone; ++a) {  // rows left over
        std::uint8_t* dst = mBuffer.data() + std::size_t(rowOf(a)) * mW;
        for (int b = bDone; b < ny; ++b) dst[mReverseJ ? ny - 1 - b : b] = pixels[std::size_t(b) * nx + a];
    }
}

namespace {

/// Along one axis of the window (@a n pixels of @a pitch from pixel @a first, part coordinate
/// (first + a + 1/2) pitch - @a offset; @a inside says which lie wholly within the part's box):
/// the fewest pixels @a period whose length spans a whole number of @a repeat's periods (to 1e-9
/// relative), and the pixels [@a begin, @a end) that show the pixel @a period before them: the
/// pixel, its neighbours and their footprints lie in the repeat, and so do those of the pixel a
/// period before, both within the part's box. None (all 0) when the field does not repeat.
void repeatSpan(const AxisRepeat& repeat, double pitch, int first, double offset,
                const std::vector<std::uint8_t>& inside, int& period, int& begin, int& end)
{
    period = begin = end = 0;
    const int n = int(inside.size());
    if (!(repeat.period > 0.0 && std::isfinite(repeat.period))) return;
    for (int p = 1; p < n && period == 0; ++p) {
        const double periods = p * pitch / repeat.period;
        if (periods >= 0.5 && std::abs(periods - std::round(periods)) <= 1e-9 * periods) period = p;
    }
    if (period == 0) return;
    const double slack = 1e-9 * repeat.period;
    auto at = [&](int a) { return (double(first + a) + 0.5) * pitch - offset; };
    begin = n;
    for (int a = period; a < n; ++a) {
        const bool copies = inside[a] && inside[a - period] && at(a - period - 1) - 0.5 * pitch >= repeat.lo + slack &&
                            at(a + 1) + 0.5 * pitch <= repeat.hi - slack;
        if (copies && begin == n) begin = a;
        if (copies) end = a + 1;
    }
    if (end <= begin) begin = end = 0;
}

}  // namespace

Slicer::Slicer(const FieldNode& field, const Box3& part, double offsetX, double offsetY, const Display& display,
               const RasterOptions& options)
    : mField(field),
      mPart(part),
      mOffsetX(offsetX),
      mOffsetY(offsetY),
      mDisplay(display),
      mOptions(options),
      mWideTiles(options.wideTiles && avx2TilesAvailable())
{
    const double px = display.pitchX(), py = display.pitchY();
    const double x0 = part.min.x() + offsetX, x1 = part.max.x() + offsetX;
    const double y0 = part.min.y() + offsetY, y1 = part.max.y() + offsetY;
    const double tolerance = 1e-6;
    mFits =
        x0 >= -tolerance && y0 >= -tolerance && x1 <= display.widthMm + tolerance && y1 <= display.heightMm + tolerance;
    // Pixels whose footprint [i, i+1) px meets [x0, x1].
    mI0 = std::clamp(int(std::floor(x0 / px + 1e-9)), 0, display.pixelsX);
    const int i1 = std::clamp(int(std::ceil(x1 / px - 1e-9)), 0, display.pixelsX);
    mJ0 = std::clamp(int(std::floor(y0 / py + 1e-9)), 0, display.pixelsY);
    const int j1 = std::clamp(int(std::ceil(y1 / py - 1e-9)), 0, display.pixelsY);
    mNx = std::max(0, i1 - mI0);
    mNy = std::max(0, j1 - mJ0);
    // rasterize()'s whole-tile tests per column and row (the same expressions as edgeTile's):
    // a pixel that overhangs the part's box by a rounding error counts as whole.
    const double slackX = 1e-9 * px, slackY = 1e-9 * py;
    std::vector<std::uint8_t> columnIn(static_cast<std::size_t>(mNx)), rowIn(static_cast<std::size_t>(mNy));
    for (int a = 0; a < mNx; ++a) {
        const double x = (double(mI0 + a) + 0.5) * px - mOffsetX;
        columnIn[a] = x - 0.5 * px >= part.min.x() - slackX && x + 0.5 * px <= part.max.x() + slackX;
    }
    for (int b = 0; b < mNy; ++b) {
        const double y = (double(mJ0 + b) + 0.5) * py - mOffsetY;
        rowIn[b] = y - 0.5 * py >= part.min.y() - slackY && y + 0.5 * py <= part.max.y() + slackY;
    }
    // Rows (columns) a whole number of y- (x-) periods apart (RasterOptions::repeatRows).
    if (options.repeatRows) {
        repeatSpan(field.axisRepeat(0), px, mI0, mOffsetX, columnIn, mColumnPeriod, mColumnCopyBegin, mColumnCopyEnd);
        repeatSpan(field.axisRepeat(1), py, mJ0, mOffsetY, rowIn, mRowPeriod, mCopyBegin, mCopyEnd);
    }
    mTileColumnsIn.assign(std::size_t(mNx), 0);
    mTileRowsIn.assign(std::size_t(mNy), 0);
    for (int a = 0; a + kLanes <= mNx; ++a) mTileColumnsIn[a] = columnIn[a] && columnIn[a + kLanes - 1];
    for (int b = 0; b + kLanes <= mNy; ++b) {
        bool all = true;
        for (int k = 0; k < kLanes; ++k) all = all && rowIn[b + k];
        mTileRowsIn[b] = all;
    }
    const int s = std::max(1, options.supersample);
    mLevels.resize(std::size_t(s * s) + 1);
    for (int k = 0; k <= s * s; ++k) {
        const double coverage = double(k) / (s * s);
        mLevels[k] = options.gamma <= 0.0 ? (coverage >= 0.5 ? 255 : 0)
                                          : std::uint8_t(std::lround(255.0 * std::pow(coverage, options.gamma)));
    }
}

void Slicer::rasterize(double z, LayerImage& out, RasterStats* stats) const
{
    out.i0 = mI0;
    out.j0 = mJ0;
    out.nx = mNx;
    out.ny = mNy;
    // Every pixel is written below (outside blocks as zeros), so a reused image is not cleared
    // first: a layer's 1.4 MB memset was 2 % of slicing.
    out.pixels.resize(std::size_t(mNx) * mNy);
    if (z < mPart.min.z() || z > mPart.max.z()) {
        std::fill(out.pixels.begin(), out.pixels.end(), std::uint8_t(0));
        return;
    }
    const double px = mDisplay.pitchX(), py = mDisplay.pitchY();
    const int tile = std::max(2, mOptions.tile), block = 8 * tile;
    std::vector<double> values, sub;
    std::vector<float> single, cells;    // the values in single precision and their cells, for the tile tests
    std::vector<signed char> tileSides;  // a block's tiles the field decided (PlaneBands)
    std::vector<TileNeed> tileNeeds;     // and what it asked of them (empty: every tile Decide)
    // Cast once per layer, not per block: a cross-cast costs about what a small block's values do.
    const auto* bands = mOptions.planeBands ? dynamic_cast<const PlaneBands*>(&mField) : nullptr;
    RasterCounts counts;
    int quartersTried = 0, quartersCulled = 0, blocksStraddling = 0, blocksSkipped = 0;
    const bool greyEdges = mOptions.supersample > 0 && mOptions.gamma == 1.0;
    const float tolerance = float(mOptions.linearTolerance);
    auto decideWholeTile = [&](const float* single, int stride, const float* cells, float blockCell,
                               std::uint8_t* pixels, std::uint16_t* slowList, int& slowCount) {
#if defined(VOXLAT_AVX2_TILES)
        if (mWideTiles)
            return decideFullTileAvx2(single, stride, cells, blockCell, tolerance, greyEdges, pixels, std::size_t(mNx),
                                      slowList, slowCount);
#endif
        return decideFullTile<QuadLanes>(single, stride, cells, blockCell, tolerance, greyEdges, pixels,
                                         std::size_t(mNx), slowList, slowCount);
    };
    // The block pass before the tile tests: single precision, cell differences, finiteness.
    auto prepareBlock = [&](const double* values, int gx, int gy, float* single, float* cells, float& cellMax) {
#if defined(VOXLAT_AVX2_TILES)
        if (mWideTiles) return prepareBlockAvx2(values, gx, gy, single, cells, cellMax);
#endif
        return prepareTileBlock<QuadLanes>(values, gx, gy, single, cells, cellMax);
    };

    // Classifies the pixel box [i, i + n) x [j, j + m) of the window: -1 inside, +1 outside, 0 both.
    // Without @a bounded only the part's box decides: 1 outside it, else 0 (no bound() taken).
    auto classify = [&](int i, int j, int n, int m, bool bounded = true) {
        const double lx = (mI0 + i) * px - mOffsetX, hx = (mI0 + i + n) * px - mOffsetX;
        const double ly = (mJ0 + j) * py - mOffsetY, hy = (mJ0 + j + m) * py - mOffsetY;
        const Box3 box{{std::max(lx, mPart.min.x()), std::max(ly, mPart.min.y()), z},
                       {std::min(hx, mPart.max.x()), std::min(hy, mPart.max.y()), z}};
        if (box.min.x() > box.max.x() || box.min.y() > box.max.y()) return 1;
        if (!bounded) return 0;
        const Interval b = mField.bound(box);
        if (b.lo > 0.0) return 1;
        const bool whole = lx >= mPart.min.x() && hx <= mPart.max.x() && ly >= mPart.min.y() && hy <= mPart.max.y();
        return b.hi < 0.0 && whole ? -1 : 0;
    };
    // A tile's rows of kLanes pixels as one 8-byte store each: fill_n called memset per row, and
    // the calls for decided tiles were 1.9 % of slicing W10's general plate.
    auto fill = [&](int i, int j, int n, int m, std::uint8_t grey) {
        std::uint8_t* const at = out.pixels.data() + std::size_t(j) * mNx + i;
        const std::size_t pitch = std::size_t(mNx);
        if (n == kLanes) {
            const std::uint64_t word = 0x0101010101010101ull * grey;
            static_assert(kLanes == sizeof word);
            for (int b = 0; b < m; ++b) std::memcpy(at + b * pitch, &word, sizeof word);
            return;
        }
        for (int b = 0; b < m; ++b) std::fill_n(at + b * pitch, n, grey);
    };
    // The tile passes of the block [bi, bi + bnx) x [bj, bj + bny) whose values (and a one-pixel
    // halo) are at @a v, their single-precision copy at @a f and cells at @a c (prepareBlock's;
    // column a at a * stride, cells at a * (stride - 1)); @a sides the tiles the field decided
    // (tile (a, b) at a * sidesStride + b; null: none), @a blockCell at least each of its cells.
    // Writes every pixel of the block and counts into @a tally.
    auto tilePass = [&](int bi, int bj, int bnx, int bny, const double* v, const float* f, const float* c, int stride,
                        bool finite, float blockCell, const signed char* sides, int sidesStride, RasterCounts& tally) {
        const int ntx = (bnx + tile - 1) / tile, nty = (bny + tile - 1) / tile;
        int decidedTiles = 0;
        if (sides)
            for (int a = 0; a < ntx; ++a)
                for (int b = 0; b < nty; ++b) decidedTiles += sides[std::size_t(a) * sidesStride + b] != 0;
        tally.pixelsEvaluated += std::uint64_t(bnx) * bny - std::uint64_t(decidedTiles) * tile * tile;
        const int cy = stride - 1;
        // Values left out (decided tiles) mean nothing: each tile's own cells decide.
        if (decidedTiles > 0) blockCell = std::numeric_limits<float>::infinity();
        // Whole 8 x 8 tiles within the part's box go straight to the tile pass; edgeTile (which
        // repeats it) only takes the others and those with pixels to sub-sample. The same tests
        // as edgeTile's, per row and column of the window (made by the constructor).
        const bool listed = bnx <= 64 && bny <= 64;
        for (int tj = bj; tj < bj + bny; tj += tile)
            for (int ti = bi; ti < bi + bnx; ti += tile) {
                const int tnx = std::min(tile, bi + bnx - ti), tny = std::min(tile, bj + bny - tj);
                if (decidedTiles > 0) {
                    const int side = sides[std::size_t((ti - bi) / tile) * sidesStride + (tj - bj) / tile];
                    if (side != 0) {
                        fill(ti, tj, tnx, tny, side < 0 ? 255 : 0);
                        ++(side < 0 ? tally.tilesInside : tally.tilesOutside);
                        continue;
                    }
                }
                const std::size_t at = std::size_t(ti - bi) * stride + (tj - bj);
                const std::size_t cellAt = std::size_t(ti - bi) * cy + (tj - bj);
                const bool whole =
                    listed && finite && tnx == kLanes && tny == kLanes && mTileColumnsIn[ti] && mTileRowsIn[tj];
                if (whole) {
                    std::uint16_t slowList[kLanes * kLanes];
                    int slowCount = 0;
                    const int decided =
                        decideWholeTile(f + at, stride, c + cellAt, blockCell,
                                        out.pixels.data() + std::size_t(tj) * mNx + ti, slowList, slowCount);
                    if (slowCount == 0) {
                        const int sure = decided & 0xffff, sureInside = decided >> 16;
                        ++(sure < kLanes * kLanes ? tally.tilesEdge
                           : sureInside == sure   ? tally.tilesInside
                           : sureInside == 0      ? tally.tilesOutside
                                                  : tally.tilesEdge);
                        continue;
                    }
                }
                const int tside =
                    edgeTile(z, ti, tj, tnx, tny, out, v + at, f + at, stride, c + cellAt, finite, sub, tally);
                ++(tside < 0 ? tally.tilesInside : tside > 0 ? tally.tilesOutside : tally.tilesEdge);
            }
    };
    // Stacks of whole blocks one above another (and up to stackColumns across), evaluated as one
    // plane batch (see decideBlock) and decided at once, while their values are in the caches;
    // a stack's slot (its left column of blocks) keeps only where it lies and what each block
    // counted, added when the layer's order reaches the block. A block the layer decides by
    // another path then (a bound, its quarters) writes all its pixels again, so the bytes are
    // those of that path; the counts too. (Decided row of blocks by row of blocks, a stack's
    // values left the caches before its lower blocks came: their tile passes were 10 % of
    // slicing W10's plate, twice the same passes on values in the caches.) The slots and arrays
    // are this call's own: a field's evaluation may run another layer on this thread.
    struct BlockStack {
        int bi = -1, bj = 0, rows = 0;          ///< window column and row of its first block, rows held
        int columns = 1;                        ///< blocks across
        std::vector<RasterCounts> blockCounts;  ///< per block, column by column of blocks
        bool holds(int i, int j, int block) const
        {
            return bi >= 0 && i >= bi && i < bi + columns * block && j >= bj && j < bj + rows;
        }
    };
    std::vector<BlockStack> stacks(std::size_t(mNx / block + 1));
    std::vector<double> stackValues;  // the stack being made (one at a time)
    std::vector<signed char> stackSides;
    std::vector<float> stackSingle, stackCells;
    const int stackBlocks = std::clamp(mOptions.stackBlocks, 1, 8);
    const int stackColumns = std::clamp(mOptions.stackColumns, 1, 8);
    int columnLimit = mNx;   // columns [.., columnLimit) are made by the current rasterBlocks call
    int rowLimit = mNy;      // rows [.., rowLimit) are made by the current rasterRows call
    bool stackable = false;  // the block being decided may make a stack (rasterBlocks)
    // Decides the pixel box of a block already classified as @a side: fills it (255 inside, 0
    // outside) or evaluates it as one batch.
    auto decideBlock = [&](int bi, int bj, int bnx, int bny, int side) {
        const std::uint64_t tiles = std::uint64_t((bnx + tile - 1) / tile) * ((bny + tile - 1) / tile);
        if (side != 0) {
            fill(bi, bj, bnx, bny, side < 0 ? 255 : 0);
            (side < 0 ? counts.tilesInside : counts.tilesOutside) += tiles;
            return;
        }
        // One batch for the block's pixel centres and a one-pixel halo: per-axis terms are shared
        // by the whole block (the separable fast paths), and no per-tile bounds are needed, as
        // the tiles' own centre values decide which pixels are sure (edgeTile's fast path).
        GridBatch grid;
        grid.origin = Vec3d(xOf(mI0 + bi - 1), yOf(mJ0 + bj - 1), z);
        grid.spacing = Vec3d(px, py, 1.0);
        grid.nx = bnx + 2;
        grid.ny = bny + 2;
        grid.nz = 1;
        // A block of whole tiles asks the field for its values where they can matter (PlaneBands:
        // a strut lattice proves the tiles far from its struts outside and leaves them out); the
        // tiles it decides are filled as a culled block's, the others take the passes below with
        // the same values as gridValues'.
        const int ntx = bnx / tile, nty = bny / tile;
        // The tiles the part's box cuts (the window's rim) ask for their values (TileNeed::Exact)
        // and take edgeTile's per-pixel rules as before; the block's other tiles may be decided.
        const bool banded = bands && tile == kLanes && bnx % tile == 0 && bny % tile == 0;
        if (banded) {
            bool rim = false;
            for (int a = 0; a < ntx; ++a) rim = rim || !mTileColumnsIn[bi + a * tile];
            for (int b = 0; b < nty; ++b) rim = rim || !mTileRowsIn[bj + b * tile];
            tileNeeds.clear();
            if (rim)
                for (int a = 0; a < ntx; ++a)
                    for (int b = 0; b < nty; ++b)
                        tileNeeds.push_back(mTileColumnsIn[bi + a * tile] && mTileRowsIn[bj + b * tile]
                                                ? TileNeed::Decide
                                                : TileNeed::Exact);
            tileSides.resize(std::size_t(ntx) * nty);
            // A whole block within the part's box takes its values from a stack of such blocks
            // below it in the same column (up to stackBlocks, evaluated once, made for the first):
            // a strut's rows along y then run through the stack's blocks once, not once per
            // block, and the rows between blocks are made once. The same points as the block's
            // own batch, whose coordinates differ only by the rounding of origin + j spacing.
            // Stacks are made only where the layer has stopped bounding blocks (stackable: a
            // lattice that fills the window, whose blocks below will be evaluated too); where
            // blocks are culled or split into quarters (a TPMS sheet, 3x the CPU when every
            // block made a stack) their values would go unused.
            // A stack several blocks wide (stackColumns) is kept in its left block's slot: the
            // blocks to its right find it there.
            const std::size_t slot = std::size_t(bi / block);
            std::size_t at = slot;
            for (std::size_t left = 1; left < std::size_t(stackColumns) && left <= slot; ++left)
                if (stacks[slot - left].holds(bi, bj, block)) at = slot - left;
            BlockStack& stack = stacks[at];
            const bool held = stack.holds(bi, bj, block);
            if (!rim && bnx == block && bny == block && (held || (stackable && stackBlocks > 1))) {
                if (!held) {
                    int m = 1;
                    while (m < stackBlocks && bj + (m + 1) * block <= rowLimit) {
                        bool in = true;
                        for (int b = 0; b < nty; ++b) in = in && mTileRowsIn[bj + m * block + b * tile];
                        if (!in) break;
                        ++m;
                    }
                    // Up to stackColumns blocks across while the next block to the right is whole,
                    // within the part's box and the columns this call makes, and held by no stack.
                    int columns = 1;
                    while (columns < stackColumns && bi + (columns + 1) * block <= columnLimit &&
                           slot + columns < stacks.size() &&
                           !stacks[slot + columns].holds(bi + columns * block, bj, block)) {
                        bool in = true;
                        for (int a = 0; a < ntx; ++a) in = in && mTileColumnsIn[bi + columns * block + a * tile];
                        if (!in) break;
                        ++columns;
                    }
                    GridBatch tall = grid;
                    tall.nx = columns * block + 2;
                    tall.ny = m * block + 2;
                    stackValues.resize(tall.size());
                    stackSides.resize(std::size_t(ntx) * columns * nty * m);
                    bands->planeValues(tall, tile, Interval{0.0, 0.0}, stackValues, stackSides, {});
                    stackSingle.resize(stackValues.size());
                    stackCells.resize(std::size_t(tall.nx - 1) * (tall.ny - 1));
                    float cellMax = 0.0f;
                    const bool finite = prepareBlock(stackValues.data(), tall.nx, tall.ny, stackSingle.data(),
                                                     stackCells.data(), cellMax);
                    stack.bi = bi;
                    stack.bj = bj;
                    stack.rows = m * block;
                    stack.columns = columns;
                    stack.blockCounts.assign(std::size_t(columns) * m, RasterCounts{});
                    // Each block's passes on the stack's arrays in place (cellMax is at least
                    // each of its cells).
                    const int tallNy = tall.ny, tallTiles = stack.rows / tile;
                    for (int a = 0; a < columns; ++a)
                        for (int b = 0; b < m; ++b) {
                            const std::size_t v = std::size_t(a) * block * tallNy + std::size_t(b) * block;
                            const std::size_t c = std::size_t(a) * block * (tallNy - 1) + std::size_t(b) * block;
                            tilePass(bi + a * block, bj + b * block, block, block, &stackValues[v], &stackSingle[v],
                                     &stackCells[c], tallNy, finite, cellMax,
                                     &stackSides[std::size_t(a) * ntx * tallTiles + std::size_t(b) * nty], tallTiles,
                                     stack.blockCounts[std::size_t(a) * m + b]);
                        }
                }
                counts += stack.blockCounts[std::size_t((bi - stack.bi) / block) * (stack.rows / block) +
                                            (bj - stack.bj) / block];
                return;
            }
            values.resize(grid.size());
            bands->planeValues(grid, tile, Interval{0.0, 0.0}, values, tileSides, tileNeeds);
        } else {
            values.resize(grid.size());
            mField.gridValues(grid, values);
        }
        // Single precision and the largest difference between the four corners of each grid cell
        // (both axes and both diagonals), for the tile passes.
        single.resize(values.size());
        cells.resize(std::size_t(grid.nx - 1) * (grid.ny - 1));
        float blockCell = 0.0f;
        const bool finite = prepareBlock(values.data(), grid.nx, grid.ny, single.data(), cells.data(), blockCell);
        tilePass(bi, bj, bnx, bny, values.data(), single.data(), cells.data(), grid.ny, finite, blockCell,
                 banded ? tileSides.data() : nullptr, nty, counts);
    };
    // Blocks of 8 x 8 tiles, culled by their quarters (4 x 4 tiles): a block whose quarters all
    // straddle the surface is evaluated as one batch (per-axis terms shared by twice the pixels per
    // side), otherwise quarter by quarter as the culling allows: here columns [colBegin, colEnd) of
    // the window's rows [bj, bj + bny).
    auto rasterBlocks = [&](int bj, int bny, int colBegin, int colEnd) {
        columnLimit = colEnd;
        for (int bi = colBegin; bi < colEnd; bi += block) {
            const int bnx = std::min(block, colEnd - bi);
            // Blocks are bounded while that pays: in a lattice that fills the window no block has
            // one sign, and bound() per block was 12 % of slicing W10's strut plate for nothing.
            // After straddlingRun (256) bounded blocks in a row that all straddled (W10's plate:
            // 2 % of a layer), only one block in eight is bounded; the first of those that is
            // decided (a lattice's edge, empty space) brings back bounds for every block. A TPMS
            // sheet decides blocks often enough to keep them (after 64 in a row, W10's gyroid
            // sheet evaluated 31 % more pixels). Counted per layer in the layer's own block
            // order: the bytes do not depend on the threads.
            bool bounded = true;
            stackable = mOptions.straddlingRun > 0 && blocksStraddling >= mOptions.straddlingRun;
            if (stackable) bounded = ++blocksSkipped % 8 == 0;
            const int side = classify(bi, bj, bnx, bny, bounded);
            if (bounded) blocksStraddling = side == 0 ? blocksStraddling + 1 : 0;
            counts.blocksUnbounded += !bounded && side == 0;
            if (side != 0 || !bounded) {
                decideBlock(bi, bj, bnx, bny, side);
                continue;
            }
            // Quarters are culled separately only while that pays: in a lattice every quarter
            // straddles the surface and its bounds are wasted work. Decided per layer, in the
            // layer's own block order, so the bytes do not depend on the threads.
            if (quartersTried >= 64 && 8 * quartersCulled < quartersTried) {
                decideBlock(bi, bj, bnx, bny, 0);
                continue;
            }
            const int half = block / 2;
            int quarterSide[4], quarters = 0;
            bool allStraddle = true;
            for (int qj = bj; qj < bj + bny; qj += half)
                for (int qi = bi; qi < bi + bnx; qi += half) {
                    quarterSide[quarters] =
                        classify(qi, qj, std::min(half, bi + bnx - qi), std::min(half, bj + bny - qj));
                    allStraddle &= quarterSide[quarters++] == 0;
                }
            quartersTried += quarters;
            for (int q = 0; q < quarters; ++q) quartersCulled += quarterSide[q] != 0;
            if (allStraddle) {
                decideBlock(bi, bj, bnx, bny, 0);
                continue;
            }
            quarters = 0;
            for (int qj = bj; qj < bj + bny; qj += half)
                for (int qi = bi; qi < bi + bnx; qi += half)
                    decideBlock(qi, qj, std::min(half, bi + bnx - qi), std::min(half, bj + bny - qj),
                                quarterSide[quarters++]);
        }
    };
    // Rows [rowBegin, rowEnd) of the window, in rows of blocks. Columns a whole number of
    // x-periods apart show the same pixels (the constructor found them): the columns left of the
    // copied ones are made first, then each copied column from the one a period left of it
    // (made or copied before it), then the columns to the right.
    auto rasterRows = [&](int rowBegin, int rowEnd) {
        rowLimit = rowEnd;
        for (int bj = rowBegin; bj < rowEnd; bj += block) {
            if (mOptions.interrupt) mOptions.interrupt();
            const int bny = std::min(block, rowEnd - bj);
            rasterBlocks(bj, bny, 0, mColumnCopyBegin);
            for (int b = bj; b < bj + bny; ++b) {
                std::uint8_t* row = &out.pixels[std::size_t(b) * mNx];
                for (int a = mColumnCopyBegin; a < mColumnCopyEnd; a += mColumnPeriod)
                    std::memcpy(row + a, row + a - mColumnPeriod,
                                std::size_t(std::min(mColumnPeriod, mColumnCopyEnd - a)));
            }
            counts.pixelsCopied += std::uint64_t(mColumnCopyEnd - mColumnCopyBegin) * std::uint64_t(bny);
            rasterBlocks(bj, bny, mColumnCopyEnd, mNx);
        }
    };
    // Rows a whole number of y-periods apart show the same pixels (the constructor found them):
    // the rows above the copied ones are made first, then each copied row from the row a period
    // above it (made or copied before it), then the rows below.
    rasterRows(0, mCopyBegin);
    for (int b = mCopyBegin; b < mCopyEnd; ++b)
        std::memcpy(&out.pixels[std::size_t(b) * mNx], &out.pixels[std::size_t(b - mRowPeriod) * mNx],
                    std::size_t(mNx));
    counts.pixelsCopied += std::uint64_t(mCopyEnd - mCopyBegin) * std::uint64_t(mNx);
    rasterRows(mCopyEnd, mNy);
    if (stats) {
        stats->tilesInside += counts.tilesInside;
        stats->tilesOutside += counts.tilesOutside;
        stats->tilesEdge += counts.tilesEdge;
        stats->pixelsEvaluated += counts.pixelsEvaluated;
        stats->pixelsSupersampled += counts.pixelsSupersampled;
        stats->blocksUnbounded += counts.blocksUnbounded;
        stats->pixelsCopied += counts.pixelsCopied;
    }
}

int Slicer::edgeTile(double z, int ti, int tj, int tnx, int tny, LayerImage& out, const double* values,
                     const float* single, int stride, const float* cells, bool finite, std::vector<double>& sub,
                     RasterCounts& counts) const
{
    const double px = mDisplay.pitchX(), py = mDisplay.pitchY();
    // values: the pixel centres of the tile plus a one-pixel halo (column a of the halo grid at
    // values[a * stride]), for the neighbourhood tests and gradients; cells: the largest difference
    // between the corners of each halo-grid cell (a, b) .. (a + 1, b + 1), at cells[a * (stride - 1) + b].
    auto v = [&](int a, int b) { return values[std::size_t(a) * stride + b]; };
    // xOf / yOf with the pitches hoisted (the same arithmetic, without a division per call).
    auto centreX = [&](int i) { return (double(i) + 0.5) * px - mOffsetX; };
    auto centreY = [&](int j) { return (double(j) + 0.5) * py - mOffsetY; };
    // A pixel that overhangs the part's box by a rounding error only (pixel edges on the box's
    // faces, as when a part is centred on the display) counts as whole: sub-sampling it would
    // only quantise its coverage.
    const double slackX = 1e-9 * px, slackY = 1e-9 * py;
    const int s = std::max(1, mOptions.supersample);
    std::uint64_t supersampled = 0;
    // The s x s sub-samples of the pixel whose low corner is (lx, ly), and how many of them lie
    // within the part's box (the same coordinates the count below tests).
    auto subSamples = [&](double lx, double ly) {
        GridBatch g;
        g.origin = Vec3d(lx + 0.5 * px / s, ly + 0.5 * py / s, z);
        g.spacing = Vec3d(px / s, py / s, 1.0);
        g.nx = s;
        g.ny = s;
        g.nz = 1;
        return g;
    };
    // Whether sub-sample column @a sa (row @a sb) of @a g lies within the part's box.
    auto columnIn = [&](const GridBatch& g, int sa) {
        const double sx = g.origin.x() + sa * g.spacing.x();
        return sx >= mPart.min.x() && sx <= mPart.max.x();
    };
    auto rowIn = [&](const GridBatch& g, int sb) {
        const double sy = g.origin.y() + sb * g.spacing.y();
        return sy >= mPart.min.y() && sy <= mPart.max.y();
    };
    auto boxedSubSamples = [&](double lx, double ly) {
        const GridBatch g = subSamples(lx, ly);
        int columns = 0, rows = 0;
        for (int sa = 0; sa < s; ++sa) columns += columnIn(g, sa);
        for (int sb = 0; sb < s; ++sb) rows += rowIn(g, sb);
        return columns * rows;
    };

    // Fast pass: every difference between a pixel's centre and one of its eight neighbours lies in
    // one of the four cells around it, so a pixel with |f| above their largest difference has no
    // sign change in its 3x3 neighbourhood and |f| above every difference to a neighbour: it is
    // surely inside or outside (the exact test below would say the same for a pixel wholly inside
    // the part, tested per row and column with the slow path's own expressions). Most pixels end
    // here; the rest are listed for the exact test.
    constexpr int kMaxListed = 64 * 64;
    const bool listSlow = tnx * tny <= kMaxListed;
    std::uint16_t slowList[kMaxListed];
    int slowCount = 0;
    bool rowInPart[64];
    const bool rowsListed = tny <= 64;
    if (rowsListed)
        for (int b = 0; b < tny; ++b) {
            const double y = centreY(mJ0 + tj + b);
            rowInPart[b] = y - 0.5 * py >= mPart.min.y() - slackY && y + 0.5 * py <= mPart.max.y() + slackY;
        }
    int sure = 0, sureInside = 0;
    // Locals, not members: the byte stores below may alias any member, which would be reloaded.
    const std::size_t rowStride = std::size_t(mNx);
    std::uint8_t* const tilePixels = out.pixels.data() + std::size_t(tj) * rowStride + ti;
    const double partMinX = mPart.min.x() - slackX, partMaxX = mPart.max.x() + slackX;
    bool tileInPart = rowsListed && tnx == kLanes && tny == kLanes;
    for (int b = 0; tileInPart && b < tny; ++b) tileInPart = rowInPart[b];
    for (int a : {0, tnx - 1}) {
        const double x = centreX(mI0 + ti + a);
        tileInPart = tileInPart && x - 0.5 * px >= partMinX && x + 0.5 * px <= partMaxX;
    }
    const bool greyEdges = mOptions.supersample > 0 && mOptions.gamma == 1.0;
    const float tolerance = float(mOptions.linearTolerance);
    // No block's largest cell here: the tile's own cells decide.
    constexpr float kNoBlockCell = std::numeric_limits<float>::infinity();
    auto decideWholeTile = [&] {
#if defined(VOXLAT_AVX2_TILES)
        if (mWideTiles)
            return decideFullTileAvx2(single, stride, cells, kNoBlockCell, tolerance, greyEdges, tilePixels, rowStride,
                                      slowList, slowCount);
#endif
        return decideFullTile<QuadLanes>(single, stride, cells, kNoBlockCell, tolerance, greyEdges, tilePixels,
                                         rowStride, slowList, slowCount);
    };
    const int decided = tileInPart && finite ? decideWholeTile() : -1;
    if (decided >= 0) {
        sure = decided & 0xffff;
        sureInside = decided >> 16;
    }
    for (int a = 0; decided < 0 && a < tnx; ++a) {
        const float* c0 = cells + std::size_t(a) * (stride - 1);
        const float* c1 = c0 + (stride - 1);
        const double* f = values + std::size_t(a + 1) * stride + 1;
        std::uint8_t* pixel = tilePixels + a;
        const double x = centreX(mI0 + ti + a);
        const bool columnInPart = rowsListed && x - 0.5 * px >= partMinX && x + 0.5 * px <= partMaxX;
        for (int b = 0; b < tny; ++b) {
            const double bound = std::max(std::max(c0[b], c0[b + 1]), std::max(c1[b], c1[b + 1]));
            const bool isSure = columnInPart & rowInPart[rowsListed ? b : 0] & (std::abs(f[b]) > bound);
            const bool inside = f[b] < 0.0;
            pixel[std::size_t(b) * rowStride] = std::uint8_t(-int(isSure & inside));
            sure += isSure;
            sureInside += isSure & inside;
            if (listSlow) {
                slowList[slowCount] = std::uint16_t(a * tny + b);
                slowCount += !isSure;
            }
        }
    }

    const int toDecide = listSlow ? slowCount : tnx * tny;
    for (int k = 0; k < toDecide; ++k) {
        const int index = listSlow ? slowList[k] : k;
        const int a = index / tny, b = index % tny;
        const int i = mI0 + ti + a, j = mJ0 + tj + b;
        const double x = centreX(i), y = centreY(j), f = v(a + 1, b + 1);
        std::uint8_t& pixel = out.pixels[std::size_t(tj + b) * mNx + (ti + a)];
        const bool centreInPart = x >= mPart.min.x() && x <= mPart.max.x() && y >= mPart.min.y() && y <= mPart.max.y();
        if (mOptions.supersample <= 0) {
            pixel = f < 0.0 && centreInPart ? 255 : 0;
            continue;
        }
        const double lx = x - 0.5 * px, hx = x + 0.5 * px, ly = y - 0.5 * py, hy2 = y + 0.5 * py;
        if (hx <= mPart.min.x() || lx >= mPart.max.x() || hy2 <= mPart.min.y() || ly >= mPart.max.y()) {
            pixel = 0;
            continue;
        }
        const bool partial = lx < mPart.min.x() - slackX || hx > mPart.max.x() + slackX ||
                             ly < mPart.min.y() - slackY || hy2 > mPart.max.y() + slackY;
        // Coverage of the linearised edge: f + gx u + gy v < 0 over the pixel (gradient by central
        // differences, per pixel), exact for a straight edge. Where the field bends within the
        // pixel (second differences not small against the gradient) or the part's box cuts the
        // pixel, count s x s sub-samples instead.
        const double gx = 0.5 * (v(a + 2, b + 1) - v(a, b + 1)), gy = 0.5 * (v(a + 1, b + 2) - v(a + 1, b));
        const double dxx = v(a + 2, b + 1) + v(a, b + 1) - 2.0 * f, dyy = v(a + 1, b + 2) + v(a + 1, b) - 2.0 * f;
        const double dxy = 0.25 * (v(a + 2, b + 2) - v(a + 2, b) - v(a, b + 2) + v(a, b));
        const double gradient = std::abs(gx) + std::abs(gy);
        const double gm = std::sqrt(gx * gx + gy * gy);
        const bool bends =
            !partial && std::isfinite(f) && bendsLittle(gx, gy, dxx, dyy, dxy, gm, mOptions.linearTolerance);
        // The linearised edge misses the pixel (|f| > (|gx| + |gy|) / 2, with a margin for rounding):
        // the coverage below would be exactly 0 or 1 and no chord would bend it, so skip it.
        if (bends && std::abs(f) > 0.5 * gradient * (1.0 + 1e-9)) {
            pixel = f < 0.0 ? 255 : 0;
            continue;
        }
        // May the boundary pass through this pixel? A sign change among the 3x3 centres, or |f| no
        // larger than the largest difference to a neighbour (sure for a locally linear field).
        double maxDiff = 0.0;
        bool signChange = false;
        for (int da = -1; da <= 1; ++da)
            for (int db = -1; db <= 1; ++db) {
                const double g = v(a + 1 + da, b + 1 + db);
                maxDiff = std::max(maxDiff, std::abs(g - f));
                signChange |= (g < 0.0) != (f < 0.0);
            }
        if (!signChange && !(std::abs(f) <= maxDiff)) {
            if (!partial) {
                pixel = f < 0.0 ? 255 : 0;
                continue;
            }
            // A pixel the part's box cuts, on one side by the same test (its values finite): its
            // sub-samples within the box would all count (inside) or none would (outside), so the
            // count is that of the sub-samples within the box, without the field's values there.
            // On a plate of struts these are most of the sub-sampled pixels (its whole rim).
            if (finite) {
                pixel = f < 0.0 ? mLevels[boxedSubSamples(lx, ly)] : 0;
                continue;
            }
        }
        const bool linear =
            bends && beyondQuadratic(v(a, b + 1), v(a, b), v(a, b + 2), f, v(a + 1, b), v(a + 1, b + 2),
                                     v(a + 2, b + 1), v(a + 2, b), v(a + 2, b + 2)) <= mOptions.linearTolerance * gm;
        if (linear) {
            // The tile passes' formula, one lane used.
            auto lane = [](double v) { return Quad{} + float(v); };
            const double coverage =
                edgeCoverage<QuadLanes>(lane(f), lane(gx), lane(gy), lane(dxx), lane(dyy), lane(dxy))[0];
            // coverage >= 0, so adding 1/2 rounds to nearest (as lround, without the call).
            const auto linearGrey = std::uint8_t(255.0 * coverage + 0.5);  // NOLINT(bugprone-incorrect-roundings)
            pixel = mOptions.gamma <= 0.0   ? (coverage >= 0.5 ? 255 : 0)
                    : mOptions.gamma == 1.0 ? linearGrey
                                            : std::uint8_t(std::lround(255.0 * std::pow(coverage, mOptions.gamma)));
            continue;
        }
        ++supersampled;
        const GridBatch g = subSamples(lx, ly);
        sub.resize(g.size());
        mField.gridValues(g, sub);
        int inside = 0;
        for (int sa = 0; sa < s; ++sa) {
            const bool xIn = columnIn(g, sa);
            for (int sb = 0; sb < s; ++sb) inside += xIn && rowIn(g, sb) && sub[std::size_t(sa) * s + sb] < 0.0;
        }
        pixel = mLevels[inside];
    }
    counts.pixelsSupersampled += supersampled;
    if (sure < tnx * tny) return 0;
    return sureInside == sure ? -1 : sureInside == 0 ? 1 : 0;
}

void Slicer::fieldValues(double z, std::vector<float>& out) const
{
    out.assign(std::size_t(mNx) * mNy, 0.0f);
    std::vector<double> values;
    const int tile = 32;
    for (int tj = 0; tj < mNy; tj += tile)
        for (int ti = 0; ti < mNx; ti += tile) {
            GridBatch g;
            g.origin = Vec3d(xOf(mI0 + ti), yOf(mJ0 + tj), z);
            g.spacing = Vec3d(mDisplay.pitchX(), mDisplay.pitchY(), 1.0);
            g.nx = std::min(tile, mNx - ti);
            g.ny = std::min(tile, mNy - tj);
            g.nz = 1;
            values.resize(g.size());
            mField.gridValues(g, values);
            for (int a = 0; a < g.nx; ++a)
                for (int b = 0; b < g.ny; ++b)
                    out[std::size_t(tj + b) * mNx + ti + a] = float(values[std::size_t(a) * g.ny + b]);
        }
}

}  // namespace voxlat
