// The `voxlat` command line: run, mesh, info and sample a recipe.
#include "engine/core/Errors.h"
#include "engine/core/Format.h"
#include "engine/core/Version.h"
#include "engine/jobs/DataFolder.h"
#include "engine/jobs/Job.h"
#include "engine/jobs/OutputPaths.h"
#include "engine/jobs/PrinterProfile.h"
#include "engine/jobs/PropertiesJob.h"
#include "engine/recipe/MeshSettings.h"
#include "engine/recipe/RecipeParams.h"
#include "engine/recipe/Schema.h"
#include "engine/recipe/SliceSettings.h"
#include "fields/core/HugePageAdvice.h"
#include "mesher/writers/AtomicFile.h"
#include "tools/HugePages.h"
#include "tools/TerminalProgress.h"

#include <malloc.h>
#include <tbb/global_control.h>
#include <unistd.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <limits>
#include <memory>
#include <sstream>

namespace {

struct Common {
    std::string recipe;
    std::vector<std::string> sets;
};

void addCommon(CLI::App* cmd, Common& c)
{
    cmd->add_option("recipe", c.recipe, "recipe file (YAML)")->required();
    cmd->add_option("--set", c.sets,
                    "override a recipe key, e.g. --set voxel=0.2 or --set fields.lattice.density=0.25");
}

/// The job of this run, held outside the command's scope: a cancelled run then ends by
/// exitSkippingTeardown() without freeing its grids and meshes piece by piece while the exception
/// unwinds (0.3 s and more of a projected mesh's cancel went there). Temporary files are not the
/// job's: they are removed as the stages unwind, before this is reached.
std::unique_ptr<voxlat::Job>& runJob()
{
    static std::unique_ptr<voxlat::Job> job;
    return job;
}

/// A new job for this run (the one before it, if any, is freed).
voxlat::Job& newJob(voxlat::Recipe recipe, voxlat::JobContext* context)
{
    runJob().reset();
    runJob() = std::make_unique<voxlat::Job>(std::move(recipe), context);
    return *runJob();
}

/// A report value as the terminal shows it: numbers to six significant digits (report.json keeps
/// every digit), arrays as [a, b, c].
std::string shown(const nlohmann::json& v)
{
    if (v.is_number_float()) return voxlat::formatNumber(v.get<double>());
    if (v.is_string()) return v.get<std::string>();
    if (v.is_array()) {
        std::string out = "[";
        for (std::size_t i = 0; i < v.size(); ++i) out += (i ? ", " : "") + shown(v[i]);
        return out + "]";
    }
    return v.dump();
}

void printSummary(voxlat::Job& job)
{
    const auto r = job.report();
    const auto& d = r["domain"];
    std::cout << "domain  " << shown(d["min"]) << " .. " << shown(d["max"]) << " mm, voxel " << shown(d["voxel"])
              << " mm, " << shown(d["dims"]) << " = " << shown(d["voxels"]) << " voxels\n";
    if (r.contains("fields"))
        for (const auto& [name, f] : r["fields"].items()) {
            // Only the values the report has: a graded lattice has a level per point, not one.
            std::vector<std::string> parts;
            auto text = [](const nlohmann::json& v) { return v.is_string() ? v.get<std::string>() : v.dump(); };
            if (f.contains("level"))
                parts.push_back("level " + text(f["level"]) +
                                (f.contains("level_radius_mm")
                                     ? " (isolated strut radius " + shown(f["level_radius_mm"]) + " mm)"
                                 : f.contains("level_above_strut_peak") ? " (above an isolated strut's peak)"
                                                                        : ""));
            if (f.contains("achieved_density"))
                // Six digits, as the warnings: the coverage sums' last bits are noise to a reader.
                parts.push_back("density " + shown(f["achieved_density"]) +
                                (f.contains("target_density") ? " (target " + shown(f["target_density"]) + ")" : ""));
            else if (f.contains("target_density"))
                parts.push_back("density " + shown(f["target_density"]));
            std::cout << "field   " << name << " (" << f["type"].get<std::string>() << ")";
            for (std::size_t i = 0; i < parts.size(); ++i) std::cout << (i ? ", " : ": ") << parts[i];
            std::cout << "\n";
        }
    if (r.contains("result") && r["result"].contains("estimated"))
        std::cout << "result  " << r["result"]["field"].get<std::string>() << ": volume fraction ~"
                  << shown(r["result"]["volume_fraction"]) << " of the domain, ~" << shown(r["result"]["volume_mm3"])
                  << " mm3 +- " << shown(2.0 * r["result"]["estimated"]["standard_error_mm3"].get<double>())
                  << " (an estimate, not a bound: " << shown(r["result"]["estimated"]["points"])
                  << " random points, one in each cell of a grid over the domain; +- two standard errors; "
                     "--exact counts every voxel)\n";
    else if (r.contains("result"))
        std::cout << "result  " << r["result"]["field"].get<std::string>() << ": volume fraction "
                  << shown(r["result"]["volume_fraction"]) << " of the domain, " << shown(r["result"]["volume_mm3"])
                  << " mm3\n";
    if (r.contains("mesh")) {
        std::cout << "mesh    " << shown(r["mesh"]["triangles"]) << " triangles, " << shown(r["mesh"]["vertices"])
                  << " vertices";
        if (r["mesh"].contains("deviation"))
            std::cout << ", within " << shown(r["mesh"]["deviation"]["max_mm"]) << " mm of the surface (rms "
                      << shown(r["mesh"]["deviation"]["rms_mm"]) << " mm)";
        std::cout << "\n";
    }
}

int sample(voxlat::Job& job, const std::string& fieldName, bool gradient)
{
    const voxlat::FieldPtr field = job.field(fieldName.empty() ? job.recipe().result : fieldName);
    std::string line;
    std::size_t lineNo = 0;
    while (std::getline(std::cin, line)) {
        ++lineNo;
        if (line.find_first_not_of(" \t\r") == std::string::npos || line[0] == '#') continue;
        std::istringstream in(line);
        voxlat::Vec3d p;
        if (!(in >> p[0] >> p[1] >> p[2]))
            throw voxlat::InputError("stdin:" + std::to_string(lineNo) + ": expected `x y z`, got `" + line + "`");
        if (gradient) {
            const auto [v, g] = field->valueAndGradient(p);
            std::printf("%.9g %.9g %.9g %.9g\n", v, g[0], g[1], g[2]);
        } else {
            std::printf("%.9g\n", field->value(p));
        }
    }
    return 0;
}

/// ", chosen by convergence, estimated error E %" when a search's resolution was chosen so.
std::string resolutionNote(const nlohmann::json& search)
{
    if (!search.contains("estimated_error")) return {};
    return ", chosen by convergence, estimated error " +
           voxlat::formatNumber(100.0 * search["estimated_error"].get<double>()) + " %";
}

/// What `stiffness:` and `optimize:` chose, one line per field (empty without them).
std::string designSummary(const nlohmann::json& report)
{
    if (!report.contains("design")) return {};
    std::ostringstream out;
    auto n = [](const nlohmann::json& v) { return voxlat::formatNumber(v.get<double>()); };
    for (const auto& [name, d] : report["design"].items()) {
        if (d.contains("optimize")) {
            const auto& o = d["optimize"];
            out << "optimize " << name << ": sigma " << n(o["sigma"]) << " mm (the stiffest E_"
                << o["axis"].get<std::string>() << " " << n(o["E_MPa"]) << " MPa at density " << n(o["density"]) << ", "
                << o["trials"].size() << " trials at " << o["resolution"].get<int>() << " voxels" << resolutionNote(o)
                << ")";
            if (o.contains("capsule_E_MPa"))
                out << "; capsule joints " << n(o["capsule_E_MPa"]) << " MPa"
                    << (o["ratio_to_capsule"].is_null() ? "" : ", ratio " + n(o["ratio_to_capsule"]));
            out << "\n";
        }
        if (d.contains("stiffness")) {
            const auto& s = d["stiffness"];
            out << "stiffness " << name << ": density " << n(s["density"]) << " gives E_"
                << s["axis"].get<std::string>() << " " << n(s["achieved_E_MPa"]) << " MPa (target "
                << n(s["target_E_MPa"]) << "; trials at " << s["resolution"].get<int>() << " voxels"
                << resolutionNote(s) << ")\n";
        }
    }
    return out.str();
}

/// `voxlat properties --curve density=FROM:TO:COUNT`: the cell at each density of the result's
/// lattice, and the Gibson–Ashby fit.
int propertiesCurve(const Common& args, const std::string& jsonFile, const std::string& curve,
                    voxlat::JobContext& context)
{
    const auto eq = curve.find('=');
    double from = 0, to = 0;
    int count = 0;
    char c1 = 0, c2 = 0;
    std::istringstream range(eq == std::string::npos ? "" : curve.substr(eq + 1));
    if (eq == std::string::npos || curve.substr(0, eq) != "density" || !(range >> from >> c1 >> to >> c2 >> count) ||
        c1 != ':' || c2 != ':' || count < 2 || count > 100 || !(from > 0.0 && to < 1.0 && from < to))
        throw voxlat::InputError("--curve " + curve +
                                 ": expected density=FROM:TO:COUNT with 0 < FROM < TO < 1 and COUNT from 2 to 100, "
                                 "e.g. density=0.05:0.4:8");
    const voxlat::Recipe base = voxlat::loadRecipe(args.recipe, args.sets);
    const std::string key = "fields." + base.result + ".density";
    std::vector<nlohmann::json> points;
    std::printf("%9s %9s %12s %12s %12s %12s %10s\n", "density", "cell", "E_x MPa", "E_y MPa", "E_z MPa", "G_yz MPa",
                "K_zz/k_s");
    for (int k = 0; k < count; ++k) {
        const double value = from + (to - from) * k / (count - 1);
        std::vector<std::string> sets = args.sets;
        char text[64];
        std::snprintf(text, sizeof text, "%.10g", value);
        sets.push_back(key + "=" + text);
        voxlat::Job& job = newJob(voxlat::loadRecipe(args.recipe, sets), &context);
        try {
            const nlohmann::json point = voxlat::densityCurvePoint(job.properties());
            std::printf("%9s %9.5f %12.5g %12.5g %12.5g %12.5g %10.5g\n", text, point["relative_density"].get<double>(),
                        point["E_MPa"][0].get<double>(), point["E_MPa"][1].get<double>(),
                        point["E_MPa"][2].get<double>(), point["G_MPa"][0].get<double>(),
                        point.contains("K_ratio") ? point["K_ratio"][2][2].get<double>() : 0.0);
            points.push_back(point);
        } catch (const voxlat::JobError& e) {
            std::printf("%9s   (falls apart: no stiffness)\n", text);
            points.push_back({{"relative_density_target", value}, {"error", e.what()}});
        }
        std::fflush(stdout);
    }
    const nlohmann::json result = voxlat::densityCurve(points);
    const auto& g = result["gibson_ashby"];
    std::printf(
        "Gibson-Ashby E/E_s = C rho^n:  C %.4g %.4g %.4g   n %.4f %.4f %.4f   (x y z; largest misfit %.2f %%)\n",
        g["C"][0].get<double>(), g["C"][1].get<double>(), g["C"][2].get<double>(), g["n"][0].get<double>(),
        g["n"][1].get<double>(), g["n"][2].get<double>(), 100.0 * g["max_relative_error"].get<double>());
    if (!jsonFile.empty()) {
        context.checkCancelled();
        voxlat::AtomicFile file(jsonFile);
        file.stream() << result.dump(2) << "\n";
        file.commit();
    }
    return 0;
}

/// `voxlat properties`: one homogenization, or a sweep of one key.
int properties(const Common& args, const std::string& jsonFile, const std::string& pngFile, const std::string& sweep,
               voxlat::JobContext& context)
{
    auto writeFile = [&](const std::string& path, const std::string& bytes) {
        context.checkCancelled();
        voxlat::AtomicFile file(path);
        file.stream() << bytes;
        file.commit();
    };
    if (sweep.empty()) {
        voxlat::Job& job = newJob(voxlat::loadRecipe(args.recipe, args.sets), &context);
        const nlohmann::json p = job.properties();
        std::cout << designSummary(job.report()) << voxlat::propertiesTable(p);
        if (!jsonFile.empty()) writeFile(jsonFile, p.dump(2) + "\n");
        if (!pngFile.empty()) {
            voxlat::Matrix6 C{};
            for (int i = 0; i < 6; ++i)
                for (int j = 0; j < 6; ++j) C[i][j] = p["C_MPa"][i][j].get<double>();
            writeFile(pngFile, voxlat::directionalModulusPng(C));
        }
        return 0;
    }
    // KEY=FROM:TO:COUNT
    const auto eq = sweep.find('=');
    double from = 0, to = 0;
    int count = 0;
    char c1 = 0, c2 = 0;
    std::istringstream range(eq == std::string::npos ? "" : sweep.substr(eq + 1));
    if (eq == std::string::npos || !(range >> from >> c1 >> to >> c2 >> count) || c1 != ':' || c2 != ':' || count < 1 ||
        count > 100)
        throw voxlat::InputError("--sweep " + sweep +
                                 ": expected KEY=FROM:TO:COUNT (COUNT from 1 to 100), e.g. "
                                 "fields.lattice.kernel.gaussian.sigma=0.4:1.6:7");
    const std::string key = sweep.substr(0, eq);
    nlohmann::json rows = nlohmann::json::array();
    std::printf("%-12s %9s %12s %12s %12s %10s\n", "value", "density", "E_x MPa", "E_y MPa", "E_z MPa", "E_z/E_s");
    for (int k = 0; k < count; ++k) {
        const double value = count == 1 ? from : from + (to - from) * k / (count - 1);
        std::vector<std::string> sets = args.sets;
        char text[64];
        std::snprintf(text, sizeof text, "%.10g", value);
        sets.push_back(key + "=" + text);
        voxlat::Job& job = newJob(voxlat::loadRecipe(args.recipe, sets), &context);
        nlohmann::json p;
        try {
            p = job.properties();
        } catch (const voxlat::JobError& e) {
            // A point where the cell falls apart (or is empty) has no stiffness: a row of zeros,
            // not the end of the sweep (the seed's Table 2 has such a point).
            std::printf("%-12s %9s %12g %12g %12g %10g   (falls apart)\n", text, "-", 0.0, 0.0, 0.0, 0.0);
            std::fflush(stdout);
            rows.push_back({{"value", value}, {"E_MPa", {0.0, 0.0, 0.0}}, {"error", e.what()}});
            continue;
        }
        std::printf("%-12s %9.4f %12.5g %12.5g %12.5g %10.5f\n", text, p["relative_density"].get<double>(),
                    p["E_MPa"][0].get<double>(), p["E_MPa"][1].get<double>(), p["E_MPa"][2].get<double>(),
                    p["E_ratio"][2].get<double>());
        std::fflush(stdout);
        rows.push_back({{"value", value}, {"properties", p}});
    }
    if (!jsonFile.empty()) writeFile(jsonFile, nlohmann::json{{"key", key}, {"sweep", rows}}.dump(2) + "\n");
    return 0;
}

/// The shortest text that reads back as @a value (a --layer of 0.0000004 stays that, not
/// std::to_string's "0.000000").
std::string exactText(double value)
{
    char text[64];
    for (int digits = 1; digits <= 17; ++digits) {
        std::snprintf(text, sizeof text, "%.*g", digits, value);
        if (std::strtod(text, nullptr) == value) break;
    }
    return text;
}

/// A file a command writes (`--json`, `--png`, `-o`), checked before any work like every
/// output: a regular file or nothing there, and the extension its content has.
void checkWritable(const std::string& file, const std::string& option, const std::string& extension)
{
    if (file.empty()) return;
    voxlat::checkReplaceable(file, option + " " + file);
    if (!extension.empty() && std::filesystem::path(file).extension() != extension)
        throw voxlat::InputError(option + " " + file + ": the file is " + extension.substr(1) +
                                 "; give a name ending in " + extension);
    const std::filesystem::path folder = std::filesystem::path(file).parent_path();
    std::error_code ec;
    if (!folder.empty() && !std::filesystem::is_directory(folder, ec))
        throw voxlat::InputError(option + " " + file + ": the folder `" + folder.string() +
                                 "` does not exist; create it first");
}

/// Runs this program again with huge pages asked for (voxlat::requestHugePages()), unless it
/// already is: the `voxlat` launcher asks before it starts this program, so this is for the
/// engine run directly. If exec fails the run goes on as it is, the environment as it was.
void useHugePages(char** argv)
{
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
    return;  // the sanitizer's allocator replaces glibc's: nothing to ask for
#endif
    std::string previous;
    bool hadPrevious = false;
    if (!voxlat::requestHugePages(previous, hadPrevious)) return;
    ::execv("/proc/self/exe", argv);
    voxlat::restoreTunables(previous, hadPrevious);
}

/// Ends a run whose outputs are all written and committed without destroying the job: freeing
/// a grid of a hundred thousand leaves and the rest piece by piece took ~40 ms of the acceptance
/// gyroid's 1.4 s, and the system takes the whole address space back at once anyway. Under a
/// sanitizer it returns, so leak checks still see the teardown.
void exitSkippingTeardown(int code)
{
#if !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)
    std::cout.flush();
    std::cerr.flush();
    std::fflush(nullptr);
    std::_Exit(code);
#else
    (void)code;
#endif
}

/// Keeps freed memory in malloc's heaps for the next block instead of giving it back to the
/// system. Why: a job allocates and frees the same large arrays stage after stage (a mesh's
/// triangles, each refinement round's tables), and every block given back came again as fresh
/// pages the kernel zeroes: on W9's tolerance run zeroing pages took a fifth of the CPU time and
/// the system time fell from 0.6-0.9 s to 0.1-0.3 s without it (wall 1.9 s to 1.5 s), the peak
/// memory the same. Blocks up to 32 MB (glibc's most) come from the heaps; the heaps grow 64 MB
/// at a time instead of page by page.
void keepFreedMemory()
{
    ::mallopt(M_TRIM_THRESHOLD, 1 << 30);
    ::mallopt(M_MMAP_THRESHOLD, 32 << 20);
    ::mallopt(M_TOP_PAD, 64 << 20);
}

}  // namespace

