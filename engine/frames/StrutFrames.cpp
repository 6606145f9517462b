#include "engine/frames/StrutFrames.h"

#include "engine/core/InputFiles.h"

#include "engine/core/Errors.h"
#include "engine/core/Format.h"
#include "engine/core/SystemInfo.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <numbers>
#include <stdexcept>
#include <string_view>

namespace voxlat {

Box3 Frame::bounds() const
{
    Box3 b{Vec3d(1e300), Vec3d(-1e300)};
    for (const Vec3d& p : nodes)
        for (int a = 0; a < 3; ++a) {
            b.min[a] = std::min(b.min[a], p[a]);
            b.max[a] = std::max(b.max[a], p[a]);
        }
    return b;
}

int FrameBuilder::node(const Vec3d& p)
{
    // A node within the tolerance of p lies in a bin that [p - tol, p + tol] reaches along each
    // axis; of several, the first made wins (the same for any order of look-up).
    const double width = 4.0 * mTol;
    std::array<long, 3> lo, hi;
    for (int a = 0; a < 3; ++a) {
        lo[a] = long(std::floor((p[a] - mTol) / width));
        hi[a] = long(std::floor((p[a] + mTol) / width));
    }
    int found = -1;
    for (long x = lo[0]; x <= hi[0]; ++x)
        for (long y = lo[1]; y <= hi[1]; ++y)
            for (long z = lo[2]; z <= hi[2]; ++z) {
                const auto it = mBins.find({x, y, z});
                if (it == mBins.end()) continue;
                for (const int i : it->second)
                    if ((found < 0 || i < found) && (mFrame.nodes[i] - p).length() <= mTol) found = i;
            }
    if (found >= 0) return found;
    mFrame.nodes.push_back(p);
    const int i = int(mFrame.nodes.size() - 1);
    mBins[{long(std::floor(p[0] / width)), long(std::floor(p[1] / width)), long(std::floor(p[2] / width))}].push_back(
        i);
    return i;
}

bool FrameBuilder::strut(const Vec3d& a, const Vec3d& b)
{
    const int i = node(a), j = node(b);
    if (i == j) return false;
    const auto key = std::minmax(i, j);
    if (!mStruts.insert(std::uint64_t(std::uint32_t(key.first)) << 32 | std::uint32_t(key.second)).second) return false;
    mFrame.struts.push_back({key.first, key.second});
    return true;
}

namespace {
/// Each strut costs about this across the frame, its convolution data and the strut index.
constexpr double kBytesPerStrut = 400.0;
}  // namespace

// 10^9 struts otherwise ran for minutes with no estimate and then ran out of memory.
void checkStrutCount(const UnitCell& cell, const std::array<int, 3>& counts)
{
    const double cells = double(counts[0]) * double(counts[1]) * double(counts[2]);
    const double struts = cells * double(cell.struts.size());
    const double bytes = struts * kBytesPerStrut;
    const double budget = 0.5 * double(availableMemoryBytes());
    if (bytes > budget || struts > 2e9)
        throw JobError("the frame would hold " + std::to_string(std::uint64_t(struts)) + " struts (" +
                       std::to_string(std::uint64_t(cells)) + " cells of " + std::to_string(cell.struts.size()) +
                       "), about " + std::to_string(std::uint64_t(bytes / 1e9 + 0.5)) +
                       " GB, more than half the memory this machine has free (" +
                       std::to_string(std::uint64_t(budget / 1e9 + 0.5)) + " GB): use larger cells or a smaller part");
}

namespace {
template <typename Map>
Frame mapCells(const UnitCell& cell, const std::array<int, 3>& counts, double tol, const FrameInterrupt& interrupt,
               Map&& map)
{
    checkStrutCount(cell, counts);
    FrameBuilder builder(tol);
    for (int i = 0; i < counts[0]; ++i)
        for (int j = 0; j < counts[1]; ++j) {
            if (interrupt) interrupt();
            for (int k = 0; k < counts[2]; ++k)
                for (const auto& s : cell.struts) {
                    const Vec3d off(i, j, k);
                    builder.strut(map(cell.nodes[s[0]] + off), map(cell.nodes[s[1]] + off));
                }
        }
    return builder.take();
}
}  // namespace

Frame boxFrame(const UnitCell& cell, const Vec3d& origin, const Vec3d& cellSize, const std::array<int, 3>& counts,
               const FrameInterrupt& interrupt)
{
    const double tol = 1e-6 * std::min({cellSize[0], cellSize[1], cellSize[2]});
    return mapCells(cell, counts, tol, interrupt, [&](const Vec3d& u) {
        return Vec3d(origin[0] + u[0] * cellSize[0], origin[1] + u[1] * cellSize[1], origin[2] + u[2] * cellSize[2]);
    });
}

Frame cylinderFrame(const UnitCell& cell, const Vec3d& base, double innerRadius, double outerRadius, double height,
                    const std::array<int, 3>& counts, const FrameInterrupt& interrupt)
{
    const int axial = counts[0], angular = counts[1], radial = counts[2];
    const double tol = 1e-6 * std::min(outerRadius - innerRadius, height) / std::max({axial, angular, radial});
    // Cell coordinates: x radial (count radial), y angular, z axial.
    return mapCells(cell, {radial, angular, axial}, tol, interrupt, [&](const Vec3d& u) {
        const double r = innerRadius + u[0] / radial * (outerRadius - innerRadius);
        const double theta = u[1] / angular * 2.0 * std::numbers::pi;
        return base + Vec3d(r * std::cos(theta), r * std::sin(theta), u[2] / axial * height);
    });
}

Frame sphereFrame(const UnitCell& cell, const Vec3d& centre, double innerRadius, double outerRadius,
                  const std::array<int, 3>& counts, const FrameInterrupt& interrupt)
{
    const int polar = counts[0], azimuthal = counts[1], radial = counts[2];
    // The smallest spacing is between nodes next to a pole on the inner shell (or the outer one
    // when the inner radius is 0); merge well below it.
    const double shortest = std::min(outerRadius - innerRadius, (innerRadius > 0 ? innerRadius : outerRadius) *
                                                                    std::sin(std::numbers::pi / polar) *
                                                                    std::sin(std::numbers::pi / azimuthal));
    const double tol = 1e-6 * shortest / std::max({polar, azimuthal, radial});
    // Cell coordinates: x radial (count radial), y azimuthal, z polar.
    return mapCells(cell, {radial, azimuthal, polar}, tol, interrupt, [&](const Vec3d& u) {
        const double r = innerRadius + u[0] / radial * (outerRadius - innerRadius);
        const double phi = u[1] / azimuthal * 2.0 * std::numbers::pi;
        const double theta = u[2] / polar * std::numbers::pi;
        return centre + r * Vec3d(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
    });
}

Frame hexGridFrame(const UnitCell& cell, const std::vector<Vec3d>& gridNodes, const std::array<int, 3>& counts,
                   const FrameInterrupt& interrupt)
{
    const int n0 = counts[0], n1 = counts[1], n2 = counts[2];
    if (gridNodes.size() != std::size_t(n0 + 1) * std::size_t(n1 + 1) * std::size_t(n2 + 1))
        throw std::invalid_argument("hexGridFrame: the grid has the wrong number of nodes for its counts");
    Box3 box{gridNodes.front(), gridNodes.front()};
    for (const Vec3d& p : gridNodes)
        for (int a = 0; a < 3; ++a) {
            box.min[a] = std::min(box.min[a], p[a]);
            box.max[a] = std::max(box.max[a], p[a]);
        }
    const double tol = std::max(1e-9 * box.extent().length(), 1e-300);
    auto corner = [&](int i, int j, int k) -> const Vec3d& {
        return gridNodes[(std::size_t(i) * (n1 + 1) + j) * (n2 + 1) + k];
    };
    return mapCells(cell, counts, tol, interrupt, [&](const Vec3d& u) {
        // The hexahedron holding u (the last one for a node on the far faces) and u within it.
        const int i = std::clamp(int(std::floor(u[0])), 0, n0 - 1);
        const int j = std::clamp(int(std::floor(u[1])), 0, n1 - 1);
        const int k = std::clamp(int(std::floor(u[2])), 0, n2 - 1);
        const double a = u[0] - i, b = u[1] - j, c = u[2] - k;
        Vec3d p(0.0);
        for (int di = 0; di < 2; ++di)
            for (int dj = 0; dj < 2; ++dj)
                for (int dk = 0; dk < 2; ++dk) {
                    const double weight = (di ? a : 1.0 - a) * (dj ? b : 1.0 - b) * (dk ? c : 1.0 - c);
                    // Zero weights are skipped, so a cell corner is its grid node exactly.
                    if (weight != 0.0) p += weight * corner(i + di, j + dj, k + dk);
                }
        return p;
    });
}

Frame clippedFrame(const UnitCell& cell, const Box3& region, const Vec3d& cellSize,
                   const std::function<double(const Vec3d&)>& inside, double minLength)
{
    std::array<int, 3> counts;
    for (int a = 0; a < 3; ++a) {
        const double n = std::ceil(region.extent()[a] / cellSize[a] - 1e-9);
        counts[a] = int(std::clamp(n, 1.0, 2e9));
    }
    checkStrutCount(cell, counts);
    const double tol = 1e-6 * std::min({cellSize[0], cellSize[1], cellSize[2]});
    FrameBuilder builder(tol);
    auto map = [&](const Vec3d& u) {
        return Vec3d(region.min[0] + u[0] * cellSize[0], region.min[1] + u[1] * cellSize[1],
                     region.min[2] + u[2] * cellSize[2]);
    };
    for (int i = 0; i < counts[0]; ++i)
        for (int j = 0; j < counts[1]; ++j)
            for (int k = 0; k < counts[2]; ++k)
                for (const auto& s : cell.struts) {
                    const Vec3d off(i, j, k);
                    Vec3d a = map(cell.nodes[s[0]] + off), b = map(cell.nodes[s[1]] + off);
                    const bool inA = inside(a) <= 0.0, inB = inside(b) <= 0.0;
                    if (!inA && !inB) continue;
                    if (inA && inB) {
                        builder.strut(a, b);
                        continue;
                    }
                    if (!inA) std::swap(a, b);  // a inside, b outside
                    double lo = 0.0, hi = 1.0;
                    for (int it = 0; it < 60; ++it) {
                        const double mid = 0.5 * (lo + hi);
                        (inside(a + mid * (b - a)) <= 0.0 ? lo : hi) = mid;
                    }
                    const double length = (b - a).length(), kept = lo * length;
                    if (kept < minLength) continue;
                    if (length - kept < minLength)
                        builder.strut(a, b);
                    else
                        builder.strut(a, a + lo * (b - a));
                }
    return builder.take();
}

Frame readWireframe(const std::string& path)
{
    const bool csv = path.size() >= 4 && path.substr(path.size() - 4) == ".csv";
    if (!csv) {
        const std::vector<CellLine> lines = readObjLines(path);
        double size = 0.0;
        for (const CellLine& l : lines) size = std::max(size, (l.b - l.a).length());
        FrameBuilder builder(1e-9 * size);
        for (const CellLine& l : lines) {
            if ((l.b - l.a).length() <= 1e-9 * size)
                throw InputError(l.where + ": zero-length strut (both ends at the same point); remove it");
            builder.strut(l.a, l.b);
        }
        return builder.take();
    }
    if (std::filesystem::exists(path))
        checkInputFile(path, kMaxDataFileBytes, "wireframe file");  // before open: a FIFO blocks
    std::ifstream in(path);
    if (!in) throw InputError(path + ": cannot open the file (check the path; it is relative to the recipe's folder)");
    std::vector<Vec3d> nodes;
    std::vector<std::tuple<Vec3d, Vec3d, int>> struts;
    std::vector<std::array<double, 2>> rowRadii;  // per 8-column row
    int sixColumns = 0, eightColumns = 0;
    std::vector<std::tuple<long, long, int>> indexed;
    std::string text;
    int lineNo = 0;
    std::vector<std::string_view> cells;
    while (std::getline(in, text)) {
        ++lineNo;
        // The line's name in messages (made only for one: a 10^5-strut file's lines each built
        // theirs, with a string stream and a string per cell: most of its 0.5 s of reading).
        auto whereAt = [&] { return path + ":" + std::to_string(lineNo); };
        if (text.find_first_not_of(" \t\r") == std::string::npos || text[text.find_first_not_of(" \t")] == '#')
            continue;
        // The cells between commas, blanks trimmed (as many as std::getline(s, c, ',') gave: none
        // after a trailing comma).
        cells.clear();
        const std::string_view line(text);
        for (std::size_t from = 0; from < line.size();) {
            const std::size_t comma = std::min(line.find(',', from), line.size());
            const std::string_view c = line.substr(from, comma - from);
            const auto b = c.find_first_not_of(" \t\r"), e = c.find_last_not_of(" \t\r");
            cells.push_back(b == std::string_view::npos ? std::string_view() : c.substr(b, e - b + 1));
            from = comma + 1;
        }
        auto num = [&](std::size_t i) {
            const std::string_view cell = i < cells.size() ? cells[i] : std::string_view();
            // std::from_chars reads the plain decimals a file holds; what it does not take whole
            // (a leading +, hexadecimal: it stops at the x) goes to std::stod as before: the same
            // doubles either way. A missing or empty cell fails both.
            double v = 0.0;
            const char* first = cell.data() + (cell.size() > 1 && cell[0] == '+' && cell[1] != '-' ? 1 : 0);
            const auto [end, error] = std::from_chars(first, cell.data() + cell.size(), v);
            if (!cell.empty() && error == std::errc() && end == cell.data() + cell.size() && std::isfinite(v)) return v;
            try {
                std::size_t used = 0;
                const std::string copy(cell);
                v = std::stod(copy, &used);
                if (used != copy.size() || !std::isfinite(v)) throw std::invalid_argument("");
                return v;
            } catch (const std::exception&) {
                throw InputError(whereAt() + ": column " + std::to_string(i + 1) + " is not a finite number");
            }
        };
        // A header row (`x1,y1,z1,x2,y2,z2,r1,r2` as a frame output writes it, or any other
        // words): first line, first cell neither a number nor a row kind.
        if (lineNo == 1 && !cells.empty() && cells[0] != "node" && cells[0] != "strut") {
            const std::string first(cells[0]);
            char* end = nullptr;
            std::strtod(first.c_str(), &end);
            if (first.empty() || *end != '\0') continue;
        }
        if (!cells.empty() && cells[0] == "node" && cells.size() == 4) {
            nodes.emplace_back(num(1), num(2), num(3));
        } else if (!cells.empty() && cells[0] == "strut" && cells.size() == 3) {
            const double i = num(1), j = num(2);
            if (i != std::floor(i) || j != std::floor(j))
                throw InputError(whereAt() + ": node indices are whole numbers (0-based)");
            // Past 2^53 a double holds no exact whole number, and a long none past 2^63: refused
            // before the conversion (a fuzzed row of 1e108 was undefined behaviour).
            if (!(std::abs(i) < 9.0e15 && std::abs(j) < 9.0e15))
                throw InputError(whereAt() + ": node index " + formatNumber(std::abs(i) < 9.0e15 ? j : i) +
                                 " is far past any node: indices count the file's `node` rows from 0");
            indexed.emplace_back(long(i), long(j), lineNo);
        } else if (cells.size() == 6 || cells.size() == 8) {
            struts.emplace_back(Vec3d(num(0), num(1), num(2)), Vec3d(num(3), num(4), num(5)), lineNo);
            if (cells.size() == 8) {
                const double r1 = num(6), r2 = num(7);
                if (!(r1 > 0.0 && r2 > 0.0)) throw InputError(whereAt() + ": radii are greater than zero (mm)");
                rowRadii.push_back({r1, r2});
                ++eightColumns;
            } else {
                ++sixColumns;
            }
            if (sixColumns && eightColumns)
                throw InputError(whereAt() +
                                 ": every strut row has radii (x1,y1,z1,x2,y2,z2,r1,r2) or none (x1,y1,z1,x2,y2,z2)");
        } else if (lineNo == 1) {
            continue;  // a header row
        } else {
            throw InputError(whereAt() +
                             ": expected `node,x,y,z`, `strut,i,j`, six numbers `x1,y1,z1,x2,y2,z2` or eight "
                             "`x1,y1,z1,x2,y2,z2,r1,r2`");
        }
    }
    if (eightColumns && !indexed.empty())
        throw InputError(path + ": give struts either as `strut,i,j` rows or as rows with radii, not both");
    for (const auto& [i, j, no] : indexed) {
        for (long k : {i, j})
            if (k < 0 || k >= long(nodes.size()))
                throw InputError(path + ":" + std::to_string(no) + ": strut refers to node " + std::to_string(k) +
                                 ", but the file defines " + std::to_string(nodes.size()) + " nodes (indices 0 to " +
                                 std::to_string(long(nodes.size()) - 1) + ")");
        struts.emplace_back(nodes[i], nodes[j], no);
    }
    if (struts.empty()) throw InputError(path + ": no struts in the file");
    double size = 0.0;
    for (const auto& [a, b, no] : struts) size = std::max(size, (b - a).length());
    FrameBuilder builder(1e-9 * size);
    std::vector<std::array<double, 2>> radii;
    std::vector<int> forward;  // per strut with radii: the node its row starts at
    for (std::size_t k = 0; k < struts.size(); ++k) {
        const auto& [a, b, no] = struts[k];
        if ((b - a).length() <= 1e-9 * size)
            throw InputError(path + ":" + std::to_string(no) +
                             ": zero-length strut (both ends at the same point); remove it");
        const int first = builder.node(a);
        if (builder.strut(a, b) && !rowRadii.empty()) {
            radii.push_back(rowRadii[k]);
            forward.push_back(first);
        }
    }
    Frame frame = builder.take();
    // Rows with radii keep their direction (the builder stores struts low index first): a frame
    // output read back gives the very struts it was written from, so the same field bits.
    for (std::size_t k = 0; k < forward.size(); ++k)
        if (frame.struts[k][0] != forward[k]) std::swap(frame.struts[k][0], frame.struts[k][1]);
    frame.radii = std::move(radii);
    return frame;
}

}  // namespace voxlat
