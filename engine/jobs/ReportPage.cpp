#include "engine/jobs/ReportPage.h"

#include "engine/jobs/DataFolder.h"
#include "mesher/writers/AtomicFile.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace voxlat {

namespace {
/// The first of @a candidates that can be read, whole; empty when none can.
std::string readFirst(const std::vector<std::filesystem::path>& candidates)
{
    for (const auto& path : candidates) {
        std::ifstream in(path, std::ios::binary);
        if (!in) continue;
        std::ostringstream text;
        text << in.rdbuf();
        if (!text.str().empty()) return text.str();
    }
    return {};
}

std::string base64(const void* data, std::size_t size)
{
    static const char* kDigits = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    const auto* bytes = static_cast<const unsigned char*>(data);
    // Sized once and written in place (the page's mesh is megabytes: no append per digit).
    std::string out((size + 2) / 3 * 4, '=');
    char* o = out.data();
    std::size_t i = 0;
    for (; i + 3 <= size; i += 3, o += 4) {
        const std::uint32_t word = (std::uint32_t(bytes[i]) << 16) | (std::uint32_t(bytes[i + 1]) << 8) | bytes[i + 2];
        o[0] = kDigits[(word >> 18) & 63];
        o[1] = kDigits[(word >> 12) & 63];
        o[2] = kDigits[(word >> 6) & 63];
        o[3] = kDigits[word & 63];
    }
    if (i < size) {  // one or two bytes left: padded with '='
        const std::uint32_t b1 = i + 1 < size ? bytes[i + 1] : 0;
        const std::uint32_t word = (std::uint32_t(bytes[i]) << 16) | (b1 << 8);
        o[0] = kDigits[(word >> 18) & 63];
        o[1] = kDigits[(word >> 12) & 63];
        if (i + 1 < size) o[2] = kDigits[(word >> 6) & 63];
    }
    return out;
}

/// @a text made safe inside a <script> element: no `</` that could close it (in JavaScript a
/// `<\/` inside strings, regular expressions and JSON means the same).
std::string scriptSafe(const std::string& text)
{
    std::string out;
    out.reserve(text.size() + text.size() / 64);
    // Whole runs up to the next `</` copied at once.
    for (std::size_t from = 0;;) {
        const std::size_t at = text.find("</", from);
        if (at == std::string::npos) {
            out.append(text, from, std::string::npos);
            return out;
        }
        out.append(text, from, at - from);
        out += "<\\/";
        from = at + 2;
    }
}

std::string htmlEscape(const std::string& text)
{
    std::string out;
    for (char c : text) {
        if (c == '<')
            out += "&lt;";
        else if (c == '>')
            out += "&gt;";
        else if (c == '&')
            out += "&amp;";
        else
            out += c;
    }
    return out;
}
}  // namespace

std::vector<std::string> reportPageScripts()
{
    const std::filesystem::path page = std::filesystem::path(dataFolder()) / "page";
    const std::filesystem::path debian = "/usr/share/javascript/three";
    const std::vector<std::pair<std::string, std::vector<std::filesystem::path>>> wanted{
        {"three.js (install Debian's libjs-three)", {page / "three.min.js", debian / "three.min.js"}},
        {"three.js's OrbitControls (install Debian's libjs-three)",
         {page / "OrbitControls.js", debian / "examples/js/controls/OrbitControls.js"}},
        {"the page's script report.js", {page / "report.js"}}};
    std::vector<std::string> scripts;
    for (const auto& [what, candidates] : wanted) {
        std::string text = readFirst(candidates);
        if (text.empty()) {
            std::string places;
            for (const auto& c : candidates) places += (places.empty() ? "" : ", ") + c.string();
            throw OutputError("report.html needs " + what + ", not found in " + places + " (or run with --no-html)");
        }
        scripts.push_back(std::move(text));
    }
    return scripts;
}

std::string reportPage(const nlohmann::json& report, const TriangleMesh& mesh, const std::vector<std::string>& scripts,
                       const PageColouring* colouring, const LayerThumbnails* layers)
{
    static_assert(sizeof(openvdb::Vec3f) == 12 && sizeof(openvdb::Vec3I) == 12);
    nlohmann::json meshJson = {
        {"vertices", mesh.points.size()},
        {"triangles", mesh.triangles.size()},
        {"points", base64(mesh.points.data(), mesh.points.size() * sizeof(openvdb::Vec3f))},
        {"indices", base64(mesh.triangles.data(), mesh.triangles.size() * sizeof(openvdb::Vec3I))}};
    if (colouring) {
        if (colouring->values.size() != mesh.points.size())
            throw std::logic_error("report.html: one colouring value per vertex");
        meshJson["colour"] = {{"by", colouring->by},
                              {"field", colouring->field},
                              {"unit", colouring->unit},
                              {"note", colouring->note},
                              {"values", base64(colouring->values.data(), colouring->values.size() * sizeof(float))}};
    }
    std::string title = "voxlat report";
    if (report.contains("recipe") && report["recipe"].is_string()) title += ": " + report["recipe"].get<std::string>();
    std::ostringstream html;
    html << "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
         << "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
         << "<meta name=\"generator\" content=\"voxlat\">\n<title>" << htmlEscape(title) << "</title>\n</head>\n"
         << "<body>\n<div id=\"voxlat-page\"></div>\n"
         << "<script type=\"application/json\" id=\"voxlat-report\">" << scriptSafe(report.dump()) << "</script>\n"
         << "<script type=\"application/json\" id=\"voxlat-mesh\">" << scriptSafe(meshJson.dump()) << "</script>\n";
    if (layers && !layers->layers.empty()) {
        nlohmann::json images = nlohmann::json::array();
        for (const std::vector<std::uint8_t>& image : layers->images)
            images.push_back(base64(image.data(), image.size()));
        const nlohmann::json kept = {{"layers", layers->layers},
                                     {"size", {layers->width, layers->height}},
                                     {"origin_mm", {layers->originMm[0], layers->originMm[1]}},
                                     {"cell_mm", {layers->cellMm[0], layers->cellMm[1]}},
                                     {"images", images}};
        html << "<script type=\"application/json\" id=\"voxlat-layers\">" << scriptSafe(kept.dump()) << "</script>\n";
    }
    for (const std::string& script : scripts) html << "<script>\n" << scriptSafe(script) << "\n</script>\n";
    html << "</body>\n</html>\n";
    return html.str();
}

double pageGridFactor(std::uint64_t voxelCount, const std::vector<double>& periods)
{
    const double factor = std::max(1.0, std::cbrt(double(voxelCount) / double(1 << 18)));
    if (periods.empty() || !(factor > 1.0)) return factor;
    for (int f = int(std::ceil(factor)); f <= int(2.0 * factor); ++f)
        if (std::all_of(periods.begin(), periods.end(), [f](double p) {
                const double cells = p / f;
                return cells >= 1.0 && std::abs(cells - std::round(cells)) <= 1e-9 * cells;
            }))
            return f;
    return factor;
}

}  // namespace voxlat
