/// @file ReportPage.h
/// @brief report.html: one self-contained page of a run (the result in 3D, its layers with the
/// printability findings, density per slab, properties, warnings, timings), for any browser,
/// offline.
///
/// The page is the report's JSON, a small preview mesh and scripts, all inlined: three.js
/// (Debian's libjs-three, or the copy an installed voxlat carries) draws the 3D views and
/// `page/report.js` of the data folder everything else. Nothing is fetched when it opens.
#pragma once

#include "mesher/extract/TriangleMesh.h"

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace voxlat {

/// The scripts a page inlines, in order (three.js, its orbit controls, the page's own), read from
/// the data folder's `page/` or else Debian's libjs-three. Throws OutputError naming what is
/// missing (install libjs-three, or run with --no-html).
std::vector<std::string> reportPageScripts();

/// The page's HTML: @a report (report.json's content), @a mesh (drawn as it is; small: see
/// clusterDecimate) and @a scripts (reportPageScripts()) inlined, so that the file opens offline.
std::string reportPage(const nlohmann::json& report, const TriangleMesh& mesh, const std::vector<std::string>& scripts);

}  // namespace voxlat
