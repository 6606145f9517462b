#include "engine/recipe/DrainSpec.h"

#include <cmath>

namespace voxlat {

DrainSpec parseDrain(const RecipeNode& d, bool allowBuild)
{
    if (!d.isMap()) d.fail("expected `drain: {diameter: D}`: every resin trap is opened by a channel of D mm");
    if (allowBuild) {
        d.checkKeys({"diameter", "build"});
    } else {
        if (d.has("build"))
            d["build"].fail(
                "slices are built along +z (the printer's axis): turn the part in the recipe instead of "
                "giving the drains another build direction");
        d.checkKeys({"diameter"});
    }
    if (!d.has("diameter")) d.fail("give the channels' `diameter:` in mm, like `drain: {diameter: 2}`");
    DrainSpec s;
    s.diameter = d["diameter"].positiveNumber();
    s.where = d.where();
    s.diameterWhere = d["diameter"].where();
    if (d.has("build")) {
        const Vec3d up = d["build"].vec3();
        if (!(up.length() > 0.0) || !std::isfinite(up.length()))
            d["build"].fail(
                "the build direction has zero length; give the direction the part grows in, such as "
                "[0, 0, 1]");
        s.up = up / up.length();
    }
    return s;
}

nlohmann::json drainSchema(bool allowBuild)
{
    using namespace valueSchema;
    std::vector<KeySpec> keys{{"diameter", number(), "the channels' diameter (mm)", "required"}};
    if (allowBuild)
        keys.push_back({"build", vec3(),
                        "the build direction [x, y, z]: each channel leaves its cavity's lowest point along it",
                        "[0, 0, 1]"});
    return object(keys, {"diameter"});
}

}  // namespace voxlat
