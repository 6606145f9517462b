#include "engine/jobs/PiecesAdvice.h"

#include "engine/core/Errors.h"
#include "engine/jobs/Job.h"
#include "engine/jobs/TrialRecipe.h"

#include <cmath>

namespace voxlat {

namespace {

/// The node's box cell (mm), or nullopt when its frame is not a plain box of cells.
std::optional<Vec3d> boxCell(const YAML::Node& struts)
{
    if (!struts.IsMap() || !struts["size"]) return std::nullopt;
    for (auto it = struts.begin(); it != struts.end(); ++it) {
        const std::string key = it->first.Scalar();
        if (key != "cell" && key != "size" && key != "origin") return std::nullopt;
    }
    const YAML::Node size = struts["size"];
    try {
        if (size.IsScalar()) return Vec3d(size.as<double>());
        if (size.IsSequence() && size.size() == 3)
            return Vec3d(size[0].as<double>(), size[1].as<double>(), size[2].as<double>());
    } catch (const YAML::Exception&) {
    }
    return std::nullopt;
}

}  // namespace

std::optional<double> sigmaKeepingOnePiece(const Recipe& recipe, const std::string& name, JobContext* context)
{
    const auto found = recipe.fieldIndex.find(name);
    if (found == recipe.fieldIndex.end() || !recipe.domainBox) return std::nullopt;
    const YAML::Node spec = found->second;
    if (!spec.IsMap() || !spec["struts"] || !spec["density"] || !spec["density"].IsScalar() || !spec["kernel"] ||
        !spec["kernel"].IsMap() || !spec["kernel"]["gaussian"] || !spec["kernel"]["gaussian"]["sigma"] ||
        !spec["kernel"]["gaussian"]["sigma"].IsScalar())
        return std::nullopt;
    const std::optional<Vec3d> cell = boxCell(spec["struts"]);
    double sigma = 0.0;
    try {
        sigma = spec["kernel"]["gaussian"]["sigma"].as<double>();
    } catch (const YAML::Exception&) {
        return std::nullopt;
    }
    if (!cell || !(sigma > 0.0)) return std::nullopt;

    // Two cells each way from the frame's origin: joints inside and struts across cell faces.
    Vec3d origin = recipe.domainBox->min;
    if (spec["struts"]["origin"]) {
        try {
            const YAML::Node o = spec["struts"]["origin"];
            origin = Vec3d(o[0].as<double>(), o[1].as<double>(), o[2].as<double>());
        } catch (const YAML::Exception&) {
            return std::nullopt;
        }
    }
    auto whole = [&](double s) {
        if (context) context->checkCancelled();
        YAML::Node trial = YAML::Clone(spec);
        trial["kernel"]["gaussian"]["sigma"] = exactNumber(s);
        Recipe r = trialRecipe(recipe, name, trial);
        r.domainBox = Box3{origin, origin + 2.0 * *cell};
        r.allow = {"pieces"};  // counted, not thrown: the trial reads the count
        JobContext quiet;
        followCancel(quiet, context);
        try {
            Job job(std::move(r), &quiet);
            job.grid();
            const nlohmann::json report = job.report();
            return report.contains("pieces") && report["pieces"].value("free", 0) == 0;
        } catch (const InputError&) {
            return false;  // a density out of reach at this sigma: not a lattice to offer
        } catch (const JobError&) {
            return false;  // no solid at all
        }
    };
    double lo = 0.25 * sigma, hi = sigma;
    if (!whole(lo)) return std::nullopt;
    for (int i = 0; i < 7; ++i) {
        const double mid = 0.5 * (lo + hi);
        (whole(mid) ? lo : hi) = mid;
    }
    return std::floor(lo * 100.0) / 100.0;
}

}  // namespace voxlat
