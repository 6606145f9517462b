/// @file PrinterProfile.h
/// @brief A resin printer's display and defaults, read from a small YAML file (data/printers/).
#pragma once

#include "mesher/writers/GooWriter.h"

#include <string>
#include <vector>

namespace voxlat {

/// What a slice job needs to know about a DLP/SLA/mono-LCD printer. The display frame is the
/// printer's landscape frame: x along `display.width` (pixels_x pixels), y along `display.height`;
/// the stored PNG follows PrusaSlicer's convention for orientation and mirroring (see Slicer.h).
struct PrinterProfile {
    std::string file;    ///< the profile file it was read from
    std::string key;     ///< the name it was asked for (`sl1s`) or the file stem
    std::string name;    ///< human name, also printerProfile in an SL1 config.ini
    std::string model;   ///< printerModel (SL1, SL1S, ...)
    std::string format;  ///< default archive format: sl1, sl1s, zip, png, exr
    double widthMm = 0, heightMm = 0;
    int pixelsX = 0, pixelsY = 0;
    bool mirrorX = false, mirrorY = false;
    bool portrait = false;
    double maxHeightMm = 0;
    double layerMm = 0.05;
    double exposureS = 2, exposureFirstS = 30;
    int fadeLayers = 0;
    double fastTiltS = 0, slowTiltS = 0;
    double areaFillPercent = 50;
    /// Layer-by-layer moves for archives that carry them (.goo): the first `bottom_layers` layers
    /// cure at exposure_first with `bottomMotion`, then `transition_layers` step down to exposure.
    int bottomLayers = 4, transitionLayers = 0;
    GooMotion bottomMotion, motion;
    int ctbVersion = 4;          ///< the .ctb layout version written for this printer (2 to 5)
    bool ctbEncrypted = false;   ///< the encrypted .ctb layout (versions 4 and 5)
    std::string displayWhere;    ///< file:line:col of `display` (for messages)
    std::string maxHeightWhere;  ///< file:line:col of `max_height`

    double pitchX() const { return widthMm / pixelsX; }
    double pitchY() const { return heightMm / pixelsY; }
};

/// The printer profile @a nameOrPath: a path to a profile file (it contains `/` or ends in
/// `.yaml`), or the name of one in the printers folder (`sl1s` -> data/printers/sl1s.yaml).
/// Throws InputError naming the file and key for an unknown printer or a bad or missing key.
/// @a where ("file:line:col" of the recipe key) prefixes the message for an unknown name.
PrinterProfile loadPrinterProfile(const std::string& nameOrPath, const std::string& where = "");

/// The folder the built-in profiles are read from: $VOXLAT_PRINTERS if set, else data/printers
/// next to the executable's source tree.
std::string printersFolder();
/// Names of the built-in profiles.
std::vector<std::string> printerNames();

}  // namespace voxlat
