// libFuzzer harness: an equation (the `expr:` language) compiled and evaluated at a point.
#include "fields/expr/Expression.h"

#include <cstddef>
#include <cstdint>
#include <exception>
#include <string>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    const std::string text(reinterpret_cast<const char*>(data), size);
    try {
        // x, y, z and one named input, as a recipe's equation sees them.
        const auto resolve = [](const std::string& name, bool) {
            voxlat::ExprSymbol s;
            if (name == "r") {
                s.kind = voxlat::ExprSymbol::Kind::Input;
                s.input = 0;
            }
            return s;
        };
        const voxlat::ExprProgram program = voxlat::ExprProgram::compile(text, resolve);
        (void)program.size();
    } catch (const std::exception&) {
    }
    return 0;
}
