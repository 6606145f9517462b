#include "engine/recipe/SliceSettings.h"

#include <cmath>

namespace voxlat {

const std::vector<std::string>& sliceKeys()
{
    static const std::vector<std::string> keys{"printer",        "layer",   "file",      "format",
                                               "position",       "aa",      "gamma",     "exposure",
                                               "exposure_first", "preview", "timestamp", "reuse"};
    return keys;
}

SliceSettings parseSliceSettings(const RecipeNode& spec)
{
    if (!spec.isMap()) spec.fail("expected a map like `{printer: sl1s, layer: 0.05, file: part.sl1s}`");
    spec.checkKeys(sliceKeys());
    SliceSettings s;
    s.printer = spec["printer"].string();
    s.printerWhere = spec["printer"].where();
    if (spec.has("layer")) s.layer = spec["layer"].positiveNumber();
    s.file = spec["file"].string();
    if (spec.has("format")) {
        s.format = spec["format"].string();
        if (s.format != "sl1" && s.format != "sl1s" && s.format != "zip" && s.format != "png" && s.format != "exr")
            spec["format"].fail("unknown format `" + s.format + "` (valid: sl1, sl1s, zip, png, exr)");
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
    }
    if (spec.has("timestamp")) s.timestamp = spec["timestamp"].string();
    if (spec.has("reuse")) {
        const std::string word = spec["reuse"].yaml().Scalar();
        if (word == "off" || word == "false")
            s.reuseBytes = 0;
        else if (word != "on" && word != "true")
            spec["reuse"].fail("expected `on` (copy layers one z-period apart, the default) or `off`");
    }
    return s;
}

}  // namespace voxlat
