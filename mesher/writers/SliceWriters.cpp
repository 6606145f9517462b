#include "mesher/writers/SliceWriters.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfOutputFile.h>
#include <png.h>
#include <zlib.h>

#include <algorithm>
#include <cstring>
#include <stdexcept>

#if defined(__SSSE3__)
#include <tmmintrin.h>
#endif

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

/// Bit t set where p[t] differs from the byte before it (@a carry's last byte before p[0]), for
/// the 64 bytes at @a p; @a carry becomes the last 16 of them. Four SSE compares instead of a
/// branch per run end: the runs of a lattice's layer are a few pixels long, and a branch per run
/// mispredicted at most of them.
inline std::uint64_t runStarts(const std::uint8_t* p, std::uint8_t before, std::uint64_t& carry)
{
#if defined(__SSSE3__)
    (void)before;
    std::uint64_t mask = 0;
    __m128i previous = _mm_cvtsi64_si128(std::int64_t(carry));
    previous = _mm_unpacklo_epi64(previous, previous);  // its byte 15 is the byte before p[0]
    for (int q = 0; q < 4; ++q) {
        const __m128i current = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 16 * q));
        const __m128i shifted = _mm_alignr_epi8(current, previous, 15);  // byte t: the byte before p[16 q + t]
        mask |= std::uint64_t(~unsigned(_mm_movemask_epi8(_mm_cmpeq_epi8(current, shifted))) & 0xffffu) << (16 * q);
        previous = current;
    }
    std::memcpy(&carry, p + 56, 8);
    return mask;
#else
    (void)carry;
    std::uint64_t mask = 0;
    for (int t = 0; t < 64; ++t) {
        mask |= std::uint64_t(p[t] != before) << t;
        before = p[t];
    }
    return mask;
#endif
}

