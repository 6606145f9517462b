// libFuzzer harness: the `material:` and `properties:` keys (the fuzzed text, appended to a small
// gyroid recipe) -> the loader -> homogenization of the cell at a coarse resolution. Any
// std::exception is the clear error the job promises; a crash, a hang or a sanitizer report is a
// defect.
#include "engine/core/JobContext.h"
#include "engine/jobs/Job.h"
#include "engine/recipe/Recipe.h"

#include <cstddef>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <string>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    const std::string text =
        "voxel: 0.5\ndomain: {box: [[0, 0, 0], [4, 4, 4]]}\nfields:\n"
        "  g: {tpms: gyroid, cell: 4, solid: network, density: 0.3}\nresult: g\n" +
        std::string(reinterpret_cast<const char*>(data), size);
    try {
        voxlat::Recipe recipe = voxlat::parseRecipe(text, "fuzz.yaml", std::filesystem::temp_directory_path());
        // Coarse cells only: the harness looks for crashes, not for converged moduli.
        if (!recipe.properties.resolution || *recipe.properties.resolution > 12) return 0;
        voxlat::JobContext context;
        voxlat::Job job(std::move(recipe), &context);
        (void)job.properties();
    } catch (const std::exception&) {
    }
    return 0;
}
