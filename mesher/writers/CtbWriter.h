/// @file CtbWriter.h
/// @brief Chitubox's `.ctb`, the plain (unencrypted) layout of versions 2 to 5
/// (shared/reference/ctb-format.md §3–§6): the header and its sections, the RLE15 previews, the
/// layer table and per-layer records, the RLE7 layer code and its per-layer XOR cipher; and the
/// same layout's bit-plane variant (`.cbddlp` version 2, `.photon` version 1: magic 0x12FD0019,
/// no key, no SlicerInfo, one table entry per layer and plane, RLE1 planes of BitPlanes.h). Every
/// number is little-endian except RLE7's run lengths.
#pragma once

#include "mesher/writers/GooWriter.h"

#include <cstdint>
#include <string>
#include <vector>

namespace voxlat {

/// The fields of a `.ctb` a writer chooses (the rest are fixed by the format).
struct CtbHeader {
    int version = 4;  ///< 2 to 5
    double displayWidthMm = 0, displayHeightMm = 0, machineZMm = 0;
    double totalHeightMm = 0, layerMm = 0, exposureS = 0, bottomExposureS = 0;
    std::uint32_t bottomLayers = 0, transitionLayers = 0;
    std::uint32_t resolutionX = 0, resolutionY = 0, layers = 0;
    std::uint32_t printTimeS = 0;
    GooMotion bottom, normal;  ///< speeds in mm/min, as the format's
    std::uint32_t key = 0;     ///< the layers' XOR key (non-zero: firmware refuses 0)
    double volumeMl = 0;
    std::string machineName;
    std::uint32_t antiAliasing = 1;
    /// The encrypted layout (magic 0x12FD0107, §7: AES-256-CBC settings and signature) that
    /// Chitubox 2 writes and some boards require; versions 4 and 5.
    bool encrypted = false;
    /// The bit-plane variant (magic 0x12FD0019): `.cbddlp` (version 2) or `.photon` (version 1).
    bool bitPlanes = false;
    /// Bit planes per layer (bit-plane variant: 1, 2, 4, 8 or 16; .ctb: 1).
    std::uint32_t planes = 1;
};

/// One entry of the layer table.
struct CtbLayerDef {
    double zMm = 0, exposureS = 0, lightOffS = 0;
    GooMotion motion;
    std::uint64_t dataOffset = 0;
    std::uint32_t dataLength = 0;
};

/// The magic of the encrypted layout.
constexpr std::uint32_t kCtbMagicEncrypted = 0x12FD0107;
/// The encrypted layout's settings checksum: any value, its SHA-256 is signed (UVtools' choice).
constexpr std::uint64_t kCtbChecksum = 0xCAFEBABE;

/// Where the sections go: the header, the two preview slots (each its 32-byte header and room
/// for the worst RLE15 image), the parameters, the layer table; layer records start at
/// `layersStart`.
struct CtbLayout {
    std::uint32_t largePreview = 0, smallPreview = 0, printParameters = 0, slicerInfo = 0, machineName = 0,
                  disclaimer = 0, printParametersV4 = 0, resinParameters = 0, layerTable = 0;
    std::uint64_t layersStart = 0;
};

constexpr int kCtbLargePreviewW = 400, kCtbLargePreviewH = 300, kCtbSmallPreviewW = 200, kCtbSmallPreviewH = 125;
/// The magic of the plain layout for versions 2–3 and 4–5, and of the bit-plane variant.
constexpr std::uint32_t kCtbMagicV3 = 0x12FD0086, kCtbMagicV4 = 0x12FD0106, kCtbMagicBitPlanes = 0x12FD0019;
/// The fixed disclaimer of versions 4 and 5 (320 bytes).
const std::string& ctbDisclaimer();

/// The layout of a file with @a header's version, machine name and layer count.
CtbLayout ctbLayout(const CtbHeader& header);

/// Everything before the first layer record: `layout.layersStart` bytes. @a largePreview and
/// @a smallPreview are RLE15 data (ctbPreview()); @a layers holds every layer's entry (the
/// bit-plane variant: every plane's, plane-major: plane p of layer i at p·N + i).
/// For the encrypted layout @a layersEnd (where the signature goes) is needed too.
std::string ctbHeadBytes(const CtbHeader& header, const std::string& largePreview, const std::string& smallPreview,
                         const std::vector<CtbLayerDef>& layers, std::uint64_t layersEnd = 0);

/// AES-256-CBC of @a plain (a multiple of 16 bytes) with the format's published key and IV
/// (§7), from the IV afresh.
std::string ctbAesCbc(const std::string& plain);

/// What follows the last layer: nothing for the plain layout; for the encrypted one the
/// signature (AES of SHA-256 of the checksum), after UVtools' 8 bytes and before its 4 for v5.
std::string ctbTailBytes(const CtbHeader& header);
/// Where the signature starts in a file whose layers end at @a layersEnd (encrypted layout).
std::uint64_t ctbSignatureOffset(const CtbHeader& header, std::uint64_t layersEnd);

/// A layer's bytes in the file from its record on: v3+ the 84-byte LayerDefEx (encrypted: the
/// 88-byte record) then @a data (already ciphered), v2 @a data alone. @a layer.dataOffset must be
/// where the data lands.
std::string ctbLayerBytes(const CtbHeader& header, const CtbLayerDef& layer, const std::string& data);
/// The size of the record before a layer's data (84 from v3, 0 for v2, 88 encrypted).
std::size_t ctbLayerRecordBytes(const CtbHeader& header);

/// RLE7 of a layer: the display is @a width x @a height grey pixels, black except the window of
/// @a w x @a h bytes (row-major) at column @a col0, row @a row0. Grey g is stored as g >> 1.
std::string encodeCtbLayer(int width, int height, const std::uint8_t* window, int col0, int row0, int w, int h);

/// Ciphers (or deciphers) @a data in place with the per-layer XOR of @a key and layer @a index.
void ctbCipher(std::string& data, std::uint32_t key, std::uint32_t index);

/// An RGBA image (4 bytes a pixel) resampled to @a outW x @a outH as RLE15 preview data.
std::string ctbPreview(const std::uint8_t* rgba, int width, int height, int outW, int outH);

}  // namespace voxlat
