#include "engine/jobs/PrinterProfile.h"

#include "engine/core/Format.h"
#include "engine/core/InputFiles.h"
#include "engine/jobs/DataFolder.h"

#include "engine/recipe/RecipeNode.h"
#include "engine/recipe/SliceSettings.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace voxlat {

namespace fs = std::filesystem;

namespace {
const std::vector<std::string> kProfileKeys{"name",
                                            "model",
                                            "format",
                                            "display",
                                            "mirror_x",
                                            "mirror_y",
                                            "orientation",
                                            "max_height",
                                            "layer",
                                            "exposure",
                                            "exposure_first",
                                            "fade_layers",
                                            "fast_tilt",
                                            "slow_tilt",
                                            "area_fill",
                                            "bottom_layers",
                                            "transition_layers",
                                            "lift_distance",
                                            "lift_speed",
                                            "retract_distance",
                                            "retract_speed",
                                            "bottom_lift_distance",
                                            "bottom_lift_speed",
                                            "bottom_retract_distance",
                                            "bottom_retract_speed",
                                            "wait_before_lift",
                                            "wait_after_lift",
                                            "wait_after_retract",
                                            "bottom_wait_before_lift",
                                            "bottom_wait_after_lift",
                                            "bottom_wait_after_retract",
                                            "light_pwm",
                                            "bottom_light_pwm",
                                            "ctb_version",
                                            "ctb_encrypted"};

bool looksLikePath(const std::string& s)
{
    return s.find('/') != std::string::npos || s.ends_with(".yaml") || s.ends_with(".yml");
}

/// A whole number from 0 to @a most.
int wholeNumber(const RecipeNode& n, int most)
{
    const double v = n.number();
    if (v < 0 || v > most || v != std::floor(v))
        n.fail("expected a whole number from 0 to " + std::to_string(most) + ", got " + n.yaml().Scalar());
    return int(v);
}

/// `[stage 1, stage 2]`, each >= 0.
std::array<double, 2> twoStages(const RecipeNode& n, const char* unit)
{
    if (!n.isSequence() || n.size() != 2)
        n.fail(std::string("expected [stage 1, stage 2] in ") + unit + ", e.g. [3, 4]");
    std::array<double, 2> v{n.at(0).number(), n.at(1).number()};
    if (v[0] < 0 || v[1] < 0) n.fail(std::string("expected values >= 0 (") + unit + ")");
    return v;
}

/// The motion keys with @a prefix (`` or `bottom_`) into @a m (unset keys keep their defaults).
void readMotion(const RecipeNode& top, const std::string& prefix, GooMotion& m)
{
    auto key = [&](const char* name) { return prefix + name; };
    if (top.has(key("lift_distance"))) m.liftDistance = twoStages(top[key("lift_distance")], "mm");
    if (top.has(key("lift_speed"))) m.liftSpeed = twoStages(top[key("lift_speed")], "mm/min");
    if (top.has(key("retract_distance"))) m.retractDistance = twoStages(top[key("retract_distance")], "mm");
    if (top.has(key("retract_speed"))) m.retractSpeed = twoStages(top[key("retract_speed")], "mm/min");
    auto seconds = [&](const char* name, double& into) {
        if (!top.has(key(name))) return;
        into = top[key(name)].number();
        if (into < 0) top[key(name)].fail("expected a time >= 0 (s)");
    };
    seconds("wait_before_lift", m.waitBeforeLift);
    seconds("wait_after_lift", m.waitAfterLift);
    seconds("wait_after_retract", m.waitAfterRetract);
    if (top.has(key("light_pwm"))) m.lightPwm = wholeNumber(top[key("light_pwm")], 255);
}

constexpr double kMaxDisplayPixels = double(1 << 28);

int positiveInt(const RecipeNode& n)
{
    const double v = n.positiveNumber();
    if (v != std::floor(v) || v > 1e6) n.fail("expected a whole number of pixels, got " + n.yaml().Scalar());
    return int(v);
}
}  // namespace

std::string printersFolder()
{
    if (const char* env = std::getenv("VOXLAT_PRINTERS"); env && *env) return env;
    return dataFolder() + "/printers";
}

std::vector<std::string> printerNames()
{
    std::vector<std::string> names;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(printersFolder(), ec))
        if (e.path().extension() == ".yaml") names.push_back(e.path().stem().string());
    std::sort(names.begin(), names.end());
    return names;
}

