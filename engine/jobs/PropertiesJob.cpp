#include "engine/jobs/PropertiesJob.h"

#include "engine/core/Errors.h"
#include "engine/core/Format.h"
#include "engine/properties/CellSample.h"
#include "mesher/extract/TriangleMesh.h"
#include "mesher/writers/MeshPreview.h"

#include <algorithm>
#include <cmath>
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

/// The largest relative difference between a cell's density and the density asked, when a level
/// is solved on the cell (issue 37: 0.5 %).
constexpr double kCellDensityTolerance = 0.005;
/// The fractions of a voxel the voxel lattice moves off a symmetric cell's corner when the
/// aligned one cannot hold the density asked: 1/(2 pi), 1/(2 e), 1/(2 sqrt 2), no two alike.
constexpr double kVoxelPhase[3] = {0.15915494309189535, 0.18393972058572117, 0.35355339059327379};

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

PropertiesResult computeProperties(const FieldNode& field, const Recipe& recipe, const Vec3d& domainMin, double voxel,
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
    const int resolution = settings.resolution ? *settings.resolution : int(std::lround(longest / voxel));
    if (resolution < 4 || resolution > 512)
        throw InputError(settings.where + ": the cell (" + formatNumber(longest) + " mm along its longest side) at " +
                         formatNumber(voxel) + " mm voxels gives " + std::to_string(resolution) +
                         " voxels per side; homogenization takes 4 to 512: set `properties: {resolution: 64}`");
    const double h = longest / resolution;
    std::array<int, 3> counts;
    for (int a = 0; a < 3; ++a) counts[a] = std::max(1, int(std::lround(size[a] / h)));

    StageProgress sampling(context, "sampling the cell", 100);
    std::uint64_t reported = 0;
    const auto sampleProgress = [&](double f) {
        const auto now = std::uint64_t(f * 100);
        if (now > reported) sampling.add(now - reported), reported = now;  // serialised by StageProgress
        return !(context && context->cancelled());
    };
    // With a density target the level is solved on this voxel model: the shift of the field's
    // values at which the voxels hold the density asked.
    double shift = 0.0;
    VoxelCell cell;
    Vec3d phase(0.0);  // how far the voxel lattice is moved off the cell's corner (mm)
    if (target) {
        std::vector<double> values = sampleCellValues(field, origin, size, counts, sampleProgress);
        shift = cellLevelShift(values, target->density);
        cell = cellAtShift(values, size, counts, shift);
        if (std::abs(solidFraction(cell) / target->density - 1.0) > kCellDensityTolerance) {
            // Struts along the voxel lattice's axes or diagonals (a grid or an X cell) put whole
            // rows of voxels, and their mirror images, at one distance: the voxel model's density
            // jumps by percents between levels. Voxel centres moved off the symmetry by a generic
            // fraction of a voxel, different along each axis, leave only rows along a strut.
            for (int a = 0; a < 3; ++a) phase[a] = kVoxelPhase[a] * size[a] / counts[a];
            values = sampleCellValues(field, origin + phase, size, counts, sampleProgress);
            shift = cellLevelShift(values, target->density);
            cell = cellAtShift(values, size, counts, shift);
        }
    } else {
        cell = sampleCell(field, origin, size, counts, sampleProgress);
    }
    sampling.finish();
    std::int64_t solid = 0;
    for (std::uint8_t v : cell.solid) solid += v;
    if (solid == 0)
        throw JobError(settings.where + ": the cell [" + formatNumber(size[0]) + ", " + formatNumber(size[1]) + ", " +
                       formatNumber(size[2]) + "] mm at " + formatNumber(origin[0]) + ", " + formatNumber(origin[1]) +
                       ", " + formatNumber(origin[2]) + " holds no solid voxel (" + std::to_string(counts[0]) + " x " +
                       std::to_string(counts[1]) + " x " + std::to_string(counts[2]) +
                       "): raise the density or move the cell (`properties: {origin: ...}`)");
    const double cellDensity = double(solid) / double(cell.solid.size());

    HomogenizationSettings solver;
    solver.tolerance = settings.tolerance;
    StageProgress solving(context, "homogenizing", 1000);
    std::uint64_t solved = 0;
    solver.progress = [&](double f) {
        const auto now = std::uint64_t(std::clamp(f, 0.0, 1.0) * 1000);
        if (now > solved) solving.add(now - solved), solved = now;
        return !(context && context->cancelled());
    };
    const ElasticityResult elastic = homogenizeElasticity(cell, {material.modulusMPa, material.poisson}, solver);
    solving.finish();
    if (!elastic.percolates[0] && !elastic.percolates[1] && !elastic.percolates[2])
        throw JobError(settings.where + ": the cell falls apart: no piece of it connects to its neighbour cell along " +
                       "x, y or z (" + std::to_string(elastic.islandsRemoved) + " loose pieces, " +
                       formatNumber(100.0 * double(elastic.islandVoxelsRemoved) / double(solid)) +
                       " % of the solid), so it carries no load: raise the density or the strut radius, or use a "
                       "finer voxel (`properties: {resolution: N}`)");
    const ConductivityResult thermal =
        settings.conductivity ? homogenizeConductivity(cell, 1.0, solver) : ConductivityResult{};
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
    out << "solver: at most " << iterations << " iterations per load case, residual <= " << formatNumber(residual)
        << "; " << p["islands_removed"].get<int>() << " loose pieces left out\n";
    return out.str();
}

}  // namespace voxlat
