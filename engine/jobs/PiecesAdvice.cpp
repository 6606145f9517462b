#include "engine/jobs/PiecesAdvice.h"

#include "engine/core/Errors.h"
#include "engine/jobs/Job.h"
#include "engine/jobs/TrialRecipe.h"

#include <cmath>

namespace voxlat {

std::optional<double> sigmaKeepingOnePiece(const Recipe& recipe, const std::string& name, JobContext* context)
{
    // The node's facts, read when the recipe loaded (and again when a design target was solved).
    const auto found = recipe.fieldFacts.find(name);
    if (found == recipe.fieldFacts.end() || !recipe.domainBox) return std::nullopt;
    const FieldFacts& facts = found->second;
    if (!facts.densityScalar || !facts.sigma || !facts.plainBoxCell) return std::nullopt;
    const Vec3d cell = *facts.plainBoxCell;
    const double sigma = *facts.sigma;
    if (!(sigma > 0.0)) return std::nullopt;

    // Two cells each way from the frame's origin: joints inside and struts across cell faces.
    const Vec3d origin = facts.plainBoxOrigin ? *facts.plainBoxOrigin : recipe.domainBox->min;
    auto whole = [&](double s) {
        if (context) context->checkCancelled();
        FieldEdit edit;
        edit.sigma = s;
        Recipe r = trialRecipe(recipe, name, edit);
        r.domainBox = Box3{origin, origin + 2.0 * cell};
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
