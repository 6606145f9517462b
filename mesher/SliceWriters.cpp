#include "mesher/SliceWriters.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfOutputFile.h>
#include <png.h>
#include <zlib.h>

#include <cstring>
#include <stdexcept>

namespace voxlat {

namespace {

void pngWrite(png_structp png, png_bytep data, png_size_t length)
{
    static_cast<std::string*>(png_get_io_ptr(png))->append(reinterpret_cast<const char*>(data), length);
}
void pngFlush(png_structp) {}
[[noreturn]] void pngError(png_structp, png_const_charp message)
{
    throw std::runtime_error(message);
}
void pngWarning(png_structp, png_const_charp) {}

struct PngReader {
    const std::string& bytes;
    std::size_t pos = 0;
};
void pngRead(png_structp png, png_bytep data, png_size_t length)
{
    auto* r = static_cast<PngReader*>(png_get_io_ptr(png));
    if (r->pos + length > r->bytes.size()) png_error(png, "truncated PNG");
    std::memcpy(data, r->bytes.data() + r->pos, length);
    r->pos += length;
}

void put16(std::string& s, std::uint32_t v)
{
    s.push_back(char(v & 0xff));
    s.push_back(char((v >> 8) & 0xff));
}
void put32(std::string& s, std::uint32_t v)
{
    put16(s, v & 0xffff);
    put16(s, v >> 16);
}
void put64(std::string& s, std::uint64_t v)
{
    put32(s, std::uint32_t(v));
    put32(s, std::uint32_t(v >> 32));
}

// 2020-01-01 00:00:00 in DOS format: a fixed time, so archives do not depend on the clock.
constexpr std::uint32_t kDosTime = 0;
constexpr std::uint32_t kDosDate = ((2020 - 1980) << 9) | (1 << 5) | 1;
constexpr std::uint64_t kMax32 = 0xffffffffull;

}  // namespace

std::string encodePng(int width, int height, int channels, const std::function<void(int, std::uint8_t*)>& row,
                      int level)
{
    std::string out;
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, pngError, pngWarning);
    png_infop info = png ? png_create_info_struct(png) : nullptr;
    if (!info) {
        png_destroy_write_struct(&png, nullptr);
        throw std::runtime_error("cannot create a PNG encoder (out of memory)");
    }
    std::vector<std::uint8_t> buffer(std::size_t(width) * channels);
    try {
        png_set_write_fn(png, &out, pngWrite, pngFlush);
        png_set_IHDR(png, info, png_uint_32(width), png_uint_32(height), 8,
                     channels == 1 ? PNG_COLOR_TYPE_GRAY : PNG_COLOR_TYPE_RGBA, PNG_INTERLACE_NONE,
                     PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
        png_set_compression_level(png, level);
        png_set_filter(png, PNG_FILTER_TYPE_BASE, PNG_FILTER_NONE);
        png_write_info(png, info);
        for (int r = 0; r < height; ++r) {
            row(r, buffer.data());
            png_write_row(png, buffer.data());
        }
        png_write_end(png, info);
    } catch (...) {
        png_destroy_write_struct(&png, &info);
        throw;
    }
    png_destroy_write_struct(&png, &info);
    return out;
}

std::vector<std::uint8_t> decodePng(const std::string& bytes, int& width, int& height, int& channels)
{
    png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, nullptr, pngError, pngWarning);
    png_infop info = png ? png_create_info_struct(png) : nullptr;
    if (!info) {
        png_destroy_read_struct(&png, nullptr, nullptr);
        throw std::runtime_error("cannot create a PNG decoder");
    }
    std::vector<std::uint8_t> pixels;
    PngReader reader{bytes};
    try {
        png_set_read_fn(png, &reader, pngRead);
        png_read_info(png, info);
        width = int(png_get_image_width(png, info));
        height = int(png_get_image_height(png, info));
        const int type = png_get_color_type(png, info);
        if (png_get_bit_depth(png, info) != 8 || (type != PNG_COLOR_TYPE_GRAY && type != PNG_COLOR_TYPE_RGBA))
            png_error(png, "only 8-bit grey or RGBA PNGs are read");
        channels = type == PNG_COLOR_TYPE_GRAY ? 1 : 4;
        pixels.resize(std::size_t(width) * height * channels);
        for (int r = 0; r < height; ++r) png_read_row(png, &pixels[std::size_t(r) * width * channels], nullptr);
        png_read_end(png, nullptr);
    } catch (...) {
        png_destroy_read_struct(&png, &info, nullptr);
        throw;
    }
    png_destroy_read_struct(&png, &info, nullptr);
    return pixels;
}

