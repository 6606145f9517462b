/// @file ReportPage.h
/// @brief report.html: one self-contained page of a run (the result in 3D, its layers with the
/// printability findings, density per slab, properties, warnings, timings), for any browser,
/// offline.
///
/// The page is the report's JSON, a small preview mesh, the first slices output's layers kept
/// small (LayerThumbnails) and scripts, all inlined: three.js
/// (Debian's libjs-three, or the copy an installed voxlat carries) draws the 3D views and
/// `page/report.js` of the data folder everything else. Nothing is fetched when it opens.
#pragma once

#include "mesher/extract/TriangleMesh.h"
#include "mesher/slice/LayerThumbnail.h"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>
#include <vector>

namespace voxlat {

/// The scripts a page inlines, in order (three.js, its orbit controls, the page's own), read from
/// the data folder's `page/` or else Debian's libjs-three. Throws OutputError naming what is
/// missing (install libjs-three, or run with --no-html).
std::vector<std::string> reportPageScripts();

/// A value per vertex of the page's mesh that colours it (with a legend), e.g. the walls measured
/// on a part whose recipe grades them.
struct PageColouring {
    std::string by;     ///< what the values are, e.g. "wall thickness"
    std::string field;  ///< the field that grades it
    std::string unit;   ///< e.g. "mm"
    std::string note;   ///< how the values were found (shown under the view)
    std::vector<float> values;
};

/// The page's HTML: @a report (report.json's content), @a mesh (drawn as it is; small: see
/// clusterDecimate) and @a scripts (reportPageScripts()) inlined, so that the file opens offline.
/// @a colouring, when given, colours the mesh by its values (one per vertex). @a layers, when
/// given (the first slices output's), are drawn in the layer view where a layer is kept, instead
/// of the mesh cut.
std::string reportPage(const nlohmann::json& report, const TriangleMesh& mesh, const std::vector<std::string>& scripts,
                       const PageColouring* colouring = nullptr, const LayerThumbnails* layers = nullptr);

/// How many of the job's voxels make one voxel of the coarse grid report.html's mesh is made on
/// when no mesh is held: enough for at most 2^18 voxels of a domain of @a voxelCount, or, where
/// the result repeats every @a periods voxels along some axes (a tiled lattice), the smallest
/// whole number from that up to twice it that divides every period, so the coarse grid is
/// read from the lattice's one-period table instead of evaluated point by point.
double pageGridFactor(std::uint64_t voxelCount, const std::vector<double>& periods);

}  // namespace voxlat
