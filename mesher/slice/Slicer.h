/// @file Slicer.h
/// @brief Layer images for resin printers decided straight from the field (no volume, no mesh).
///
/// Pixel grid: the printer's landscape frame, pixel (i, j) covers [i, i+1) x [j, j+1) pitches and
/// is sampled at its centre ((i + 1/2) pitchX, (j + 1/2) pitchY) on the display ("bed"). A part
/// point p maps to the bed at p + offset. Stored images follow PrusaSlicer's raster convention
/// (SLA/RasterBase Trafo): portrait swaps the axes and toggles the x mirror, and the raster's
/// y axis is flipped unless mirror_y (row 0 is the top of the image).
///
/// Anti-aliasing is by area coverage: a pixel whose 3x3 neighbourhood of centre values shows the
/// boundary may pass through it (a sign change, or |f| no larger than the largest difference to a
/// neighbour, which for a locally linear field is a sure test) gets the exact area of the
/// linearised edge (value and central-difference gradient) in the pixel plus a second-order
/// curvature correction, where the edge bends little and the 3x3 values are nearly a quadratic
/// (bendsLittle, beyondQuadratic in SliceTiles.h); elsewhere, or where the part's box cuts it, an
/// s x s grid of sub-samples is counted instead (a pixel the box cuts that the 3x3 test puts on
/// one side counts its sub-samples within the box, or none, without evaluating them: most of a
/// plate's rim). The grey level is 255 * coverage^gamma (gamma 0: a threshold at coverage 1/2, as
/// PrusaSlicer's gamma_correction).
///
/// Cost: blocks of 64 x 64 pixels (and their 32 x 32 quarters, while that culls anything) are
/// culled by bound(); the rest is evaluated as one grid batch per block (a block of whole tiles
/// through PlaneBands where the field has it, exact values asked only for the tiles the part's box
/// cuts: the tiles it proves on one side are filled, only the others and their halo evaluated),
/// and each whole 8 x 8 tile is decided by four- or eight-lane single-precision passes (the whole
/// tile at once where it is surely on one side, first against the block's largest cell
/// difference, lane by lane, then its own; else per pixel: sure, far from the linearised edge, or
/// its coverage, computed for the grey pixels packed into full vectors), so the scalar code only
/// sees the pixels that need sub-samples and the tiles the part's box cuts.
#pragma once

#include "fields/core/FieldNode.h"

#include <atomic>
#include <cstdint>
#include <functional>
#include <vector>

namespace voxlat {

/// A printer display: size, pixels and the orientation of the stored image.
struct Display {
    double widthMm = 0, heightMm = 0;  ///< landscape frame
    int pixelsX = 0, pixelsY = 0;
    bool mirrorX = false, mirrorY = false, portrait = false;

