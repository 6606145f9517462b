#include "mesher/writers/AnycubicZipWriter.h"

#include "mesher/writers/LittleEndian.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <tuple>

namespace voxlat {

namespace {

/// 8-connected pieces of lit pixels gathered row by row from the rows' lit spans: each span a
/// label, joined (union-find) with the spans of the row above that touch it, diagonals included.
class Pieces {
public:
    /// Lit pixels [a, b) of @a row; rows come in order, spans in order within a row.
    void add(int row, int a, int b)
    {
        if (row != mRow) closeRow();
        mRow = row;
        if (!mPending.empty() && mPending.back().second == a)
            mPending.back().second = b;  // runs of two greys side by side are one span
        else
            mPending.emplace_back(a, b);
    }
    /// The count of pieces and the largest one's pixels, once every row is added.
    std::pair<std::uint32_t, std::uint64_t> result()
    {
        closeRow();
        std::uint32_t count = 0;
        std::uint64_t largest = 0;
        for (std::uint32_t i = 0; i < mParent.size(); ++i)
            if (mParent[i] == i) {
                ++count;
                largest = std::max<std::uint64_t>(largest, mSize[i]);
            }
        return {count, largest};
    }

private:
    struct Span {
        int a, b;
        std::uint32_t label;
    };
    std::uint32_t find(std::uint32_t i)
    {
        while (mParent[i] != i) i = mParent[i] = mParent[mParent[i]];
        return i;
    }
    void join(std::uint32_t i, std::uint32_t j)
    {
        i = find(i), j = find(j);
        if (i == j) return;
        if (mSize[i] < mSize[j]) std::swap(i, j);
        mParent[j] = i;
        mSize[i] += mSize[j];
    }
    void closeRow()
    {
        if (mPending.empty()) return;
        std::vector<Span> spans;
        spans.reserve(mPending.size());
        for (const auto& [a, b] : mPending) {
            const auto label = std::uint32_t(mParent.size());  // a display has < 2^28 pixels
            spans.push_back({a, b, label});
            mParent.push_back(label);
            mSize.push_back(std::uint32_t(b - a));
        }
        if (mPreviousRow == mRow - 1) {
            // Spans [a, b) of adjacent rows touch when a <= b' and a' <= b (a diagonal counts).
            for (std::size_t i = 0, j = 0; i < spans.size() && j < mPrevious.size();) {
                if (spans[i].a <= mPrevious[j].b && mPrevious[j].a <= spans[i].b)
                    join(spans[i].label, mPrevious[j].label);
                if (spans[i].b < mPrevious[j].b)
                    ++i;
                else
                    ++j;
            }
        }
        mPrevious = std::move(spans);
        mPreviousRow = mRow;
        mPending.clear();
    }

