// libFuzzer harness: the part-mesh readers. The first byte picks the format (STL, PLY, OBJ, 3MF),
// the rest is the file.
#include "FuzzUtil.h"
#include "engine/parts/MeshReader.h"

#include <cstddef>
#include <cstdint>
#include <exception>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    if (size == 0) return 0;
    static const char* const kExtensions[] = {".stl", ".ply", ".obj", ".3mf"};
    const voxlat::fuzz::InputFile file(data + 1, size - 1, kExtensions[data[0] % 4]);
    try {
        (void)voxlat::readPartMesh(file.path(), "fuzz");
    } catch (const std::exception&) {
    }
    return 0;
}
