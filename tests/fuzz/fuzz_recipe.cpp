// libFuzzer harness: recipe text -> loader -> field builder -> a few point values. Any
// std::exception is the clear error the loader promises; a crash, a hang or a sanitizer report
// is a defect.
#include "engine/core/JobContext.h"
#include "engine/recipe/FieldBuilder.h"
#include "engine/recipe/Recipe.h"

#include <cstddef>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <string>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    const std::string text(reinterpret_cast<const char*>(data), size);
    try {
        const voxlat::Recipe recipe = voxlat::parseRecipe(text, "fuzz.yaml", std::filesystem::temp_directory_path());
        voxlat::JobContext context;
        voxlat::FieldBuilder builder(recipe, context);
        const voxlat::FieldPtr field = builder.field(recipe.result);
        for (double t : {0.0, 0.37, 1.3}) (void)field->value(voxlat::Vec3d(t, 2 * t, -t));
    } catch (const std::exception&) {
    }
    return 0;
}
