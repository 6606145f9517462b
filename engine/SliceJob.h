/// @file SliceJob.h
/// @brief A `slices:` output: the result field sliced for a resin printer, streamed to an archive.
#pragma once

#include "engine/PrinterProfile.h"
#include "engine/RecipeNode.h"
#include "fields/FieldNode.h"

#include <nlohmann/json.hpp>

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace voxlat {

/// The keys a `slices:` entry may have.
const std::vector<std::string>& sliceKeys();

/// A `slices:` entry, checked.
struct SliceSettings {
    std::string printer;          ///< profile name or path
    std::string printerWhere;     ///< file:line:col of `printer` (for messages)
    std::optional<double> layer;  ///< layer height (mm); default: the printer's
    std::string file;
    std::string format;                             ///< sl1, sl1s, zip, png, exr; "" = from the file name
    std::optional<std::array<double, 2>> position;  ///< where the part's xy centre goes on the display
    int supersample = 8;                            ///< sub-samples per axis in bent edge pixels; 0 = aa off
    double gamma = 1.0;
    std::optional<double> exposure, exposureFirst;
    std::string preview;  ///< contact sheet file; "" = FILE.preview.png; "off"
    std::string timestamp = "2020-01-01 at 00:00:00 UTC";
    int threads = 0;  ///< 0: all
    /// Where the field repeats along z over a whole number of layers, the encoded images of one
    /// period are kept up to this many bytes and copied to the layers a period above (`reuse:
    /// off` sets 0: every layer computed).
    std::size_t reuseBytes = std::size_t(64) << 20;
};

/// Reads a `slices:` map (errors name file, line and key).
SliceSettings parseSliceSettings(const RecipeNode& spec);

/// What a slice job did, for report.json and the tests.
struct SliceResult {
    nlohmann::json report;
    std::vector<double> layerAreas;  ///< exposed area per layer (mm^2): sum of pixel/255 x pixel area
    int maxLayersHeld = 0;           ///< most layer images alive at once
    int layersPerPeriod = 0;         ///< layers in one z-period of the field (0: not periodic)
    int layersCopied = 0;            ///< layers copied from one a period below instead of computed
};

/// Slices @a field (negative inside) clipped to @a part for @a printer into @a path. @a recipeWhere
/// and @a partWhere name the recipe and its domain for messages. Validates everything before the
/// first byte; the archive (or folder) appears whole or not at all.
SliceResult sliceToFile(const FieldNode& field, const Box3& part, const PrinterProfile& printer,
                        const SliceSettings& settings, const std::filesystem::path& path, const std::string& partWhere);

}  // namespace voxlat
