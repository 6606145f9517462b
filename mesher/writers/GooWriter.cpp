#include "mesher/writers/GooWriter.h"

#include "mesher/writers/WindowRuns.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>

namespace voxlat {

namespace {

/// Appends big-endian numbers and fixed-width strings.
class BigEndian {
public:
    explicit BigEndian(std::string& out) : mOut(out) {}
    void u8(unsigned v) { mOut.push_back(char(v & 0xFF)); }
    void u16(unsigned v)
    {
        u8(v >> 8);
        u8(v);
    }
    void u32(std::uint32_t v)
    {
        u16(v >> 16);
        u16(v & 0xFFFF);
    }
    void f32(double v)
    {
        const float f = float(v);
        std::uint32_t bits;
        std::memcpy(&bits, &f, 4);
        u32(bits);
    }
    /// @a s NUL-padded to @a width bytes (cut to width - 1 so a NUL always ends it).
    void text(const std::string& s, std::size_t width)
    {
        const std::size_t n = std::min(s.size(), width - 1);
        mOut.append(s, 0, n);
        mOut.append(width - n, '\0');
    }
    void raw(const std::string& s) { mOut += s; }
    void crlf() { mOut += "\r\n"; }

private:
    std::string& mOut;
};

/// The motion block shared by the header (twice: bottom, normal) is laid out differently there;
/// this is the per-layer order (§4 of the reference).
void layerMotion(BigEndian& out, const GooMotion& m)
{
    out.f32(m.waitBeforeLift);
    out.f32(m.waitAfterLift);
    out.f32(m.waitAfterRetract);
    out.f32(m.liftDistance[0]);
    out.f32(m.liftSpeed[0]);
    out.f32(m.liftDistance[1]);
    out.f32(m.liftSpeed[1]);
    out.f32(m.retractDistance[0]);
    out.f32(m.retractSpeed[0]);
    out.f32(m.retractDistance[1]);
    out.f32(m.retractSpeed[1]);
    out.u16(unsigned(std::clamp(m.lightPwm, 0, 255)));
}

std::string flatPreview(int side)
{
    std::string out;
    BigEndian be(out);
    for (int k = 0; k < side * side; ++k) be.u16(((40 >> 3) << 11) | ((40 >> 2) << 5) | (40 >> 3));
    return out;
}

/// Appends one run: value @a v, @a n pixels (n >= 1), as one or more chunks of at most 2^28 - 1.
void appendRun(std::string& out, std::uint8_t v, std::uint64_t n)
{
    while (n > 0) {
        const std::uint32_t len = std::uint32_t(std::min<std::uint64_t>(n, 0xFFFFFFF));
        n -= len;
        const unsigned type = v == 0 ? 0u : v == 255 ? 3u : 1u;
        const unsigned k = len <= 0xF ? 0u : len <= 0xFFF ? 1u : len <= 0xFFFFF ? 2u : 3u;
        out.push_back(char((type << 6) | (k << 4) | (len & 0xF)));
        if (type == 1) out.push_back(char(v));
        for (unsigned b = k; b >= 1; --b) out.push_back(char((len >> (4 + 8 * (b - 1))) & 0xFF));
    }
}

}  // namespace

std::string gooHeaderBytes(const GooHeader& h)
{
    std::string out;
    out.reserve(kGooHeaderBytes);
    BigEndian be(out);
    be.raw("V3.0");
    be.raw(std::string("\x07\x00\x00\x00\x44\x4C\x50\x00", 8));
    be.text(h.softwareName, 32);
    be.text(h.softwareVersion, 24);
    be.text(h.created, 24);
    be.text(h.printerName, 32);
    be.text(h.printerType, 32);
    be.text(h.resinName, 32);
    be.u16(unsigned(h.antiAliasing));
    be.u16(unsigned(h.greyLevel));
    be.u16(unsigned(h.blurLevel));
    const std::size_t small = std::size_t(2) * kGooSmallPreview * kGooSmallPreview;
    const std::size_t big = std::size_t(2) * kGooBigPreview * kGooBigPreview;
    if ((!h.smallPreview.empty() && h.smallPreview.size() != small) ||
        (!h.bigPreview.empty() && h.bigPreview.size() != big))
        throw std::logic_error("goo previews must be 116 x 116 and 290 x 290 RGB565");
    be.raw(h.smallPreview.empty() ? flatPreview(kGooSmallPreview) : h.smallPreview);
    be.crlf();
    be.raw(h.bigPreview.empty() ? flatPreview(kGooBigPreview) : h.bigPreview);
    be.crlf();
    be.u32(h.layers);
    be.u16(unsigned(h.resolutionX));
    be.u16(unsigned(h.resolutionY));
    be.u8(h.mirrorX);
    be.u8(h.mirrorY);
    be.f32(h.displayWidthMm);
    be.f32(h.displayHeightMm);
    be.f32(h.machineZMm);
    be.f32(h.layerMm);
    be.f32(h.exposureS);
    be.u8(1);   // delay mode: the wait times below are used
    be.f32(0);  // light-off delay (delay mode 0 only)
    be.f32(h.bottom.waitBeforeLift);
    be.f32(h.bottom.waitAfterLift);
    be.f32(h.bottom.waitAfterRetract);
    be.f32(h.normal.waitBeforeLift);
    be.f32(h.normal.waitAfterLift);
    be.f32(h.normal.waitAfterRetract);
    be.f32(h.bottomExposureS);
    be.u32(h.bottomLayers);
    be.f32(h.bottom.liftDistance[0]);
    be.f32(h.bottom.liftSpeed[0]);
    be.f32(h.normal.liftDistance[0]);
    be.f32(h.normal.liftSpeed[0]);
    be.f32(h.bottom.retractDistance[0]);
    be.f32(h.bottom.retractSpeed[0]);
    be.f32(h.normal.retractDistance[0]);
    be.f32(h.normal.retractSpeed[0]);
    be.f32(h.bottom.liftDistance[1]);
    be.f32(h.bottom.liftSpeed[1]);
    be.f32(h.normal.liftDistance[1]);
    be.f32(h.normal.liftSpeed[1]);
    be.f32(h.bottom.retractDistance[1]);
    be.f32(h.bottom.retractSpeed[1]);
    be.f32(h.normal.retractDistance[1]);
    be.f32(h.normal.retractSpeed[1]);
    be.u16(unsigned(std::clamp(h.bottom.lightPwm, 0, 255)));
    be.u16(unsigned(std::clamp(h.normal.lightPwm, 0, 255)));
    be.u8(0);  // advance mode off: the printer uses the header's values (firmware trouble otherwise)
    be.u32(h.printTimeS);
    be.f32(h.volumeMm3);
    be.f32(h.weightG);
    be.f32(h.price);
    be.text(h.priceUnit, 8);
    be.u32(std::uint32_t(kGooHeaderBytes));  // where layer 0 starts
    be.u8(1);                                // grey levels 0x00..0xFF
    be.u16(unsigned(h.transitionLayers));
    if (out.size() != kGooHeaderBytes) throw std::logic_error("goo header has the wrong size");
    return out;
}

std::string gooPreview(const std::uint8_t* rgba, int width, int height, int side)
{
    std::string out;
    out.reserve(std::size_t(2) * side * side);
    BigEndian be(out);
    for (int r = 0; r < side; ++r)
        for (int c = 0; c < side; ++c) {
            const int x = std::min(width - 1, c * width / side), y = std::min(height - 1, r * height / side);
            const std::uint8_t* p = rgba + 4 * (std::size_t(y) * width + x);
            be.u16(unsigned((p[0] >> 3) << 11) | unsigned((p[1] >> 2) << 5) | unsigned(p[2] >> 3));
        }
    return out;
}

std::string encodeGooLayer(int width, int height, const std::uint8_t* window, int col0, int row0, int w, int h)
{
    std::string out(1, char(0x55));
    // Runs of equal pixels over the whole display, row after row; the margins are black.
    windowRuns(
        width, height, window, col0, row0, w, h, [](std::uint8_t g) { return g; },
        [&](std::uint8_t v, std::uint64_t n) { appendRun(out, v, n); });
    unsigned sum = 0;
    for (std::size_t k = 1; k < out.size(); ++k) sum += std::uint8_t(out[k]);
    out.push_back(char(~sum & 0xFF));
    return out;
}

std::string gooLayerBytes(const GooLayerDefinition& d, const std::string& image)
{
    std::string out;
    out.reserve(72 + image.size());
    BigEndian be(out);
    be.u16(0);      // no pause
    be.f32(d.zMm);  // pause Z: the layer's own, as CHITUBOX writes
    be.f32(d.zMm);
    be.f32(d.exposureS);
    be.f32(0);  // light-off delay
    layerMotion(be, d.motion);
    be.crlf();
    be.u32(std::uint32_t(image.size()));
    be.raw(image);
    be.crlf();
    return out;
}

std::string gooEnding()
{
    return std::string("\x00\x00\x00\x07\x00\x00\x00\x44\x4C\x50\x00", 11);
}

}  // namespace voxlat
