// The compiled core of the Python module `voxlat` (imported as voxlat._voxlat): recipes, jobs
// and fields of the engine, with numpy arrays in and out. The GIL is released while the engine
// works, so Python threads run alongside.
#include "engine/core/Errors.h"
#include "engine/jobs/DataFolder.h"
#include "engine/jobs/Job.h"
#include "engine/recipe/RecipeParams.h"
#include "engine/recipe/Schema.h"
#include "fields/core/HugePageAdvice.h"
#include "fields/maps/VectorField.h"
#include "tools/HugePages.h"

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>
#include <tbb/parallel_for.h>

#include <chrono>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <thread>

namespace py = pybind11;
using namespace voxlat;

namespace {

using Points = py::array_t<double, py::array::c_style | py::array::forcecast>;

/// The (N, 3) points of @a a as a span of Vec3d (numpy's C layout is three doubles per row).
std::span<const Vec3d> pointsOf(const Points& a)
{
    if (a.ndim() != 2 || a.shape(1) != 3) throw py::value_error("expected an array of points with shape (N, 3)");
    static_assert(sizeof(Vec3d) == 3 * sizeof(double));
    return {reinterpret_cast<const Vec3d*>(a.data()), std::size_t(a.shape(0))};
}

/// A field of a job, sampled on numpy arrays.
struct Field {
    FieldPtr field;
    std::string name;

    py::array_t<double> values(const Points& pts) const
    {
        const auto p = pointsOf(pts);
        py::array_t<double> out(py::ssize_t(p.size()));
        double* o = out.mutable_data();
        {
            py::gil_scoped_release release;
            const std::size_t chunks = (p.size() + kBatchSize - 1) / kBatchSize;
            tbb::parallel_for(std::size_t(0), chunks, [&](std::size_t c) {
                const std::size_t b = c * kBatchSize, n = std::min(kBatchSize, p.size() - b);
                field->values(p.subspan(b, n), std::span<double>(o + b, n));
            });
        }
        return out;
    }

    py::tuple gradients(const Points& pts) const
    {
        const auto p = pointsOf(pts);
        py::array_t<double> values(py::ssize_t(p.size()));
        py::array_t<double> grads({py::ssize_t(p.size()), py::ssize_t(3)});
        double* v = values.mutable_data();
        Vec3d* g = reinterpret_cast<Vec3d*>(grads.mutable_data());
        {
            py::gil_scoped_release release;
            const std::size_t chunks = (p.size() + kBatchSize - 1) / kBatchSize;
            tbb::parallel_for(std::size_t(0), chunks, [&](std::size_t c) {
                const std::size_t b = c * kBatchSize, n = std::min(kBatchSize, p.size() - b);
                field->gradients(p.subspan(b, n), std::span<double>(v + b, n), std::span<Vec3d>(g + b, n));
            });
        }
        return py::make_tuple(values, grads);
    }

    py::tuple bound(const std::array<double, 3>& lo, const std::array<double, 3>& hi) const
    {
        Interval b;
        {
            py::gil_scoped_release release;
            b = field->bound({Vec3d(lo[0], lo[1], lo[2]), Vec3d(hi[0], hi[1], hi[2])});
        }
        return py::make_tuple(b.lo, b.hi);
    }

    py::array_t<double> directions(const Points& pts) const
    {
        const auto* vec = dynamic_cast<const VectorField*>(field.get());
        if (!vec) throw py::type_error("field `" + name + "` is not a vector field");
        const auto p = pointsOf(pts);
        py::array_t<double> out({py::ssize_t(p.size()), py::ssize_t(3)});
        Vec3d* o = reinterpret_cast<Vec3d*>(out.mutable_data());
        {
            py::gil_scoped_release release;
            vec->directions(p, std::span<Vec3d>(o, p.size()));
        }
        return out;
    }
};

py::object jsonToPython(const nlohmann::json& j)
{
    return py::module_::import("json").attr("loads")(j.dump());
}

/// A Python job's context: one call at a time (`busy`), and the Python exception that stopped
/// the job (one raised in the progress callable, or KeyboardInterrupt), raised again once the
/// job has unwound.
struct PyJobContext : JobContext {
    std::mutex busy;
    std::mutex errorMutex;
    std::shared_ptr<py::error_already_set> error;  // set and reset with the GIL held

