#include "mesher/writers/BitPlanes.h"

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
        bool on = false;
        std::uint64_t length = 0;
        auto add = [&](bool v, std::uint64_t n) {
            if (n == 0) return;
            if (v != on && length > 0) {
                appendRuns(out, on, length);
                length = 0;
            }
            on = v;
            length += n;
        };
        add(false, std::uint64_t(row0) * width);
        for (int r = 0; r < h; ++r) {
            add(false, std::uint64_t(col0));
            const std::uint8_t* row = window + std::size_t(r) * w;
            for (int c = 0; c < w;) {
                const bool v = row[c] >= threshold;
                int e = c + 1;
                while (e < w && (row[e] >= threshold) == v) ++e;
                add(v, std::uint64_t(e - c));
                c = e;
            }
            add(false, std::uint64_t(width - col0 - w));
        }
        add(false, std::uint64_t(height - row0 - h) * width);
        appendRuns(out, on, length);
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
