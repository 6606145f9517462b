#include "engine/jobs/PropertyDesign.h"

#include "engine/core/Errors.h"
#include "engine/core/Format.h"
#include "engine/jobs/Job.h"
#include "engine/jobs/TrialRecipe.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

namespace voxlat {

namespace {

const char* kAxisName[3] = {"x", "y", "z"};

/// One trial: a job on a copy of @a base whose only field (with its inputs) is @a name, edited
/// by the trial's values, homogenized at the search's resolution.
struct Measured {
    double modulus = 0.0;  ///< along the axis asked for; 0 when the cell falls apart or is empty
    double density = 0.0;  ///< the voxel model's relative density
    std::string failure;   ///< why the modulus is 0, if it is
};

/// The resolution every trial of a search is homogenized at: given (the key's `resolution:` or
/// `properties: {resolution}`), or the one the convergence check of `voxlat properties` chooses
/// (Richardson extrapolation of E to `properties: {convergence}`) at the search's first trial that
/// carries load, then kept for the others, so that trials compare on one voxel model size.
struct TrialResolution {
    std::optional<int> voxels;   ///< empty until the first converged trial has set it
    nlohmann::json convergence;  ///< that trial's `convergence` report (null when given)
    std::string from;            ///< "given" or "convergence"
};

Measured measure(const Recipe& base, const std::string& name, const FieldEdit& edit, int axis,
                 TrialResolution& resolution, JobContext* parent)
{
    if (parent) parent->checkCancelled();
    Recipe r = trialRecipe(base, name, edit);
    r.properties.resolution = resolution.voxels;
    r.properties.conductivity = false;
    // The trials' own warnings (loose pieces, a cell with no load path) are about candidates the
    // search leaves behind, not about the result.
    JobContext quiet;
    followCancel(quiet, parent);
    Measured m;
    try {
        const CellLevelTrial trial;
        Job job(std::move(r), &quiet);
        const nlohmann::json& p = job.properties();
        m.modulus = p["E_MPa"][axis].get<double>();
        m.density = p["relative_density"].get<double>();
        if (!resolution.voxels && p.contains("convergence") && m.modulus > 0.0) {
            resolution.voxels = p["convergence"]["resolutions"].back().get<int>();
            resolution.convergence = p["convergence"];
        }
    } catch (const JobError& e) {
        m.failure = e.what();  // no solid, or no load path along any axis: no stiffness
    }
    return m;
}

TrialResolution trialResolution(const std::optional<int>& own, const Recipe& recipe)
{
    if (own) return {own, nullptr, "given"};
    if (recipe.properties.resolution) return {recipe.properties.resolution, nullptr, "given"};
    return {std::nullopt, nullptr, "convergence"};
}

/// The search's resolution for report.json `design`: the voxels, where they came from and, when
/// chosen by convergence, the check's numbers (its estimated error is the trials' error in E).
void reportResolution(nlohmann::json& entry, const TrialResolution& r)
{
    entry["resolution"] = r.voxels ? nlohmann::json(*r.voxels) : nlohmann::json();
    entry["resolution_from"] = r.from == "given" ? "given (`resolution:`)"
                                                 : "the convergence check at the search's first trial that carries "
                                                   "load, kept for every trial";
    if (!r.convergence.is_null()) {
        entry["convergence"] = r.convergence;
        entry["estimated_error"] = r.convergence["estimated_error"];
    }
}

/// `stiffness:`: Illinois (regula falsi with the stale end halved) on log E against density,
/// bracketed first by steps of 1.6x from the Gibson-Ashby guess rho = sqrt(E / E_s).
/// @a target was checked at load (parseFieldDesign): a material, a goal below its modulus.
nlohmann::json solveStiffness(Recipe& recipe, const std::string& name, const StiffnessTarget& target,
                              JobContext* context)
{
    const StiffnessTarget& key = target;  // its fail() names the `stiffness:` line
    const double Es = recipe.material->modulusMPa;
    const double goal = target.goalMPa;
    const std::string goalText = formatNumber(goal) + " MPa along " + kAxisName[target.axis];
    TrialResolution resolution = trialResolution(target.resolution, recipe);

    struct Trial {
        double rho, modulus, cellDensity;
    };
    std::vector<Trial> trials;
    StageProgress progress(context, "stiffness of " + name, 16);
    auto f = [&](double rho) {
        FieldEdit edit;
        edit.density = rho;
        const Measured m = measure(recipe, name, edit, target.axis, resolution, context);
        trials.push_back({rho, m.modulus, m.density});
        progress.add();
        return m.modulus > 0.0 ? std::log(m.modulus / goal) : -std::numeric_limits<double>::infinity();
    };
    const double logTolerance = std::log1p(target.tolerance);
    constexpr double kLow = 0.02, kHigh = 0.9;
    double a = std::clamp(std::sqrt(goal / Es), 0.03, 0.8);
    double fa = f(a);
    double b = a, fb = fa;
    // Bracket: a below the target, b above.
    if (fa < 0.0) {
        while (fb < 0.0) {
            if (b >= kHigh)
                key.fail("the target modulus " + goalText + " is out of reach: at density " + formatNumber(kHigh) +
                         " this lattice has " + formatNumber(trials.back().modulus) + " MPa (" + recipe.material->name +
                         ", E_s " + formatNumber(Es) + " MPa)");
            a = b, fa = fb;
            b = std::min(kHigh, b * 1.6);
            fb = f(b);
        }
    } else {
        while (fa > 0.0) {
            if (a <= kLow)
                key.fail("the target modulus " + goalText + " is below this lattice's reach: already at density " +
                         formatNumber(kLow) + " it has " + formatNumber(trials.back().modulus) +
                         " MPa; choose a more compliant cell or a lower target");
            b = a, fb = fa;
            a = std::max(kLow, a / 1.6);
            fa = f(a);
        }
    }
    int side = 0;  // which end moved last time (Illinois halves the other end's value on a repeat)
    auto within = [&](double fx) { return std::abs(fx) <= logTolerance; };
    bool done = within(fa) || within(fb);
    for (int k = 0; k < 14 && !done; ++k) {
        // Regula falsi on log E; bisection while the low end carries no load (log E = -inf).
        double x = std::isfinite(fa) ? b - fb * (b - a) / (fb - fa) : 0.5 * (a + b);
        if (!(x > a && x < b)) x = 0.5 * (a + b);
        const double fx = f(x);
        if (fx < 0.0) {
            a = x, fa = fx;
            if (side == -1) fb *= 0.5;
            side = -1;
        } else {
            b = x, fb = fx;
            if (side == 1 && std::isfinite(fa)) fa *= 0.5;
            side = 1;
        }
        done = within(fx) || b - a < 2e-4;
    }
    progress.finish();
    // The trial closest to the target: its density is written in, so the job (and any later
    // homogenization at the same resolution) reproduces its modulus exactly.
    const Trial best = *std::min_element(trials.begin(), trials.end(), [&](const Trial& p, const Trial& q) {
        auto err = [&](const Trial& t) { return t.modulus > 0 ? std::abs(std::log(t.modulus / goal)) : 1e300; };
        return err(p) < err(q);
    });
    FieldEdit solved;
    solved.density = best.rho;
    editField(recipe, name, solved);

    nlohmann::json rows = nlohmann::json::array();
    for (const Trial& t : trials) rows.push_back({{"density", t.rho}, {"E_MPa", t.modulus}});
    const double error = best.modulus / goal - 1.0;
    if (context && std::abs(error) > target.tolerance) {
        // The voxel model changes in steps (voxels flip, necks join) as the density rises: the
        // bracket closed on a step that jumps over the target.
        double below = 0.0, above = std::numeric_limits<double>::infinity();
        for (const Trial& t : trials) {
            if (t.modulus < goal) below = std::max(below, t.modulus);
            if (t.modulus >= goal) above = std::min(above, t.modulus);
        }
        context->warn("stiffness_tolerance",
                      "field `" + name + "`: the closest density found gives " + formatNumber(best.modulus) + " MPa, " +
                          formatNumber(100.0 * error) + " % from the target " + goalText + ": at " +
                          std::to_string(resolution.voxels.value_or(0)) + " voxels the modulus steps from " +
                          formatNumber(below) + " to " + formatNumber(above) + " MPa within a density change of " +
                          formatNumber(b - a) +
                          " (voxels flip together); a finer `resolution:` makes the steps smaller",
                      {{"field", name}, {"steps_MPa", {below, above}}});
    }
    nlohmann::json entry{{"target_E_MPa", goal},
                         {"axis", kAxisName[target.axis]},
                         {"density", best.rho},
                         {"achieved_E_MPa", best.modulus},
                         {"achieved_E_ratio", best.modulus / Es},
                         {"relative_error", error},
                         {"cell_relative_density", best.cellDensity},
                         {"tolerance", target.tolerance},
                         {"method", "Illinois on log E vs density, bracketed from sqrt(E/E_s)"},
                         {"trials", rows}};
    reportResolution(entry, resolution);
    return entry;
}

/// How far a trial cell's voxel density may stray from the density asked (relative) and still
/// count: a coarse trial model holds the density to about a percent.
constexpr double kTrialDensityTolerance = 0.05;

/// `optimize:`: a coarse sweep of sigma, then golden-section refinement around its best point.
/// @a o was checked at load (parseFieldDesign): a struts node with a fixed density, a Gaussian
/// kernel and a material.
nlohmann::json optimizeSigma(Recipe& recipe, const std::string& name, const SigmaOptimization& o, JobContext* context)
{
    const SigmaOptimization& key = o;  // its fail() names the `optimize:` line
    TrialResolution resolution = trialResolution(o.resolution, recipe);
    auto withSigma = [&](double sigma) {
        FieldEdit edit;
        edit.sigma = sigma;
        return edit;
    };

    struct Trial {
        double sigma, modulus, cellDensity;
    };
    std::vector<Trial> trials;
    const int golden = int(std::ceil(std::log(2.0 * (o.hi - o.lo) / (o.samples - 1) / o.tolerance) / std::log(1.618)));
    StageProgress progress(context, "optimizing sigma of " + name, std::uint64_t(o.samples + std::max(0, golden) + 1));
    // A sigma whose cell cannot hold the density asked (a kernel so wide the field is flat: the
    // cell turns solid) is no candidate, however stiff: it counts as carrying nothing.
    const double density = o.density;
    auto holdsDensity = [&](double cellDensity) {
        return std::abs(cellDensity / density - 1.0) <= kTrialDensityTolerance;
    };
    auto f = [&](double sigma) {
        const Measured m = measure(recipe, name, withSigma(sigma), o.axis, resolution, context);
        trials.push_back({sigma, m.modulus, m.density});
        progress.add();
        return holdsDensity(m.density) ? m.modulus : 0.0;
    };
    std::vector<double> xs(o.samples), ys(o.samples);
    for (int k = 0; k < o.samples; ++k) xs[k] = o.lo + (o.hi - o.lo) * k / (o.samples - 1);
    // The middle of the range first: with no `resolution:` its convergence check chooses the
    // resolution of every trial (the range's ends are the likeliest to fall apart or to be
    // outliers).
    const int middle = o.samples / 2;
    ys[middle] = f(xs[middle]);
    for (int k = 0; k < o.samples; ++k)
        if (k != middle) ys[k] = f(xs[k]);
    const int k = int(std::max_element(ys.begin(), ys.end()) - ys.begin());
    if (ys[k] <= 0.0)
        key.fail("no sigma in [" + formatNumber(o.lo) + ", " + formatNumber(o.hi) + "] gives a lattice that carries " +
                 "load along " + kAxisName[o.axis] + " at this density: raise the density or lower sigma");
    // Golden section on [x_{k-1}, x_{k+1}] (the maximum of a unimodal curve lies there).
    double lo = xs[std::max(0, k - 1)], hi = xs[std::min(o.samples - 1, k + 1)];
    const double g = (std::sqrt(5.0) - 1.0) / 2.0;
    double x1 = hi - g * (hi - lo), x2 = lo + g * (hi - lo);
    double y1 = f(x1), y2 = f(x2);
    while (hi - lo > o.tolerance) {
        if (y1 >= y2) {
            hi = x2, x2 = x1, y2 = y1;
            x1 = hi - g * (hi - lo);
            y1 = f(x1);
        } else {
            lo = x1, x1 = x2, y1 = y2;
            x2 = lo + g * (hi - lo);
            y2 = f(x2);
        }
    }
    const Trial best = *std::max_element(trials.begin(), trials.end(), [&](const Trial& p, const Trial& q) {
        return (holdsDensity(p.cellDensity) ? p.modulus : 0.0) < (holdsDensity(q.cellDensity) ? q.modulus : 0.0);
    });
    if (!holdsDensity(best.cellDensity))
        throw JobError(key.where + ": the best sigma found (" + formatNumber(best.sigma) +
                       " mm) gives a cell of density " + formatNumber(best.cellDensity) + ", not the " +
                       formatNumber(density) + " asked: narrow `sigma:` to kernels about the struts' size");
    std::sort(trials.begin(), trials.end(), [](const Trial& p, const Trial& q) { return p.sigma < q.sigma; });
    nlohmann::json rows = nlohmann::json::array();
    for (const Trial& t : trials) rows.push_back({{"sigma", t.sigma}, {"E_MPa", t.modulus}});
    nlohmann::json entry{{"sigma", best.sigma},
                         {"axis", kAxisName[o.axis]},
                         {"density", o.density},
                         {"E_MPa", best.modulus},
                         {"E_ratio", best.modulus / recipe.material->modulusMPa},
                         {"cell_relative_density", best.cellDensity},
                         {"range", {o.lo, o.hi}},
                         {"tolerance", o.tolerance},
                         {"method", "coarse sweep of " + std::to_string(o.samples) +
                                        " points, golden-section refinement around the best"},
                         {"trials", rows}};
    reportResolution(entry, resolution);
    if (o.baseline) {
        // The Boolean-joint lattice: hard capsules of one radius, solved for the same density.
        FieldEdit capsule;
        capsule.capsule = true;
        const Measured m = measure(recipe, name, capsule, o.axis, resolution, context);
        progress.add();
        entry["capsule_E_MPa"] = m.modulus;
        entry["capsule_cell_relative_density"] = m.density;
        entry["ratio_to_capsule"] = m.modulus > 0.0 ? nlohmann::json(best.modulus / m.modulus) : nlohmann::json();
    }
    progress.finish();
    editField(recipe, name, withSigma(best.sigma));
    return entry;
}

}  // namespace

nlohmann::json resolvePropertyTargets(Recipe& recipe, JobContext* context)
{
    nlohmann::json report = nlohmann::json::object();
    // A copy: each resolution edits its field, which takes its entry out of recipe.designs.
    const std::vector<FieldDesign> designs = recipe.designs;
    for (const FieldDesign& d : designs) {
        if (d.stiffness) {
            report[d.field]["stiffness"] = solveStiffness(recipe, d.field, *d.stiffness, context);
        } else if (d.optimizeOff) {
            // `--set fields.NAME.optimize=off`: the sigma as written (a sweep of it, say).
            editField(recipe, d.field, FieldEdit{});
        } else if (d.optimize) {
            report[d.field]["optimize"] = optimizeSigma(recipe, d.field, *d.optimize, context);
        }
    }
    return report;
}

}  // namespace voxlat
