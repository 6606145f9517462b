#include "engine/checks/Printability.h"
#include "engine/checks/UnionFind.h"

#include "engine/core/Format.h"

#include <algorithm>
#include <cstring>
#include <numeric>
#include <tuple>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace voxlat {

namespace {

using Word = std::uint64_t;

/// A closed cavity of fewer pixel-layers than this (3 x 3 x 3) is a numeric crumb of the surface.
constexpr double kCrumbVoxels = 27.0;

/// Exposed pixels of a row as bits (bit i of word i / 64 = pixel i has grey >= 128).
void packRow(const std::uint8_t* pixels, int nx, Word* bits)
{
    const int words = (nx + 63) / 64;
    std::fill(bits, bits + words, Word(0));
    int i = 0;
#if defined(__SSE2__)
    // Sixteen pixels' high bits at a time (the grey >= 128 test), four to a word.
    for (; i + 64 <= nx; i += 64) {
        Word w = 0;
        for (int k = 0; k < 4; ++k) {
            const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(pixels + i + 16 * k));
            w |= Word(unsigned(_mm_movemask_epi8(v))) << (16 * k);
        }
        bits[i / 64] = w;
    }
#endif
    for (; i + 8 <= nx; i += 8) {
        Word w;
        std::memcpy(&w, pixels + i, 8);
        // The high bit of each byte gathered into one byte (byte k -> bit k; no carries, since
        // the shifted bits land on distinct positions).
        const Word packed = ((w & 0x8080808080808080ULL) * 0x0002040810204081ULL) >> 56;
        bits[i / 64] |= packed << (i % 64);
    }
    for (; i < nx; ++i)
        if (pixels[i] >= 128) bits[i / 64] |= Word(1) << (i % 64);
}

/// The first pixel at or after @a from (below @a nx) whose bit equals @a value; nx if none.
int nextWith(const Word* bits, int nx, int from, bool value)
{
    const int words = (nx + 63) / 64;
    int w = from / 64;
    if (w >= words) return nx;
    Word word = (value ? bits[w] : ~bits[w]) & (~Word(0) << (from % 64));
    while (word == 0) {
        if (++w >= words) return nx;
        word = value ? bits[w] : ~bits[w];
    }
    return std::min(nx, w * 64 + __builtin_ctzll(word));
}

/// Bits shifted so that bit i holds pixel i + 1 (across word boundaries).
inline Word nextPixel(const Word* bits, int w, int words)
{
    return (bits[w] >> 1) | (w + 1 < words ? bits[w + 1] << 63 : Word(0));
}
/// Bits shifted so that bit i holds pixel i - 1.
inline Word previousPixel(const Word* bits, int w)
{
    return (bits[w] << 1) | (w > 0 ? bits[w - 1] >> 63 : Word(0));
}