    /// Keeps the Python exception now set (GIL held) unless one is kept already, and cancels.
    void stopWith(py::error_already_set&& e)
    {
        {
            std::lock_guard<std::mutex> lock(errorMutex);
            if (!error) error = std::make_shared<py::error_already_set>(std::move(e));
        }
        cancel();
    }
};

/// A job and the context it reports through, alive together (the Job's shared_ptr aliases this).
struct JobWithContext {
    PyJobContext context;
    std::optional<Job> job;
};

/// Runs @a work (a job's stage) on a thread of its own while this one, without the GIL, looks for
/// Python signals every tenth of a second: Ctrl-C (KeyboardInterrupt) cancels the job, which
/// unwinds cleanly (no output left) before the exception is raised here. An exception from the
/// progress callable is raised the same way. A Job used from a second Python thread while it runs
/// refuses with RuntimeError instead of racing. Called with the GIL held.
template <class F>
auto runJob(Job& j, F work) -> decltype(work())
{
    using Result = decltype(work());
    auto& context = static_cast<PyJobContext&>(j.context());
    std::unique_lock<std::mutex> busy(context.busy, std::try_to_lock);
    if (!busy.owns_lock())
        throw std::runtime_error(
            "this Job is running in another thread: a Job does one thing at a time; wait for that call to return, or "
            "make a Job per thread");
    std::packaged_task<Result()> task(std::move(work));
    std::future<Result> done = task.get_future();
    {
        py::gil_scoped_release release;
        std::thread worker(std::move(task));
        while (done.wait_for(std::chrono::milliseconds(100)) != std::future_status::ready) {
            py::gil_scoped_acquire gil;
            if (PyErr_CheckSignals() != 0) context.stopWith(py::error_already_set());
        }
        worker.join();
    }
    std::shared_ptr<py::error_already_set> error;
    {
        std::lock_guard<std::mutex> lock(context.errorMutex);
        error.swap(context.error);
    }
    if (error) {
        try {
            done.get();  // the job's own exception (Cancelled) gives way to the one that caused it
        } catch (...) {
        }
        throw py::error_already_set(*error);
    }
    return done.get();
}

/// Makes a Job whose progress goes to @a progress (a Python callable `f(stage, done, total)`, or None).
/// The mesh options of `mesh()` and `write_mesh()`: as `voxlat mesh --tolerance T --project on|off
/// --extractor E`
/// (a tolerance turns projection on unless `project=False` is given).
MeshOptions meshOptions(std::optional<double> tolerance, std::optional<bool> project, const std::string& extractor)
{
    MeshOptions options;
    const std::optional<MeshExtractor> e = meshExtractorFromName(extractor);
    if (!e) throw InputError("extractor=" + extractor + ": expected one of " + joinWords(meshExtractorNames()));
    options.extractor = *e;
    if (tolerance) {
        options.tolerance = checkMeshTolerance(*tolerance, "tolerance=");
        options.toleranceWhere = "tolerance=";
        options.project = true;
    }
    if (project) options.project = *project;
    return options;
}

std::shared_ptr<Job> makeJob(const Recipe& recipe, py::object progress)
{
    auto owner = std::make_shared<JobWithContext>();
    if (!progress.is_none()) {
        if (!PyCallable_Check(progress.ptr()))
            throw py::type_error("progress= takes a callable f(stage, done, total), not " +
                                 std::string(py::str(py::type::of(progress).attr("__name__"))));
        // Called from worker threads while the job runs without the GIL: take it for the call.
        // An exception there cancels the job; runJob raises it once the job has unwound.
        auto callback = std::make_shared<py::object>(std::move(progress));
        PyJobContext* context = &owner->context;
        owner->context.setProgressCallback(
            [callback, context](const std::string& stage, std::uint64_t done, std::uint64_t total) {
                py::gil_scoped_acquire gil;
                if (context->error) return;
                try {
                    (*callback)(stage, done, total);
                } catch (py::error_already_set& e) {
                    context->stopWith(std::move(e));
                }
            });
    }
    try {
        py::gil_scoped_release release;
        owner->job.emplace(recipe, &owner->context);
    } catch (const Cancelled&) {
        // Stopped by the progress callable while the job was set up (a design solve): its error.
        if (std::shared_ptr<py::error_already_set> error = std::move(owner->context.error))
            throw py::error_already_set(*error);
        throw;
    }
    return std::shared_ptr<Job>(owner, &*owner->job);
}

}  // namespace