void ZipStreamWriter::add(const std::string& name, const std::string& data)
{
    Entry e{name, std::uint32_t(crc32(0L, reinterpret_cast<const Bytef*>(data.data()), uInt(data.size()))), data.size(),
            mOffset};
    if (data.size() >= kMax32) throw std::runtime_error("zip entry " + name + " is larger than 4 GiB");
    std::string h;
    put32(h, 0x04034b50);
    put16(h, 20);  // version needed: 2.0
    put16(h, 0);   // flags
    put16(h, 0);   // method: stored
    put16(h, kDosTime);
    put16(h, kDosDate);
    put32(h, e.crc);
    put32(h, std::uint32_t(e.size));
    put32(h, std::uint32_t(e.size));
    put16(h, std::uint32_t(name.size()));
    put16(h, 0);
    h += name;
    mOut.write(h.data(), std::streamsize(h.size()));
    mOut.write(data.data(), std::streamsize(data.size()));
    if (!mOut) throw std::runtime_error("cannot write the archive (disk full?)");
    mOffset += h.size() + data.size();
    mEntries.push_back(std::move(e));
}

void ZipStreamWriter::finish()
{
    const std::uint64_t cdOffset = mOffset;
    std::string cd;
    for (const Entry& e : mEntries) {
        const bool big = e.offset >= kMax32;
        put32(cd, 0x02014b50);
        put16(cd, big ? 45 : 20);  // made by
        put16(cd, big ? 45 : 20);  // needed
        put16(cd, 0);
        put16(cd, 0);
        put16(cd, kDosTime);
        put16(cd, kDosDate);
        put32(cd, e.crc);
        put32(cd, std::uint32_t(e.size));
        put32(cd, std::uint32_t(e.size));
        put16(cd, std::uint32_t(e.name.size()));
        put16(cd, big ? 12 : 0);  // extra length
        put16(cd, 0);             // comment
        put16(cd, 0);             // disk
        put16(cd, 0);             // internal attributes
        put32(cd, 0);             // external attributes
        put32(cd, big ? std::uint32_t(kMax32) : std::uint32_t(e.offset));
        cd += e.name;
        if (big) {  // Zip64 extended information: the local header offset
            put16(cd, 0x0001);
            put16(cd, 8);
            put64(cd, e.offset);
        }
    }
    const std::uint64_t cdSize = cd.size(), count = mEntries.size();
    const bool zip64 = cdOffset >= kMax32 || cdOffset + cdSize >= kMax32 || count >= 0xffff;
    if (zip64) {
        const std::uint64_t recordOffset = cdOffset + cdSize;
        put32(cd, 0x06064b50);
        put64(cd, 44);
        put16(cd, 45);
        put16(cd, 45);
        put32(cd, 0);
        put32(cd, 0);
        put64(cd, count);
        put64(cd, count);
        put64(cd, cdSize);
        put64(cd, cdOffset);
        put32(cd, 0x07064b50);
        put32(cd, 0);
        put64(cd, recordOffset);
        put32(cd, 1);
    }
    put32(cd, 0x06054b50);
    put16(cd, 0);
    put16(cd, 0);
    put16(cd, zip64 ? 0xffff : std::uint32_t(count));
    put16(cd, zip64 ? 0xffff : std::uint32_t(count));
    put32(cd, zip64 ? std::uint32_t(kMax32) : std::uint32_t(cdSize));
    put32(cd, zip64 ? std::uint32_t(kMax32) : std::uint32_t(cdOffset));
    put16(cd, 0);
    mOut.write(cd.data(), std::streamsize(cd.size()));
    mOut.flush();
    if (!mOut) throw std::runtime_error("cannot write the archive (disk full?)");
    mOffset += cd.size();
}

void writeExrFloat(const std::string& path, int width, int height, int x0, int y0, const std::vector<float>& data)
{
    try {
        Imf::Header header(Imath::Box2i(Imath::V2i(x0, y0), Imath::V2i(x0 + width - 1, y0 + height - 1)),
                           Imath::Box2i(Imath::V2i(x0, y0), Imath::V2i(x0 + width - 1, y0 + height - 1)));
        header.compression() = Imf::ZIP_COMPRESSION;
        header.channels().insert("Y", Imf::Channel(Imf::FLOAT));
        Imf::OutputFile file(path.c_str(), header, 1);
        Imf::FrameBuffer frame;
        // The base pointer is offset so that (x, y) in data-window coordinates lands in `data`.
        char* base = reinterpret_cast<char*>(const_cast<float*>(data.data())) -
                     (std::ptrdiff_t(y0) * width + x0) * std::ptrdiff_t(sizeof(float));
        frame.insert("Y", Imf::Slice(Imf::FLOAT, base, sizeof(float), sizeof(float) * std::size_t(width)));
        file.setFrameBuffer(frame);
        file.writePixels(height);
    } catch (const std::exception& e) {
        throw std::runtime_error(path + ": cannot write the EXR image: " + e.what());
    }
}

}  // namespace voxlat
