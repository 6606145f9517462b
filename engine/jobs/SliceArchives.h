/// @file SliceArchives.h
/// @brief Slice archive formats behind one interface: one class per format of the archive table
/// (engine/recipe/SliceSettings.h `archiveFormats()`), chosen by name.
#pragma once

#include "engine/jobs/PrinterProfile.h"
#include "engine/recipe/SliceSettings.h"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace voxlat {

/// What a slice job knows once every layer is written: what an archive adds after its layers.
struct SliceSummary {
    const PrinterProfile& printer;
    const SliceSettings& settings;
    const nlohmann::json& meta;  ///< the job's description (slices.json)
    int layers = 0;
    double layerMm = 0, exposureS = 0, exposureFirstS = 0;
    int slowLayers = 0;
    double volumeMm3 = 0, printTimeS = 0;
    /// A top view of the part as a PNG of the given size (thumbnails).
    std::function<std::string(int width, int height)> thumbnail;
};

/// What a slice job knows before its first layer.
struct SliceStart {
    const PrinterProfile& printer;
    const SliceSettings& settings;
    int layers = 0;
    double layerMm = 0, exposureS = 0, exposureFirstS = 0;
    int storedWidth = 0, storedHeight = 0;  ///< the stored image's size (pixels)
};

/// How an archive wants its layers.
enum class LayerEncoding {
    png,         ///< PNG bytes of the stored image (encodeWindowPng)
    goo,         ///< Elegoo .goo image data (encodeGooLayer)
    ctb,         ///< Chitubox RLE7, not yet ciphered (encodeCtbLayer)
    pw0,         ///< Anycubic Photon Workshop PW0 (encodePw0Layer)
    bitPlanes,   ///< RLE1 bit planes, concatenated (encodeBitPlanes with bitPlanes())
    fieldValues  ///< the field's float values over the window
};

/// One slice output being written. Layers arrive in order; nothing carries the final name until
/// finish() (a file through AtomicFile, a folder under a temporary name renamed at the end), so a
/// job that fails or is cancelled leaves nothing.
class SliceArchive {
public:
    virtual ~SliceArchive() = default;
    /// The form addLayer() (or addLayerValues()) takes.
    virtual LayerEncoding encoding() const { return LayerEncoding::png; }
    /// The planes of a LayerEncoding::bitPlanes layer (known after begin()).
    virtual int bitPlanes() const { return 1; }
    /// Called once before the first layer; checks what the format cannot hold (throws InputError).
    virtual void begin(const SliceStart&) {}
    /// Layer @a index in the archive's encoding().
    virtual void addLayer(int index, const std::string& bytes) = 0;
    /// Layer @a index as PNG bytes (LayerEncoding::png) whose CRC-32 is @a crc: a zip stores it
    /// without reading the bytes again (encodeWindowPng gives it); others take it as addLayer().
    virtual void addPngLayer(int index, const std::string& png, std::uint32_t crc)
    {
        (void)crc;
        addLayer(index, png);
    }
    /// Layer @a index as field values over the window (@a i0, @a j0, @a nx x @a ny) of the display.
    virtual void addLayerValues(int index, int nx, int ny, int i0, int j0, const std::vector<float>& values);
    /// Writes what follows the layers and makes the output appear whole.
    virtual void finish(const SliceSummary& summary) = 0;
};

/// The format of a slice output: `format:` if given, else the format whose extension @a path
/// has, else the printer profile's `format:`.
std::string sliceFormatOf(const SliceSettings& settings, const PrinterProfile& printer,
                          const std::filesystem::path& path);

/// Opens @a format at @a path. Checks before any layer is made: a folder format refuses an
/// existing path that is not an empty folder (an output never deletes what it did not create).
std::unique_ptr<SliceArchive> openSliceArchive(const std::string& format, const std::filesystem::path& path,
                                               const std::string& where);

}  // namespace voxlat
