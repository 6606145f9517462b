#include "mesher/writers/PhotonWorkshopWriter.h"

#include "mesher/writers/LittleEndian.h"
#include "mesher/writers/WindowRuns.h"

#include <algorithm>
#include <cstring>
#include <stdexcept>

namespace voxlat {

namespace {

/// Little-endian bytes plus the format's named tables.
class Tables : public LittleEndian {
public:
    using LittleEndian::LittleEndian;
    /// A named table's prefix: its 12-byte name and length field.
    void table(const char* name, std::uint32_t length)
    {
        text(name, 12);
        u32(length);
    }
};

constexpr std::uint32_t kPreviewTableBytes = 28 + 2 * kPhotonPreviewW * kPhotonPreviewH,
                        kPreview2TableBytes = 28 + 2 * kPhotonPreview2W * kPhotonPreview2H;
constexpr std::uint32_t kColourTableBytes = 28, kExtraTableBytes = 16 + 56, kSoftwareTableBytes = 164,
                        kModelTableBytes = 48;

std::uint32_t fileMarkBytes(std::uint32_t version)
{
    return version >= 518 ? 64 : version == 517 ? 56 : version == 516 ? 52 : 48;
}

std::uint32_t headerBodyBytes(std::uint32_t version)
{
    return version >= 518 ? 96 : version == 517 ? 92 : version == 516 ? 84 : 80;
}

std::uint32_t machineTableBytes(std::uint32_t version)
{
    return version >= 518 ? 224 : 156;
}

std::uint32_t tableCount(std::uint32_t version)
{
    return version >= 518 ? 11 : version == 517 ? 9 : version == 516 ? 8 : version == 515 ? 5 : 4;
}

std::uint32_t subImagesBytes(std::uint32_t layers)
{
    return 24 + 44 * layers;
}

/// Where each table starts (0: absent), in the order real files have them.
struct Addresses {
    std::uint32_t header = 0, preview = 0, colour = 0, layerDef = 0, extra = 0, machine = 0, software = 0, model = 0,
                  subImages = 0, preview2 = 0, layers = 0;
};

Addresses addresses(std::uint32_t version, std::uint32_t layers)
{
    if (version != 1 && (version < 515 || version > 518))
        throw std::logic_error("photon workshop: file versions 1 and 515 to 518 only");
    Addresses a;
    a.header = fileMarkBytes(version);
    a.preview = a.header + 16 + headerBodyBytes(version);
    a.layerDef = a.preview + kPreviewTableBytes;
    if (version >= 515) {
        a.colour = a.layerDef;
        a.layerDef = a.colour + kColourTableBytes;
    }
    std::uint32_t next = a.layerDef + 16 + 4 + 32 * layers;
    if (version >= 516) {
        a.extra = next;
        a.machine = a.extra + kExtraTableBytes;
        next = a.machine + machineTableBytes(version);
    }
    if (version >= 517) {
        a.software = next;
        a.model = a.software + kSoftwareTableBytes;
        next = a.model + kModelTableBytes;
    }
    if (version >= 518) {
        a.subImages = next;
        a.preview2 = a.subImages + subImagesBytes(layers);
        next = a.preview2 + kPreview2TableBytes;
    }
    a.layers = next;
    return a;
}

/// A preview's RGB565 pixels: @a pixels, or dark grey when empty.
void previewPixels(LittleEndian& le, const std::string& pixels, int w, int h)
{
    const std::size_t bytes = std::size_t(2) * w * h;
    if (pixels.empty()) {
        for (std::size_t k = 0; k < bytes / 2; ++k) le.u16(((40 >> 3) << 11) | ((40 >> 2) << 5) | (40 >> 3));
        return;
    }
    if (pixels.size() != bytes) throw std::logic_error("photon workshop: a preview of the wrong size");
    le.raw(pixels);
}

double mmPerSecond(double mmPerMinute)
{
    return mmPerMinute / 60.0;
}

}  // namespace

std::uint32_t photonWorkshopLayersStart(std::uint32_t version, std::uint32_t layers)
{
    return addresses(version, layers).layers;
}

std::string photonWorkshopHeadBytes(const PhotonWorkshopHeader& h, const std::vector<PhotonWorkshopLayer>& layers)
{
    if (layers.size() != h.layers) throw std::logic_error("photon workshop: one LAYERDEF record per layer");
    const Addresses a = addresses(h.version, h.layers);
    std::string out;
    out.reserve(a.layers);
    Tables le(out);
    const bool twoStages = h.normal.liftDistance[1] > 0 || h.bottom.liftDistance[1] > 0;
    // File mark (§3).
    le.text("ANYCUBIC", 12);
    le.u32(h.version);
    le.u32(tableCount(h.version));
    le.u32(a.header);
    le.u32(a.software);
    le.u32(a.preview);
    le.u32(a.colour);
    le.u32(a.layerDef);
    le.u32(a.extra);
    if (h.version <= 515) {
        le.u32(a.layers);
    } else {
        le.u32(a.machine);
        le.u32(a.layers);
    }
    if (h.version >= 517) le.u32(a.model);
    if (h.version >= 518) {
        le.u32(a.subImages);
        le.u32(a.preview2);
    }
    // HEADER (§4).
    le.table("HEADER", headerBodyBytes(h.version));
    le.f32(h.pixelUm);
    le.f32(h.layerMm);
    le.f32(h.exposureS);
    le.f32(h.normal.waitAfterRetract);  // wait before cure
    le.f32(h.bottomExposureS);
    le.f32(double(h.bottomLayers));  // a float in this format
    le.f32(h.normal.liftDistance[0] + h.normal.liftDistance[1]);
    le.f32(mmPerSecond(h.normal.liftSpeed[0]));
    le.f32(mmPerSecond(h.normal.retractSpeed[0]));
    le.f32(h.volumeMl);
    le.u32(h.antiAliasing);  // PW0: 1 (grey is in the pixels); .pws: its bit planes
    le.u32(h.resolutionX);
    le.u32(h.resolutionY);
    le.f32(0);  // weight
    le.f32(0);  // price
    le.raw(std::string("$\0\0\0", 4));
    le.u32(0);  // per-layer values off: the printer uses these globals (firmware trouble otherwise)
    le.u32(h.printTimeS);
    le.u32(0);                                        // transition layers
    le.u32(0);                                        // transition type
    if (h.version >= 516) le.u32(twoStages ? 1 : 0);  // advanced mode: EXTRA's two-stage lift
    if (h.version >= 517) {
        le.u16(0);  // grey
        le.u16(0);  // blur
        le.u32(0);  // resin type
    }
    if (h.version >= 518) le.u32(0);  // intelligent mode off: the file's exposures
    // PREVIEW (§5).
    le.table("PREVIEW", kPreviewTableBytes);
    le.u32(kPhotonPreviewW);
    le.raw(std::string("x\0\0\0", 4));
    le.u32(kPhotonPreviewH);
    previewPixels(le, h.preview, kPhotonPreviewW, kPhotonPreviewH);
    if (h.version >= 515) {
        // Layer image colour table (§6).
        le.u32(0);
        le.u32(16);
        for (int k = 0; k < 16; ++k) le.u8(0xFF);
        le.u32(0);
    }
    // LAYERDEF (§7): each record as the globals of its kind of layer.
    le.table("LAYERDEF", 4 + 32 * h.layers);
    le.u32(h.layers);
    for (const PhotonWorkshopLayer& l : layers) {
        const GooMotion& m = l.bottom ? h.bottom : h.normal;
        le.u32(l.address);
        le.u32(l.length);
        le.f32(m.liftDistance[0] + m.liftDistance[1]);
        le.f32(mmPerSecond(m.liftSpeed[0]));
        le.f32(l.exposureS);
        le.f32(h.layerMm);
        le.u32(l.exposedPixels);
        le.u32(0);
    }
    if (h.version >= 516) {
        // EXTRA (§8): its length field says 24 although it holds 56 bytes.
        le.table("EXTRA", 24);
        for (const GooMotion* m : {&h.bottom, &h.normal}) {
            le.u32(2);
            le.f32(m->liftDistance[0]);
            le.f32(mmPerSecond(m->liftSpeed[0]));
            le.f32(mmPerSecond(m->retractSpeed[0]));
            le.f32(m->liftDistance[1]);
            le.f32(mmPerSecond(m->liftSpeed[1]));
            le.f32(mmPerSecond(m->retractSpeed[1]));
        }
        le.table("MACHINE", machineTableBytes(h.version));
        le.text(h.machineName, 96);
        le.text("pw0Img", 16);
        le.u32(16);                         // most anti-aliasing levels
        le.u32(h.version >= 518 ? 15 : 7);  // property fields, as real files (518: as UVtools)
        le.f32(h.displayWidthMm);
        le.f32(h.displayHeightMm);
        le.f32(h.machineZMm);
        le.u32(h.version);
        le.u32(6506241);  // machine background, as real files
        if (h.version >= 518) {
            le.f32(1000.0 * h.displayWidthMm / h.resolutionX);  // pixel width and height, µm
            le.f32(1000.0 * h.displayHeightMm / h.resolutionY);
            le.zeros(32);
            le.u32(1);  // one display
            le.u32(0);
            le.u16(h.resolutionX);
            le.u16(h.resolutionY);
            le.zeros(16);
        }
    }
    if (h.version >= 517) {
        le.text("voxlat", 32);
        le.u32(kSoftwareTableBytes);
        le.text(h.softwareVersion, 32);
        le.text("linux-x64", 64);
        le.text("", 32);
        le.table("MODEL", kModelTableBytes);
        for (double v : h.modelBox) le.f32(v);
        le.u32(0);  // no supports
        le.f32(0);
    }
    if (h.version >= 518) {
        // SUBIMGS (§8): copies of LAYERDEF's address, length and count; PREVIEW2 (§5).
        le.table("SUBIMGS", subImagesBytes(h.layers));
        le.u32(h.layers);
        le.u32(1);
        for (const PhotonWorkshopLayer& l : layers) {
            le.u32(l.address);
            le.u32(l.length);
            le.u32(l.exposedPixels);
            le.zeros(32);
        }
        le.table("PREVIEW2", kPreview2TableBytes);
        le.u32(kPhotonPreview2W);
        le.u16(4293);  // background colour, as UVtools
        le.u16(0);
        le.u32(kPhotonPreview2H);
        previewPixels(le, h.preview2, kPhotonPreview2W, kPhotonPreview2H);
    }
    if (out.size() != a.layers) throw std::logic_error("photon workshop: the head has the wrong size");
    return out;
}

std::string encodePw0Layer(int width, int height, const std::uint8_t* window, int col0, int row0, int w, int h)
{
    std::string out;
    auto emit = [&](unsigned colour, std::uint64_t length) {
        const std::uint64_t most = colour == 0 || colour == 15 ? 4095 : 15;
        while (length > 0) {
            const unsigned run = unsigned(std::min(length, most));
            length -= run;
            if (most == 4095) {
                const unsigned word = (colour << 12) | run;
                out.push_back(char(word >> 8));
                out.push_back(char(word & 0xFF));
            } else {
                out.push_back(char((colour << 4) | run));
            }
        }
    };
    windowRuns(
        width, height, window, col0, row0, w, h, [](std::uint8_t g) { return unsigned(g >> 4); }, emit);
    return out;
}

std::uint32_t pw0ExposedPixels(const std::string& code)
{
    std::uint64_t exposed = 0;
    for (std::size_t k = 0; k < code.size();) {
        const unsigned b = std::uint8_t(code[k]);
        const unsigned c = b >> 4;
        if (c == 0 || c == 15) {
            const unsigned run = ((b & 0x0F) << 8) | std::uint8_t(code[k + 1]);
            if (c == 15) exposed += run;
            k += 2;
        } else {
            exposed += b & 0x0F;
            k += 1;
        }
    }
    return std::uint32_t(exposed);
}

std::string photonWorkshopPreview(const std::uint8_t* rgba, int width, int height, int outW, int outH)
{
    std::string out;
    out.reserve(std::size_t(2) * outW * outH);
    Tables le(out);
    for (int r = 0; r < outH; ++r)
        for (int c = 0; c < outW; ++c) {
            const int x = std::min(width - 1, c * width / outW);
            const int y = std::min(height - 1, r * height / outH);
            const std::uint8_t* p = rgba + 4 * (std::size_t(y) * width + x);
            le.u16(unsigned((p[0] & 0xF8) << 8) | unsigned((p[1] & 0xFC) << 3) | unsigned(p[2] >> 3));
        }
    return out;
}

}  // namespace voxlat