int main(int argc, char** argv)
{
    useHugePages(argv);
    // The engine's own mapped blocks follow malloc: huge pages where they were asked for, none
    // where refused (VOXLAT_NO_HUGEPAGES, the caller's hugetlb=0, a sanitizer's allocator).
    voxlat::setHugePageAdvice(voxlat::mallocOnHugePages());
    keepFreedMemory();
    // An installed copy reads its profiles and examples from <prefix>/share/voxlat, never from a
    // source tree.
    if (const std::string data = voxlat::installedDataFolder("/proc/self/exe"); !data.empty())
        voxlat::setDataFolder(data);
    CLI::App app{"voxlat: implicit lattices on sparse voxel grids"};
    app.require_subcommand(1);
    int threads = 0;
    bool quiet = false;
    // Global options are accepted before or after the subcommand (`voxlat run r.yaml --threads 2 -q`).
    app.fallthrough();
    app.add_option("--threads", threads, "worker threads (default: all cores)")->check(CLI::NonNegativeNumber);
    app.add_flag("-q,--quiet", quiet, "no progress bars");
    app.set_version_flag("--version", "voxlat " + voxlat::versionString());

    Common runArgs, meshArgs, infoArgs, sampleArgs;
    std::string outDir = ".", meshFile, sampleField;
    bool sampleGradient = false;
    bool infoExact = false;

    auto* run = app.add_subcommand("run", "run a recipe: write its outputs, report.json and report.html");
    addCommon(run, runArgs);
    run->add_option("--out", outDir, "output folder (default: current folder)");
    bool noPreview = false;
    run->add_flag("--no-preview", noPreview, "do not render NAME.preview.png next to the first mesh");
    bool noHtml = false;
    run->add_flag("--no-html", noHtml, "do not write report.html (the run's page: 3D view, layers, findings)");
    auto* mesh = app.add_subcommand("mesh", "mesh a recipe's result to one file (.stl, .3mf, .ply, .obj)");
    addCommon(mesh, meshArgs);
    mesh->add_option("-o,--output", meshFile, "mesh file")->required();
    double meshTolerance = 0.0;
    std::string meshProject;
    mesh->add_option("--tolerance", meshTolerance,
                     "decimate while every point of the mesh stays within this of the true surface (mm); "
                     "default: the recipe's first mesh output's");
    mesh->add_option("--project", meshProject,
                     "on: vertices moved onto the true surface (the default with a tolerance); off: marching "
                     "cubes' vertices");
    std::string meshRefine;
    mesh->add_option("--refine", meshRefine,
                     "with a tolerance: on, a coarse grid refined where it strays (the default); off, a grid fine "
                     "enough for the tolerance, decimated (slower, fewer triangles)");
    std::string meshStrict;
    mesh->add_option("--strict", meshStrict,
                     "with a tolerance: on, a mesh that strays beyond it fails (exit 3) instead of a warning; "
                     "default: the recipe's first mesh output's, else off");
    std::string meshExtractor;
    mesh->add_option("--extractor", meshExtractor,
                     "how the grid becomes triangles: " + voxlat::joinWords(voxlat::meshExtractorNames()) +
                         " (default: the recipe's first mesh output's, else marching-cubes)");
    auto* info = app.add_subcommand("info", "print the domain, voxel count, solved levels and density");
    addCommon(info, infoArgs);
    info->add_flag("--exact", infoExact,
                   "count the volume on the recipe's grid even when the domain has more than 2^24 voxels "
                   "(else estimated from 2^20 random points, with its standard error)");
    auto* sampleCmd = app.add_subcommand("sample", "read `x y z` lines on stdin, print the field value per line");
    addCommon(sampleCmd, sampleArgs);
    sampleCmd->add_option("--field", sampleField, "field to sample (default: the result)");
    sampleCmd->add_flag("--gradient", sampleGradient, "also print the gradient");

    auto* schemaCmd = app.add_subcommand("schema", "print the recipe language as a JSON Schema");
    bool schemaMarkdown = false;
    schemaCmd->add_flag("--markdown", schemaMarkdown, "print every key as Markdown tables instead (docs/recipes.md)");
    Common checkArgs;
    int checkRepeat = 1;
    auto* check = app.add_subcommand("check", "load and validate a recipe and build its fields, without evaluating");
    addCommon(check, checkArgs);
    check->add_option("--repeat", checkRepeat, "time this many loads and report the fastest and the median")
        ->check(CLI::PositiveNumber);
    Common sliceArgs;
    std::string slicePrinter, sliceFile, sliceAa, sliceFormat, slicePreview;
    double sliceLayer = 0.0, sliceGamma = -1.0;
    std::vector<double> slicePosition;
    // The lists in the help come from the printer and archive tables.
    const std::string formats = voxlat::joinWords(voxlat::sliceFormatNames());
    const std::string printers = voxlat::joinWords(voxlat::printerNames());
    auto* sliceCmd = app.add_subcommand("slice", "slice a recipe's result for a resin printer (" + formats + ")");
    addCommon(sliceCmd, sliceArgs);
    sliceCmd->add_option("--printer", slicePrinter, "printer profile: " + printers + " or a profile file");
    sliceCmd->add_option("-o,--output", sliceFile,
                         "archive, its format named by its extension (.ctb, .goo, .pwmx, .sl1s, ...), or folder (with "
                         "--format png|exr)");
    sliceCmd->add_option("--layer", sliceLayer, "layer height in mm (default: the recipe's, else the printer's)");
    sliceCmd->add_option("--aa", sliceAa,
                         "anti-aliasing: on (default), off (binary, pixel centre) or sub-samples per axis");
    sliceCmd->add_option("--gamma", sliceGamma, "grey = 255 * coverage^gamma; 0 = threshold at half coverage");
    sliceCmd->add_option("--position", slicePosition, "where the part's centre goes on the display, X Y in mm")
        ->expected(2);
    sliceCmd->add_option("--format", sliceFormat, "archive format: " + formats);
    sliceCmd->add_option("--preview", slicePreview, "contact-sheet PNG (default FILE.preview.png; `off` for none)");

    Common propertiesArgs;
    std::string propertiesJson, propertiesPng, propertiesSweep, propertiesCurveSpec;
    auto* propertiesCmd = app.add_subcommand(
        "properties", "effective stiffness and conductivity of one periodic cell of the result (homogenization)");
    addCommon(propertiesCmd, propertiesArgs);
    propertiesCmd->add_option("--json", propertiesJson, "write the numbers to this JSON file");
    propertiesCmd->add_option("--png", propertiesPng, "write the directional Young's modulus picture to this PNG");
    propertiesCmd->add_option("--sweep", propertiesSweep,
                              "KEY=FROM:TO:COUNT: the moduli against any --set key, e.g. "
                              "fields.lattice.kernel.gaussian.sigma=0.4:1.6:7");
    propertiesCmd->add_option("--curve", propertiesCurveSpec,
                              "density=FROM:TO:COUNT: C^H, E, G and conductivity against the result lattice's "
                              "density, with the Gibson-Ashby fit E/E_s = C rho^n, e.g. density=0.05:0.4:8");

    auto* printersCmd = app.add_subcommand("printers", "list the printer profiles: display size, pixels, format");

    // One example per subcommand, in the order above (tests/test_cli.cpp checks each is here).
    app.footer(
        "Examples:\n"
        "  voxlat run gyroid.yaml --out out             all outputs of a recipe and report.json into out/\n"
        "  voxlat mesh gyroid.yaml -o part.stl --tolerance 0.01\n"
        "                                               one mesh, within 0.01 mm of the surface\n"
        "  voxlat info gyroid.yaml --set voxel=0.1      domain, voxels, solved levels, density\n"
        "  echo '1 2 3' | voxlat sample gyroid.yaml --gradient\n"
        "                                               the field's value and gradient at points\n"
        "  voxlat schema --markdown                     the recipe language's keys\n"
        "  voxlat check gyroid.yaml                     validate a recipe without evaluating it\n"
        "  voxlat slice gyroid.yaml --printer saturn4 -o part.goo\n"
        "                                               layers for a resin printer (the extension names the "
        "format)\n"
        "  voxlat properties gyroid.yaml --json cell.json\n"
        "                                               stiffness and conductivity of one cell\n"
        "  voxlat printers                              the printer profiles --printer takes\n"
        "Shell completion for bash: tools/completion/voxlat.bash");

    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        // --help and --version print and succeed; every usage error is bad input: exit 2.
        const int code = app.exit(e);
        return code == 0 ? 0 : 2;
    }
    voxlat::JobContext context;
    voxlat::cli::attachTerminal(context, quiet);
    voxlat::cli::cancelOnSignals(context);
    std::unique_ptr<tbb::global_control> limit;
    if (threads > 0)
        limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, threads);

    try {
        openvdb::initialize();
        if (*printersCmd) {
            std::printf("%-18s %-17s %-13s %-7s %s\n", "printer", "display mm", "pixels", "format", "name");
            for (const std::string& name : voxlat::printerNames()) {
                const voxlat::PrinterProfile p = voxlat::loadPrinterProfile(name);
                const std::string mm = voxlat::formatNumber(p.widthMm) + " x " + voxlat::formatNumber(p.heightMm);
                const std::string px = std::to_string(p.pixelsX) + " x " + std::to_string(p.pixelsY);
                std::printf("%-18s %-17s %-13s %-7s %s\n", name.c_str(), mm.c_str(), px.c_str(), p.format.c_str(),
                            p.name.c_str());
            }
            std::printf("(profiles in %s; --printer also takes the path of a profile file)\n",
                        voxlat::printersFolder().c_str());
        } else if (*run) {
            voxlat::Job& job = newJob(voxlat::loadRecipe(runArgs.recipe, runArgs.sets), &context);
            job.writeOutputs(outDir, !noPreview, !noHtml);
            printSummary(job);
            std::cout << "outputs written to " << std::filesystem::absolute(outDir).lexically_normal().string()
                      << " (report.json has levels, densities and timings; open report.html to see them)\n";
            exitSkippingTeardown(0);
        } else if (*mesh) {
            checkWritable(meshFile, "-o", "");
            voxlat::Recipe recipe = voxlat::loadRecipe(meshArgs.recipe, meshArgs.sets);
            // The recipe's first mesh output says how to mesh; the options here override it.
            voxlat::MeshOptions options;
            for (const voxlat::OutputSpec& out : recipe.outputs)
                if (out.kind == "mesh") {
                    options = out.mesh->options;
                    break;
                }
            if (mesh->count("--tolerance")) {
                options.tolerance = voxlat::checkMeshTolerance(meshTolerance, "--tolerance");
                options.toleranceWhere = "--tolerance";
                options.project = true;
            }
            auto onOff = [](const std::string& option, const std::string& word) {
                if (word != "on" && word != "off")
                    throw voxlat::InputError(option + " " + word + ": expected on or off");
                return word == "on";
            };
            if (!meshProject.empty()) options.project = onOff("--project", meshProject);
            if (!meshExtractor.empty()) {
                const auto extractor = voxlat::meshExtractorFromName(meshExtractor);
                if (!extractor)
                    throw voxlat::InputError("--extractor " + meshExtractor + ": expected one of " +
                                             voxlat::joinWords(voxlat::meshExtractorNames()));
                options.extractor = *extractor;
            }
            if (!meshRefine.empty()) {
                options.refine = onOff("--refine", meshRefine);
                if (!options.tolerance)
                    throw voxlat::InputError(
                        "--refine applies to a mesh with a tolerance: add --tolerance, like "
                        "--tolerance 0.01");
                // Refinement starts from a projected marching-cubes mesh on a coarse grid.
                if (!options.project || options.extractor != voxlat::MeshExtractor::MarchingCubes)
                    throw voxlat::InputError(
                        "--refine applies to a projected marching-cubes mesh: drop --project off or --extractor bcc, "
                        "or --refine");
            }
            if (!meshStrict.empty()) {
                options.strict = onOff("--strict", meshStrict);
                if (!options.tolerance)
                    throw voxlat::InputError(
                        "--strict applies to a mesh with a tolerance: add --tolerance, like --tolerance 0.01");
            }
            voxlat::Job& job = newJob(std::move(recipe), &context);
            job.setGridReleasable(true);  // nothing after the mesh reads the grid
            job.writeMesh(meshFile, options);
            printSummary(job);
        } else if (*info) {
            voxlat::Job& job = newJob(voxlat::loadRecipe(infoArgs.recipe, infoArgs.sets), &context);
            // Above kInfoVoxels voxels the volume is estimated from kInfoVoxels / 16 random points
            // (said in the output) unless --exact asks for every voxel.
            constexpr std::uint64_t kInfoVoxels = std::uint64_t(1) << 24;
            job.measureVolume(infoExact ? std::numeric_limits<std::uint64_t>::max() : kInfoVoxels);
            printSummary(job);
        } else if (*schemaCmd) {
            if (schemaMarkdown)
                std::cout << voxlat::recipeKeysMarkdown();
            else
                std::cout << voxlat::recipeSchema().dump(2) << "\n";
        } else if (*check) {
            // Times recipe load + validation in this process: reading, includes, parameters,
            // key checks and building every field node (no evaluation).
            std::vector<double> ms;
            std::unique_ptr<voxlat::Job> job;
            for (int i = 0; i < checkRepeat; ++i) {
                const auto start = std::chrono::steady_clock::now();
                job = std::make_unique<voxlat::Job>(voxlat::loadRecipe(checkArgs.recipe, checkArgs.sets), &context);
                ms.push_back(
                    std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
            }
            std::sort(ms.begin(), ms.end());
            std::cout << "ok: " << job->recipe().fieldNames.size() << " fields, result `" << job->recipe().result
                      << "`, recipe sha256 " << voxlat::recipeHash(job->recipe()) << "\n"
                      << "load + validation: " << ms.front() << " ms fastest, " << ms[ms.size() / 2] << " ms median of "
                      << ms.size() << "\n";
        } else if (*sliceCmd) {
            // Command-line settings override the recipe's `slices:` entry (or make one).
            std::vector<std::string> sets = sliceArgs.sets;
            auto set = [&](const std::string& key, const std::string& value) {
                sets.push_back("outputs.slices." + key + "=" + value);
            };
            if (!slicePrinter.empty()) set("printer", slicePrinter);
            // -o is the user's own path (anywhere); the recipe's entry takes only its name.
            if (!sliceFile.empty()) set("file", std::filesystem::path(sliceFile).filename().string());
            // Numbers keep every digit given (the option's text, not a re-formatted double).
            if (sliceCmd->count("--layer")) set("layer", exactText(sliceLayer));
            if (!sliceAa.empty()) set("aa", sliceAa);
            if (sliceCmd->count("--gamma")) set("gamma", exactText(sliceGamma));
            if (!slicePosition.empty())
                set("position", "[" + exactText(slicePosition[0]) + ", " + exactText(slicePosition[1]) + "]");
            if (!sliceFormat.empty()) set("format", sliceFormat);
            if (!slicePreview.empty()) set("preview", slicePreview);
            voxlat::Recipe recipe = voxlat::loadRecipe(sliceArgs.recipe, sets);
            const voxlat::OutputSpec* spec = recipe.firstOutput("slices");
            if (!spec) throw voxlat::InputError(sliceArgs.recipe + ": no printer given; use --printer NAME -o FILE");
            const voxlat::SliceSettings settings = *spec->slices;
            const std::string file = sliceFile.empty() ? spec->file : sliceFile;
            voxlat::Job& job = newJob(std::move(recipe), &context);
            job.writeSlices(settings, file);
            const auto r = job.report();
            const auto& s = r["slices"].back();
            std::cout << "slices  " << s["layers"] << " layers of " << s["layer_height_mm"] << " mm for "
                      << s["printer"].get<std::string>() << " (" << s["display_pixels"][0] << " x "
                      << s["display_pixels"][1] << " px), " << s["format"].get<std::string>() << " -> " << file
                      << "\n        exposed volume " << s["exposed_volume_mm3"] << " mm3, " << s["num_slow"]
                      << " slow layers, peak memory " << r["peak_memory_mb"] << " MB\n";
            if (!s["preview"].get<std::string>().empty())
                std::cout << "preview " << s["preview"].get<std::string>() << "\n";
        } else if (*propertiesCmd) {
            // Both files are checked before any work, with the rules of every output: a regular
            // file or nothing (never a device, FIFO or symbolic link), and not one file twice.
            checkWritable(propertiesJson, "--json", ".json");
            checkWritable(propertiesPng, "--png", ".png");
            if (!propertiesJson.empty() && !propertiesPng.empty() &&
                std::filesystem::absolute(propertiesJson).lexically_normal() ==
                    std::filesystem::absolute(propertiesPng).lexically_normal())
                throw voxlat::InputError("--json and --png name one file `" + propertiesJson +
                                         "`: give each its own name");
            if (!propertiesCurveSpec.empty()) {
                if (!propertiesSweep.empty()) throw voxlat::InputError("give either --curve or --sweep, not both");
                return propertiesCurve(propertiesArgs, propertiesJson, propertiesCurveSpec, context);
            }
            return properties(propertiesArgs, propertiesJson, propertiesPng, propertiesSweep, context);
        } else if (*sampleCmd) {
            voxlat::Job& job = newJob(voxlat::loadRecipe(sampleArgs.recipe, sampleArgs.sets), &context);
            return sample(job, sampleField, sampleGradient);
        }
    } catch (const voxlat::Cancelled&) {
        // Temporary files were removed while the job unwound; nothing carries a final name.
        const int signal = voxlat::cli::receivedSignal();
        std::fprintf(stderr, "\ncancelled: no output written\n");
        exitSkippingTeardown(128 + (signal ? signal : SIGINT));  // the job is not freed piece by piece
        return 128 + (signal ? signal : SIGINT);
    } catch (const voxlat::InputError& e) {
        std::cerr << "error: " << e.what() << "\n";
        return 2;
    } catch (const voxlat::JobError& e) {
        std::cerr << "error: " << e.what() << "\n";
        return 3;
    } catch (const voxlat::OutputError& e) {
        // The disk, not the recipe: full, read-only or not ours to write.
        std::cerr << "error: " << e.what() << "\n";
        return 3;
    } catch (const std::invalid_argument& e) {
        // The fields' own checks of their inputs (a direction field zero somewhere, a bad size):
        // bad input the recipe loader could not see, found at run time.
        std::cerr << "error: " << e.what() << "\n";
        return 2;
    } catch (const std::domain_error& e) {
        std::cerr << "error: " << e.what() << "\n";
        return 2;
    } catch (const std::bad_alloc&) {
        std::cerr << "error: this machine ran out of memory for the job: raise `voxel:` or shrink the domain\n";
        return 3;
    } catch (const std::exception& e) {
        std::cerr << "error: " << e.what() << "\n";
        return 1;
    }
    return 0;
}
