#include "engine/jobs/PropertiesJob.h"

#include "engine/core/Errors.h"
#include "engine/core/Format.h"
#include "engine/core/SystemInfo.h"
#include "engine/properties/CellSample.h"
#include "engine/properties/MemoryEstimate.h"
#include "mesher/extract/TriangleMesh.h"
#include "mesher/writers/MeshPreview.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <numbers>
#include <sstream>

namespace voxlat {

namespace {

nlohmann::json matrixJson(const Matrix6& m, double scale = 1.0)
{
    nlohmann::json rows = nlohmann::json::array();
    for (const auto& row : m) {
        nlohmann::json r = nlohmann::json::array();
        for (double v : row) r.push_back(v * scale);
        rows.push_back(r);
    }
    return rows;
}

nlohmann::json matrixJson(const Matrix3& m, double scale = 1.0)
{
    nlohmann::json rows = nlohmann::json::array();
    for (const auto& row : m) rows.push_back({row[0] * scale, row[1] * scale, row[2] * scale});
    return rows;
}

const char* kAxis = "xyz";
/// Bytes a voxel of the cell takes while it is sampled: the field's values, their copy the level
/// solve sorts (with a density target) and the cell's own byte.
constexpr double kSamplingBytesPerVoxel = 17.0;
/// The resolution of the voxel model whose share of nodes (MemoryEstimate.h) estimates a larger
/// one's before it is sampled: a coarser model has more surface, so more nodes a voxel.
constexpr int kMemoryProbe = 32;

/// The largest relative difference between a cell's density and the density asked, when a level
/// is solved on the cell (issue 37: 0.5 %).
constexpr double kCellDensityTolerance = 0.005;
/// The fractions of a voxel the voxel lattice moves off a symmetric cell's corner when the
/// aligned one cannot hold the density asked: 1/(2 pi), 1/(2 e), 1/(2 sqrt 2), no two alike.
constexpr double kVoxelPhase[3] = {0.15915494309189535, 0.18393972058572117, 0.35355339059327379};

/// The first resolution of the default convergence ladder (voxels along the cell's longest side).
constexpr int kConvergenceStart = 24;

/// The default resolutions: 24 voxels, then steps of sqrt 2 (34, 48, 68, 96, 136, ...) up to
/// @a most.
std::vector<int> convergenceLadder(int most)
{
    std::vector<int> ladder;
    for (int k = 0;; ++k) {
        const int n = int(std::lround(kConvergenceStart * std::pow(std::sqrt(2.0), k)));
        if (n > most) break;
        ladder.push_back(n);
    }
    return ladder;
}

/// Richardson extrapolation of the moduli over the last three resolutions of @a n.
struct ConvergenceEstimate {
    double error = std::numeric_limits<double>::infinity();  ///< largest |E - limit| / limit over the axes
    std::array<double, 3> limit{};                           ///< the extrapolated E per axis
    std::array<double, 3> order{};                           ///< the observed order p (E = limit + a h^p)
    int axis = 0;                                            ///< the axis of the largest error
    /// No axis converged faster than second order (a last step much smaller than the one
    /// before, which can be a step that happened to be small: the next estimate must confirm).
    bool steady = true;
};

ConvergenceEstimate richardson(const std::vector<int>& n, const std::vector<std::array<double, 3>>& E)
{
    ConvergenceEstimate out;
    out.error = 0.0;
    const std::size_t m = E.size();
    const double r12 = double(n[m - 2]) / n[m - 3], r23 = double(n[m - 1]) / n[m - 2];
    for (int a = 0; a < 3; ++a) {
        const double e1 = E[m - 3][a], e2 = E[m - 2][a], e3 = E[m - 1][a];
        out.limit[a] = e3;
        if (e1 == 0.0 && e2 == 0.0 && e3 == 0.0) continue;  // no load path along a at any resolution
        double error = std::numeric_limits<double>::infinity();
        if (e1 > 0.0 && e2 > 0.0 && e3 > 0.0) {
            const double d1 = e2 - e1, d2 = e3 - e2;
            // E = limit + a h^p: d1 / d2 = (h1^p - h2^p) / (h2^p - h3^p), for steps of one ratio
            // r^p. Differences of one sign that do not shrink are not yet in the asymptotic
            // range: first order (p = 1), the cautious guess, extrapolates from the last step.
            // Differences that change sign are the voxel model's jitter (which voxels a strut's
            // surface takes): no trend to extrapolate, the error is their spread.
            if (d1 * d2 < 0.0) {
                out.limit[a] = (e1 + e2 + e3) / 3.0;
                out.order[a] = 0.0;
                error = (std::max({e1, e2, e3}) - std::min({e1, e2, e3})) / e3;
            } else {
                double p = 1.0;
                if (d2 == 0.0)
                    p = std::numeric_limits<double>::infinity();
                else if (std::abs(d2) < std::abs(d1))
                    p = std::log(d1 / d2) / std::log(std::sqrt(r12 * r23));
                if (p > 2.0) out.steady = false;
                p = std::clamp(p, 0.5, 2.0);
                out.limit[a] = std::isfinite(p) ? e3 + d2 / (std::pow(r23, p) - 1.0) : e3;
                out.order[a] = std::isfinite(p) ? p : 0.0;
                error = out.limit[a] > 0.0 ? std::abs(e3 - out.limit[a]) / out.limit[a]
                                           : std::numeric_limits<double>::infinity();
            }
        }
        if (error > out.error) out.error = error, out.axis = a;
    }
    return out;
}

double solidFraction(const VoxelCell& cell)
{
    std::int64_t solid = 0;
    for (std::uint8_t v : cell.solid) solid += v;
    return double(solid) / double(cell.solid.size());
}

}  // namespace

std::optional<RepeatZone> frameWithoutWholeCell(const FieldNode& field, const PropertiesSettings& settings)
{
    if (settings.cell) return std::nullopt;
    bool periodless = false;
    for (int a = 0; a < 3; ++a) periodless = periodless || field.period(a) == FieldNode::kNoPeriod;
    if (!periodless) return std::nullopt;
    const std::optional<RepeatZone> zone = field.repeatZone();
    if (!zone) return std::nullopt;
    for (int a = 0; a < 3; ++a) {
        const double p = zone->period[a];
        const double o = zone->phase[a] + p * std::ceil((zone->box.min[a] - zone->phase[a]) / p - 1e-9);
        if (o + p > zone->box.max[a] + 1e-9 * p) return zone;
    }
    return std::nullopt;
}

PropertiesResult computeProperties(const FieldNode& field, const Recipe& recipe, const Vec3d& domainMin,
                                   const JobContext* context, const CellDensityTarget* target)
{
    const PropertiesSettings& settings = recipe.properties;
    if (!recipe.material)
        throw InputError(settings.where +
                         ": properties need the material the part is made of: add `material: form2` (or ti6al4v, "
                         "316l, 17-4ph, pa12) or `material: {E: 1.6 GPa, nu: 0.38}` at the top of the recipe");
    const Material& material = *recipe.material;

    // The cell: given, one period of the result along each axis, or a cell of a frame's
    // repeating interior (a finite frame of identical cells has no period, yet repeats there).
    Vec3d size;
    std::optional<Vec3d> zoneOrigin;
    const auto periodless = [&] {
        for (int a = 0; a < 3; ++a)
            if (field.period(a) == FieldNode::kNoPeriod) return a;
        return -1;
    };
    if (settings.cell) {
        size = Vec3d((*settings.cell)[0], (*settings.cell)[1], (*settings.cell)[2]);
        // A cell the result does not repeat over is not a periodic cell: its moduli would be
        // of a lattice cut and glued wrong at the faces (3 mm of a 5 mm gyroid).
        for (int a = 0; a < 3; ++a) {
            const double p = field.period(a);
            if (p == FieldNode::kNoPeriod || !std::isfinite(p) || p <= 0.0) continue;
            const double cells = size[a] / p;
            if (std::abs(cells - std::round(cells)) > 1e-6 * std::max(1.0, cells) || std::round(cells) < 1.0)
                throw InputError(settings.where + ": `cell:` is " + formatNumber(size[a]) + " mm along " + kAxis[a] +
                                 ", not a whole number of the result's period there (" + formatNumber(p) +
                                 " mm): give " + formatNumber(p) + " mm or a multiple of it");
        }
    } else if (const std::optional<RepeatZone> zone = periodless() >= 0 ? field.repeatZone() : std::nullopt) {
        size = zone->period;
        Vec3d o;
        for (int a = 0; a < 3; ++a) {
            // The first whole cell (aligned with the frame's cells) inside the zone.
            const double p = zone->period[a];
            o[a] = zone->phase[a] + p * std::ceil((zone->box.min[a] - zone->phase[a]) / p - 1e-9);
            if (o[a] + p > zone->box.max[a] + 1e-9 * p)
                throw InputError(
                    settings.where + ": the result `" + recipe.result +
                    "` is a frame of identical cells, which repeat "
                    "only deeper inside its box than the struts reach (" +
                    formatNumber(zone->box.min[a] - zone->phase[a]) + " mm), and along " + kAxis[a] +
                    " no whole cell of " + formatNumber(p) +
                    " mm lies that deep, and voxlat cannot repeat this frame's cell itself (a frame of "
                    "identical cells in a box, `struts: {cell, size}`, is homogenized as its cell repeated): "
                    "make the frame longer along " +
                    kAxis[a] + ", or give the cell, e.g. `properties: {cell: [" + formatNumber(size[0]) + ", " +
                    formatNumber(size[1]) + ", " + formatNumber(size[2]) + "], origin: [x, y, z]}`");
        }
        zoneOrigin = o;
    } else {
        double longest = 0.0;
        for (int a = 0; a < 3; ++a) {
            const double p = field.period(a);
            if (p == FieldNode::kNoPeriod)
                throw InputError(settings.where + ": the result `" + recipe.result + "` does not repeat along " +
                                 kAxis[a] +
                                 " (no period is known there), so it has no periodic cell to homogenize: give one, "
                                 "e.g. `properties: {cell: [10, 10, 10]}` (mm), over which the result repeats");
            if (std::isfinite(p)) longest = std::max(longest, p);
            size[a] = p;
        }
        if (longest == 0.0)
            throw InputError(settings.where + ": the result `" + recipe.result +
                             "` is the same everywhere; give a cell, e.g. `properties: {cell: [10, 10, 10]}`");
        // An axis along which nothing changes: any length is a period; take the longest one.
        for (int a = 0; a < 3; ++a)
            if (!std::isfinite(size[a])) size[a] = longest;
    }
    const Vec3d origin = settings.origin ? Vec3d((*settings.origin)[0], (*settings.origin)[1], (*settings.origin)[2])
                                         : zoneOrigin.value_or(domainMin);
    const double longest = std::max({size[0], size[1], size[2]});

    // One voxel model of the cell and its stiffness at @a n voxels along the longest side.
    struct Solved {
        int n = 0;
        std::array<int, 3> counts{};
        double h = 0.0;
        VoxelCell cell;
        std::int64_t solid = 0;
        double shift = 0.0;
        Vec3d phase{0.0};  // how far the voxel lattice is moved off the cell's corner (mm)
        ElasticityResult elastic;
    };
    HomogenizationSettings solver;
    solver.tolerance = settings.tolerance;
    const auto voxelsAt = [&](int n) {
        double voxels = 1.0;
        for (int a = 0; a < 3; ++a) voxels *= std::max(1.0, std::round(size[a] / (longest / n)));
        return voxels;
    };
    // A cell whose sampling or solve cannot fit in memory is refused with the estimate, before
    // the allocation (`resolution: 512` ran out of memory at 6 GB).
    const double have = 0.7 * double(availableMemoryBytes());
    const auto refuseMemory = [&](int n, double need) {
        throw JobError(settings.where + ": homogenizing the cell at " + std::to_string(n) + " voxels (" +
                       formatNumber(voxelsAt(n)) + " voxels) needs about " +
                       formatNumber(std::round(need / 1048576.0)) + " MB, more than the " +
                       formatNumber(std::round(have / 1048576.0)) +
                       " MB this machine can give: lower `resolution:` (or `max_resolution:`)");
    };
    // One voxel model of the cell at n voxels along its longest side (not yet solved).
    const auto modelAt = [&](int n) {
        Solved s;
        StageProgress sampling(context, "sampling the cell at " + std::to_string(n) + " voxels", 100);
        std::uint64_t reported = 0;
        const auto sampleProgress = [&](double f) {
            const auto now = std::uint64_t(f * 100);
            if (now > reported) sampling.add(now - reported), reported = now;  // serialised by StageProgress
            return !(context && context->cancelled());
        };
        const std::function<bool(double)> cancelOnly = [&](double) { return !(context && context->cancelled()); };
        const auto at = [&](int m) {
            s.n = m;
            s.h = longest / m;
            for (int a = 0; a < 3; ++a) s.counts[a] = std::max(1, int(std::lround(size[a] / s.h)));
        };
        at(n);
        // With a density target the level is solved on this voxel model: the shift of the field's
        // values at which the voxels hold the density asked.
        if (target) {
            // The voxel lattice is moved off the cell's corner by a generic fraction of a voxel,
            // different along each axis: struts along the voxel lattice's axes or diagonals (a grid
            // or an X cell) would otherwise put whole rows of voxels, and their mirror images, at
            // one distance, and the voxel model's density would jump by percents between levels
            // (a capsule X cell at 40 voxels: 0.094, then above 0.1). Moved, only rows along a
            // strut stay together, and the models at successive resolutions sample the struts
            // alike (E converges smoothly instead of jumping with the alignment). Where a row
            // is still too large a step (few voxels), the resolution is raised until the density
            // is met.
            for (int m = n;; ++m) {
                at(m);
                for (int a = 0; a < 3; ++a) s.phase[a] = kVoxelPhase[a] * size[a] / s.counts[a];
                const std::vector<double> values =
                    sampleCellValues(field, origin + s.phase, size, s.counts,
                                     m == n ? std::function<bool(double)>(sampleProgress) : cancelOnly);
                s.shift = cellLevelShift(values, target->density);
                s.cell = cellAtShift(values, size, s.counts, s.shift);
                if (std::abs(solidFraction(s.cell) / target->density - 1.0) <= kCellDensityTolerance ||
                    m >= std::min(512, 2 * n))
                    break;
            }
        } else {
            s.cell = sampleCell(field, origin, size, s.counts, sampleProgress);
        }
        sampling.finish();
        return s;
    };
    // Before sampling: the sampling's memory, and the solve's as if every grid point were a node;
    // when that does not fit, the solve's with the node share of a coarse model.
    const auto checkMemory = [&](int n) {
        const double voxels = voxelsAt(n), sampling = (target ? kSamplingBytesPerVoxel : 1.0) * voxels;
        if (sampling > have) refuseMemory(n, sampling);
        if (homogenizationBytes(voxels, voxels) <= have || n <= kMemoryProbe) return;
        const Solved probe = modelAt(kMemoryProbe);
        const double share = double(cellNodes(probe.cell)) / double(probe.cell.solid.size());
        if (const double need = homogenizationBytes(voxels, share * voxels); need > have) refuseMemory(n, need);
    };
    const auto solveAt = [&](int n) {
        checkMemory(n);
        Solved s = modelAt(n);
        // After sampling, the solve's own estimate from the cell's nodes.
        if (const double need = homogenizationBytes(s.cell); need > have) refuseMemory(s.n, need);
        for (std::uint8_t v : s.cell.solid) s.solid += v;
        if (s.solid == 0) return s;
        StageProgress solving(context, "homogenizing at " + std::to_string(s.n) + " voxels", 1000);
        std::uint64_t solved = 0;
        solver.progress = [&](double f) {
            const auto now = std::uint64_t(std::clamp(f, 0.0, 1.0) * 1000);
            if (now > solved) solving.add(now - solved), solved = now;
            return !(context && context->cancelled());
        };
        s.elastic = homogenizeElasticity(s.cell, {material.modulusMPa, material.poisson}, solver);
        solving.finish();
        return s;
    };
    const auto moduli = [](const Solved& s) {
        if (s.solid == 0) return std::array<double, 3>{0.0, 0.0, 0.0};
        const EngineeringConstants e = engineeringConstants(s.elastic.C);
        return std::array<double, 3>{s.elastic.percolates[0] ? e.Ex : 0.0, s.elastic.percolates[1] ? e.Ey : 0.0,
                                     s.elastic.percolates[2] ? e.Ez : 0.0};
    };

    // The resolution: given, or the first of a ladder (24 voxels, then steps of sqrt 2) at which
    // Richardson extrapolation of E over the last three resolutions says E is within the
    // tolerance of its limit.
    Solved final;
    nlohmann::json convergence;
    if (settings.resolution) {
        final = solveAt(*settings.resolution);
    } else {
        const std::vector<int> ladder = convergenceLadder(settings.maxResolution);
        if (ladder.size() < 3)
            throw InputError(settings.where + ": `max_resolution: " + std::to_string(settings.maxResolution) +
                             "` leaves fewer than three resolutions to check convergence on (" +
                             std::to_string(kConvergenceStart) + ", 34, 48): raise it, or give `resolution:`");
        std::vector<int> used;
        std::vector<std::array<double, 3>> E;
        ConvergenceEstimate estimate;
        for (int n : ladder) {
            final = solveAt(n);
            used.push_back(final.n);  // raised from n when the density asked needs it
            E.push_back(moduli(final));
            if (E.size() < 3) continue;
            // An estimate from a last step much smaller than the one before (faster than second
            // order) needs the next to confirm it: such a step can have happened to be small (the
            // voxel model's jitter; the Gaussian X cell at rho 0.1 moved 0.4 % from 48 to 68
            // voxels, then 1.9 % to 96).
            const double before = estimate.error;
            estimate = richardson(used, E);
            if (estimate.error <= settings.convergence && (estimate.steady || before <= settings.convergence)) break;
        }
        nlohmann::json rows = nlohmann::json::array();
        for (const auto& e : E) rows.push_back({e[0], e[1], e[2]});
        convergence = {
            {"resolutions", used},
            {"E_MPa", rows},
            {"estimated_error", estimate.error},
            {"extrapolated_E_MPa", {estimate.limit[0], estimate.limit[1], estimate.limit[2]}},
            {"order", {estimate.order[0], estimate.order[1], estimate.order[2]}},
            {"tolerance", settings.convergence},
            {"method",
             "Richardson extrapolation of E_x, E_y, E_z over three successive resolutions (order 0.5 to 2; faster "
             "convergence confirmed by the next)"}};
        if (estimate.error > settings.convergence && context) {
            const int a = estimate.axis;
            const std::size_t m = E.size();
            context->warn("not_converged",
                          "the cell's moduli are within an estimated " + formatNumber(100.0 * estimate.error) +
                              " % of their extrapolated values at " + std::to_string(used.back()) +
                              " voxels, more than the " + formatNumber(100.0 * settings.convergence) + " % asked: E_" +
                              kAxis[a] + " is " + formatNumber(E[m - 3][a]) + ", " + formatNumber(E[m - 2][a]) + ", " +
                              formatNumber(E[m - 1][a]) + " MPa at " + std::to_string(used[m - 3]) + ", " +
                              std::to_string(used[m - 2]) + ", " + std::to_string(used[m - 1]) +
                              " voxels (extrapolated " + formatNumber(estimate.limit[a]) +
                              "); raise `properties: {max_resolution: N}` (now " +
                              std::to_string(settings.maxResolution) + ") or give `resolution:`",
                          {{"estimated_error", estimate.error}, {"resolutions", used}});
        }
    }
    const VoxelCell& cell = final.cell;
    const std::array<int, 3>& counts = final.counts;
    const double h = final.h;
    const double shift = final.shift;
    const Vec3d phase = final.phase;
    const std::int64_t solid = final.solid;
    if (solid == 0)
        throw JobError(settings.where + ": the cell [" + formatNumber(size[0]) + ", " + formatNumber(size[1]) + ", " +
                       formatNumber(size[2]) + "] mm at " + formatNumber(origin[0]) + ", " + formatNumber(origin[1]) +
                       ", " + formatNumber(origin[2]) + " holds no solid voxel (" + std::to_string(counts[0]) + " x " +
                       std::to_string(counts[1]) + " x " + std::to_string(counts[2]) +
                       "): raise the density or move the cell (`properties: {origin: ...}`)");
    const double cellDensity = double(solid) / double(cell.solid.size());
    if (target && context) {
        if (settings.resolution && final.n != *settings.resolution)
            context->warn("resolution_raised",
                          "the cell is homogenized at " + std::to_string(final.n) + " voxels instead of " +
                              std::to_string(*settings.resolution) + ": at " + std::to_string(*settings.resolution) +
                              " no level gives the density asked (" + formatNumber(target->density) +
                              ") within 0.5 % on the voxels",
                          {{"resolution", final.n}, {"asked", *settings.resolution}});
        if (std::abs(cellDensity / target->density - 1.0) > kCellDensityTolerance)
            context->warn("cell_density",
                          "the cell's voxel model holds " + formatNumber(cellDensity) + ", not the density asked (" +
                              formatNumber(target->density) + ") within 0.5 %, even at " + std::to_string(final.n) +
                              " voxels: give a finer `resolution:`",
                          {{"relative_density", cellDensity}, {"target", target->density}});
    }
    const ElasticityResult& elastic = final.elastic;
    if (!elastic.percolates[0] && !elastic.percolates[1] && !elastic.percolates[2])
        throw JobError(settings.where + ": the cell falls apart: no piece of it connects to its neighbour cell along " +
                       "x, y or z (" + std::to_string(elastic.islandsRemoved) + " loose pieces, " +
                       formatNumber(100.0 * double(elastic.islandVoxelsRemoved) / double(solid)) +
                       " % of the solid), so it carries no load: raise the density or the strut radius, or use a "
                       "finer voxel (`properties: {resolution: N}`)");
    solver.progress = {};
    const ConductivityResult thermal =
        settings.conductivity ? homogenizeConductivity(cell, 1.0, solver) : ConductivityResult{};
    // A load case that stopped above its tolerance (the iteration cap, or a solve that diverged)
    // gives moduli that are not the cell's: exit 3 with the numbers, never a report at exit 0.
    auto refuseUnconverged = [&](const char* what, const auto& residuals, const auto& iterations) {
        for (std::size_t k = 0; k < residuals.size(); ++k)
            if (!(residuals[k] <= 10.0 * settings.tolerance))
                throw JobError(settings.where + ": the " + what + " solve of load case " + std::to_string(k + 1) +
                               " stopped after " + std::to_string(iterations[k]) +
                               " iterations at a relative residual of " + formatNumber(residuals[k]) +
                               ", above its tolerance " + formatNumber(settings.tolerance) +
                               " (not converged): use the default `tolerance: 1e-6` or a coarser `resolution:`");
    };
    refuseUnconverged("elastic", elastic.residual, elastic.iterations);
    if (settings.conductivity) refuseUnconverged("conductivity", thermal.residual, thermal.iterations);
    for (const auto& row : elastic.C)
        for (const double v : row)
            if (!std::isfinite(v))
                throw JobError(settings.where +
                               ": the stiffness of the cell is not a finite number (the solve broke "
                               "down): check `material:` and the cell");
    const EngineeringConstants c = engineeringConstants(elastic.C);

    PropertiesResult result;
    result.stiffnessMPa = elastic.C;
    result.relativeDensity = cellDensity;
    const double Es = material.modulusMPa;
    nlohmann::json nu = matrixJson(c.nu);
    nlohmann::json& r = result.report;
    r["relative_density"] = cellDensity;
    if (target) {
        // Below and Band: value = indicator - level, so the shift adds to the level; Above subtracts.
        const double level = target->side == SolidSide::Above ? target->level - shift : target->level + shift;
        r["relative_density_target"] = target->density;
        r["level"] = target->recipeLevel ? target->recipeLevel(level) : level;
    }
    if (elastic.islandVoxelsRemoved > 0) r["load_bearing_relative_density"] = elastic.relativeDensity;
    r["C_MPa"] = matrixJson(elastic.C);
    r["S_per_MPa"] = matrixJson(c.S);
    r["E_MPa"] = {c.Ex, c.Ey, c.Ez};
    r["G_MPa"] = {c.Gyz, c.Gxz, c.Gxy};
    r["nu"] = nu;
    r["E_ratio"] = {c.Ex / Es, c.Ey / Es, c.Ez / Es};
    r["bulk_modulus_MPa"] = c.bulkModulus;
    const bool cubic = std::abs(size[0] - size[1]) <= 1e-9 * longest && std::abs(size[0] - size[2]) <= 1e-9 * longest;
    if (cubic) r["zener_ratio"] = c.zenerRatio;
    r["iterations"] = elastic.iterations;
    r["residual"] = elastic.residual;
    r["islands_removed"] = elastic.islandsRemoved;
    r["island_voxels_removed"] = elastic.islandVoxelsRemoved;
    r["percolates"] = {elastic.percolates[0], elastic.percolates[1], elastic.percolates[2]};
    if (settings.conductivity) {
        r["conductivity"] = {
            {"K_ratio", matrixJson(thermal.K)}, {"iterations", thermal.iterations}, {"residual", thermal.residual}};
        if (material.conductivity) r["conductivity"]["K_W_per_mK"] = matrixJson(thermal.K, *material.conductivity);
    }
    r["material"] = {{"name", material.name}, {"E_MPa", Es}, {"nu", material.poisson}, {"source", material.source}};
    if (material.conductivity) r["material"]["k_W_per_mK"] = *material.conductivity;
    // The cell's corner is where its voxel lattice starts (moved off a symmetric corner, the same
    // periodic lattice): `properties: {origin}` with it and `level:` give this voxel model again.
    if (target) r["cell"]["voxel_offset_mm"] = {phase[0], phase[1], phase[2]};
    const Vec3d corner = origin + phase;
    r["cell"].update({{"origin", {corner[0], corner[1], corner[2]}},
                      {"size", {size[0], size[1], size[2]}},
                      {"voxels", counts},
                      {"voxel_mm", h},
                      {"from", settings.cell ? "properties: cell"
                               : zoneOrigin  ? "the frame's repeating interior"
                                             : "the result's periods"}});
    if (!convergence.is_null()) r["convergence"] = convergence;
    r["solver"] = {{"method", "voxel FE homogenization (8-node hexahedra, periodic), multigrid-preconditioned CG"},
                   {"tolerance", settings.tolerance}};
    if (context) {
        for (int a = 0; a < 3; ++a)
            if (!elastic.percolates[a])
                context->warn("no_load_path",
                              std::string("the cell carries no load along ") + kAxis[a] +
                                  ": no piece connects to the next cell that way, so E_" + kAxis[a] +
                                  " = 0 (raise the density or check the cell)",
                              {{"axis", std::string(1, kAxis[a])}});
        if (elastic.islandsRemoved > 0)
            context->warn("loose_pieces",
                          std::to_string(elastic.islandsRemoved) + " piece(s) of the cell (" +
                              std::to_string(elastic.islandVoxelsRemoved) +
                              " voxels) connect to nothing and were left out of the stiffness",
                          {{"islands_removed", elastic.islandsRemoved}});
    }
    return result;
}

GibsonAshbyFit fitGibsonAshby(const std::vector<double>& density,
                              const std::vector<std::array<double, 3>>& modulusRatio)
{
    GibsonAshbyFit fit;
    for (int a = 0; a < 3; ++a) {
        double sx = 0, sy = 0, sxx = 0, sxy = 0;
        int m = 0;
        for (std::size_t k = 0; k < density.size(); ++k)
            if (density[k] > 0.0 && modulusRatio[k][a] > 0.0) {
                const double x = std::log(density[k]), y = std::log(modulusRatio[k][a]);
                sx += x, sy += y, sxx += x * x, sxy += x * y, ++m;
            }
        const double d = m * sxx - sx * sx;
        if (m < 2 || !(std::abs(d) > 0.0)) continue;
        fit.n[a] = (m * sxy - sx * sy) / d;
        fit.C[a] = std::exp((sy - fit.n[a] * sx) / m);
        for (std::size_t k = 0; k < density.size(); ++k)
            if (density[k] > 0.0 && modulusRatio[k][a] > 0.0)
                fit.maxRelativeError =
                    std::max(fit.maxRelativeError,
                             std::abs(fit.C[a] * std::pow(density[k], fit.n[a]) / modulusRatio[k][a] - 1.0));
    }
    return fit;
}

nlohmann::json densityCurvePoint(const nlohmann::json& p)
{
    nlohmann::json row{{"relative_density", p["relative_density"]},
                       {"C_MPa", p["C_MPa"]},
                       {"E_MPa", p["E_MPa"]},
                       {"G_MPa", p["G_MPa"]},
                       {"E_ratio", p["E_ratio"]},
                       {"nu", p["nu"]},
                       {"resolution", p["cell"]["voxels"]}};
    if (p.contains("relative_density_target")) row["relative_density_target"] = p["relative_density_target"];
    if (p.contains("level")) row["level"] = p["level"];
    if (p.contains("conductivity")) row["K_ratio"] = p["conductivity"]["K_ratio"];
    return row;
}

nlohmann::json densityCurve(const std::vector<nlohmann::json>& points)
{
    std::vector<double> rho;
    std::vector<std::array<double, 3>> ratio;
    nlohmann::json curve = nlohmann::json::array();
    for (const nlohmann::json& p : points) {
        curve.push_back(p);
        if (!p.contains("E_ratio")) continue;  // a point where the cell falls apart
        rho.push_back(p["relative_density"].get<double>());
        ratio.push_back({p["E_ratio"][0].get<double>(), p["E_ratio"][1].get<double>(), p["E_ratio"][2].get<double>()});
    }
    const GibsonAshbyFit fit = fitGibsonAshby(rho, ratio);
    return {{"curve", curve},
            {"gibson_ashby",
             {{"C", fit.C},
              {"n", fit.n},
              {"max_relative_error", fit.maxRelativeError},
              {"law", "E/E_s = C rho^n per axis, least squares on log E/E_s against log rho"}}}};
}

std::string abaqusMaterialCard(const nlohmann::json& p, const std::string& name, const std::string& recipe,
                               const std::string& region)
{
    // Abaqus/CalculiX order the shear components 12, 13, 23; voxlat's Voigt order is xx, yy, zz,
    // yz, xz, xy.
    constexpr int kVoigt[6] = {0, 1, 2, 5, 4, 3};  // Abaqus component 11, 22, 33, 12, 13, 23 -> voxlat index
    std::vector<double> d;
    for (int j = 0; j < 6; ++j)
        for (int i = 0; i <= j; ++i) d.push_back(p["C_MPa"][kVoigt[i]][kVoigt[j]].get<double>());
    std::string upper = name;
    for (char& c : upper) c = char(std::toupper(static_cast<unsigned char>(c)));
    std::ostringstream out;
    out << "** voxlat: homogenized elastic constants of one periodic cell of `" << recipe << "`\n";
    out << "** units: MPa (N/mm^2); use with lengths in mm and forces in N\n";
    if (!region.empty()) out << "** region: " << region << "\n";
    out << "** cell relative density " << formatNumber(p["relative_density"].get<double>()) << ", "
        << p["cell"]["voxels"][0].get<int>() << " x " << p["cell"]["voxels"][1].get<int>() << " x "
        << p["cell"]["voxels"][2].get<int>() << " voxels; solid: " << p["material"]["name"].get<std::string>() << ", E "
        << formatNumber(p["material"]["E_MPa"].get<double>()) << " MPa, nu "
        << formatNumber(p["material"]["nu"].get<double>()) << "\n";
    out << "** E_x E_y E_z " << formatNumber(p["E_MPa"][0].get<double>()) << " "
        << formatNumber(p["E_MPa"][1].get<double>()) << " " << formatNumber(p["E_MPa"][2].get<double>()) << " MPa\n";
    out << "*MATERIAL, NAME=" << upper << "\n";
    out << "*ELASTIC, TYPE=ANISO\n";
    for (std::size_t k = 0; k < d.size(); ++k) {
        char text[32];
        std::snprintf(text, sizeof text, "%.10g", d[k]);
        out << text << (k + 1 == d.size() || k % 8 == 7 ? "\n" : ", ");
    }
    return out.str();
}

std::string directionalModulusPng(const Matrix6& C, int size)
{
    // A latitude-longitude sphere whose radius is E(d) / max E.
    constexpr int kRings = 48, kSegments = 96;
    std::vector<double> modulus;
    std::vector<openvdb::Vec3d> dirs;
    for (int i = 0; i <= kRings; ++i) {
        const double theta = std::numbers::pi * i / kRings;
        for (int j = 0; j < kSegments; ++j) {
            const double phi = 2.0 * std::numbers::pi * j / kSegments;
            const openvdb::Vec3d d(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
            dirs.push_back(d);
            modulus.push_back(directionalYoungsModulus(C, {d[0], d[1], d[2]}));
        }
    }
    const double top = std::max(1e-300, *std::max_element(modulus.begin(), modulus.end()));
    TriangleMesh mesh;
    for (std::size_t k = 0; k < dirs.size(); ++k) mesh.points.push_back(openvdb::Vec3f(dirs[k] * (modulus[k] / top)));
    auto at = [](int i, int j) { return unsigned(i * kSegments + (j % kSegments)); };
    for (int i = 0; i < kRings; ++i)
        for (int j = 0; j < kSegments; ++j) {
            mesh.triangles.emplace_back(at(i, j), at(i + 1, j), at(i + 1, j + 1));
            mesh.triangles.emplace_back(at(i, j), at(i + 1, j + 1), at(i, j + 1));
        }
    return renderMeshPreview(mesh, size);
}

std::string propertiesTable(const nlohmann::json& p)
{
    std::ostringstream out;
    auto n = [](const nlohmann::json& v) { return formatNumber(v.get<double>()); };
    out << "relative density " << n(p["relative_density"]);
    if (p.contains("relative_density_target")) out << " (asked " << n(p["relative_density_target"]) << ")";
    out << "   material " << p["material"]["name"].get<std::string>() << " (E_s " << n(p["material"]["E_MPa"])
        << " MPa, nu " << n(p["material"]["nu"]) << ")\n";
    out << "E_x E_y E_z     " << n(p["E_MPa"][0]) << "  " << n(p["E_MPa"][1]) << "  " << n(p["E_MPa"][2])
        << " MPa   (E/E_s " << n(p["E_ratio"][0]) << "  " << n(p["E_ratio"][1]) << "  " << n(p["E_ratio"][2]) << ")\n";
    out << "G_yz G_xz G_xy  " << n(p["G_MPa"][0]) << "  " << n(p["G_MPa"][1]) << "  " << n(p["G_MPa"][2]) << " MPa\n";
    out << "nu_xy nu_xz nu_yz " << n(p["nu"][0][1]) << "  " << n(p["nu"][0][2]) << "  " << n(p["nu"][1][2])
        << "   bulk " << n(p["bulk_modulus_MPa"]) << " MPa";
    if (p.contains("zener_ratio")) out << "   Zener " << n(p["zener_ratio"]);
    out << "\nC (MPa, Voigt xx yy zz yz xz xy):\n";
    for (const auto& row : p["C_MPa"]) {
        out << " ";
        for (const auto& v : row) {
            char buf[32];
            std::snprintf(buf, sizeof buf, " %11.4g", v.get<double>());
            out << buf;
        }
        out << "\n";
    }
    out << "K/k_s (conductivity) " << n(p["conductivity"]["K_ratio"][0][0]) << "  "
        << n(p["conductivity"]["K_ratio"][1][1]) << "  " << n(p["conductivity"]["K_ratio"][2][2]) << "\n";
    int iterations = 0;
    double residual = 0;
    for (std::size_t k = 0; k < 6; ++k) {
        iterations = std::max(iterations, p["iterations"][k].get<int>());
        residual = std::max(residual, p["residual"][k].get<double>());
    }
    if (p.contains("convergence")) {
        const nlohmann::json& c = p["convergence"];
        out << "resolution " << c["resolutions"].back().get<int>() << " voxels, chosen by convergence: E_x E_y E_z";
        for (std::size_t k = 0; k < c["resolutions"].size(); ++k)
            out << (k ? ";" : "") << " " << c["resolutions"][k].get<int>() << ": " << n(c["E_MPa"][k][0]) << " "
                << n(c["E_MPa"][k][1]) << " " << n(c["E_MPa"][k][2]);
        out << " MPa; estimated error " << formatNumber(100.0 * c["estimated_error"].get<double>()) << " %\n";
    }
    out << "solver: at most " << iterations << " iterations per load case, residual <= " << formatNumber(residual)
        << "; " << p["islands_removed"].get<int>() << " loose pieces left out\n";
    return out.str();
}

}  // namespace voxlat
