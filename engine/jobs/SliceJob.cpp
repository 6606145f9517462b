#include "engine/jobs/SliceJob.h"

#include "engine/jobs/OutputPaths.h"
#include "engine/jobs/SliceArchives.h"

#include "engine/checks/Printability.h"

#include "engine/core/Errors.h"
#include "engine/core/Format.h"
#include "engine/core/Version.h"
#include "mesher/slice/LayerThumbnail.h"
#include "mesher/slice/Slicer.h"
#include "mesher/writers/AtomicFile.h"
#include "mesher/writers/BitPlanes.h"
#include "mesher/writers/CtbWriter.h"
#include "mesher/writers/GooWriter.h"
#include "mesher/writers/PhotonWorkshopWriter.h"
#include "mesher/writers/SliceWriters.h"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/info.h>
#include <tbb/parallel_pipeline.h>
#include <tbb/task_arena.h>

#include <unistd.h>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <memory>
#include <mutex>
#include <sstream>

namespace voxlat {

namespace fs = std::filesystem;

namespace {

/// A small top view of the part: the highest exposed layer per cell, shaded, for thumbnails.
struct HeightMap {
    int w = 0, h = 0, step = 1;
    std::vector<int> top;  ///< -1: never exposed
    /// For layers copied from a period below (LayerRepeats): per cell the highest kept phase
    /// exposed there, over all phases and over the phases up to `lastPhase`.
    std::vector<int> phaseTop, phaseTopLow;
    int lastPhase = -1;
    void init(int nx, int ny)
    {
        step = std::max(1, std::max((nx + 799) / 800, (ny + 799) / 800));
        w = (nx + step - 1) / step;
        h = (ny + step - 1) / step;
        top.assign(std::size_t(w) * h, -1);
    }
    /// A map of the highest layer marked per cell, as `top` but of layer + 1 (0: never), in 16
    /// bits where the layers fit (half the bytes to read and write per layer).
    struct Marks {
        std::vector<std::uint16_t> narrow;
        std::vector<int> wide;
    };
    /// Marks @a image into @a into: layers may come in any order and on any thread, each into its
    /// own map, merged into `top` at the end (merge()).
    void add(const LayerImage& image, Marks& into, int layers) const
    {
        if (layers < 0xffff) {
            if (into.narrow.empty()) into.narrow.assign(top.size(), 0);
            mark(image, into.narrow, std::uint16_t(image.index + 1));
        } else {
            if (into.wide.empty()) into.wide.assign(top.size(), 0);
            mark(image, into.wide, image.index + 1);
        }
    }
    /// Takes the highest layer of @a marks where it is higher (the same map for any order of layers).
    void merge(const Marks& marks)
    {
        for (std::size_t c = 0; c < marks.narrow.size(); ++c) top[c] = std::max(top[c], int(marks.narrow[c]) - 1);
        for (std::size_t c = 0; c < marks.wide.size(); ++c) top[c] = std::max(top[c], marks.wide[c] - 1);
    }
    /// Layer @a image.index is a phase whose copies go up to layer @a count - 1, @a period apart.
    void addPhase(const LayerImage& image, int period, int count)
    {
        if (phaseTop.empty()) {
            phaseTop.assign(top.size(), -1);
            phaseTopLow.assign(top.size(), -1);
            lastPhase = (count - 1) % period;
        }
        mark(image, phaseTop, image.index);
        if (image.index <= lastPhase) mark(image, phaseTopLow, image.index);
    }
    /// Adds the copies of the kept phases: phase j's last copy is layer j + period floor((count -
    /// 1 - j) / period), so the phases up to lastPhase rank above the others.
    void addCopies(int period, int count)
    {
        for (std::size_t c = 0; c < phaseTop.size(); ++c) {
            const int j = phaseTopLow[c] >= 0 ? phaseTopLow[c] : phaseTop[c];
            if (j >= 0) top[c] = std::max(top[c], j + period * ((count - 1 - j) / period));
        }
    }
    /// Raises @a into to @a value where the image is exposed (at least half), sampled every `step`.
    template <class T>
    void mark(const LayerImage& image, std::vector<T>& into, T value) const
    {
        // A thumbnail needs no more than every `step` pixels. The samples of a row are gathered
        // first so the select runs as a vector loop (a branch per pixel mispredicts on lattices).
        // Locals, not members: the byte stores may alias any member, which would be reloaded.
        const int width = w, stride = step, rows = image.ny;
        const std::size_t pitch = std::size_t(image.nx);
        std::vector<std::uint8_t> row(static_cast<std::size_t>(width));
        std::uint8_t* const samples = row.data();
        const std::uint8_t* const pixels = image.pixels.data();
        for (int j = 0; j < rows; j += stride) {
            const std::uint8_t* src = pixels + std::size_t(j) * pitch;
            if (stride == 2)  // the usual case (a display's window up to 1600 wide), a constant stride vectorises
                for (int c = 0; c < width; ++c) samples[c] = src[std::size_t(c) * 2];
            else
                for (int c = 0; c < width; ++c) samples[c] = src[std::size_t(c) * stride];
            T* t = &into[std::size_t(j / stride) * width];
            for (int c = 0; c < width; ++c) t[c] = samples[c] >= 128 ? std::max(t[c], value) : t[c];
        }
    }
    /// An RGBA image of tw x th with the map fitted in, y up.
    std::string render(int tw, int th, int layers) const
    {
        const double scale = std::min(double(tw) / std::max(1, w), double(th) / std::max(1, h));
        const double ox = 0.5 * (tw - scale * w), oy = 0.5 * (th - scale * h);
        return encodePng(
            tw, th, 4,
            [&](int row, std::uint8_t* out) {
                for (int c = 0; c < tw; ++c) {
                    const int i = int(std::floor((c + 0.5 - ox) / scale));
                    const int j = h - 1 - int(std::floor((row + 0.5 - oy) / scale));
                    int t = -1;
                    if (i >= 0 && i < w && j >= 0 && j < h) t = top[std::size_t(j) * w + i];
                    std::uint8_t* p = out + 4 * c;
                    if (t < 0) {
                        p[0] = p[1] = p[2] = 40;
                        p[3] = 255;
                    } else {
                        const double shade = 0.45 + 0.55 * double(t + 1) / std::max(1, layers);
                        p[0] = std::uint8_t(std::lround(250 * shade));
                        p[1] = std::uint8_t(std::lround(140 * shade));
                        p[2] = std::uint8_t(std::lround(30 * shade));
                        p[3] = 255;
                    }
                }
            },
            6);
    }
};

/// A few layers, downsampled by area averaging, laid out on a grid (a contact sheet).
struct ContactSheet {
    std::vector<int> layers;
    int cell = 320, columns = 4, step = 1, cw = 0, ch = 0;
    std::vector<std::vector<std::uint8_t>> cells;
    void init(int count, int nx, int ny)
    {
        const int n = std::min(count, 12);
        for (int k = 0; k < n; ++k) layers.push_back(int((k + 0.5) * count / n));
        step = std::max(1, cellsAcross(std::max(nx, ny), cell));
        cw = std::max(1, cellsAcross(nx, step));
        ch = std::max(1, cellsAcross(ny, step));
        cells.resize(layers.size());
        columns = std::min<int>(columns, std::max<std::size_t>(1, layers.size()));
    }
    /// Takes @a image for its own layer and, with @a period > 0, for the layers copied from it
    /// (a period and more above).
    void add(const LayerImage& image, int period = 0)
    {
        auto shows = [&](int layer) {
            return layer == image.index || (period > 0 && layer >= period && layer % period == image.index);
        };
        if (std::none_of(layers.begin(), layers.end(), shows)) return;
        std::vector<std::uint32_t> sum;
        layerCellSums(image, step, 1, sum);
        std::vector<std::uint8_t> cell(sum.size());
        for (std::size_t k = 0; k < sum.size(); ++k) cell[k] = std::uint8_t(sum[k] / (step * step));
        for (std::size_t k = 0; k < layers.size(); ++k)
            if (shows(layers[k])) cells[k] = cell;
    }
    std::string render() const
    {
        const int rows = int((layers.size() + columns - 1) / columns), gap = 4;
        const int width = columns * (cw + gap) + gap, height = rows * (ch + gap) + gap;
        return encodePng(
            width, height, 1,
            [&](int r, std::uint8_t* out) {
                std::fill(out, out + width, std::uint8_t(96));
                const int cr = (r - gap) / (ch + gap), y = (r - gap) % (ch + gap);
                if (r < gap || y >= ch || cr >= rows) return;
                for (int cc = 0; cc < columns; ++cc) {
                    const std::size_t k = std::size_t(cr) * columns + cc;
                    if (k >= cells.size()) break;
                    const int j = ch - 1 - y;  // y up, as seen from above
                    for (int x = 0; x < cw; ++x)
                        out[gap + cc * (cw + gap) + x] = cells[k].empty() ? 0 : cells[k][std::size_t(j) * cw + x];
                }
            },
            6);
    }
};

/// The fewest layers, below @a count, whose height spans a whole number of @a field's z-periods
/// (to 1e-9 relative): 8 mm cells at 0.05 mm give 160, at 0.03 mm 800 (three cells); 1 when
/// the field does not change along z; 0 when it does not repeat within the part.
int layersPerPeriod(const FieldNode& field, double layer, int count)
{
    const double period = field.period(2);
    if (period == FieldNode::kNoPeriod) return 0;
    if (std::isinf(period)) return count > 1 ? 1 : 0;
    for (int layers = 1; layers < count; ++layers) {
        const double periods = layers * layer / period;
        if (periods >= 0.5 && std::abs(periods - std::round(periods)) <= 1e-9 * periods) return layers;
    }
    return 0;
}

/// Layers a z-period apart (layersPerPeriod()): layer i >= period shows the slice of layer
/// i % period (its phase), the same plane of a field that repeats along z (up to the rounding of
/// z, about 1e-15 mm).
/// The phases' encoded images are kept in order while they fit the budget; a layer whose phase
/// was kept is copied, any other computed. What is kept depends only on the images' sizes, never
/// on timing, so the archive's bytes are the same for any thread count.
struct LayerRepeats {
    int period = 0;  ///< 0: every layer computed
    std::size_t budget = 0, bytes = 0;
    std::vector<std::string> images;  ///< encoded images of the kept phases
    std::vector<double> exposed;      ///< exposed pixels of the kept phases
    std::vector<std::uint32_t> crcs;  ///< CRC-32 of the kept phases' images (PNG)
    std::atomic<int> kept{0};         ///< phases kept so far (always a prefix)
    std::atomic<bool> closed{false};  ///< no further phase will be kept
    int copied = 0;