/// A deflate stream of one fixed-Huffman block that codes each run of equal bytes as a literal and
/// matches at distance 1 (RFC 1951 3.2.6), with the zlib wrapper's Adler-32 kept alongside. It
/// appends to a string (kept from layer to layer by the caller, so its capacity is reused),
/// writing whole words at a pointer: a string append per word was a call each time.
class RunDeflater {
public:
    explicit RunDeflater(std::string& out) : mOut(out), mPos(out.size())
    {
        static const Tables tables;
        mTables = &tables;
        reserve(64);
        char* ptr = mOut.data() + mPos;
        put(ptr, 1, 1);  // BFINAL
        put(ptr, 1, 2);  // BTYPE 01: fixed Huffman codes
        mPos = std::size_t(ptr - mOut.data());
    }
    void zeros(std::uint64_t n)
    {
        mB = (mB + (n % kBase) * mA) % kBase;
        if (mRunByte != 0) flushRun(), mRunByte = 0;
        mRun += n;
    }
    void bytes(const std::uint8_t* p, std::size_t n)
    {
        // Rows longer than this are coded in parts, so the Adler sums below fit 64 bits.
        constexpr std::size_t kPart = std::size_t(1) << 24;
        for (; n > kPart; p += kPart, n -= kPart) bytes(p, kPart);
        if (n == 0) return;
        reserve(n + n / 8 + 64);  // a run of m bytes takes at most 9 m bits (long runs reserve their own)
        // Adler-32 piece by piece, reduced once at the end: m bytes c add m c to A and, to B, m A
        // plus c m (m + 1) / 2 (A < 2^33 and B < 2^57 for at most 2^24 bytes). Locals: the stores
        // through the output pointer may alias members.
        const Tables& tables = *mTables;
        std::uint64_t a = mA, b = mB, sum = mSum, run = mRun, bits = mBits;
        int count = mCount;
        std::uint8_t runByte = mRunByte;
        char* ptr = mOut.data() + mPos;
        std::uint64_t carry = 0x0101010101010101ull * runByte;
        std::size_t last = 0;  // where the current piece (bytes equal to runByte) starts in p
        std::uint8_t tail[64];
        for (std::size_t k = 0; k < n; k += 64) {
            const std::uint8_t* chunk = p + k;
            if (n - k < 64) {  // the last bytes padded with the last byte (no run starts there)
                std::memcpy(tail, chunk, n - k);
                std::memset(tail + (n - k), p[n - 1], 64 - (n - k));
                chunk = tail;
            }
            for (std::uint64_t starts = runStarts(chunk, k == 0 ? runByte : p[k - 1], carry); starts != 0;
                 starts &= starts - 1) {
                const std::size_t e = k + std::size_t(__builtin_ctzll(starts));
                const std::uint64_t m = e - last;
                b += m * a + runByte * (m * (m + 1) / 2);
                a += m * runByte;
                sum += m * runByte;
                run += m;
                // The run ends here: its first byte as a literal, then the rest as literals
                // (1 or 2) or one match, in one word (at most 9 + 18 bits); long runs elsewhere.
                if (run - 1 < 259) {
                    const std::uint32_t literal = tables.code[runByte], literalBits = tables.bits[runByte];
                    const std::uint32_t rest = std::uint32_t(run) - 1;
                    const std::uint32_t twice = literal | literal << literalBits;
                    const std::uint32_t restCode =
                        rest >= 3 ? tables.lengthCode[rest] : twice & ((1u << (rest * literalBits)) - 1u);
                    const std::uint32_t restBits = rest >= 3 ? tables.lengthBits[rest] : rest * literalBits;
                    putBits(ptr, bits, count, literal | std::uint64_t(restCode) << literalBits,
                            int(literalBits + restBits));
                } else if (run > 0) {
                    mPos = std::size_t(ptr - mOut.data());
                    mBits = bits, mCount = count, mRunByte = runByte, mRun = run;
                    flushRun();
                    ptr = mOut.data() + mPos;
                    bits = mBits, count = mCount;
                }
                runByte = p[e];
                run = 0;
                last = e;
            }
        }
        const std::uint64_t m = n - last;
        b += m * a + runByte * (m * (m + 1) / 2);
        a += m * runByte;
        sum += m * runByte;
        mRun = run + m;
        mRunByte = runByte;
        mBits = bits;
        mCount = count;
        mPos = std::size_t(ptr - mOut.data());
        mSum = sum;
        mA = std::uint32_t(a % kBase);
        mB = std::uint32_t(b % kBase);
    }
    /// The sum of every byte coded.
    std::uint64_t byteSum() const { return mSum; }
    /// Ends the block, cuts the string after it and returns the Adler-32 of everything coded.
    std::uint32_t finish()
    {
        flushRun();
        reserve(64);
        char* ptr = mOut.data() + mPos;
        put(ptr, mTables->code[256], mTables->bits[256]);
        mPos = std::size_t(ptr - mOut.data()) + (mCount > 0 ? 1 : 0);  // the last bits' byte is written
        mOut.resize(mPos);
        return std::uint32_t((mB << 16) | mA);
    }

private:
    static constexpr std::uint32_t kBase = 65521;
    struct Tables {
        std::uint16_t code[288];
        std::uint8_t bits[288];
        std::uint32_t lengthCode[259];  ///< length symbol code, then its extra bits, then distance code 0
        std::uint8_t lengthBits[259];
        Tables()
        {
            auto reversed = [](std::uint32_t c, int n) {
                std::uint32_t r = 0;
                for (int i = 0; i < n; ++i) r |= ((c >> i) & 1u) << (n - 1 - i);
                return r;
            };
            for (int s = 0; s < 288; ++s) {
                const int n = s < 144 ? 8 : s < 256 ? 9 : s < 280 ? 7 : 8;
                const std::uint32_t c = s < 144   ? 0x30 + s
                                        : s < 256 ? 0x190 + (s - 144)
                                        : s < 280 ? s - 256
                                                  : 0xc0 + (s - 280);
                code[s] = std::uint16_t(reversed(c, n));
                bits[s] = std::uint8_t(n);
            }
            static const int base[29] = {3,  4,  5,  6,  7,  8,  9,  10, 11,  13,  15,  17,  19,  23, 27,
                                         31, 35, 43, 51, 59, 67, 83, 99, 115, 131, 163, 195, 227, 258};
            static const int extra[29] = {0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2,
                                          2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0};
            for (int len = 3; len <= 258; ++len) {
                int s = 28;
                while (base[s] > len) --s;
                const int sym = 257 + s, n = bits[sym];
                lengthCode[len] = code[sym] | (std::uint32_t(len - base[s]) << n);  // distance code 0: 5 zero bits
                lengthBits[len] = std::uint8_t(n + extra[s] + 5);
            }
            for (int len = 0; len < 3; ++len) lengthCode[len] = lengthBits[len] = 0;  // not used
        }
    };

    /// Makes room for @a n more bytes (and a word's slack) after mPos.
    void reserve(std::size_t n)
    {
        const std::size_t need = mPos + n + 8;
        if (need > mOut.size()) mOut.resize(std::max(need, 2 * mOut.size()));
    }
    /// Appends the @a n low bits of @a value (n <= 32; fewer than 8 bits pending before): the
    /// pending bits are stored as a whole word and the pointer moves on by the whole bytes.
    static void putBits(char*& ptr, std::uint64_t& bits, int& count, std::uint64_t value, int n)
    {
        bits |= value << count;
        count += n;
#if __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
        const std::uint64_t word = __builtin_bswap64(bits);
#else
        const std::uint64_t word = bits;
#endif
        std::memcpy(ptr, &word, 8);
        const int whole = count >> 3;  // at most 4
        ptr += whole;
        bits >>= 8 * whole;
        count &= 7;
    }
    void put(char*& ptr, std::uint32_t value, int n)
    {
        putBits(ptr, mBits, mCount, value, n);
    }
    void flushRun()
    {
        if (mRun == 0) return;
        reserve(std::size_t(mRun / 128) + 64);  // a match of 258 bytes takes 13 bits
        char* ptr = mOut.data() + mPos;
        put(ptr, mTables->code[mRunByte], mTables->bits[mRunByte]);
        std::uint64_t rest = mRun - 1;
        for (; rest >= 258 + 3; rest -= 258) put(ptr, mTables->lengthCode[258], mTables->lengthBits[258]);
        if (rest > 258) {  // leave at least 3 for the last match
            put(ptr, mTables->lengthCode[rest - 3], mTables->lengthBits[rest - 3]);
            rest = 3;
        }
        if (rest >= 3)
            put(ptr, mTables->lengthCode[rest], mTables->lengthBits[rest]);
        else
            for (; rest > 0; --rest) put(ptr, mTables->code[mRunByte], mTables->bits[mRunByte]);
        mRun = 0;
        mPos = std::size_t(ptr - mOut.data());
    }

