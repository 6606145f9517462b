/// @file Printability.h
/// @brief What a resin printer would make of a stack of layer images, found while slicing:
/// islands (regions that cure onto nothing), resin traps (closed cavities) and features narrower
/// than the printer can form.
///
/// Streamed: analyseLayer() reads one image (any thread) into its runs and connected regions;
/// addLayer() takes the layers in order and keeps only the previous layer's runs plus the void
/// components still open, so memory does not grow with the number of layers. Where the field
/// repeats along z every P layers (the slicer's z-period), layer i >= P + 1 with its layer below
/// is the same pair of images as layer i - P with its own, so only layers 0..P are analysed and
/// the rest are replayed from their summaries (exact, and no pixel is looked at twice).
///
/// Definitions (exposed = grey >= 128, what a pixel-centre test would cure):
/// - island: an 8-connected region of exposed pixels of layer i > 0 with no exposed pixel at the
///   same position in layer i - 1 (layer 0 sits on the plate);
/// - resin trap: a region of void pixels, 4-connected within a layer and connected across layers
///   where the same pixel is void in both, that reaches neither the window's border (the outside
///   of the part's box) nor the last layer (open to the vat); the plate closes layer 0 from below;
/// - thin: an exposed pixel that lies in no fully exposed 2 x 2 block of pixels (a feature less
///   than two pixels across), counted where such pixels form a group (8-connected) of at least 4
///   or a whole exposed region: the pixel or two at the tip of any acute corner are not a feature.
#pragma once

#include "mesher/slice/Slicer.h"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace voxlat {

/// One layer read into runs and regions (analyseLayer()); pass it to PrintabilityCheck::addLayer().
struct LayerFeatures {
    struct Run {
        int row, begin, end;  ///< pixels [begin, end) of row `row`
        int region;           ///< index into solids or voids
    };
    struct Region {
        std::int64_t pixels = 0;
        double sumI = 0, sumJ = 0;  ///< for the centroid
        bool border = false;        ///< touches the window's border
        int nearI = 0, nearJ = 0;   ///< the pixel nearest to the border (a drain hole's shortest way)
        int nearDistance = 0;       ///< in pixels
    };
    int index = -1;
    std::vector<Run> solidRuns, voidRuns;  ///< row by row, left to right
    std::vector<Region> solids, voids;
    std::int64_t thinPixels = 0, thinFeatures = 0;  ///< pixels of thin features, and how many
    double thinI = -1, thinJ = -1;                  ///< the first thin feature's centre (pixels)
    bool analysed = false;
};

/// Where the pixels sit: the window of the slicer and the layer geometry.
struct LayerGeometry {
    int nx = 0, ny = 0;               ///< window size in pixels
    double pitchX = 0, pitchY = 0;    ///< pixel size (mm)
    double layer = 0, z0 = 0;         ///< layer height and the part's bottom (mm)
    std::function<double(double)> x;  ///< part x of window column i (pixel centre at i)
    std::function<double(double)> y;  ///< part y of window row j
};

/// Reads @a image (exposed = grey >= 128) into runs, regions and thin pixels.
LayerFeatures analyseLayer(const LayerImage& image);

/// The streamed checks over a job's layers.
class PrintabilityCheck {
public:
    /// @a count layers; @a period layers per z-period of the images (0: none, every layer analysed).
    PrintabilityCheck(const LayerGeometry& geometry, int count, int period);
    ~PrintabilityCheck();

    /// Whether layer @a index must be analysed (analyseLayer()) before addLayer(); the others are
    /// replayed from a period below and addLayer() takes an empty LayerFeatures for them.
    bool needsImage(int index) const;

    /// Takes layer @a index (in order, 0 first).
    void addLayer(int index, LayerFeatures features);

    /// After the last layer: the findings as report.json's `printability`, lists of at most
    /// @a listed entries each (the counts are complete).
    nlohmann::json report(std::size_t listed = 200) const;

    std::int64_t islandCount() const;
    std::int64_t trapCount() const;
    /// Traps of at least `resin_trap_crumb_mm3` (27 pixel-layers): the ones worth a warning.
    std::int64_t trapCountAboveCrumbs() const;
    std::int64_t thinPixelCount() const;
    /// The first @a count islands as readable text, for messages.
    std::string describeIslands(std::size_t count) const;

private:
    struct State;
    std::unique_ptr<State> mState;
};

}  // namespace voxlat