    double pitchX() const { return widthMm / pixelsX; }
    double pitchY() const { return heightMm / pixelsY; }
    int storedWidth() const { return portrait ? pixelsY : pixelsX; }
    int storedHeight() const { return portrait ? pixelsX : pixelsY; }
    /// The landscape pixel (i, j) shown at stored image column @a col, row @a row.
    void landscapeOf(int col, int row, int& i, int& j) const
    {
        const bool mx = portrait ? !mirrorX : mirrorX, my = !mirrorY;
        const int u = mx ? storedWidth() - 1 - col : col, v = my ? storedHeight() - 1 - row : row;
        i = portrait ? v : u;
        j = portrait ? u : v;
    }
};

struct RasterOptions {
    int supersample = 8;  ///< sub-samples per axis in an edge pixel; 0 = no anti-aliasing (centre test)
    double gamma = 1.0;   ///< grey = 255 * coverage^gamma; 0 = binary threshold at coverage 1/2
    /// Edge pixels use the linearised edge when the field's second differences across and along
    /// the edge, and the changes of its second differences over the 3x3 values, are each at most
    /// this share of the gradient's length (the edge bends by a small part of a pixel and no crease
    /// lies within a pixel of it); else sub-samples. 0 sub-samples every edge pixel.
    double linearTolerance = 0.25;
    int tile = 8;  ///< tile side in pixels for culling by bound() (blocks of 8 x 8 tiles first)
    /// Whole tiles eight lanes at a time where the CPU has AVX2 (else four); the bytes are the
    /// same either way, so this only exists to compare the two.
    bool wideTiles = true;
    /// Within a layer, after this many bounded blocks in a row that all straddle the surface (a
    /// lattice filling the window), only one block in eight is bounded until one of those is
    /// decided; 0 bounds every block (to compare: a block left unbounded is evaluated, and its
    /// pixels are decided from the values as those of every straddling block are).
    int straddlingRun = 256;
    /// A block of whole tiles takes its values from the field's PlaneBands::planeValues where it
    /// has them (a strut lattice proves the tiles far from its struts outside and leaves their
    /// values out; the tiles the part's box cuts are asked exactly); off: gridValues for every
    /// pixel (to compare: the bytes are the same where the proven tiles' pixels would have been 0
    /// anyway).
    bool planeBands = true;
    /// Where the field repeats along y (FieldNode::axisRepeat()) and a whole number of periods
    /// spans a whole number of pixel rows (to 1e-9 relative; 2 mm cells at the Saturn 4's 24 um:
    /// 250 rows, three cells), a row whose pixels and their neighbours lie in the repeat, with
    /// the row that many rows above, shows that row's pixels: it is copied instead of computed
    /// (the same plane up to the rounding of the struts' coordinates). The same for columns
    /// along x (19 um: 2000 columns, 19 cells). off: compute every pixel.
    bool repeatRows = true;
    /// Where a layer has stopped bounding blocks (straddlingRun), whole 64 x 64 blocks within the
    /// part's box are evaluated in stacks of up to this many blocks one above another, one plane
    /// batch each (PlaneBands fields: a strut's rows along y are set up once per stack instead of
    /// once per block). 1: every block alone. The same points; their values differ by rounding
    /// (their coordinates, the Gaussians' recurrences over longer rows; the same bytes on every
    /// W10 case measured). At most 8 (64 tiles a column).
    int stackBlocks = 8;
    /// Stacks are up to this many blocks wide where the blocks to the right are whole and within
    /// the part's box too (1 to 8): a strut's set-up then serves more pixels, and a plane whose
    /// columns are interpolated (ColumnStencils) has fewer exact ones near its ends. The same
    /// points; their values differ by rounding and, where columns are interpolated, by the
    /// stencils' (below their bound).
    int stackColumns = 8;
    /// Called once per row of 64 x 64 blocks while a layer is made (none: never); it throws to
    /// stop the layer (a job's cancel check), so a layer of a large plate stops promptly.
    std::function<void()> interrupt;
};

/// A window [i0, i0 + nx) x [j0, j0 + ny) of the landscape pixel grid, row-major (row = j).
struct LayerImage {
    int index = 0;
    int i0 = 0, j0 = 0, nx = 0, ny = 0;
    std::vector<std::uint8_t> pixels;

    std::uint8_t at(int i, int j) const
    {
        return (i < i0 || j < j0 || i >= i0 + nx || j >= j0 + ny) ? 0 : pixels[std::size_t(j - j0) * nx + (i - i0)];
    }
    /// Sum of pixel / 255: the exposed area in pixels.
    double exposedPixels() const;
    /// The stored (oriented, mirrored) image row @a row of the full display, @a out has storedWidth() bytes.
    void storedRow(const Display& display, int row, std::uint8_t* out) const;
    /// The window in the stored orientation: @a w x @a h bytes at stored column @a col0, row @a row0
    /// (a cache-blocked transpose for portrait displays), so stored rows are contiguous copies.
    void storedWindow(const Display& display, std::vector<std::uint8_t>& out, int& col0, int& row0, int& w,
                      int& h) const;
};

/// The window of a layer image in the stored orientation (LayerImage::storedWindow()), row by
/// row: a portrait window is transposed kStripRows stored rows at a time into a strip that stays
/// in the cache while the rows are read (a whole stored copy of a 1200 x 1200 window is written
/// to and read back from memory); other orientations are copied whole once. The same bytes.
class StoredRows {
public:
    /// Stored rows per strip: source columns of a whole cache line, so a line fetched from
    /// memory is used whole while it is in L2 (16-row strips fetched every line four times).
    static constexpr int kStripRows = 64;

    /// Rows of @a image shown on @a display; @a buffer is storage reused from layer to layer. The
    /// image must outlive this object.
    StoredRows(const LayerImage& image, const Display& display, std::vector<std::uint8_t>& buffer);
    /// Placement and size of the stored window, as storedWindow() gives them.
    int col0() const { return mCol0; }
    int row0() const { return mRow0; }
    int width() const { return mW; }
    int height() const { return mH; }
    /// Stored window row @a r (width() bytes, valid until the next call); cheapest in order.
    const std::uint8_t* row(int r);

private:
    void makeStrip(int strip);