    std::string& mOut;
    std::size_t mPos;  ///< the first byte not yet whole: bits still pending (mCount < 8) go there
    const Tables* mTables;
    std::uint64_t mBits = 0;
    int mCount = 0;
    std::uint8_t mRunByte = 0;
    std::uint64_t mRun = 0;
    std::uint32_t mA = 1, mB = 0;
    std::uint64_t mSum = 0;
};

void putBig32(std::string& s, std::uint32_t v)
{
    for (int shift = 24; shift >= 0; shift -= 8) s.push_back(char((v >> shift) & 0xff));
}

/// Appends a PNG chunk (length, type, data, CRC of type and data).
void pngChunk(std::string& out, const char* type, const std::string& data)
{
    putBig32(out, std::uint32_t(data.size()));
    const std::size_t start = out.size();
    out.append(type, 4);
    out += data;
    putBig32(out,
             std::uint32_t(crc32(0L, reinterpret_cast<const Bytef*>(out.data() + start), uInt(out.size() - start))));
}

}  // namespace

void encodeWindowPng(std::string& out, int width, int height, const std::function<const std::uint8_t*(int)>& row,
                     int col0, int row0, int w, int h, std::uint64_t* byteSum, std::uint32_t* crc)
{
    if (w <= 0 || h <= 0) col0 = row0 = w = h = 0;
    if (col0 < 0 || row0 < 0 || col0 + w > width || row0 + h > height)
        throw std::runtime_error("PNG window lies outside the image");
    out.assign("\x89PNG\r\n\x1a\n", 8);
    std::string ihdr;
    putBig32(ihdr, std::uint32_t(width));
    putBig32(ihdr, std::uint32_t(height));
    ihdr += std::string{char(8), char(0), char(0), char(0), char(0)};  // 8-bit grey, deflate, adaptive, no interlace
    pngChunk(out, "IHDR", ihdr);
    // The IDAT chunk is coded in place: its length is filled in once known.
    const std::size_t idat = out.size();
    out.append(4, '\0');
    out.append("IDAT", 4);
    out.append({char(0x78), char(0x01)});  // zlib header: deflate, 32K window, no dictionary
    RunDeflater deflater(out);
    const std::uint64_t rowBytes = std::uint64_t(width) + 1;  // filter byte NONE (0), then the pixels
    deflater.zeros(std::uint64_t(row0) * rowBytes);
    for (int r = 0; r < h; ++r) {
        deflater.zeros(1 + std::uint64_t(col0));
        deflater.bytes(row(r), std::size_t(w));
        deflater.zeros(std::uint64_t(width - col0 - w));
    }
    deflater.zeros(std::uint64_t(height - row0 - h) * rowBytes);
    putBig32(out, deflater.finish());
    if (byteSum) *byteSum = deflater.byteSum();
    const std::size_t length = out.size() - idat - 8;
    for (int k = 0; k < 4; ++k) out[idat + k] = char((length >> (24 - 8 * k)) & 0xff);
    const uLong idatCrc = crc32(0L, reinterpret_cast<const Bytef*>(out.data() + idat + 4), uInt(length + 4));
    putBig32(out, std::uint32_t(idatCrc));
    pngChunk(out, "IEND", std::string());
    if (crc) {
        // The whole file's CRC from the IDAT chunk's (every byte is read once): the bytes before
        // it, the chunk's own CRC combined in, then its CRC field and IEND.
        const auto* bytes = reinterpret_cast<const Bytef*>(out.data());
        uLong whole = crc32(0L, bytes, uInt(idat + 4));
        whole = crc32_combine(whole, idatCrc, z_off_t(length + 4));
        const std::size_t after = idat + 8 + length;
        *crc = std::uint32_t(crc32(whole, bytes + after, uInt(out.size() - after)));
    }
}

std::string encodeWindowPng(int width, int height, const std::uint8_t* window, int col0, int row0, int w, int h,
                            std::uint64_t* byteSum)
{
    std::string out;
    encodeWindowPng(
        out, width, height, [&](int r) { return window + std::size_t(r) * std::size_t(std::max(w, 0)); }, col0, row0, w,
        h, byteSum, nullptr);
    out.shrink_to_fit();
    return out;
}

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
    add(name, data, std::uint32_t(crc32(0L, reinterpret_cast<const Bytef*>(data.data()), uInt(data.size()))));
}

void ZipStreamWriter::add(const std::string& name, const std::string& data, std::uint32_t crc)
{
    Entry e{name, crc, data.size(), mOffset};
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