    bool repeats(int layer) const { return period > 0 && layer >= period; }
    /// Whether a layer may be copied, as far as the input stage can tell (the writer decides).
    bool mayCopy(int layer) const { return repeats(layer) && !(closed.load() && layer % period >= kept.load()); }
    bool copies(int layer) const { return repeats(layer) && layer % period < kept.load(); }
    /// Keeps the next phase's image (moved from @a image, whose CRC-32 is @a crc) if it and every
    /// phase before it fit; the kept image, or null (@a image untouched).
    const std::string* keep(std::string& image, double exposedPixels, std::uint32_t crc)
    {
        if (closed.load() || bytes + image.size() > budget) {
            closed = true;
            return nullptr;
        }
        bytes += image.size();
        image.shrink_to_fit();  // a layer's buffer is reused with slack; a kept image holds none
        images.push_back(std::move(image));
        exposed.push_back(exposedPixels);
        crcs.push_back(crc);
        kept = int(images.size());
        if (kept.load() == period) closed = true;
        return &images.back();
    }
};

/// Warns of what the printability checks found and, with `checks: strict`, fails the job on an
/// island (before the archive is finished, so nothing is left).
void reportPrintability(const PrintabilityCheck& check, const SliceSettings& settings, const fs::path& path,
                        const JobContext* context)
{
    const nlohmann::json found = check.report(5);
    const std::string name = path.filename().string();
    if (check.islandCount() > 0) {
        const std::string message =
            name + ": " + std::to_string(check.islandCount()) + " island(s), " +
            formatNumber10(found["island_area_mm2"].get<double>()) + " mm^2 in all, the largest " +
            formatNumber10(found["largest_island_mm2"].get<double>()) + " mm^2, cure onto nothing (" +
            check.describeIslands(3) +
            "); they will drop into the vat or print as loose debris: add supports there, turn the part so the "
            "region grows from the layers below, or check that the lattice connects (report.json "
            "`printability.islands`)";
        if (settings.checks == "strict")
            throw JobError(settings.printerWhere + ": " + message + "; `checks: strict` refuses the job");
        if (context) context->warn("islands", message, {{"islands", check.islandCount()}});
    }
    // Largest first; crumbs of a few pixels are listed in report.json but not warned of.
    const std::int64_t traps = check.trapCountAboveCrumbs();
    if (traps > 0 && context) {
        const nlohmann::json& first = found["resin_traps"][0];
        const std::int64_t crumbs = check.trapCount() - traps;
        context->warn(
            "resin_traps",
            name + ": " + std::to_string(traps) + " closed cavit" + (traps == 1 ? "y holds " : "ies hold ") +
                formatNumber10(found["resin_trap_volume_mm3"].get<double>()) +
                " mm^3 of uncured resin (the largest: " + formatNumber10(first["volume_mm3"].get<double>()) +
                " mm^3, a drain hole at x " + formatNumber10(first["x"].get<double>()) + ", y " +
                formatNumber10(first["y"].get<double>()) + ", z " + formatNumber10(first["z"].get<double>()) +
                " reaches it after " + formatNumber10(first["drain_mm"].get<double>()) + " mm" +
                (crumbs > 0 ? "; " + std::to_string(crumbs) + " crumbs below " +
                                  formatNumber10(found["resin_trap_crumb_mm3"].get<double>()) + " mm^3 not counted"
                            : std::string()) +
                "); they cause suction (cupping) and leak later: add drain holes (`drain: {diameter: "
                "2}` on an infill or shell; report.json `printability.resin_traps`)",
            {{"resin_traps", traps}, {"largest_mm3", first["volume_mm3"]}});
    }
    if (check.thinPixelCount() > 0 && context) {
        const nlohmann::json& first = found["thin"]["first"][0];
        context->warn("thin_features",
                      name + ": " + std::to_string(check.thinPixelCount()) + " exposed pixels in " +
                          std::to_string(found["thin"]["layers"].get<std::int64_t>()) +
                          " layers belong to features less than 2 pixels across (first: layer " +
                          std::to_string(first["layer"].get<int>()) + " at x " +
                          formatNumber10(first["x"].get<double>()) + ", y " + formatNumber10(first["y"].get<double>()) +
                          "); the printer may not form them: thicken the walls or struts (report.json "
                          "`printability.thin`)",
                      {{"thin_pixels", check.thinPixelCount()}});
    }
}

}  // namespace

SliceResult sliceToFile(const FieldNode& field, const Box3& part, const PrinterProfile& printer,
                        const SliceSettings& settings, const fs::path& path, const std::string& partWhere,
                        const JobContext* context, bool pageLayers)
{
    // Check everything before the first byte is written.
    const double layer = settings.layer.value_or(printer.layerMm);
    const double height = part.max.z() - part.min.z();
    const std::string printerRef = "printer `" + printer.key + "` (" + printer.file + ")";
    if (height > printer.maxHeightMm + 1e-9)
        throw InputError(partWhere + ": the part is " + formatNumber10(height) + " mm tall, taller than the " +
                         formatNumber10(printer.maxHeightMm) + " mm build height (`max_height` at " +
                         printer.maxHeightWhere + ") of " + printerRef + "; lower the domain or split the part");
    if (layer > height)
        throw InputError(settings.printerWhere + ": the layer height " + formatNumber10(layer) +
                         " mm is larger than the part (" + formatNumber10(height) +
                         " mm tall); set `layer:` below the part height");
    const int count = int(std::floor(height / layer - 0.5 + 1e-9)) + 1;
    const std::string format = sliceFormatOf(settings, printer, path);
    Display display;
    display.widthMm = printer.widthMm;
    display.heightMm = printer.heightMm;
    display.pixelsX = printer.pixelsX;
    display.pixelsY = printer.pixelsY;
    display.mirrorX = printer.mirrorX;
    display.mirrorY = printer.mirrorY;
    display.portrait = printer.portrait;
    const Vec3d centre = part.center();
    const double px = settings.position ? (*settings.position)[0] : 0.5 * printer.widthMm;
    const double py = settings.position ? (*settings.position)[1] : 0.5 * printer.heightMm;
    RasterOptions options;
    options.supersample = settings.supersample;
    options.gamma = settings.gamma;
    if (context) options.interrupt = [context] { context->checkCancelled(); };
    const Slicer slicer(field, part, px - centre.x(), py - centre.y(), display, options);
    if (!slicer.fitsDisplay())
        throw InputError(partWhere + ": the part (" + formatNumber10(part.extent().x()) + " x " +
                         formatNumber10(part.extent().y()) + " mm, centred at " + formatNumber10(px) + ", " +
                         formatNumber10(py) + ") does not fit the " + formatNumber10(printer.widthMm) + " x " +
                         formatNumber10(printer.heightMm) + " mm display (`display`) of " + printerRef +
                         "; shrink the domain, move it with `position:` or pick a larger printer");

    const std::unique_ptr<SliceArchive> archive = openSliceArchive(format, path, settings.printerWhere);
    const double exposure = settings.exposure.value_or(printer.exposureS);
    const double exposureFirst = settings.exposureFirst.value_or(printer.exposureFirstS);
    archive->begin(
        {printer, settings, count, layer, exposure, exposureFirst, display.storedWidth(), display.storedHeight()});
    const LayerEncoding encoding = archive->encoding();
    const bool fieldValues = encoding == LayerEncoding::fieldValues;
    const int planes = archive->bitPlanes();

    SliceResult result;
    result.layerAreas.resize(count);
    const double pixelArea = display.pitchX() * display.pitchY();
    const double displayArea = printer.widthMm * printer.heightMm;
    HeightMap heights;
    heights.init(slicer.nx(), slicer.ny());
    ContactSheet sheet;
    sheet.init(count, slicer.nx(), slicer.ny());
    RasterStats stats;

    const int period = layersPerPeriod(field, layer, count);
    LayerRepeats repeats;
    if (!fieldValues && settings.reuseBytes > 0) repeats.period = period;
    repeats.budget = settings.reuseBytes;

    LayerGeometry geometry;
    geometry.nx = slicer.nx();
    geometry.ny = slicer.ny();
    geometry.pitchX = display.pitchX();
    geometry.pitchY = display.pitchY();
    geometry.layer = layer;
    geometry.z0 = part.min.z();
    geometry.x = [&](double i) { return slicer.xOf(slicer.i0() + i); };
    geometry.y = [&](double j) { return slicer.yOf(slicer.j0() + j); };
    const bool checks = settings.checks != "off";
    PrintabilityCheck printability(geometry, count, period);

    // report.html's layer view: a few dozen layers kept small, a phase's thumbnail standing for the
    // layers copied from it (made in the parallel stage, where the layer's pixels are); none
    // where no page shows them.
    LayerThumbnails& thumbnails = result.thumbnails;
    if (pageLayers) thumbnails.choose(count, slicer.nx(), slicer.ny());
    thumbnails.originMm[0] = geometry.x(-0.5);
    thumbnails.originMm[1] = geometry.y(-0.5);
    thumbnails.cellMm[0] = thumbnails.step * geometry.pitchX;
    thumbnails.cellMm[1] = thumbnails.step * geometry.pitchY;
    std::vector<char> phaseShown(std::size_t(std::max(repeats.period, 0)), 0);
    for (const int shown : thumbnails.layers)
        if (repeats.period > 0 && shown >= repeats.period) phaseShown[std::size_t(shown % repeats.period)] = 1;
    std::vector<std::vector<std::uint8_t>> phaseThumbnails(phaseShown.size());
    auto thumbnailWanted = [&](int i) {
        return thumbnails.indexOf(i) >= 0 || (i < repeats.period && phaseShown[std::size_t(i)]);
    };

    struct Token {
        LayerImage image;
        bool copy = false;     ///< the layer's phase image is expected to be kept (LayerRepeats)
        bool analyse = false;  ///< the printability checks need this layer's image
        LayerFeatures features;
        double exposedPixels = 0.0;  ///< summed in the parallel stage
        std::string bytes;
        std::uint32_t crc = 0;  ///< CRC-32 of bytes (PNG layers)
        std::vector<float> values;
        std::vector<std::uint8_t> thumbnail;  ///< the layer small (thumbnailWanted), else empty
    };
    // Tokens are reused once written: a layer's image and encoded bytes keep their buffers, so no
    // layer allocates, clears and faults in 1.4 MB of pixels again (rasterize() writes every
    // pixel). What a token holds is all set anew for its next layer.
    std::mutex poolMutex;
    std::vector<std::unique_ptr<Token>> pool;
    std::atomic<int> held{0}, maxHeld{0};
    const int threads = tbb::this_task_arena::max_concurrency();
    const std::size_t tokens = std::size_t(threads) + 2;
    int next = 0;
    StageProgress progress(context, "slicing", count);
    const int storedW = display.storedWidth(), storedH = display.storedHeight();
    // A layer's stored window (Goo) or a strip of it (PNG): kept per thread.
    tbb::enumerable_thread_specific<std::vector<std::uint8_t>> windows;
    // The height map's marks per thread, made where the layer was (its pixels still in that core's
    // cache, not in the serial stage's on the other core), merged after the last layer.
    tbb::enumerable_thread_specific<HeightMap::Marks> tops;
    auto render = [&](Token* t) {
        const double z = part.min.z() + (t->image.index + 0.5) * layer;
        slicer.rasterize(z, t->image, &stats);
        heights.add(t->image, tops.local(), count);
        if (thumbnailWanted(t->image.index))
            t->thumbnail = layerThumbnail(t->image, thumbnails.step, thumbnails.rowStride);
        else
            t->thumbnail.clear();
        if (fieldValues) {
            t->exposedPixels = t->image.exposedPixels();
            slicer.fieldValues(z, t->values);
        } else if (encoding != LayerEncoding::png) {
            std::vector<std::uint8_t>& window = windows.local();
            int col0, row0, w, h;
            t->image.storedWindow(display, window, col0, row0, w, h);
            t->exposedPixels = t->image.exposedPixels();
            if (encoding == LayerEncoding::bitPlanes) {
                t->bytes = encodeBitPlanes(planes, storedW, storedH, window.data(), col0, row0, w, h);
            } else {
                const auto encode = encoding == LayerEncoding::goo   ? encodeGooLayer
                                    : encoding == LayerEncoding::ctb ? encodeCtbLayer
                                                                     : encodePw0Layer;
                t->bytes = encode(storedW, storedH, window.data(), col0, row0, w, h);
            }
        } else {
            // The exposed pixels summed by the encoder as it reads the window (the same sum), and
            // the PNG's CRC-32 for the zip from the encoder's own.
            StoredRows rows(t->image, display, windows.local());
            std::uint64_t sum = 0;
            encodeWindowPng(
                t->bytes, storedW, storedH, [&](int r) { return rows.row(r); }, rows.col0(), rows.row0(), rows.width(),
                rows.height(), &sum, &t->crc);
            t->exposedPixels = double(sum) / 255.0;
        }
    };

    // The serial last stage: one layer, in order, into the archive and the summaries.
    auto write = [&](Token& t) {
        const int i = t.image.index;
        if (checks) printability.addLayer(i, std::move(t.features));
        if (repeats.copies(i)) {
            const int phase = i % repeats.period;
            result.layerAreas[i] = repeats.exposed[phase] * pixelArea;
            if (const int shown = thumbnails.indexOf(i); shown >= 0)
                thumbnails.images[std::size_t(shown)] = phaseThumbnails[std::size_t(phase)];
            ++repeats.copied;
            if (encoding == LayerEncoding::png)
                archive->addPngLayer(i, repeats.images[phase], repeats.crcs[phase]);
            else
                archive->addLayer(i, repeats.images[phase]);
            progress.add();
            return;
        }
        // The budget ran out while this layer waited as a copy: computed here.
        if (t.copy) render(&t);
        result.layerAreas[i] = t.exposedPixels * pixelArea;
        if (i < repeats.period && phaseShown[std::size_t(i)]) phaseThumbnails[std::size_t(i)] = t.thumbnail;
        if (const int shown = thumbnails.indexOf(i); shown >= 0) thumbnails.images[std::size_t(shown)] = t.thumbnail;
        const std::string* kept = i < repeats.period ? repeats.keep(t.bytes, t.exposedPixels, t.crc) : nullptr;
        if (kept) heights.addPhase(t.image, repeats.period, count);
        sheet.add(t.image, kept ? repeats.period : 0);
        if (fieldValues)
            archive->addLayerValues(i, slicer.nx(), slicer.ny(), slicer.i0(), slicer.j0(), t.values);
        else if (encoding == LayerEncoding::png)
            archive->addPngLayer(i, kept ? *kept : t.bytes, t.crc);
        else
            archive->addLayer(i, kept ? *kept : t.bytes);
        progress.add();
    };

    tbb::parallel_pipeline(
        tokens, tbb::make_filter<void, Token*>(tbb::filter_mode::serial_in_order, [&](tbb::flow_control& fc) -> Token* {
                    if (next >= count) {
                        fc.stop();
                        return nullptr;
                    }
                    const int now = ++held;
                    int seen = maxHeld.load();
                    while (now > seen && !maxHeld.compare_exchange_weak(seen, now)) {
                    }
                    Token* t = nullptr;
                    {
                        const std::lock_guard<std::mutex> lock(poolMutex);
                        if (!pool.empty()) {
                            t = pool.back().release();
                            pool.pop_back();
                        }
                    }
                    if (!t) t = new Token;
                    t->features = LayerFeatures{};
                    t->image.index = next++;
                    t->copy = repeats.mayCopy(t->image.index);
                    t->analyse = checks && printability.needsImage(t->image.index);
                    return t;
                }) & tbb::make_filter<Token*, Token*>(tbb::filter_mode::parallel, [&](Token* t) {
                    if (!t->copy) render(t);
                    if (t->analyse) t->features = analyseLayer(t->image);
                    return t;
                }) & tbb::make_filter<Token*, void>(tbb::filter_mode::serial_in_order, [&](Token* raw) {
                    std::unique_ptr<Token> t(raw);
                    write(*t);
                    --held;
                    const std::lock_guard<std::mutex> lock(poolMutex);
                    pool.push_back(std::move(t));
                }));

    for (const HeightMap::Marks& local : tops) heights.merge(local);
    if (repeats.kept.load() > 0) heights.addCopies(repeats.period, count);
    if (checks) reportPrintability(printability, settings, path, context);

    // Statistics for config.ini: slow tilts where a layer covers more than area_fill of the display.
    int slow = 0;
    double volume = 0.0, printTime = 0.0;
    for (int i = 0; i < count; ++i) {
        const bool isSlow = result.layerAreas[i] > printer.areaFillPercent / 100.0 * displayArea;
        slow += isSlow;
        volume += result.layerAreas[i] * layer;
        const double e = i < printer.fadeLayers
                             ? exposureFirst + (exposure - exposureFirst) * double(i) / printer.fadeLayers
                             : exposure;
        printTime += e + (isSlow ? printer.slowTiltS : printer.fastTiltS);
    }

    nlohmann::json meta = {{"voxlat_version", versionString()},
                           {"printer", printer.key},
                           {"printer_profile", printer.file},
                           {"format", format},
                           {"layers", count},
                           {"layer_height_mm", layer},
                           {"first_layer_z_mm", part.min.z() + 0.5 * layer},
                           {"display_pixels", {printer.pixelsX, printer.pixelsY}},
                           {"display_mm", {printer.widthMm, printer.heightMm}},
                           {"stored_png_size", {storedW, storedH}},
                           {"orientation", printer.portrait ? "portrait" : "landscape"},
                           {"mirror", {printer.mirrorX, printer.mirrorY}},
                           {"part_centre_on_display_mm", {px, py}},
                           {"window_pixels", {slicer.i0(), slicer.j0(), slicer.nx(), slicer.ny()}},
                           {"anti_aliasing", settings.supersample > 0 ? "edge coverage" : "off (pixel centre)"},
                           {"supersample", settings.supersample},
                           {"gamma", settings.gamma}};

    archive->finish({printer, settings, meta, count, layer, exposure, exposureFirst, slow, volume, printTime,
                     [&](int w, int h) { return heights.render(w, h, count); }});

    std::string previewPath;
    if (settings.preview != "off") {
        // Named after the slices' whole file name (two archives of one part never share it), or
        // the recipe's `preview:` next to the slices (a relative name, checked at load).
        previewPath = settings.preview.empty() ? path.string() + ".preview.png"
                                               : (path.parent_path() / settings.preview).string();
        checkReplaceable(previewPath, "the slices' preview");
        AtomicFile preview(previewPath);
        const std::string png = sheet.render();
        preview.stream().write(png.data(), std::streamsize(png.size()));
        preview.commit();
    }

    double total = 0.0;
    for (double a : result.layerAreas) total += a;
    result.maxLayersHeld = maxHeld.load();
    result.layersPerPeriod = repeats.period;
    result.layersCopied = repeats.copied;
    result.report = meta;
    result.report["file"] = path.string();
    result.report["num_fast"] = count - slow;
    result.report["num_slow"] = slow;
    result.report["exposed_volume_mm3"] = volume;
    result.report["mean_layer_area_mm2"] = total / count;
    result.report["print_time_s"] = std::round(printTime);
    result.report["preview"] = previewPath;
    result.report["preview_layers"] = sheet.layers;
    result.report["max_layers_held"] = result.maxLayersHeld;
    result.report["layers_per_z_period"] = result.layersPerPeriod;
    result.report["layers_copied"] = result.layersCopied;
    result.report["tiles"] = {
        {"inside", stats.tilesInside.load()}, {"outside", stats.tilesOutside.load()}, {"edge", stats.tilesEdge.load()}};
    result.report["pixels_evaluated"] = stats.pixelsEvaluated.load();
    result.report["pixels_supersampled"] = stats.pixelsSupersampled.load();
    result.report["rows_per_y_period"] = slicer.rowPeriod();
    result.report["columns_per_x_period"] = slicer.columnPeriod();
    result.report["pixels_copied"] = stats.pixelsCopied.load();
    result.report["pixels_total"] = double(count) * slicer.nx() * slicer.ny();
    if (checks) result.report["printability"] = printability.report();
    return result;
}

}  // namespace voxlat
