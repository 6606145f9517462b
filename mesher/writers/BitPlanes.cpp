#include "mesher/writers/BitPlanes.h"

#include "mesher/writers/WindowRuns.h"

#include <algorithm>
#include <stdexcept>

namespace voxlat {

namespace {

constexpr unsigned kMostRun = 125;  // Chitubox never writes more; UVtools and uv3dp split there too

void appendRuns(std::string& out, bool on, std::uint64_t n)
{
    while (n > 0) {
        const unsigned run = unsigned(std::min<std::uint64_t>(n, kMostRun));
        n -= run;
        out.push_back(char((on ? 0x80u : 0u) | run));
    }
}

}  // namespace

int bitPlanesGrey(int n, int planes)
{
    return n == 0 ? 0 : n * (256 / planes) - 1;
}

std::string encodeBitPlanes(int planes, int width, int height, const std::uint8_t* window, int col0, int row0, int w,
                            int h)
{
    if (planes < 1 || planes > 16 || 256 % planes != 0) throw std::logic_error("bit planes: 1, 2, 4, 8 or 16 planes");
    std::string out;
    for (int k = 1; k <= planes; ++k) {
        // On where the grey is nearer bitPlanesGrey(k) than bitPlanesGrey(k - 1).
        const unsigned threshold = unsigned(bitPlanesGrey(k - 1, planes) + bitPlanesGrey(k, planes)) / 2 + 1;
        windowRuns(
            width, height, window, col0, row0, w, h, [threshold](std::uint8_t g) { return g >= threshold; },
            [&](bool on, std::uint64_t n) { appendRuns(out, on, n); });
    }
    return out;
}

std::vector<std::size_t> bitPlaneLengths(const std::string& code, int planes, std::uint64_t pixels)
{
    std::vector<std::size_t> lengths;
    std::size_t start = 0;
    std::uint64_t covered = 0;
    for (std::size_t k = 0; k < code.size(); ++k) {
        covered += std::uint8_t(code[k]) & 0x7F;
        if (covered == pixels) {
            lengths.push_back(k + 1 - start);
            start = k + 1;
            covered = 0;
        }
    }
    if (int(lengths.size()) != planes || start != code.size())
        throw std::logic_error("bit planes: the code does not hold whole planes");
    return lengths;
}

std::uint32_t bitPlanesExposed(const std::string& code, std::uint64_t pixels)
{
    std::uint64_t covered = 0, exposed = 0;
    for (std::size_t k = 0; k < code.size() && covered < pixels; ++k) {
        const unsigned b = std::uint8_t(code[k]);
        covered += b & 0x7F;
        if (b & 0x80) exposed += b & 0x7F;
    }
    return std::uint32_t(exposed);
}

}  // namespace voxlat