/// Joins runs of consecutive rows that touch (@a diagonal: 8-connected, else 4-connected) and
/// numbers the regions in the order of their first run; fills @a regions.
void labelRuns(std::vector<LayerFeatures::Run>& runs, std::vector<LayerFeatures::Region>& regions, int nx, int ny,
               bool diagonal)
{
    const int n = int(runs.size());
    std::vector<int> parent(n);
    std::iota(parent.begin(), parent.end(), 0);
    const int reach = diagonal ? 1 : 0;
    // Two pointers over the previous row's runs and the current row's.
    int prevBegin = 0, prevEnd = 0;
    for (int k = 0; k < n;) {
        const int row = runs[k].row;
        int rowEnd = k;
        while (rowEnd < n && runs[rowEnd].row == row) ++rowEnd;
        if (prevEnd > prevBegin && runs[prevBegin].row == row - 1) {
            int p = prevBegin;
            for (int c = k; c < rowEnd; ++c) {
                while (p < prevEnd && runs[p].end + reach <= runs[c].begin) ++p;
                for (int q = p; q < prevEnd && runs[q].begin < runs[c].end + reach; ++q) {
                    const int a = findRoot(parent, c), b = findRoot(parent, q);
                    if (a != b) parent[std::max(a, b)] = std::min(a, b);
                }
            }
        }
        prevBegin = k;
        prevEnd = rowEnd;
        k = rowEnd;
    }
    std::vector<int> id(n, -1);
    regions.clear();
    for (int k = 0; k < n; ++k) {
        LayerFeatures::Run& r = runs[k];
        const int root = findRoot(parent, k);
        if (id[root] < 0) {
            id[root] = int(regions.size());
            regions.emplace_back();
            regions.back().nearDistance = std::numeric_limits<int>::max();
        }
        r.region = id[root];
        LayerFeatures::Region& g = regions[r.region];
        const double length = r.end - r.begin;
        g.pixels += r.end - r.begin;
        g.sumI += 0.5 * (r.begin + r.end - 1) * length;
        g.sumJ += double(r.row) * length;
        g.border = g.border || r.row == 0 || r.row == ny - 1 || r.begin == 0 || r.end == nx;
        // The run's pixel nearest to the border: its first or last pixel, or any for a row's edge.
        const int toRows = std::min(r.row, ny - 1 - r.row), left = r.begin, right = nx - r.end;
        const int distance = std::min({toRows, left, right});
        if (distance < g.nearDistance) {
            g.nearDistance = distance;
            g.nearI = distance == right && distance != left ? r.end - 1 : r.begin;
            g.nearJ = r.row;
        }
    }
}

/// The thin pixels (@a thinRuns) that make a feature: a group of thin pixels (8-connected) that
/// is a whole exposed region, or at least kMinThinPixels long. The one or two pixels at the tip of
/// every acute corner (a wall meeting the part's box at a slant) are thin too, but the printer
/// forms them with the wall they belong to.
void keepThinFeatures(std::vector<LayerFeatures::Run>& thinRuns, LayerFeatures& f, int nx, int ny)
{
    constexpr std::int64_t kMinThinPixels = 4;
    if (thinRuns.empty()) return;
    std::vector<LayerFeatures::Region> groups;
    labelRuns(thinRuns, groups, nx, ny, true);
    // The exposed region of each group: the solid run that holds its first run.
    std::vector<int> regionOf(groups.size(), -1);
    std::vector<std::int64_t> thinInRegion(f.solids.size(), 0);
    for (const LayerFeatures::Run& r : thinRuns) {
        auto it = std::upper_bound(f.solidRuns.begin(), f.solidRuns.end(), r, [](const auto& a, const auto& b) {
            return std::tie(a.row, a.begin) < std::tie(b.row, b.begin);
        });
        const int region = std::prev(it)->region;
        regionOf[r.region] = region;
        thinInRegion[region] += r.end - r.begin;
    }
    for (std::size_t g = 0; g < groups.size(); ++g) {
        const bool wholeRegion = thinInRegion[regionOf[g]] == f.solids[regionOf[g]].pixels;
        if (groups[g].pixels < kMinThinPixels && !wholeRegion) continue;
        if (f.thinPixels == 0) {
            f.thinI = groups[g].sumI / double(groups[g].pixels);
            f.thinJ = groups[g].sumJ / double(groups[g].pixels);
        }
        f.thinPixels += groups[g].pixels;
        ++f.thinFeatures;
    }
}

}  // namespace

