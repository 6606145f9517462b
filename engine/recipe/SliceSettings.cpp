#include "engine/recipe/SliceSettings.h"

#include "engine/recipe/DrainSpec.h"

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
        {"goo", ".goo", "Elegoo .goo (V3) for Elegoo's Saturn and Mars printers: run-length layers, previews"},
        {"ctb", ".ctb",
         "Chitubox .ctb, unencrypted (version 2 to 5, the profile's `ctb_version:`, default 4) for the printers "
         "that read Chitubox files (Elegoo Mars and Saturn, Creality LD, Phrozen, ...): RLE7 layers, previews"},
        {"cbddlp", ".cbddlp",
         "Chitubox .cbddlp (version 2) for older Chitubox printers (Elegoo Mars, EPAX X1, ...): bit-plane layers, "
         "previews"},
        {"photon", ".photon", "Anycubic Photon's .photon (the .cbddlp layout, version 1): bit-plane layers, previews"}};
    static const std::vector<ArchiveFormatInfo> all = [] {
        // Anycubic Photon Workshop: one binary layout, one extension per printer (its firmware
        // reads only its own).
        const std::vector<std::pair<const char*, const char*>> photon{
            {"pwmo", "Photon Mono"},       {"pwms", "Photon Mono SE"},    {"pwma", "Photon Mono 4K"},
            {"pwmx", "Photon Mono X"},     {"pmsq", "Photon Mono SQ"},    {"pwmb", "Photon Mono X 6K, M3 Plus"},
            {"px6s", "Photon Mono X 6Ks"}, {"pmx2", "Photon Mono X2"},    {"pm3", "Photon M3"},
            {"pm3m", "Photon M3 Max"},     {"pm3r", "Photon M3 Premium"}, {"pm3n", "Photon Mono 2"},
            {"pm4n", "Photon Mono 4"},     {"pm5", "Photon Mono M5"},     {"dlp", "Photon Ultra"},
            {"dl2p", "Photon D2"},         {"pm5s", "Photon Mono M5s"},   {"m5sp", "Photon Mono M5s Pro"},
            {"pws", "Photon S"},           {"pw0", "Photon Zero"},        {"pwx", "Photon X"}};
        std::vector<ArchiveFormatInfo> table = formats;
        for (const auto& [ext, printer] : photon)
            table.push_back(
                {ext, std::string(".") + ext,
                 std::string("Anycubic Photon Workshop file for the ") + printer +
                     (std::string(ext) == "pws" ? ": bit-plane layers, preview" : ": PW0 layers, preview")});
        // Anycubic's zip layout (docs/formats/anycubic-zip.md), with PW0 bitmap layers (pw0Img).
        const std::vector<std::pair<const char*, const char*>> zipped{{"pm7", "Photon Mono M7"},
                                                                      {"pm7m", "Photon Mono M7 Max"},
                                                                      {"pm4u", "Photon Mono 4 Ultra"},
                                                                      {"pp1", "Photon P1"},
                                                                      {"pp1m", "Photon P1 Max"}};
        for (const auto& [ext, printer] : zipped)
            table.push_back({ext, std::string(".") + ext,
                             std::string("Anycubic Photon Workshop zip for the ") + printer +
                                 ": JSON settings, PW0 layers (pw0Img), scene summary, previews"});
        return table;
    }();
    return all;
}

std::string formatNotWritten(const std::string& name)
{
    if (name != "pwsz") return "";
    return "`.pwsz` (the Photon Mono M7 Pro's file) is not written: Anycubic's own slicer stores its layers as "
           "vector outlines (`.pwszImg`, which voxlat does not write), and no public source shows that the M7 Pro "
           "reads the PW0 bitmap layers voxlat writes in .pm7, .pm7m, .pm4u, .pp1 and .pp1m files "
           "(docs/formats/anycubic-zip.md); slice as .zip or png for a host that takes PNG layers";
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
         "on"},
        {"drain", drainSchema(false),
         "drain holes in the result: every resin trap opened by a channel of D mm (the mesh has them too)", "—"}};
    return keys;
}

SliceSettings parseSliceSettings(const RecipeNode& spec)
{
    if (!spec.isMap()) spec.fail("expected a map like `{printer: sl1s, layer: 0.05, file: part.sl1s}`");
    spec.checkKeys(keyNames(sliceKeys()));
    SliceSettings s;
    s.where = spec.where();
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
        if (const std::string why = formatNotWritten(s.format); !why.empty()) spec["format"].fail(why);
        const auto formats = sliceFormatNames();
        if (std::find(formats.begin(), formats.end(), s.format) == formats.end())
            spec["format"].fail("unknown format `" + s.format + "` (valid: " + joinWords(formats) + ")");
    }
    // A file's extension names its format: one that names none is refused, never written in
    // another format (a folder of PNG or EXR layers, `format: png` / `exr`, may have any name).
    const std::string extension = std::filesystem::path(s.file).extension().string();
    const auto formats = archiveFormats();
    const auto named = std::find_if(formats.begin(), formats.end(),
                                    [&](const ArchiveFormatInfo& f) { return f.extension == extension; });
    const bool folder = s.format == "png" || s.format == "exr";
    if (!extension.empty() && !folder && named == formats.end()) {
        if (const std::string why = formatNotWritten(extension.substr(1)); !why.empty()) spec["file"].fail(why);
        std::string known;
        for (const ArchiveFormatInfo& f : formats)
            if (!f.extension.empty()) known += (known.empty() ? "" : " ") + f.extension;
        spec["file"].fail("`" + s.file + "` ends in `" + extension +
                          "`, which names no slice format; name the file after the format the printer reads (" + known +
                          "), or give `format: png` or `exr` for a folder of layers");
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
    if (spec.has("drain")) {
        const DrainSpec d = parseDrain(spec["drain"], false);
        s.drainDiameter = d.diameter;
        s.drainWhere = d.where;
        s.drainDiameterWhere = d.diameterWhere;
    }
    return s;
}

}  // namespace voxlat