    const LayerImage& mImage;
    std::vector<std::uint8_t>& mBuffer;
    int mCol0 = 0, mRow0 = 0, mW = 0, mH = 0;
    bool mStrips = false;                       ///< portrait, made a strip at a time (else the whole window)
    bool mReverseI = false, mReverseJ = false;  ///< stored rows (columns) run against i (j)
    int mStrip = -1;                            ///< the strip in the buffer
};

/// Counters of the work done (summed over layers; read after slicing).
struct RasterStats {
    std::atomic<std::uint64_t> tilesInside{0}, tilesOutside{0}, tilesEdge{0};
    std::atomic<std::uint64_t> pixelsEvaluated{0}, pixelsSupersampled{0};
    std::atomic<std::uint64_t> blocksUnbounded{0};  ///< blocks evaluated without a bound() first
    std::atomic<std::uint64_t> pixelsCopied{0};     ///< pixels of rows copied a period apart
};

/// Plain counters of one layer, added to RasterStats once per layer: atomics updated per tile
/// would bounce their cache line between the threads.
struct RasterCounts {
    std::uint64_t tilesInside = 0, tilesOutside = 0, tilesEdge = 0, pixelsEvaluated = 0, pixelsSupersampled = 0;
    std::uint64_t blocksUnbounded = 0, pixelsCopied = 0;
    RasterCounts& operator+=(const RasterCounts& o)
    {
        tilesInside += o.tilesInside;
        tilesOutside += o.tilesOutside;
        tilesEdge += o.tilesEdge;
        pixelsEvaluated += o.pixelsEvaluated;
        pixelsSupersampled += o.pixelsSupersampled;
        blocksUnbounded += o.blocksUnbounded;
        pixelsCopied += o.pixelsCopied;
        return *this;
    }
};

/// Rasterizes slices of one field (negative inside), clipped to the part box.
class Slicer {
public:
    /// @a field in part coordinates, @a part the box it is clipped to, bed = part + (offsetX, offsetY).
    Slicer(const FieldNode& field, const Box3& part, double offsetX, double offsetY, const Display& display,
           const RasterOptions& options);

    /// The window every layer covers: the pixels whose footprint meets the part's xy box.
    int i0() const { return mI0; }
    int j0() const { return mJ0; }
    int nx() const { return mNx; }
    int ny() const { return mNy; }
    /// False when the part's xy box does not lie within the display.
    bool fitsDisplay() const { return mFits; }
    /// Window rows [copyBegin(), copyEnd()) show the row rowPeriod() rows above (copied); the
    /// range is empty when the field does not repeat along y (RasterOptions::repeatRows).
    int rowPeriod() const { return mRowPeriod; }
    int copyBegin() const { return mCopyBegin; }
    int copyEnd() const { return mCopyEnd; }
    /// The same along x: window columns [columnCopyBegin(), columnCopyEnd()) show the column
    /// columnPeriod() to their left.
    int columnPeriod() const { return mColumnPeriod; }
    int columnCopyBegin() const { return mColumnCopyBegin; }
    int columnCopyEnd() const { return mColumnCopyEnd; }

    /// The layer image at height @a z (part coordinates).
    void rasterize(double z, LayerImage& out, RasterStats* stats = nullptr) const;
    /// The field's values at the window's pixel centres at height @a z (row = j), no culling.
    void fieldValues(double z, std::vector<float>& out) const;

    /// True when whole tiles are decided eight lanes at a time (AVX2).
    bool wideTiles() const { return mWideTiles; }

    /// Part x of the centre of landscape pixel column i (and y of row j).
    double xOf(double i) const { return (i + 0.5) * mDisplay.pitchX() - mOffsetX; }
    double yOf(double j) const { return (j + 0.5) * mDisplay.pitchY() - mOffsetY; }

private:
    /// Decides the pixels of one tile from its centre values (with a one-pixel halo, column-major
    /// with @a stride; @a single holds them in single precision for the vectorised tests) and the
    /// largest corner difference of each halo cell (@a cells); @a finite says that every value of
    /// the batch is finite. Returns -1 (+1) if every pixel was surely inside
    /// (outside), else 0.
    int edgeTile(double z, int ti, int tj, int tnx, int tny, LayerImage& out, const double* values, const float* single,
                 int stride, const float* cells, bool finite, std::vector<double>& sub, RasterCounts& counts) const;

    const FieldNode& mField;
    Box3 mPart;
    double mOffsetX, mOffsetY;
    Display mDisplay;
    RasterOptions mOptions;
    int mI0 = 0, mJ0 = 0, mNx = 0, mNy = 0;
    bool mFits = true;
    bool mWideTiles = false;            ///< options.wideTiles and the CPU has AVX2
    std::vector<std::uint8_t> mLevels;  ///< grey of k inside sub-samples, k = 0..s^2
    /// Per window column i (row j): whether columns i .. i + 7 (rows j .. j + 7) all lie within the
    /// part's box up to edgeTile's slack, so a whole tile there may take the tile pass. They do
    /// not depend on z: made once here, not per block of every layer.
    std::vector<std::uint8_t> mTileColumnsIn, mTileRowsIn;
    int mRowPeriod = 0, mCopyBegin = 0, mCopyEnd = 0;
    int mColumnPeriod = 0, mColumnCopyBegin = 0, mColumnCopyEnd = 0;
};

}  // namespace voxlat