PYBIND11_MODULE(_voxlat, m)
{
    m.doc() = "voxlat engine core: recipes, jobs, fields (see the `voxlat` package for the graph builder)";
    // The engine's mapped blocks in huge pages, except where the host takes freed memory back and
    // they fault in no faster there (the command line decides the same, tools/HugePages.h's
    // hugePagesPay(); Python's malloc is left as it is).
    static voxlat::HugePageFaultTimes probed;
    voxlat::setHugePageAdvice(voxlat::hugePagesPay(&probed));
    static py::exception<InputError> inputError(m, "InputError", PyExc_ValueError);
    static py::exception<JobError> jobError(m, "JobError", PyExc_RuntimeError);
    static py::exception<Cancelled> cancelled(m, "Cancelled", PyExc_RuntimeError);
    py::register_exception_translator([](std::exception_ptr p) {
        try {
            if (p) std::rethrow_exception(p);
        } catch (const InputError& e) {
            inputError(e.what());
        } catch (const JobError& e) {
            jobError(e.what());
        } catch (const Cancelled& e) {
            cancelled(e.what());
        }
    });
    openvdb::initialize();

    m.def("set_data_folder", &setDataFolder, py::arg("folder"),
          "where printer profiles and examples are read from (an installed package sets its own)");
    m.def("data_folder", &dataFolder, "where printer profiles and examples are read from");
    m.def(
        "huge_page_advice", [] { return voxlat::hugePageAdvice(); },
        "whether the engine's long-held blocks ask for transparent huge pages (not where the machine reports its "
        "free memory to its host and a huge page faults in no faster there)");
    m.def(
        "huge_page_probe", [] { return py::make_tuple(probed.huge, probed.small); },
        "the milliseconds the module's probe took to fault in 2 MB as a huge page and as 4 KB pages where the "
        "machine reports its free memory to its host ((-1, -1): no probe)");
    m.def(
        "schema", [] { return recipeSchema().dump(2); }, "the recipe language as JSON Schema text");

    py::class_<Recipe>(m, "Recipe", "a loaded and checked recipe")
        .def_static(
            "load",
            [](const std::string& path, const std::vector<std::string>& sets) {
                py::gil_scoped_release release;
                return loadRecipe(path, sets);
            },
            py::arg("path"), py::arg("sets") = std::vector<std::string>{})
        .def_static(
            "parse",
            [](const std::string& text, const std::string& name, const std::string& folder,
               const std::vector<std::string>& sets) {
                py::gil_scoped_release release;
                return parseRecipe(text, name, std::filesystem::absolute(folder), sets);
            },
            py::arg("text"), py::arg("name") = "<python>", py::arg("folder") = ".",
            py::arg("sets") = std::vector<std::string>{})
        .def_property_readonly("path", [](const Recipe& r) { return r.source->path; })
        .def_property_readonly("result", [](const Recipe& r) { return r.result; })
        .def_property_readonly("field_names", [](const Recipe& r) { return r.fieldNames; })
        .def_property_readonly("voxel", [](const Recipe& r) { return r.voxel; })
        .def(
            "canonical", [](const Recipe& r) { return jsonToPython(canonicalRecipe(r)); },
            "the recipe as run (includes merged, parameters applied), as a dict")
        .def("canonical_text", [](const Recipe& r) { return canonicalRecipe(r).dump(); })
        .def("sha256", [](const Recipe& r) { return recipeHash(r); });

    py::class_<Field>(m, "Field", "a field of a job, sampled on numpy arrays of points (N, 3)")
        .def_readonly("name", &Field::name)
        .def("values", &Field::values, py::arg("points"), "values at points (N, 3) -> (N,)")
        .def("gradients", &Field::gradients, py::arg("points"), "values (N,) and analytic gradients (N, 3)")
        .def("bound", &Field::bound, py::arg("lo"), py::arg("hi"), "(lo, hi) bounding the value over a box")
        .def("directions", &Field::directions, py::arg("points"), "vectors (N, 3) of a vector field");

    py::class_<Job, std::shared_ptr<Job>>(m, "Job", "a recipe taken through the stages")
        .def(py::init(&makeJob), py::arg("recipe"), py::arg("progress") = py::none(),
             "a job; `progress(stage, done, total)` is called as stages advance (from worker threads)")
        .def(
            "warnings",
            [](const Job& j) {
                py::list out;
                for (const Warning& w : j.context().warnings()) {
                    nlohmann::json entry = w.details;
                    entry["code"] = w.code;
                    entry["message"] = w.message;
                    out.append(jsonToPython(entry));
                }
                return out;
            },
            "the warnings so far: dicts with `code`, `message` and the numbers")
        .def(
            "cancel", [](Job& j) { j.context().cancel(); },
            "ask a running stage (in another thread) to stop; it raises voxlat.Cancelled")
        .def(
            "solve", [](Job& j) { runJob(j, [&j] { j.solveLevels(); }); }, "solve every density: level")
        .def(
            "field",
            [](Job& j, const std::string& name) {
                const FieldPtr f = runJob(j, [&] { return j.field(name.empty() ? j.recipe().result : name); });
                return Field{f, name.empty() ? j.recipe().result : name};
            },
            py::arg("name") = "", "a named field (levels solved); the result by default")
        .def(
            "mesh",
            [](Job& j, std::optional<double> tolerance, std::optional<bool> project, const std::string& extractor) {
                const MeshOptions options = meshOptions(tolerance, project, extractor);
                const TriangleMesh* mesh = runJob(j, [&] { return &j.mesh(options); });
                py::array_t<float> points({py::ssize_t(mesh->points.size()), py::ssize_t(3)});
                py::array_t<std::uint32_t> tris({py::ssize_t(mesh->triangles.size()), py::ssize_t(3)});
                std::memcpy(points.mutable_data(), mesh->points.data(), mesh->points.size() * 3 * sizeof(float));
                std::memcpy(tris.mutable_data(), mesh->triangles.data(),
                            mesh->triangles.size() * 3 * sizeof(std::uint32_t));
                return py::make_tuple(points, tris);
            },
            py::arg("tolerance") = py::none(), py::arg("project") = py::none(), py::arg("extractor") = "marching-cubes",
            "the mesh of the result: points (V, 3) float32 and triangles (T, 3) uint32; tolerance (mm): "
            "decimated to that distance from the true surface; project: vertices on the true surface; extractor: "
            "marching-cubes or bcc")
        .def(
            "write_outputs",
            [](Job& j, const std::string& dir, bool html) { runJob(j, [&] { j.writeOutputs(dir, true, html); }); },
            py::arg("out_dir"), py::arg("html") = true,
            "write the recipe's outputs, report.json and (html) report.html")
        .def(
            "write_mesh",
            [](Job& j, const std::string& path, std::optional<double> tolerance, std::optional<bool> project,
               const std::string& extractor) {
                const MeshOptions options = meshOptions(tolerance, project, extractor);
                runJob(j, [&] { j.writeMesh(path, options); });
            },
            py::arg("path"), py::arg("tolerance") = py::none(), py::arg("project") = py::none(),
            py::arg("extractor") = "marching-cubes",
            "write the mesh (.stl, .3mf, .ply, .obj), with the options of mesh()")
        .def(
            "write_report", [](Job& j, const std::string& path) { runJob(j, [&] { j.writeReport(path); }); },
            py::arg("path"))
        .def(
            "properties",
            [](Job& j) {
                const nlohmann::json p = runJob(j, [&] { return j.properties(); });
                return jsonToPython(p);
            },
            "effective stiffness and conductivity of one periodic cell of the result (a dict; needs material:)")
        .def(
            "report", [](Job& j) { return jsonToPython(runJob(j, [&j] { return j.report(); })); },
            "levels, densities, counts, timings");
}
