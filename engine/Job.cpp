#include "engine/Job.h"

#include "engine/DensitySolver.h"
#include "engine/GridMeasure.h"
#include "engine/Progress.h"
#include "engine/SliceJob.h"
#include "engine/SparseEvaluator.h"
#include "engine/SystemInfo.h"
#include "mesher/AtomicFile.h"
#include "mesher/MarchingCubes.h"
#include "mesher/MeshWriters.h"

#include <openvdb/io/Stream.h>
#include <tbb/global_control.h>
#include <tbb/info.h>

#include <chrono>
#include <iostream>

namespace voxlat {

namespace {
Domain domainOf(const Recipe& recipe)
{
    if (!recipe.domainBox)
        throw InputError(recipe.source->path + ": no `domain:` given; add one, e.g. `domain: {box: [[0, 0, 0], [50, 50, 50]]}`");
    return Domain::fromBox(*recipe.domainBox, recipe.voxel);
}

nlohmann::json vec(const Vec3d& v) { return {v[0], v[1], v[2]}; }
}  // namespace

template <typename Fn>
auto Job::timed(const std::string& stage, Fn&& fn)
{
    const auto start = std::chrono::steady_clock::now();
    struct Record {
        nlohmann::json& timings;
        const std::string& stage;
        std::chrono::steady_clock::time_point start;
        ~Record()
        {
            timings[stage] = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        }
    } record{mTimings, stage, start};
    return fn();
}

Job::Job(Recipe recipe) : mRecipe(std::move(recipe)), mBuilder(mRecipe), mDomain(domainOf(mRecipe))
{
    timed("build fields", [&] {
        // Build every field, so a mistake anywhere in the recipe is reported before any work.
        for (const std::string& name : mRecipe.fieldNames) mBuilder.field(name);
        mResult = mBuilder.field(mRecipe.result);
        return 0;
    });
    mReport["recipe"] = mRecipe.source->path;
    mReport["domain"] = {{"min", vec(mDomain.box.min)},
                         {"max", vec(mDomain.box.max)},
                         {"voxel", mDomain.voxel},
                         {"dims", {mDomain.dims.x(), mDomain.dims.y(), mDomain.dims.z()}},
                         {"voxels", mDomain.voxelCount()}};
    if (recipe.domainBox) {
        for (int a = 0; a < 3; ++a)
            if (std::abs(mDomain.box.max[a] - mRecipe.domainBox->max[a]) > 1e-6 * mDomain.voxel)
                std::cerr << "note: the domain is snapped to a whole number of voxels: " << mDomain.box.max[a]
                          << " instead of " << mRecipe.domainBox->max[a] << " on axis " << "xyz"[a] << "\n";
    }
}

void Job::solveLevels()
{
    if (mSolved) return;
    nlohmann::json fields = nlohmann::json::object();
    for (const LevelNode& node : mBuilder.levelNodes()) {
        nlohmann::json entry{{"type", node.description}};
        if (node.density) {
            const DensitySolution s = timed("solve " + node.name, [&] {
                return solveDensity(*node.solid->indicator(),
                                    node.densityBox ? mDomain.subDomain(*node.densityBox) : mDomain, *node.density);
            });
            node.solid->setLevel(node.solid->levelFromIndicator(s.level));
            entry["target_density"] = *node.density;
            entry["achieved_density"] = s.achieved;
            entry["solve_rounds"] = s.rounds;
            entry["density_measure"] = s.coverage ? "sub-voxel coverage" : "voxel count";
            entry["evaluated_leaves"] = s.evaluatedLeaves;
        }
        entry["level"] = node.solid->level();
        fields[node.name] = entry;
    }
    mReport["fields"] = fields;
    mSolved = true;
}

FieldPtr Job::field(const std::string& name)
{
    solveLevels();
    return mBuilder.field(name);
}

const openvdb::FloatGrid& Job::grid()
{
    if (mGrid) return *mGrid;
    solveLevels();
    SparseStats stats;
    mGrid = timed("evaluate", [&] {
        SparseOptions options;
        options.clipToDomain = true;
        options.stage = "evaluating " + mRecipe.result;
        return evaluateSparse(*mResult, mDomain, options, &stats);
    });
    mGrid->setName(mRecipe.result);
    const std::uint64_t inside = countBelow(*mGrid, mDomain.indexBox(), 0.0f);
    mReport["result"] = {{"field", mRecipe.result},
                         {"volume_fraction", double(inside) / double(mDomain.voxelCount())},
                         {"volume_mm3", double(inside) * std::pow(mDomain.voxel, 3)},
                         {"evaluated_leaves", stats.leaves},
                         {"inside_tiles", stats.insideTiles}};
    return *mGrid;
}

const TriangleMesh& Job::mesh()
{
    if (mMesh) return *mMesh;
    const openvdb::FloatGrid& g = grid();
    mMesh = timed("mesh", [&] {
        Progress progress("meshing", 1000, true);
        std::atomic<std::uint64_t> last{0};
        return std::make_unique<TriangleMesh>(marchingCubes(g, 0.0f, [&](double fraction) {
            const auto now = std::uint64_t(fraction * 1000);
            const std::uint64_t before = last.exchange(now);
            if (now > before) progress.add(now - before);
        }));
    });
    mReport["mesh"] = {{"triangles", mMesh->triangles.size()},
                       {"vertices", mMesh->points.size()},
                       {"volume_mm3", mMesh->volume()},
                       {"area_mm2", mMesh->area()}};
    return *mMesh;
}

void Job::writeMesh(const std::filesystem::path& path)
{
    const TriangleMesh& m = mesh();
    timed("write " + path.filename().string(), [&] {
        voxlat::writeMesh(m, path.string());
        return 0;
    });
    mReport["outputs"].push_back(path.string());
}

void Job::writeOutputs(const std::filesystem::path& outDir)
{
    std::filesystem::create_directories(outDir);
    for (const OutputSpec& out : mRecipe.outputs) {
        const std::filesystem::path path = outDir / out.file;
        if (out.kind == "mesh") {
            writeMesh(path);
        } else if (out.kind == "vdb") {
            const openvdb::FloatGrid& g = grid();
            timed("write " + out.file, [&] {
                AtomicFile file(path.string());
                openvdb::GridCPtrVec grids{g.copyGrid()};
                openvdb::io::Stream(file.stream()).write(grids);
                file.commit();
                return 0;
            });
            mReport["outputs"].push_back(path.string());
        } else if (out.kind == "slices") {
            writeSlices(out.spec, path);
        }
    }
    writeReport(outDir / "report.json");
}

void Job::writeSlices(const YAML::Node& spec, const std::filesystem::path& path)
{
    const RecipeNode node(spec, mRecipe.source, "outputs `slices`");
    const SliceSettings settings = parseSliceSettings(node);
    const PrinterProfile printer = loadPrinterProfile(settings.printer, settings.printerWhere);
    solveLevels();  // a `density:` level is solved on the recipe's voxel grid first
    // The part is the recipe's domain box as written (not snapped to voxels): slices need no voxels.
    const Box3 part = *mRecipe.domainBox;
    const SliceResult result = timed("slice " + path.filename().string(), [&] {
        return sliceToFile(*mResult, part, printer, settings, path, mRecipe.node("domain").where());
    });
    mReport["slices"].push_back(result.report);
    mReport["outputs"].push_back(path.string());
}

nlohmann::json Job::report() const
{
    nlohmann::json r = mReport;
    r["timings_s"] = mTimings;
    r["peak_memory_mb"] = double(peakMemoryBytes()) / (1024.0 * 1024.0);
    r["threads"] = tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
    return r;
}

void Job::writeReport(const std::filesystem::path& path)
{
    AtomicFile file(path.string());
    file.stream() << report().dump(2) << "\n";
    file.commit();
}

}  // namespace voxlat
