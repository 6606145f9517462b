#include "engine/recipe/SliceSettings.h"

#include <algorithm>
#include <cmath>
#include <filesystem>

namespace voxlat {

const std::vector<ArchiveFormatInfo>& archiveFormats()
{
    static const std::vector<ArchiveFormatInfo> formats{
        {"sl1", ".sl1", "Prusa SL1 archive: PNG layers, config.ini, prusaslicer.ini, thumbnails"},
        {"sl1s", ".sl1s", "Prusa SL1S archive (as sl1, for the SL1S Speed)"},
        {"zip", ".zip", "a zip of PNG layers and slices.json, for DLP hosts that take PNG stacks"},
        {"png", "", "a folder of PNG layers and slices.json"},
        {"exr", "", "a folder of OpenEXR float layers (the field's values) and slices.json"},
        {"goo", ".goo", "Elegoo .goo (V3) for Elegoo's Saturn and Mars printers: run-length layers, previews"}};
    return formats;
}

std::vector<std::string> sliceFormatNames()
{
    std::vector<std::string> names;
    for (const ArchiveFormatInfo& f : archiveFormats()) names.push_back(f.name);
    return names;
}

const std::vector<KeySpec>& sliceKeys()
{
    using namespace valueSchema;
    static const std::vector<KeySpec> keys{
        {"printer", string(), "printer profile: a name in data/printers or a profile file", "required"},
        {"layer", number(), "layer height (mm)", "the printer's"},
        {"file", string(), "the archive (or folder for png / exr), inside the output folder", "required"},
        {"format", oneOfWords(sliceFormatNames()), "archive format",
         "from the file's extension, else the printer profile's `format:`"},
        {"position", json{{"type", "array"}, {"items", number()}, {"minItems", 2}, {"maxItems", 2}},
         "where the part's xy centre goes on the display (mm)", "the display's centre"},
        {"aa",
         {{"anyOf", {{{"type", {"string", "boolean"}}}, number()}}},
         "anti-aliasing: on, off or sub-samples per axis (1 to 16)",
         "on (8)"},
        {"gamma", number(), "grey = 255 coverage^gamma; 0 = threshold at half coverage", "1"},
        {"exposure", number(), "exposure time (s)", "the printer's"},
        {"exposure_first", number(), "first layers' exposure time (s)", "the printer's"},
        {"preview", {{"type", {"string", "boolean"}}}, "contact-sheet PNG, or off", "FILE.preview.png"},
        {"timestamp", string(), "the archive's timestamp (fixed, so archives are reproducible)",
         "2020-01-01 at 00:00:00 UTC"},
        {"reuse",
         {{"type", {"string", "boolean"}}},
         "copy layers one z-period apart (on) or compute every layer (off)",
         "on"},
        {"checks",
         {{"type", {"string", "boolean"}}},
         "printability checks (islands, resin traps, thin features): on, off, or strict (an island fails the job)",
         "on"}};
    return keys;
}

SliceSettings parseSliceSettings(const RecipeNode& spec)
{
    if (!spec.isMap()) spec.fail("expected a map like `{printer: sl1s, layer: 0.05, file: part.sl1s}`");
    spec.checkKeys(keyNames(sliceKeys()));
    SliceSettings s;
    s.printer = spec["printer"].string();
    s.printerWhere = spec["printer"].where();
    if (spec.has("layer")) {
        s.layer = spec["layer"].positiveNumber();
        // Resin printers lay 0.01 to 0.3 mm; 4e-7 mm would be 15 million layers for 6 mm.
        if (*s.layer < 0.001 || *s.layer > 10.0)
            spec["layer"].fail("a layer of " + spec["layer"].yaml().Scalar() +
                               " mm is outside what a resin printer lays (0.001 to 10 mm), like 0.05");
    }
    s.file = spec["file"].string();
    if (spec.has("format")) {
        s.format = spec["format"].string();
        const auto formats = sliceFormatNames();
        if (std::find(formats.begin(), formats.end(), s.format) == formats.end())
            spec["format"].fail("unknown format `" + s.format + "` (valid: " + joinWords(formats) + ")");
    }
    if (spec.has("position")) {
        const RecipeNode p = spec["position"];
        if (!p.isSequence() || p.size() != 2)
            p.fail("expected [x, y]: where the part's centre goes on the display (mm)");
        s.position = std::array<double, 2>{p.at(0).number(), p.at(1).number()};
    }
    if (spec.has("aa")) {
        const RecipeNode aa = spec["aa"];
        const std::string word = aa.yaml().Scalar();
        if (word == "off" || word == "false") {
            s.supersample = 0;
        } else if (word == "on" || word == "true") {
            s.supersample = 8;
        } else {
            const double v = aa.number();
            if (v != std::floor(v) || v < 1 || v > 16)
                aa.fail("expected `off`, `on` or a number of sub-samples per axis from 1 to 16");
            s.supersample = int(v);
        }
    }
    if (spec.has("gamma")) {
        s.gamma = spec["gamma"].number();
        if (s.gamma < 0 || s.gamma > 10)
            spec["gamma"].fail("expected a gamma from 0 (binary) to 10; 1 is linear coverage");
    }
    if (spec.has("exposure")) s.exposure = spec["exposure"].positiveNumber();
    if (spec.has("exposure_first")) s.exposureFirst = spec["exposure_first"].positiveNumber();
    if (spec.has("preview")) {
        const std::string word = spec["preview"].yaml().Scalar();
        s.preview = word == "false" || word == "off" ? "off" : word;
        if (s.preview != "off") {
            // A side file of the slices: inside the output folder, like every output.
            const std::filesystem::path p(s.preview);
            if (p.is_absolute() || s.preview.front() == '~' ||
                std::any_of(p.begin(), p.end(), [](const auto& part) { return part == ".."; }))
                spec["preview"].fail(
                    "the preview is a PNG inside the output folder (--out), like `part.preview.png`; `" + s.preview +
                    "` leaves it");
            if (p.extension() != ".png")
                spec["preview"].fail("the preview is a PNG picture: its name ends in .png; `" + s.preview +
                                     "` does not");
        }
    }
    if (spec.has("timestamp")) s.timestamp = spec["timestamp"].string();
    if (spec.has("reuse")) {
        const std::string word = spec["reuse"].yaml().Scalar();
        if (word == "off" || word == "false")
            s.reuseBytes = 0;
        else if (word != "on" && word != "true")
            spec["reuse"].fail("expected `on` (copy layers one z-period apart, the default) or `off`");
    }
    if (spec.has("checks")) {
        const std::string word = spec["checks"].yaml().Scalar();
        s.checks = word == "false" ? "off" : word == "true" ? "on" : word;
        if (s.checks != "on" && s.checks != "off" && s.checks != "strict")
            spec["checks"].fail(
                "expected `on` (report islands, resin traps and thin features), `strict` (an island "
                "fails the job) or `off`");
    }
    return s;
}

}  // namespace voxlat