LayerFeatures analyseLayer(const LayerImage& image)
{
    LayerFeatures f;
    f.index = image.index;
    f.analysed = true;
    const int nx = image.nx, ny = image.ny, words = (nx + 63) / 64;
    if (nx <= 0 || ny <= 0) return f;
    // Three rows of bits at a time: the thin test looks one row up and down.
    std::vector<Word> rows(std::size_t(3) * words);
    std::vector<Word> blocksAbove(words, 0), blocks(words), thinBits(words);
    std::vector<LayerFeatures::Run> thinRuns;
    auto bitsOf = [&](int j) { return &rows[std::size_t(j % 3) * words]; };
    packRow(image.pixels.data(), nx, bitsOf(0));
    for (int j = 0; j < ny; ++j) {
        const Word* bits = bitsOf(j);
        Word* below = nullptr;
        if (j + 1 < ny) {
            below = bitsOf(j + 1);
            packRow(image.pixels.data() + std::size_t(j + 1) * nx, nx, below);
        }
        // Runs of exposed and of void pixels.
        for (int i = 0; i < nx;) {
            const bool exposed = (bits[i / 64] >> (i % 64)) & 1;
            const int end = nextWith(bits, nx, i, !exposed);
            (exposed ? f.solidRuns : f.voidRuns).push_back({j, i, end, -1});
            i = end;
        }
        // Thin: exposed pixels in no fully exposed 2 x 2 block. blocks[] marks the blocks whose
        // top-left pixel is (i, j); a pixel is covered by the blocks at (i - 1 .. i, j - 1 .. j).
        for (int w = 0; w < words; ++w)
            blocks[w] = below ? bits[w] & nextPixel(bits, w, words) & below[w] & nextPixel(below, w, words) : 0;
        for (int w = 0; w < words; ++w) {
            const Word covered =
                blocks[w] | previousPixel(blocks.data(), w) | blocksAbove[w] | previousPixel(blocksAbove.data(), w);
            thinBits[w] = bits[w] & ~covered;
        }
        for (int i = nextWith(thinBits.data(), nx, 0, true); i < nx; i = nextWith(thinBits.data(), nx, i, true)) {
            const int end = nextWith(thinBits.data(), nx, i, false);
            thinRuns.push_back({j, i, end, -1});
            i = end;
        }
        std::swap(blocks, blocksAbove);
    }
    labelRuns(f.solidRuns, f.solids, nx, ny, true);
    labelRuns(f.voidRuns, f.voids, nx, ny, false);
    keepThinFeatures(thinRuns, f, nx, ny);
    return f;
}

namespace {

/// What a layer contributes to the checks, given the layer below: kept for replay a period above.
struct LayerSummary {
    struct Island {
        std::int64_t pixels;
        double i, j;  ///< centroid (window pixels)
    };
    std::vector<Island> islands;
    std::vector<LayerFeatures::Region> voids;
    std::vector<std::pair<int, int>> voidEdges;  ///< (void region below, void region here) that share a pixel
    std::int64_t thinPixels = 0, thinFeatures = 0;
    double thinI = -1, thinJ = -1;
};

/// Calls @a touch(a, b) for each pair of runs of @a below and @a above on the same row that share a pixel.
template <typename Touch>
void overlappingRuns(const std::vector<LayerFeatures::Run>& below, const std::vector<LayerFeatures::Run>& above,
                     Touch touch)
{
    std::size_t p = 0;
    for (const LayerFeatures::Run& r : above) {
        while (p < below.size() && (below[p].row < r.row || (below[p].row == r.row && below[p].end <= r.begin))) ++p;
        for (std::size_t q = p; q < below.size() && below[q].row == r.row && below[q].begin < r.end; ++q)
            touch(below[q], r);
    }
}

LayerSummary summarise(const LayerFeatures* below, const LayerFeatures& here)
{
    LayerSummary s;
    s.voids = here.voids;
    s.thinPixels = here.thinPixels;
    s.thinFeatures = here.thinFeatures;
    s.thinI = here.thinI;
    s.thinJ = here.thinJ;
    if (!below) return s;  // on the plate: nothing is an island, no void continues below
    std::vector<char> supported(here.solids.size(), 0);
    overlappingRuns(below->solidRuns, here.solidRuns,
                    [&](const LayerFeatures::Run&, const LayerFeatures::Run& r) { supported[r.region] = 1; });
    for (std::size_t k = 0; k < here.solids.size(); ++k)
        if (!supported[k]) {
            const LayerFeatures::Region& g = here.solids[k];
            s.islands.push_back({g.pixels, g.sumI / double(g.pixels), g.sumJ / double(g.pixels)});
        }
    // Most regions below overlap one region here, row after row: skip a pair just seen for the
    // region below, so the list to sort stays about as short as the regions.
    std::vector<int> lastHere(below->voids.size(), -1);
    overlappingRuns(below->voidRuns, here.voidRuns, [&](const LayerFeatures::Run& a, const LayerFeatures::Run& b) {
        if (lastHere[a.region] == b.region) return;
        lastHere[a.region] = b.region;
        s.voidEdges.emplace_back(a.region, b.region);
    });
    std::sort(s.voidEdges.begin(), s.voidEdges.end());
    s.voidEdges.erase(std::unique(s.voidEdges.begin(), s.voidEdges.end()), s.voidEdges.end());
    s.voidEdges.shrink_to_fit();  // kept a period long for replay
    return s;
}

/// A void region followed up through the layers (a union of layer regions).
struct VoidBody {
    std::int64_t pixels = 0;
    bool open = false;
    int nearDistance = 0, nearLayer = 0, nearI = 0, nearJ = 0;
    int firstLayer = 0, lastLayer = 0;