    int mRow = -1, mPreviousRow = -2;
    std::vector<std::pair<int, int>> mPending;
    std::vector<Span> mPrevious;
    std::vector<std::uint32_t> mParent;  ///< 8 bytes a span with mSize
    std::vector<std::uint32_t> mSize;
};

}  // namespace

Pw0LayerShape pw0LayerShape(const std::string& code, int width, int height)
{
    Pw0LayerShape s;
    Pieces pieces;
    const std::uint64_t total = std::uint64_t(width) * std::uint64_t(height);
    std::uint64_t at = 0;
    s.col0 = width, s.row0 = height;
    for (std::size_t k = 0; k < code.size();) {
        const unsigned b = std::uint8_t(code[k]);
        const unsigned c = b >> 4;
        std::uint64_t run = 0;
        if (c == 0 || c == 15) {
            if (k + 1 >= code.size()) throw std::invalid_argument("a PW0 layer ends inside a two-byte run");
            run = ((b & 0x0F) << 8) | std::uint8_t(code[k + 1]);
            k += 2;
        } else {
            run = b & 0x0F;
            k += 1;
        }
        if (run == 0 || at + run > total) throw std::invalid_argument("a PW0 layer's runs do not cover its display");
        if (c != 0) {
            s.litPixels += run;
            s.coverage += double(run) * c / 15.0;
            // The run's pixels row by row (a run may go on into the next rows).
            for (std::uint64_t p = at, end = at + run; p < end;) {
                const int row = int(p / std::uint64_t(width)), col = int(p % std::uint64_t(width));
                const int stop = int(std::min<std::uint64_t>(end - p + std::uint64_t(col), std::uint64_t(width)));
                pieces.add(row, col, stop);
                s.col0 = std::min(s.col0, col), s.col1 = std::max(s.col1, stop);
                s.row0 = std::min(s.row0, row), s.row1 = std::max(s.row1, row + 1);
                p += std::uint64_t(stop - col);
            }
        }
        at += run;
    }
    if (at != total) throw std::invalid_argument("a PW0 layer's runs do not cover its display");
    if (s.litPixels == 0) s.col0 = s.row0 = 0;
    std::tie(s.pieces, s.largestPiecePixels) = pieces.result();
    return s;
}

std::string anycubicSceneBytes(const std::string& software, const std::array<double, 6>& box,
                               const std::vector<AnycubicSceneLayer>& layers)
{
    std::string out;
    out.reserve(0x18C + 64 * layers.size() + 4);
    LittleEndian le(out);
    le.text("ANYCUBIC-PWSZ", 16);
    le.text(software, 64);
    le.u32(3);    // binary type: "FPGA release", what the firmware expects
    le.u32(3);    // the layout's version, as Photon Workshop 4.2 writes it
    le.u32(0);    // slice type
    le.u32(0);    // model unit: mm
    le.f32(1.0);  // point ratio
    le.u32(std::uint32_t(layers.size()));
    for (double v : box) le.f32(v);
    le.u32(0);  // model status flags
    le.to(0x184);
    le.raw("<---");
    le.u32(std::uint32_t(layers.size()));
    for (const AnycubicSceneLayer& l : layers) {
        le.f32(l.zMm);
        le.f32(l.areaMm2);
        for (double v : l.box) le.f32(v);
        le.u32(l.pieces);
        le.f32(l.largestPieceMm2);
        le.zeros(32);
    }
    le.raw("--->");
    return out;
}

std::vector<AnycubicVolumeSlab> anycubicVolumeSlabs(const std::vector<double>& areasMm2, double thicknessMm,
                                                    double totalMl)
{
    std::vector<AnycubicVolumeSlab> slabs;
    const int n = int(areasMm2.size());
    if (n == 0 || !(thicknessMm > 0)) return slabs;
    const int perSlab = std::max(1, int(std::lround(0.2 / thicknessMm)));
    const int leftOut = std::max(1, int(std::lround(0.1 / thicknessMm)));
    const int counted = std::max(1, n - leftOut);
    double z = 0, sum = 0;
    for (int first = 0; first < counted; first += perSlab) {
        const int take = std::min(perSlab, counted - first);
        AnycubicVolumeSlab s;
        s.layer = std::uint32_t(first == 0 ? 0 : first - 1);
        s.zMm = z;
        s.thicknessMm = take * thicknessMm;
        for (int i = first; i < first + take; ++i) s.raw += areasMm2[std::size_t(i)] * thicknessMm;
        sum += s.raw;
        z += s.thicknessMm;
        slabs.push_back(s);
    }
    // The raw unit is 0.0011 mL (1.1 mm3): scaled so the slabs add up to the job's volume.
    const double scale = totalMl > 0 && sum > 0 ? totalMl / kAnycubicRawVolumeMl / sum : 1.0 / 1.1;
    for (AnycubicVolumeSlab& s : slabs) s.raw *= scale;
    return slabs;
}

std::string anycubicVolumesBytes(const std::vector<AnycubicVolumeSlab>& slabs)
{
    std::string out;
    LittleEndian le(out);
    le.u32(0x20251024);
    le.f32(0.2);
    le.u32(1);
    le.u32(std::uint32_t(slabs.size()));
    for (const AnycubicVolumeSlab& s : slabs) {
        le.u32(s.layer);
        le.f32(s.zMm);
        le.f32(s.thicknessMm);
        le.zeros(32);
        le.f32(s.raw);
    }
    return out;
}

}  // namespace voxlat
