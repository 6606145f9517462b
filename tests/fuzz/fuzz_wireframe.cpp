// libFuzzer harness: wireframe files (CSV or OBJ lines); the first byte picks the format.
#include "FuzzUtil.h"
#include "engine/frames/StrutFrames.h"

#include <cstddef>
#include <cstdint>
#include <exception>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    if (size == 0) return 0;
    const voxlat::fuzz::InputFile file(data + 1, size - 1, data[0] % 2 ? ".csv" : ".obj");
    try {
        (void)voxlat::readWireframe(file.path().string());
    } catch (const std::exception&) {
    }
    return 0;
}
