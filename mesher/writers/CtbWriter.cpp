#include "mesher/writers/CtbWriter.h"

#include "mesher/writers/LittleEndian.h"
#include "mesher/writers/WindowRuns.h"

#include <nettle/aes.h>
#include <nettle/cbc.h>
#include <nettle/sha2.h>

#include <algorithm>
#include <cstring>
#include <stdexcept>

namespace voxlat {

namespace {

constexpr std::uint32_t kHeaderBytes = 112, kPreviewHeaderBytes = 32, kPrintParametersBytes = 60, kSlicerInfoBytes = 76,
                        kPrintParametersV4Bytes = 464, kResinParametersBytes = 40, kLayerDefBytes = 36,
                        kLayerDefExBytes = 84, kEncryptedHeaderBytes = 48, kSettingsBytes = 288,
                        kEncryptedPreviewHeaderBytes = 16, kLayerPointerBytes = 16, kEncryptedLayerBytes = 88;

constexpr std::uint32_t previewSlot(int w, int h)
{
    return std::uint32_t(2 * w * h);  // RLE15 never takes more than a word a pixel
}

// ResinParameters' strings (v5): type, name, machine ([U]'s order).
const std::string kResinType = "normal", kResinName = "voxlat";

std::uint32_t resinParametersBytes(const CtbHeader& h)
{
    return kResinParametersBytes + std::uint32_t(kResinType.size() + kResinName.size() + h.machineName.size());
}

/// ResinParameters (§3.7) at @a at: colour, then the strings type, name, machine.
void resinParameters(LittleEndian& le, const CtbHeader& h, std::uint32_t at)
{
    const std::uint32_t type = at + kResinParametersBytes;
    const std::uint32_t name = type + std::uint32_t(kResinType.size());
    const std::uint32_t machine = name + std::uint32_t(kResinName.size());
    le.u32(0);
    le.u8(0x20);  // B, G, R, A: an orange resin
    le.u8(0x80);
    le.u8(0xF0);
    le.u8(0xFF);
    le.u32(machine);
    le.u32(std::uint32_t(kResinType.size()));
    le.u32(type);
    le.u32(std::uint32_t(kResinName.size()));
    le.u32(name);
    le.u32(std::uint32_t(h.machineName.size()));
    le.f32(1.1);
    le.u32(0);
    le.raw(kResinType);
    le.raw(kResinName);
    le.raw(h.machineName);
}

const std::uint8_t kAesKey[32] = {0xD0, 0x5B, 0x8E, 0x33, 0x71, 0xDE, 0x3D, 0x1A, 0xE5, 0x4F, 0x22,
                                  0xDD, 0xDF, 0x5B, 0xFD, 0x94, 0xAB, 0x5D, 0x64, 0x3A, 0x9D, 0x7E,
                                  0xBF, 0xAF, 0x42, 0x03, 0xF3, 0x10, 0xD8, 0x52, 0x2A, 0xEA};
const std::uint8_t kAesIv[16] = {0x0F, 0x01, 0x0A, 0x05, 0x05, 0x0B, 0x06, 0x07,
                                 0x08, 0x06, 0x0A, 0x0C, 0x0C, 0x0D, 0x09, 0x0F};

double lightOff(const CtbHeader& h, const GooMotion& m)
{
    // v4+ states the waits themselves; older versions only know one light-off delay.
    return h.version >= 4 ? 0.0 : m.waitBeforeLift + m.waitAfterLift + m.waitAfterRetract;
}

void layerDef(LittleEndian& le, const CtbHeader& h, const CtbLayerDef& d)
{
    le.f32(d.zMm);
    le.f32(d.exposureS);
    le.f32(d.lightOffS);
    le.u32(std::uint32_t(d.dataOffset & 0xFFFFFFFFu));
    le.u32(d.dataLength);
    le.u32(std::uint32_t(d.dataOffset >> 32));
    le.u32(h.version >= 3 ? kLayerDefExBytes : kLayerDefBytes);
    le.u32(0);
    le.u32(0);
}

/// Appends one run of @a n pixels of 7-bit value @a v.
void appendRun(std::string& out, unsigned v, std::uint64_t n)
{
    while (n > 0) {
        const std::uint32_t len = std::uint32_t(std::min<std::uint64_t>(n, 0xFFFFFFF));
        n -= len;
        if (len == 1) {
            out.push_back(char(v));
            continue;
        }
        out.push_back(char(v | 0x80));
        if (len <= 0x7F) {
            out.push_back(char(len));
        } else if (len <= 0x3FFF) {
            out.push_back(char(0x80 | (len >> 8)));
            out.push_back(char(len & 0xFF));
        } else if (len <= 0x1FFFFF) {
            out.push_back(char(0xC0 | (len >> 16)));
            out.push_back(char((len >> 8) & 0xFF));
            out.push_back(char(len & 0xFF));
        } else {
            out.push_back(char(0xE0 | (len >> 24)));
            out.push_back(char((len >> 16) & 0xFF));
            out.push_back(char((len >> 8) & 0xFF));
            out.push_back(char(len & 0xFF));
        }
    }
}

/// PrintParameters (§3.3) at @a at: heights are the totals of both stages from v4 on.
void printParameters(LittleEndian& le, const CtbHeader& h, std::uint32_t at)
{
    const bool v4 = h.version >= 4;
    le.to(at);
    const double bottomLift = h.bottom.liftDistance[0] + (v4 ? h.bottom.liftDistance[1] : 0.0);
    const double lift = h.normal.liftDistance[0] + (v4 ? h.normal.liftDistance[1] : 0.0);
    le.f32(bottomLift);
    le.f32(h.bottom.liftSpeed[0]);
    le.f32(lift);
    le.f32(h.normal.liftSpeed[0]);
    le.f32(h.normal.retractSpeed[0]);
    le.f32(h.volumeMl);
    le.f32(0);  // weight
    le.f32(0);  // cost
    le.f32(lightOff(h, h.bottom));
    le.f32(lightOff(h, h.normal));
    le.u32(h.bottomLayers);
    le.zeros(16);
}

}  // namespace

const std::string& ctbDisclaimer()
{
    static const std::string text =
        "Layout and record format for the ctb and cbddlp file types are the copyrighted programs or codes of CBD "
        "Technology (China) Inc..The Customer or User shall not in any manner reproduce, distribute, modify, "
        "decompile, disassemble, decrypt, extract, reverse engineer, lease, assign, or sublicense the said programs "
        "or codes.";
    return text;
}

CtbLayout ctbLayout(const CtbHeader& h)
{
    if (h.bitPlanes ? h.version < 1 || h.version > 2 || h.encrypted : h.version < 2 || h.version > 5)
        throw std::logic_error("ctb: versions 2 to 5 (bit planes: 1 or 2) only");
    if (h.encrypted && h.version < 4) throw std::logic_error("ctb: the encrypted layout is version 4 or 5");
    CtbLayout l;
    if (h.bitPlanes) {
        // Header, previews, PrintParameters (version 2), the table: no SlicerInfo, no name.
        l.largePreview = kHeaderBytes;
        l.smallPreview = l.largePreview + kPreviewHeaderBytes + previewSlot(kCtbLargePreviewW, kCtbLargePreviewH);
        std::uint32_t next = l.smallPreview + kPreviewHeaderBytes + previewSlot(kCtbSmallPreviewW, kCtbSmallPreviewH);
        if (h.version >= 2) {
            l.printParameters = next;
            next += kPrintParametersBytes;
        }
        l.layerTable = next;
        l.layersStart = std::uint64_t(l.layerTable) + std::uint64_t(kLayerDefBytes) * h.layers * h.planes;
        return l;
    }
    if (h.encrypted) {
        l.largePreview = kEncryptedHeaderBytes + kSettingsBytes;
        l.smallPreview =
            l.largePreview + kEncryptedPreviewHeaderBytes + previewSlot(kCtbLargePreviewW, kCtbLargePreviewH);
        l.machineName =
            l.smallPreview + kEncryptedPreviewHeaderBytes + previewSlot(kCtbSmallPreviewW, kCtbSmallPreviewH);
        l.disclaimer = l.machineName + std::uint32_t(h.machineName.size());
        std::uint32_t next = l.disclaimer + std::uint32_t(ctbDisclaimer().size());
        if (h.version >= 5) {
            l.resinParameters = next;
            next += resinParametersBytes(h);
        }
        l.layerTable = next;
        l.layersStart = std::uint64_t(l.layerTable) + std::uint64_t(kLayerPointerBytes) * h.layers;
        return l;
    }
    l.largePreview = kHeaderBytes;
    l.smallPreview = l.largePreview + kPreviewHeaderBytes + previewSlot(kCtbLargePreviewW, kCtbLargePreviewH);
    l.printParameters = l.smallPreview + kPreviewHeaderBytes + previewSlot(kCtbSmallPreviewW, kCtbSmallPreviewH);
    l.slicerInfo = l.printParameters + kPrintParametersBytes;
    l.machineName = l.slicerInfo + kSlicerInfoBytes;
    std::uint32_t next = l.machineName + std::uint32_t(h.machineName.size());
    if (h.version >= 4) {
        l.disclaimer = next;
        l.printParametersV4 = l.disclaimer + std::uint32_t(ctbDisclaimer().size());
        next = l.printParametersV4 + kPrintParametersV4Bytes;
    }
    if (h.version >= 5) {
        l.resinParameters = next;
        next += resinParametersBytes(h);
    }
    l.layerTable = next;
    l.layersStart = std::uint64_t(l.layerTable) + std::uint64_t(kLayerDefBytes) * h.layers;
    return l;
}

std::string ctbAesCbc(const std::string& plain)
{
    if (plain.size() % AES_BLOCK_SIZE != 0) throw std::logic_error("ctb: AES-CBC takes whole 16-byte blocks");
    aes256_ctx ctx;
    aes256_set_encrypt_key(&ctx, kAesKey);
    std::uint8_t iv[AES_BLOCK_SIZE];
    std::memcpy(iv, kAesIv, sizeof iv);
    std::string out(plain.size(), '\0');
    cbc_encrypt(&ctx, reinterpret_cast<nettle_cipher_func*>(aes256_encrypt), AES_BLOCK_SIZE, iv, plain.size(),
                reinterpret_cast<std::uint8_t*>(out.data()), reinterpret_cast<const std::uint8_t*>(plain.data()));
    return out;
}

std::uint64_t ctbSignatureOffset(const CtbHeader& h, std::uint64_t layersEnd)
{
    return layersEnd + (h.version >= 5 ? 8 : 0);
}

std::string ctbTailBytes(const CtbHeader& h)
{
    if (!h.encrypted) return {};
    std::string checksum;
    LittleEndian le(checksum);
    le.u32(std::uint32_t(kCtbChecksum & 0xFFFFFFFFu));
    le.u32(std::uint32_t(kCtbChecksum >> 32));
    sha256_ctx sha;
    sha256_init(&sha);
    sha256_update(&sha, checksum.size(), reinterpret_cast<const std::uint8_t*>(checksum.data()));
    std::string digest(SHA256_DIGEST_SIZE, '\0');
    sha256_digest(&sha, SHA256_DIGEST_SIZE, reinterpret_cast<std::uint8_t*>(digest.data()));
    const std::string signature = ctbAesCbc(digest);
    // UVtools' bytes around the signature for v5 (none in Chitubox's v4 file).
    if (h.version >= 5) return std::string("\xFA\x52\x20\x42\0\0\0\0", 8) + signature + "\xB3\x32\x42\x6D";
    return signature;
}

namespace {

/// The encrypted layout's head (§7): header, AES settings, previews, name, disclaimer,
/// [resin parameters], layer pointers.
std::string encryptedHead(const CtbHeader& h, const std::string& largePreview, const std::string& smallPreview,
                          const std::vector<CtbLayerDef>& layers, std::uint64_t layersEnd)
{
    const CtbLayout l = ctbLayout(h);
    std::string out;
    out.reserve(std::size_t(l.layersStart));
    LittleEndian le(out);
    const std::uint64_t signature = ctbSignatureOffset(h, layersEnd);
    le.u32(kCtbMagicEncrypted);
    le.u32(kSettingsBytes);
    le.u32(kEncryptedHeaderBytes);
    le.u32(0);
    le.u32(std::uint32_t(h.version));
    le.u32(32);
    le.u32(std::uint32_t(signature));
    le.u32(0);
    le.u16(1);
    le.u16(1);
    le.u32(0);
    le.u32(42);
    le.u32(0);
    // Settings, 288 bytes, then AES-CBC.
    std::string settings;
    LittleEndian s(settings);
    const GooMotion &b = h.bottom, &n = h.normal;
    s.u32(std::uint32_t(kCtbChecksum & 0xFFFFFFFFu));
    s.u32(std::uint32_t(kCtbChecksum >> 32));
    s.u32(l.layerTable);
    s.f32(h.displayWidthMm);
    s.f32(h.displayHeightMm);
    s.f32(h.machineZMm);
    s.u32(0);
    s.u32(0);
    s.f32(h.totalHeightMm);
    s.f32(h.layerMm);
    s.f32(h.exposureS);
    s.f32(h.bottomExposureS);
    s.f32(0);  // light-off delay: the waits below are used
    s.u32(h.bottomLayers);
    s.u32(h.resolutionX);
    s.u32(h.resolutionY);
    s.u32(h.layers);
    s.u32(l.largePreview);
    s.u32(l.smallPreview);
    s.u32(h.printTimeS);
    s.u32(1);  // projector type
    s.f32(b.liftDistance[0] + b.liftDistance[1]);
    s.f32(b.liftSpeed[0]);
    s.f32(n.liftDistance[0] + n.liftDistance[1]);
    s.f32(n.liftSpeed[0]);
    s.f32(n.retractSpeed[0]);
    s.f32(h.volumeMl);
    s.f32(0);  // weight
    s.f32(0);  // cost
    s.f32(0);  // bottom light-off delay
    s.u32(1);
    s.u16(unsigned(std::clamp(n.lightPwm, 0, 255)));
    s.u16(unsigned(std::clamp(b.lightPwm, 0, 255)));
    s.u32(h.key);
    s.f32(b.liftDistance[1]);
    s.f32(b.liftSpeed[1]);
    s.f32(n.liftDistance[1]);
    s.f32(n.liftSpeed[1]);
    s.f32(n.retractDistance[1]);
    s.f32(n.retractSpeed[1]);
    s.f32(n.waitAfterLift);
    s.u32(l.machineName);
    s.u32(std::uint32_t(h.machineName.size()));
    s.u8(0x0F);
    s.u16(0);
    s.u8(0);   // per-layer settings off
    s.u32(0);  // modified time
    s.u32(h.antiAliasing);
    s.f32(n.waitAfterRetract);
    s.f32(n.waitAfterLift);
    s.u32(h.transitionLayers);
    s.f32(b.retractSpeed[0]);
    s.f32(b.retractSpeed[1]);
    s.u32(0);
    s.f32(4.0);
    s.u32(0);
    s.f32(4.0);
    s.f32(n.waitAfterRetract);
    s.f32(n.waitAfterLift);
    s.f32(n.waitBeforeLift);
    s.f32(b.retractDistance[1]);
    s.u32(0);
    s.u32(0);
    s.u32(4);
    s.u32(h.layers > 0 ? h.layers - 1 : 0);
    s.zeros(16);
    s.u32(l.disclaimer);
    s.u32(std::uint32_t(ctbDisclaimer().size()));
    s.u32(0);
    s.u32(l.resinParameters);
    s.u32(0);
    s.u32(0);
    if (settings.size() != kSettingsBytes) throw std::logic_error("ctb: the settings have the wrong size");
    le.raw(ctbAesCbc(settings));
    auto preview = [&](std::uint32_t at, int w, int hgt, const std::string& data) {
        le.to(at);
        le.u32(std::uint32_t(w));
        le.u32(std::uint32_t(hgt));
        le.u32(at + kEncryptedPreviewHeaderBytes);
        le.u32(std::uint32_t(data.size()));
        le.raw(data);
    };
    preview(l.largePreview, kCtbLargePreviewW, kCtbLargePreviewH, largePreview);
    preview(l.smallPreview, kCtbSmallPreviewW, kCtbSmallPreviewH, smallPreview);
    le.to(l.machineName);
    le.raw(h.machineName);
    le.raw(ctbDisclaimer());
    if (h.version >= 5) resinParameters(le, h, l.resinParameters);
    le.to(l.layerTable);
    for (const CtbLayerDef& d : layers) {
        const std::uint64_t record = d.dataOffset - kEncryptedLayerBytes;
        le.u32(std::uint32_t(record & 0xFFFFFFFFu));
        le.u32(std::uint32_t(record >> 32));
        le.u32(kEncryptedLayerBytes);
        le.u32(0);
    }
    if (out.size() != l.layersStart) throw std::logic_error("ctb: the head has the wrong size");
    return out;
}

}  // namespace

std::string ctbHeadBytes(const CtbHeader& h, const std::string& largePreview, const std::string& smallPreview,
                         const std::vector<CtbLayerDef>& layers, std::uint64_t layersEnd)
{
    if (h.encrypted) return encryptedHead(h, largePreview, smallPreview, layers, layersEnd);
    const CtbLayout l = ctbLayout(h);
    if (layers.size() != std::size_t(h.layers) * h.planes)
        throw std::logic_error("ctb: one table entry per layer and plane");
    if (largePreview.size() > previewSlot(kCtbLargePreviewW, kCtbLargePreviewH) ||
        smallPreview.size() > previewSlot(kCtbSmallPreviewW, kCtbSmallPreviewH))
        throw std::logic_error("ctb: a preview is larger than its slot");
    std::string out;
    out.reserve(std::size_t(l.layersStart));
    LittleEndian le(out);
    const bool v4 = h.version >= 4;
    const double normalOff = lightOff(h, h.normal);
    // Header, 112 bytes (§3.1).
    le.u32(h.bitPlanes ? kCtbMagicBitPlanes : v4 ? kCtbMagicV4 : kCtbMagicV3);
    le.u32(std::uint32_t(h.version));
    le.f32(h.displayWidthMm);
    le.f32(h.displayHeightMm);
    le.f32(h.machineZMm);
    le.u32(0);
    le.u32(0);
    le.f32(h.totalHeightMm);
    le.f32(h.layerMm);
    le.f32(h.exposureS);
    le.f32(h.bottomExposureS);
    le.f32(normalOff);
    le.u32(h.bottomLayers);
    le.u32(h.resolutionX);
    le.u32(h.resolutionY);
    le.u32(l.largePreview);
    le.u32(l.layerTable);
    le.u32(h.layers);
    le.u32(l.smallPreview);
    le.u32(h.printTimeS);
    le.u32(1);  // projector type: mirrored LCD, as every real file
    le.u32(l.printParameters);
    le.u32(l.printParameters ? kPrintParametersBytes : 0);
    le.u32(h.planes);  // .ctb: one plane (anti-aliasing is in the grey levels)
    le.u16(unsigned(std::clamp(h.normal.lightPwm, 0, 255)));
    le.u16(unsigned(std::clamp(h.bottom.lightPwm, 0, 255)));
    le.u32(h.bitPlanes ? 0 : h.key);  // the bit-plane variant has no cipher
    le.u32(l.slicerInfo);
    le.u32(l.slicerInfo ? kSlicerInfoBytes : 0);
    // Previews (§3.2): each header, its data, the rest of its slot zero.
    auto preview = [&](std::uint32_t at, int w, int hgt, const std::string& data) {
        le.to(at);
        le.u32(std::uint32_t(w));
        le.u32(std::uint32_t(hgt));
        le.u32(at + kPreviewHeaderBytes);
        le.u32(std::uint32_t(data.size()));
        le.zeros(16);
        le.raw(data);
    };
    preview(l.largePreview, kCtbLargePreviewW, kCtbLargePreviewH, largePreview);
    preview(l.smallPreview, kCtbSmallPreviewW, kCtbSmallPreviewH, smallPreview);
    if (l.printParameters) printParameters(le, h, l.printParameters);
    if (l.slicerInfo) {  // not in the bit-plane variant
        // SlicerInfo (§3.4) and the machine name.
        le.to(l.slicerInfo);
        le.f32(v4 ? h.bottom.liftDistance[1] : 0.0);
        le.f32(v4 ? h.bottom.liftSpeed[1] : 0.0);
        le.f32(v4 ? h.normal.liftDistance[1] : 0.0);
        le.f32(v4 ? h.normal.liftSpeed[1] : 0.0);
        le.f32(v4 ? h.normal.retractDistance[1] : 0.0);
        le.f32(v4 ? h.normal.retractSpeed[1] : 0.0);
        le.f32(h.normal.waitAfterLift);
        le.u32(l.machineName);
        le.u32(std::uint32_t(h.machineName.size()));
        le.u8(0x0F);  // anti-alias flag, as real files
        le.u16(0);
        le.u8(0);   // per-layer settings off: the header's values
        le.u32(0);  // modified time (0: the same bytes every run)
        le.u32(h.antiAliasing);
        le.u32(h.version >= 5 ? 0x02000000u : 0x01090000u);
        le.f32(h.normal.waitAfterRetract);
        le.f32(h.normal.waitAfterLift);
        le.u32(h.transitionLayers);
        le.u32(l.printParametersV4);
        le.u32(0);
        le.u32(0);
        le.raw(h.machineName);
        if (v4) {
            // Disclaimer (§3.5) and PrintParametersV4 (§3.6).
            le.to(l.disclaimer);
            le.raw(ctbDisclaimer());
            le.to(l.printParametersV4);
            le.f32(h.bottom.retractSpeed[0]);
            le.f32(h.bottom.retractSpeed[1]);
            le.u32(0);
            le.f32(4.0);
            le.u32(0);
            le.f32(4.0);
            le.f32(h.normal.waitAfterRetract);
            le.f32(h.normal.waitAfterLift);
            le.f32(h.normal.waitBeforeLift);
            le.f32(h.bottom.retractDistance[1]);
            le.f32(0);
            le.u32(0);
            le.u32(4);
            le.u32(h.layers > 0 ? h.layers - 1 : 0);
            le.zeros(16);
            le.u32(l.disclaimer);
            le.u32(std::uint32_t(ctbDisclaimer().size()));
            le.u32(l.resinParameters);
            le.zeros(380);
        }
        if (h.version >= 5) {
            le.to(l.resinParameters);
            resinParameters(le, h, l.resinParameters);
        }
    }
    // The layer table (§4).
    le.to(l.layerTable);
    for (const CtbLayerDef& d : layers) layerDef(le, h, d);
    if (out.size() != l.layersStart) throw std::logic_error("ctb: the head has the wrong size");
    return out;
}

std::size_t ctbLayerRecordBytes(const CtbHeader& h)
{
    return h.encrypted ? kEncryptedLayerBytes : h.version >= 3 ? kLayerDefExBytes : 0;
}

std::string ctbLayerBytes(const CtbHeader& h, const CtbLayerDef& d, const std::string& data)
{
    std::string out;
    out.reserve(ctbLayerRecordBytes(h) + data.size());
    if (h.encrypted) {
        // The encrypted layout's 88-byte record (§7); no AES window in the data.
        LittleEndian le(out);
        const GooMotion& m = d.motion;
        le.u32(kEncryptedLayerBytes);
        le.f32(d.zMm);
        le.f32(d.exposureS);
        le.f32(d.lightOffS);
        le.u32(std::uint32_t(d.dataOffset & 0xFFFFFFFFu));
        le.u32(std::uint32_t(d.dataOffset >> 32));
        le.u32(d.dataLength);
        le.u32(0);
        le.u32(0);  // AES window offset
        le.u32(0);  // AES window length: none
        le.f32(m.liftDistance[0] + m.liftDistance[1]);
        le.f32(m.liftSpeed[0]);
        le.f32(m.liftDistance[1]);
        le.f32(m.liftSpeed[1]);
        le.f32(m.retractSpeed[0]);
        le.f32(m.retractDistance[1]);
        le.f32(m.retractSpeed[1]);
        le.f32(m.waitBeforeLift);
        le.f32(m.waitAfterLift);
        le.f32(m.waitAfterRetract);
        le.f32(double(std::clamp(m.lightPwm, 0, 255)));
        le.u32(0);
    } else if (h.version >= 3) {
        LittleEndian le(out);
        const bool v4 = h.version >= 4;
        const GooMotion& m = d.motion;
        layerDef(le, h, d);
        le.u32(kLayerDefExBytes + d.dataLength);
        le.f32(m.liftDistance[0] + (v4 ? m.liftDistance[1] : 0.0));
        le.f32(m.liftSpeed[0]);
        le.f32(v4 ? m.liftDistance[1] : 0.0);
        le.f32(v4 ? m.liftSpeed[1] : 0.0);
        le.f32(m.retractSpeed[0]);
        le.f32(v4 ? m.retractDistance[1] : 0.0);
        le.f32(v4 ? m.retractSpeed[1] : 0.0);
        le.f32(m.waitBeforeLift);
        le.f32(m.waitAfterLift);
        le.f32(m.waitAfterRetract);
        le.f32(double(std::clamp(m.lightPwm, 0, 255)));
    }
    out += data;
    return out;
}

std::string encodeCtbLayer(int width, int height, const std::uint8_t* window, int col0, int row0, int w, int h)
{
    std::string out;
    windowRuns(
        width, height, window, col0, row0, w, h, [](std::uint8_t g) { return unsigned(g >> 1); },
        [&](unsigned v, std::uint64_t n) { appendRun(out, v, n); });
    return out;
}

void ctbCipher(std::string& data, std::uint32_t key, std::uint32_t index)
{
    if (key == 0) return;
    const std::uint32_t c = key * 0x2D83CDACu + 0xD8A83423u;
    std::uint32_t x = (index * 0x1E1530CDu + 0xEC3D47CDu) * c;
    for (std::size_t j = 0; j < data.size(); ++j) {
        data[j] = char(std::uint8_t(data[j]) ^ std::uint8_t(x >> (8 * (j & 3))));
        if ((j & 3) == 3) x += c;
    }
}

std::string ctbPreview(const std::uint8_t* rgba, int width, int height, int outW, int outH)
{
    std::string out;
    LittleEndian le(out);
    auto colour = [&](int c, int r) {
        const int x = std::min(width - 1, c * width / outW), y = std::min(height - 1, r * height / outH);
        const std::uint8_t* p = rgba + 4 * (std::size_t(y) * width + x);
        return unsigned((p[0] >> 3) << 11) | unsigned((p[1] >> 3) << 6) | unsigned(p[2] >> 3);
    };
    auto flush = [&](unsigned word, int run) {
        if (run >= 3) {
            le.u16(word | 0x20);
            le.u16(0x3000u | unsigned(run - 1));
        } else {
            for (int k = 0; k < run; ++k) le.u16(word);
        }
    };
    unsigned word = 0;
    int run = 0;
    for (int r = 0; r < outH; ++r)
        for (int c = 0; c < outW; ++c) {
            const unsigned w = colour(c, r);
            if (run > 0 && (w != word || run == 4095)) {
                flush(word, run);
                run = 0;
            }
            word = w;
            ++run;
        }
    if (run > 0) flush(word, run);
    return out;
}

}  // namespace voxlat