    void merge(const VoidBody& o)
    {
        pixels += o.pixels;
        open = open || o.open;
        if (std::tie(o.nearDistance, o.nearLayer, o.nearJ, o.nearI) < std::tie(nearDistance, nearLayer, nearJ, nearI)) {
            nearDistance = o.nearDistance;
            nearLayer = o.nearLayer;
            nearI = o.nearI;
            nearJ = o.nearJ;
        }
        firstLayer = std::min(firstLayer, o.firstLayer);
        lastLayer = std::max(lastLayer, o.lastLayer);
    }
};

}  // namespace

struct PrintabilityCheck::State {
    LayerGeometry geometry;
    int count = 0, period = 0, analysed = 0, replayed = 0;
    std::unique_ptr<LayerFeatures> previous, first;  ///< layer i - 1's runs; layer 0's while it recurs
    std::vector<LayerSummary> phases;                ///< layers 0..period, for replay

    // Findings.
    std::int64_t islands = 0, thinPixels = 0, thinFeatures = 0, thinLayers = 0, traps = 0;
    double islandArea = 0, largestIsland = 0, trapVolume = 0;
    nlohmann::json islandList = nlohmann::json::array(), trapList = nlohmann::json::array(),
                   thinList = nlohmann::json::array();
    std::size_t listed = 200;
    std::int64_t trapsAboveCrumbs = 0;

    // Void bodies of the previous layer: body per void region, and the bodies themselves.
    std::vector<int> bodyOf;
    std::vector<VoidBody> bodies;

    double zOf(int layer) const { return geometry.z0 + (layer + 0.5) * geometry.layer; }
    double voxel() const { return geometry.pitchX * geometry.pitchY * geometry.layer; }

    void take(int index, const LayerSummary& s)
    {
        const double pixelArea = geometry.pitchX * geometry.pitchY;
        for (const LayerSummary::Island& island : s.islands) {
            ++islands;
            islandArea += double(island.pixels) * pixelArea;
            largestIsland = std::max(largestIsland, double(island.pixels) * pixelArea);
            if (islandList.size() < listed)
                islandList.push_back({{"layer", index},
                                      {"z", zOf(index)},
                                      {"x", geometry.x(island.i)},
                                      {"y", geometry.y(island.j)},
                                      {"area_mm2", double(island.pixels) * pixelArea}});
        }
        if (s.thinPixels > 0) {
            thinPixels += s.thinPixels;
            thinFeatures += s.thinFeatures;
            ++thinLayers;
            if (thinList.size() < listed)
                thinList.push_back({{"layer", index},
                                    {"z", zOf(index)},
                                    {"x", geometry.x(s.thinI)},
                                    {"y", geometry.y(s.thinJ)},
                                    {"pixels", s.thinPixels},
                                    {"features", s.thinFeatures}});
        }
        followVoids(index, s);
    }

