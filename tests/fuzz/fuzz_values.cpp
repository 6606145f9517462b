// libFuzzer harness: value files (a grid of numbers, CSV or whitespace separated) and cell files
// (a unit cell's lines, OBJ); the first byte picks which.
#include "FuzzUtil.h"
#include "engine/frames/UnitCells.h"
#include "engine/recipe/ScalarMaps.h"

#include <cstddef>
#include <cstdint>
#include <exception>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    if (size == 0) return 0;
    try {
        if (data[0] % 2 == 0) {
            const voxlat::fuzz::InputFile file(data + 1, size - 1, ".csv");
            const voxlat::FieldPtr f = voxlat::readValueGrid(file.path(), "fuzz.csv");
            (void)f->value(voxlat::Vec3d(0.5, 0.25, 0.125));
        } else {
            const voxlat::fuzz::InputFile file(data + 1, size - 1, ".obj");
            const auto lines = voxlat::readObjLines(file.path().string());
            (void)voxlat::unitCellProblems(voxlat::unitCellFromLines(lines, "fuzz"));
        }
    } catch (const std::exception&) {
    }
    return 0;
}