PrinterProfile loadPrinterProfile(const std::string& nameOrPath, const std::string& where)
{
    std::string path = nameOrPath;
    if (!looksLikePath(nameOrPath)) {
        path = printersFolder() + "/" + nameOrPath + ".yaml";
        if (!fs::exists(path)) {
            const std::vector<std::string> names = printerNames();
            std::string message = "unknown printer `" + nameOrPath + "`";
            const std::string guess = closestMatch(nameOrPath, names);
            if (!guess.empty()) message += "; did you mean `" + guess + "`?";
            throw InputError((where.empty() ? "" : where + ": ") + message + " (printers in " + printersFolder() +
                             ": " + joinWords(names) + "; or give the path of a profile file)");
        }
    }
    // A profile is a few hundred bytes of YAML: a regular file of at most 1 MB.
    std::string text;
    try {
        text = readInputFile(path, std::uintmax_t(1) << 20, "printer profile");
    } catch (const InputError& e) {
        throw InputError((where.empty() ? "" : where + ": ") + e.what());
    }
    const YAML::Node root = loadYaml(text, path);
    auto source = std::make_shared<RecipeSource>();
    source->path = path;
    if (!root.IsMap()) throw InputError(path + ":1:1: a printer profile is a map of keys (display, orientation, ...)");
    const RecipeNode top(root, source, "printer profile");
    top.checkKeys(kProfileKeys);

    PrinterProfile p;
    p.file = path;
    p.key = looksLikePath(nameOrPath) ? fs::path(path).stem().string() : nameOrPath;
    p.name = top.has("name") ? top["name"].string() : p.key;
    p.model = top.has("model") ? top["model"].string() : p.key;
    p.format = top.has("format") ? top["format"].string() : "zip";
    if (const std::string why = formatNotWritten(p.format); !why.empty()) top["format"].fail(why);
    if (const auto formats = sliceFormatNames(); std::find(formats.begin(), formats.end(), p.format) == formats.end())
        top["format"].fail("unknown format `" + p.format + "` (valid: " + joinWords(formats) + ")");
    const RecipeNode display = top["display"];
    p.displayWhere = display.where();
    display.checkKeys({"width", "height", "pixels_x", "pixels_y"});
    p.widthMm = display["width"].positiveNumber();
    p.heightMm = display["height"].positiveNumber();
    p.pixelsX = positiveInt(display["pixels_x"]);
    p.pixelsY = positiveInt(display["pixels_y"]);
    // A layer is held as one byte a pixel, several layers at once: a display past 2^28 pixels
    // (twice a 16K printer's) cannot be sliced in memory (10^6 x 10^6 ran out of it).
    if (double(p.pixelsX) * double(p.pixelsY) > kMaxDisplayPixels)
        display.fail("a display of " + std::to_string(p.pixelsX) + " x " + std::to_string(p.pixelsY) + " = " +
                     formatNumber(double(p.pixelsX) * double(p.pixelsY)) + " pixels is more than the " +
                     formatNumber(kMaxDisplayPixels) +
                     " a layer may have (a 16K printer has 1.3e8): check pixels_x and pixels_y");
    p.mirrorX = top["mirror_x"].boolean();
    p.mirrorY = top["mirror_y"].boolean();
    const std::string orientation = top["orientation"].string();
    if (orientation != "portrait" && orientation != "landscape")
        top["orientation"].fail("expected `portrait` or `landscape`, got `" + orientation + "`");
    p.portrait = orientation == "portrait";
    p.maxHeightMm = top["max_height"].positiveNumber();
    p.maxHeightWhere = top["max_height"].where();
    if (top.has("layer")) p.layerMm = top["layer"].positiveNumber();
    if (top.has("exposure")) p.exposureS = top["exposure"].positiveNumber();
    if (top.has("exposure_first")) p.exposureFirstS = top["exposure_first"].positiveNumber();
    if (top.has("fade_layers")) {
        const double v = top["fade_layers"].number();
        if (v < 0 || v != std::floor(v)) top["fade_layers"].fail("expected a whole number >= 0");
        p.fadeLayers = int(v);
    }
    if (top.has("fast_tilt")) p.fastTiltS = top["fast_tilt"].number();
    if (top.has("slow_tilt")) p.slowTiltS = top["slow_tilt"].number();
    if (top.has("area_fill")) p.areaFillPercent = top["area_fill"].positiveNumber();
    if (top.has("bottom_layers")) p.bottomLayers = wholeNumber(top["bottom_layers"], 1000);
    if (top.has("transition_layers")) p.transitionLayers = wholeNumber(top["transition_layers"], 1000);
    if (top.has("ctb_version")) {
        const RecipeNode v = top["ctb_version"];
        p.ctbVersion = wholeNumber(v, 5);
        if (p.ctbVersion < 2) v.fail("expected a .ctb version from 2 to 5 (4 is what Chitubox 1.9 writes)");
    }
    if (top.has("ctb_encrypted")) {
        p.ctbEncrypted = top["ctb_encrypted"].boolean();
        if (p.ctbEncrypted && p.ctbVersion < 4)
            top["ctb_encrypted"].fail(
                "the encrypted .ctb layout is version 4 or 5: set `ctb_version: 5` (what "
                "Chitubox 2 writes) or drop `ctb_encrypted`");
    }
    readMotion(top, "", p.motion);
    readMotion(top, "bottom_", p.bottomMotion);
    return p;
}

}  // namespace voxlat
