/// @file SliceSettings.h
/// @brief A `slices:` output entry as the recipe states it, checked when the recipe is loaded.
#pragma once

#include "engine/recipe/KeySpec.h"
#include "engine/recipe/RecipeNode.h"

#include <array>
#include <cstddef>
#include <optional>
#include <string>
#include <vector>

namespace voxlat {

/// The keys a `slices:` entry may have, with their schemas, defaults and meanings.
const std::vector<KeySpec>& sliceKeys();
/// One slice archive format of the language (`format:` of a slices entry or a printer profile).
/// Each has one writer class in engine/jobs/SliceArchives.cpp.
struct ArchiveFormatInfo {
    std::string name;       ///< `sl1`
    std::string extension;  ///< a file name ending in it picks the format (empty: a folder format)
    std::string meaning;
};
/// The archive table: every slice format, in the order the docs list them.
const std::vector<ArchiveFormatInfo>& archiveFormats();
/// The names of archiveFormats().
std::vector<std::string> sliceFormatNames();
/// Why a printer's format that is not in the archive table is not written (`pwsz`, the Photon
/// Mono M7 Pro's vector layers), or "" for any other name. @a name has no leading dot.
std::string formatNotWritten(const std::string& name);

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
    /// Printability checks: `on` (islands, resin traps and thin features reported and warned),
    /// `strict` (an island fails the job) or `off`.
    std::string checks = "on";
    /// Where the field repeats along z over a whole number of layers, the encoded images of one
    /// period are kept up to this many bytes and copied to the layers a period above (`reuse:
    /// off` sets 0: every layer computed).
    std::size_t reuseBytes = std::size_t(64) << 20;
    /// `drain: {diameter}`: the result's resin traps opened by channels of this diameter (mm),
    /// in the result itself, so a mesh of the same run has them too.
    std::optional<double> drainDiameter;
    std::string drainWhere;          ///< file:line:col of `drain:`
    std::string drainDiameterWhere;  ///< file:line:col of `drain: {diameter}`
    std::string where;               ///< file:line:col of the entry
};

/// Reads a `slices:` map (errors name file, line and key).
SliceSettings parseSliceSettings(const RecipeNode& spec);

}  // namespace voxlat