    /// One step of the streamed 3D components of the void: the layer's regions join the bodies
    /// of the regions below them that share a pixel; a body no region of this layer joins is
    /// complete, and a trap unless it reached the outside.
    void followVoids(int index, const LayerSummary& s)
    {
        const int below = int(bodies.size()), here = int(s.voids.size());
        std::vector<VoidBody> all = bodies;
        for (const LayerFeatures::Region& g : s.voids) {
            VoidBody b;
            b.pixels = g.pixels;
            b.open = g.border;
            b.nearDistance = g.nearDistance;
            b.nearLayer = index;
            b.nearI = g.nearI;
            b.nearJ = g.nearJ;
            b.firstLayer = b.lastLayer = index;
            all.push_back(b);
        }
        std::vector<int> parent(all.size());
        std::iota(parent.begin(), parent.end(), 0);
        for (const auto& [a, b] : s.voidEdges) {
            const int x = findRoot(parent, bodyOf[a]), y = findRoot(parent, below + b);
            if (x != y) parent[std::max(x, y)] = std::min(x, y);
        }
        std::vector<char> continues(all.size(), 0);
        for (int k = 0; k < here; ++k) continues[findRoot(parent, below + k)] = 1;
        // Merge each body into its root in index order (deterministic), then close or renumber.
        std::vector<VoidBody> merged(all.size());
        std::vector<char> started(all.size(), 0);
        for (int k = 0; k < int(all.size()); ++k) {
            const int r = findRoot(parent, k);
            if (!started[r]) {
                merged[r] = all[k];
                started[r] = 1;
            } else {
                merged[r].merge(all[k]);
            }
        }
        for (int k = 0; k < int(all.size()); ++k)
            if (findRoot(parent, k) == k && !continues[k] && !merged[k].open) closeTrap(merged[k]);
        std::vector<int> renumber(all.size(), -1);
        std::vector<VoidBody> next;
        bodyOf.assign(here, -1);
        for (int k = 0; k < here; ++k) {
            const int r = findRoot(parent, below + k);
            if (renumber[r] < 0) {
                renumber[r] = int(next.size());
                next.push_back(merged[r]);
            }
            bodyOf[k] = renumber[r];
        }
        bodies = std::move(next);
    }

    /// Traps smaller than this are numeric crumbs (a few pixels across): listed, not warned of.
    double crumbVolume() const { return kCrumbVoxels * voxel(); }

    /// Largest volume first; ties in the order found (a stable sort: the same for any run).
    static void sortByVolume(nlohmann::json& list)
    {
        std::stable_sort(list.begin(), list.end(), [](const nlohmann::json& a, const nlohmann::json& b) {
            return a["volume_mm3"].get<double>() > b["volume_mm3"].get<double>();
        });
    }

    void closeTrap(const VoidBody& b)
    {
        ++traps;
        const double volume = double(b.pixels) * voxel();
        trapVolume += volume;
        // The largest `listed` traps are kept (a sealed core first, numeric crumbs last): pruned to
        // the largest half whenever the list doubles, so memory stays bounded and order fixed.
        if (trapList.size() >= 2 * listed) {
            sortByVolume(trapList);
            trapList.erase(trapList.begin() + std::ptrdiff_t(listed), trapList.end());
        }
        if (volume >= crumbVolume()) ++trapsAboveCrumbs;
        trapList.push_back({{"volume_mm3", volume},
                            {"x", geometry.x(b.nearI)},
                            {"y", geometry.y(b.nearJ)},
                            {"z", zOf(b.nearLayer)},
                            {"drain_mm", b.nearDistance * std::min(geometry.pitchX, geometry.pitchY)},
                            {"layers", {b.firstLayer, b.lastLayer}}});
    }
};

PrintabilityCheck::PrintabilityCheck(const LayerGeometry& geometry, int count, int period)
    : mState(std::make_unique<State>())
{
    mState->geometry = geometry;
    mState->count = count;
    mState->period = period > 0 && period < count ? period : 0;
}

PrintabilityCheck::~PrintabilityCheck() = default;

