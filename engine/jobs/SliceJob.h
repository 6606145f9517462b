/// @file SliceJob.h
/// @brief A `slices:` output: the result field sliced for a resin printer, streamed to an archive.
#pragma once

#include "engine/core/JobContext.h"
#include "engine/jobs/PrinterProfile.h"
#include "engine/recipe/SliceSettings.h"
#include "fields/core/FieldNode.h"
#include "mesher/slice/LayerThumbnail.h"

#include <nlohmann/json.hpp>

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace voxlat {

/// What a slice job did, for report.json and the tests.
struct SliceResult {
    nlohmann::json report;
    std::vector<double> layerAreas;  ///< exposed area per layer (mm^2): sum of pixel/255 x pixel area
    int maxLayersHeld = 0;           ///< most layer images alive at once
    int layersPerPeriod = 0;         ///< layers in one z-period of the field (0: not periodic)
    int layersCopied = 0;            ///< layers copied from one a period below instead of computed
    LayerThumbnails thumbnails;      ///< layers kept small for report.html's layer view
};

/// Slices @a field (negative inside) clipped to @a part for @a printer into @a path. @a recipeWhere
/// and @a partWhere name the recipe and its domain for messages. Validates everything before the
/// first byte; the archive (or folder) appears whole or not at all. With @a pageLayers the result
/// holds some layers kept small (SliceResult::thumbnails), else none.
SliceResult sliceToFile(const FieldNode& field, const Box3& part, const PrinterProfile& printer,
                        const SliceSettings& settings, const std::filesystem::path& path, const std::string& partWhere,
                        const JobContext* context = nullptr, bool pageLayers = false);

}  // namespace voxlat
