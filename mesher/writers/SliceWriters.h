/// @file SliceWriters.h
/// @brief Byte-exact writers for slice jobs: PNG (libpng), a streaming zip, OpenEXR float images.
///
/// Everything here is deterministic: fixed compression settings, fixed zip timestamps, entries in
/// the order they are added, so the same images give the same bytes on any machine and thread count.
#pragma once

#include <cstdint>
#include <functional>
#include <ostream>
#include <string>
#include <vector>

namespace voxlat {

/// Encodes a PNG of @a width x @a height pixels with @a channels (1 grey, 4 RGBA) 8-bit samples;
/// @a row(r, out) fills row r (width * channels bytes). zlib level @a level (deterministic).
std::string encodePng(int width, int height, int channels, const std::function<void(int, std::uint8_t*)>& row,
                      int level = 1);

/// Encodes a grey PNG of @a width x @a height pixels that is black except for a window of @a w x @a h
/// bytes (row-major) placed at column @a col0, row @a row0. A dedicated run-length deflate (one
/// fixed-Huffman block, matches at distance 1, filter NONE) made for layer images, which are long
/// runs of 0 and 255 with a grey pixel at each edge: the black margins cost almost nothing and the
/// window is scanned once. Deterministic; any PNG reader decodes it. With @a byteSum, also the sum
/// of the window's bytes (gathered run by run on the way).
std::string encodeWindowPng(int width, int height, const std::uint8_t* window, int col0, int row0, int w, int h,
                            std::uint64_t* byteSum = nullptr);

/// encodeWindowPng into @a out (replaced; its capacity is kept, so a string reused from layer to
/// layer is not grown again), the window's row r (@a w bytes) from @a row(r), asked for in order.
/// With @a crc, also the CRC-32 of the whole PNG (a zip entry's), derived from the IDAT chunk's so
/// the bytes are not read again.
void encodeWindowPng(std::string& out, int width, int height, const std::function<const std::uint8_t*(int)>& row,
                     int col0, int row0, int w, int h, std::uint64_t* byteSum = nullptr, std::uint32_t* crc = nullptr);

/// Decodes an 8-bit grey or RGBA PNG (for tests and previews); throws std::runtime_error if it cannot.
std::vector<std::uint8_t> decodePng(const std::string& bytes, int& width, int& height, int& channels);

/// Writes a zip archive to a stream as entries arrive (no entry is held in memory after add()):
/// entries are stored (PNG data is already deflated), with CRC-32, a fixed DOS timestamp and
/// Zip64 records once the archive passes 4 GiB.
class ZipStreamWriter {
public:
    explicit ZipStreamWriter(std::ostream& out) : mOut(out) {}
    void add(const std::string& name, const std::string& data);
    /// add() with the CRC-32 of @a data already known (where the data was made), so it is not read again.
    void add(const std::string& name, const std::string& data, std::uint32_t crc);
    /// Writes the central directory; call once, after the last add().
    void finish();
    std::uint64_t bytesWritten() const { return mOffset; }

private:
    struct Entry {
        std::string name;
        std::uint32_t crc = 0;
        std::uint64_t size = 0, offset = 0;
    };
    std::ostream& mOut;
    std::vector<Entry> mEntries;
    std::uint64_t mOffset = 0;
};

/// Writes one float channel "Y" (@a width x @a height, row-major, row 0 first) to an OpenEXR file,
/// with the data window at (@a x0, @a y0). Throws std::runtime_error naming the file on failure.
void writeExrFloat(const std::string& path, int width, int height, int x0, int y0, const std::vector<float>& data);

}  // namespace voxlat
