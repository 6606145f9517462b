// libFuzzer harness: a printer profile file -> loadPrinterProfile (YAML, keys, numbers, the
// display's pixel limit). Any std::exception is the clear error the loader promises.
#include "FuzzUtil.h"
#include "engine/jobs/PrinterProfile.h"

#include <cstddef>
#include <cstdint>
#include <exception>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    const voxlat::fuzz::InputFile file(data, size, ".yaml");
    try {
        (void)voxlat::loadPrinterProfile(file.path().string(), "fuzz");
    } catch (const std::exception&) {
    }
    return 0;
}