bool PrintabilityCheck::needsImage(int index) const
{
    return mState->period == 0 || index < mState->period;
}

void PrintabilityCheck::addLayer(int index, LayerFeatures features)
{
    State& s = *mState;
    const int P = s.period;
    if (P > 0 && index > P) {
        // The pair (index - 1, index) is the pair (index - 1 - P, index - P): replayed.
        s.take(index, s.phases[std::size_t((index - 1) % P + 1)]);
        ++s.replayed;
        return;
    }
    if (P > 0 && index == P) {
        // Layer P shows layer 0's image over layer P - 1.
        LayerSummary summary = summarise(s.previous.get(), *s.first);
        s.take(index, summary);
        s.phases.push_back(std::move(summary));
        s.previous.reset();
        s.first.reset();
        ++s.replayed;
        return;
    }
    auto here = std::make_unique<LayerFeatures>(std::move(features));
    LayerSummary summary = summarise(s.previous.get(), *here);
    s.take(index, summary);
    ++s.analysed;
    if (P > 0) {
        s.phases.push_back(std::move(summary));
        if (index == 0) s.first = std::make_unique<LayerFeatures>(*here);
    }
    s.previous = std::move(here);
}

nlohmann::json PrintabilityCheck::report(std::size_t listed) const
{
    const State& s = *mState;
    nlohmann::json traps = s.trapList;
    State::sortByVolume(traps);
    auto cut = [&](const nlohmann::json& list) {
        nlohmann::json out = nlohmann::json::array();
        for (std::size_t k = 0; k < std::min(listed, list.size()); ++k) out.push_back(list[k]);
        return out;
    };
    return {
        {"islands", cut(s.islandList)},
        {"island_count", s.islands},
        {"island_area_mm2", s.islandArea},
        {"largest_island_mm2", s.largestIsland},
        {"resin_traps", cut(traps)},
        {"resin_trap_count", s.traps},
        {"resin_trap_crumb_mm3", s.crumbVolume()},
        {"resin_traps_above_crumb", s.trapsAboveCrumbs},
        {"resin_trap_volume_mm3", s.trapVolume},
        {"thin",
         {{"pixels", s.thinPixels},
          {"features", s.thinFeatures},
          {"layers", s.thinLayers},
          {"first", cut(s.thinList)}}},
        {"layers_analysed", s.analysed},
        {"layers_replayed", s.replayed},
        {"definitions",
         "islands: exposed regions (8-connected, grey >= 128) touching no exposed pixel of the layer below; "
         "resin traps: void regions reaching neither the part box's sides nor the last layer, largest first (those "
         "below resin_trap_crumb_mm3, 27 pixel-layers, are listed but not warned of); thin: exposed "
         "pixels in no fully exposed 2 x 2 block, in groups (8-connected) of at least 4 pixels or making up a whole "
         "exposed region"}};
}

std::int64_t PrintabilityCheck::islandCount() const
{
    return mState->islands;
}
std::int64_t PrintabilityCheck::trapCount() const
{
    return mState->traps;
}
std::int64_t PrintabilityCheck::trapCountAboveCrumbs() const
{
    return mState->trapsAboveCrumbs;
}
std::int64_t PrintabilityCheck::thinPixelCount() const
{
    return mState->thinPixels;
}

std::string PrintabilityCheck::describeIslands(std::size_t count) const
{
    const State& s = *mState;
    std::string text;
    for (std::size_t k = 0; k < std::min(count, s.islandList.size()); ++k) {
        const nlohmann::json& i = s.islandList[k];
        text += (k ? "; " : "") + std::string("layer ") + std::to_string(i["layer"].get<int>()) + " (z " +
                formatNumber(i["z"].get<double>()) + " mm) at x " + formatNumber(i["x"].get<double>()) + ", y " +
                formatNumber(i["y"].get<double>()) + ", " + formatNumber(i["area_mm2"].get<double>()) + " mm^2";
    }
    if (s.islands > std::int64_t(count)) text += "; ...";
    return text;
}

}  // namespace voxlat
