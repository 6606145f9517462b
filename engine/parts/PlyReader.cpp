#include "engine/parts/PlyReader.h"

#include "engine/core/Errors.h"

#include <bit>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <optional>
#include <sstream>
#include <vector>

namespace voxlat {

namespace {

/// The longest header read: real headers are a few hundred bytes.
constexpr std::size_t kMaxHeaderBytes = 64 * 1024;

enum class Scalar { Int8, UInt8, Int16, UInt16, Int32, UInt32, Float32, Float64 };

std::optional<Scalar> scalarOf(const std::string& name)
{
    if (name == "char" || name == "int8") return Scalar::Int8;
    if (name == "uchar" || name == "uint8") return Scalar::UInt8;
    if (name == "short" || name == "int16") return Scalar::Int16;
    if (name == "ushort" || name == "uint16") return Scalar::UInt16;
    if (name == "int" || name == "int32") return Scalar::Int32;
    if (name == "uint" || name == "uint32") return Scalar::UInt32;
    if (name == "float" || name == "float32") return Scalar::Float32;
    if (name == "double" || name == "float64") return Scalar::Float64;
    return std::nullopt;
}

std::size_t sizeOf(Scalar s)
{
    switch (s) {
        case Scalar::Int8:
        case Scalar::UInt8:
            return 1;
        case Scalar::Int16:
        case Scalar::UInt16:
            return 2;
        case Scalar::Int32:
        case Scalar::UInt32:
        case Scalar::Float32:
            return 4;
        case Scalar::Float64:
            return 8;
    }
    return 0;
}

struct Property {
    std::string name;
    Scalar type = Scalar::Float32;
    bool isList = false;
    Scalar countType = Scalar::UInt8;
};

struct Element {
    std::string name;
    std::uint64_t count = 0;
    std::vector<Property> properties;
};

enum class Format { Ascii, BinaryLittle, BinaryBig };

/// Reads values one after another from the body, failing with the file's name when the bytes
/// run out or an ASCII token is not a number.
class BodyReader {
public:
    BodyReader(const std::string& bytes, std::size_t start, Format format, const std::string& shown)
        : mBytes(bytes), mPos(start), mFormat(format), mShown(shown)
    {
    }

    double read(Scalar type) { return mFormat == Format::Ascii ? readText() : readBinary(type); }

    std::size_t remaining() const { return mBytes.size() - mPos; }

private:
    double readText()
    {
        while (mPos < mBytes.size() && std::isspace(static_cast<unsigned char>(mBytes[mPos]))) ++mPos;
        if (mPos == mBytes.size()) truncated();
        std::size_t end = mPos;
        while (end < mBytes.size() && !std::isspace(static_cast<unsigned char>(mBytes[end]))) ++end;
        double value = 0;
        const auto [ptr, ec] = std::from_chars(mBytes.data() + mPos, mBytes.data() + end, value);
        if (ec != std::errc() || ptr != mBytes.data() + end)
            throw InputError(mShown + ": corrupted PLY: a value in the body (byte " + std::to_string(mPos) +
                             ") is not a number");
        mPos = end;
        return value;
    }

    double readBinary(Scalar type)
    {
        const std::size_t n = sizeOf(type);
        if (remaining() < n) truncated();
        unsigned char b[8] = {};
        std::memcpy(b, mBytes.data() + mPos, n);
        mPos += n;
        if ((mFormat == Format::BinaryBig) == (std::endian::native == std::endian::little))
            for (std::size_t i = 0; i < n / 2; ++i) std::swap(b[i], b[n - 1 - i]);
        switch (type) {
            case Scalar::Int8:
                return double(std::bit_cast<std::int8_t>(b[0]));
            case Scalar::UInt8:
                return double(b[0]);
            case Scalar::Int16:
                return double(load<std::int16_t>(b));
            case Scalar::UInt16:
                return double(load<std::uint16_t>(b));
            case Scalar::Int32:
                return double(load<std::int32_t>(b));
            case Scalar::UInt32:
                return double(load<std::uint32_t>(b));
            case Scalar::Float32:
                return double(load<float>(b));
            case Scalar::Float64:
                return load<double>(b);
        }
        return 0;
    }

    template <typename T>
    static T load(const unsigned char* b)
    {
        T v;
        std::memcpy(&v, b, sizeof v);
        return v;
    }

    [[noreturn]] void truncated() const
    {
        throw InputError(mShown +
                         ": corrupted PLY: the file ends before the elements its header announces "
                         "(truncated?)");
    }

    const std::string& mBytes;
    std::size_t mPos;
    Format mFormat;
    const std::string& mShown;
};

}  // namespace

TriangleMesh readPly(const std::string& bytes, const std::string& shown)
{
    auto bad = [&](const std::string& why) { return InputError(shown + ": corrupted PLY: " + why); };
    if (bytes.compare(0, 3, "ply") != 0 || bytes.size() < 4 || (bytes[3] != '\n' && bytes[3] != '\r'))
        throw bad("the file does not start with the line `ply`");
    // The header ends at the line `end_header`; looked for only within the first 64 kB.
    std::size_t headerEnd = std::string::npos;
    for (std::size_t at = bytes.find("end_header"); at != std::string::npos && at < kMaxHeaderBytes;
         at = bytes.find("end_header", at + 1)) {
        if (at == 0 || bytes[at - 1] != '\n') continue;
        std::size_t next = at + 10;
        while (next < bytes.size() && (bytes[next] == ' ' || bytes[next] == '\t' || bytes[next] == '\r')) ++next;
        if (next < bytes.size() && bytes[next] == '\n') {
            headerEnd = next + 1;
            break;
        }
        if (next == bytes.size()) {
            headerEnd = next;
            break;
        }
    }
    if (headerEnd == std::string::npos)
        throw bad("no `end_header` line in the first 64 kB (not a PLY file, or cut off)");

    std::istringstream header(bytes.substr(0, headerEnd));
    std::string line;
    std::getline(header, line);  // "ply"
    std::optional<Format> format;
    std::vector<Element> elements;
    int lineNo = 1;
    while (std::getline(header, line)) {
        ++lineNo;
        std::istringstream words(line);
        std::string word;
        if (!(words >> word) || word == "comment" || word == "obj_info") continue;
        const std::string at = " (header line " + std::to_string(lineNo) + ")";
        if (word == "format") {
            std::string kind, version;
            words >> kind >> version;
            if (kind == "ascii")
                format = Format::Ascii;
            else if (kind == "binary_little_endian")
                format = Format::BinaryLittle;
            else if (kind == "binary_big_endian")
                format = Format::BinaryBig;
            else
                throw bad("unknown format (ascii, binary_little_endian or binary_big_endian)" + at);
        } else if (word == "element") {
            Element e;
            std::string count;
            if (!(words >> e.name >> count)) throw bad("`element` needs a name and a count" + at);
            const auto [ptr, ec] = std::from_chars(count.data(), count.data() + count.size(), e.count);
            if (ec != std::errc() || ptr != count.data() + count.size())
                throw bad("element count `" + count + "` is not a whole number" + at);
            elements.push_back(std::move(e));
        } else if (word == "property") {
            if (elements.empty()) throw bad("a property before any element" + at);
            Property p;
            std::string type;
            words >> type;
            if (type == "list") {
                std::string countType, itemType;
                words >> countType >> itemType >> p.name;
                const auto c = scalarOf(countType), i = scalarOf(itemType);
                if (!c || !i || p.name.empty()) throw bad("malformed `property list`" + at);
                if (*c == Scalar::Float32 || *c == Scalar::Float64)
                    throw bad("a list count must be an integer type" + at);
                p.isList = true;
                p.countType = *c;
                p.type = *i;
            } else {
                const auto t = scalarOf(type);
                if (!t || !(words >> p.name)) throw bad("malformed property `" + line + "`" + at);
                p.type = *t;
            }
            elements.back().properties.push_back(p);
        } else if (word != "end_header") {
            throw bad("unexpected header keyword" + at);
        }
    }
    if (!format) throw bad("no `format` line in the header");

    // Every value takes at least one byte (binary) or two (ASCII: a digit and a separator): a
    // header announcing more than the body can hold is refused before anything is allocated.
    const std::size_t body = bytes.size() - headerEnd;
    const double minBytesPerValue = *format == Format::Ascii ? 2.0 : 1.0;
    double leastBytes = 0;
    for (const Element& e : elements) {
        double perItem = 0;
        for (const Property& p : e.properties)
            perItem += p.isList ? double(sizeOf(p.countType)) : double(sizeOf(p.type));
        if (*format == Format::Ascii) perItem = minBytesPerValue * double(e.properties.size());
        leastBytes += perItem * double(e.count);
    }
    if (leastBytes > double(body))
        throw bad("the header announces elements that need at least " + std::to_string(std::uint64_t(leastBytes)) +
                  " bytes, but the body holds " + std::to_string(body) + " (truncated or damaged)");

    TriangleMesh mesh;
    BodyReader in(bytes, headerEnd, *format, shown);
    std::uint64_t vertexCount = 0;
    bool sawFaces = false;
    for (const Element& e : elements) {
        if (e.name == "vertex") {
            int axis[3] = {-1, -1, -1};
            for (std::size_t i = 0; i < e.properties.size(); ++i) {
                const Property& p = e.properties[i];
                if (!p.isList && p.name.size() == 1 && p.name[0] >= 'x' && p.name[0] <= 'z')
                    axis[p.name[0] - 'x'] = int(i);
            }
            if (axis[0] < 0 || axis[1] < 0 || axis[2] < 0) throw bad("the vertex element lacks an x, y or z property");
            vertexCount = e.count;
            mesh.points.reserve(std::size_t(e.count));
            std::vector<double> values(e.properties.size());
            for (std::uint64_t v = 0; v < e.count; ++v) {
                for (std::size_t i = 0; i < e.properties.size(); ++i) {
                    const Property& p = e.properties[i];
                    if (p.isList) {
                        const double n = in.read(p.countType);
                        if (n < 0 || n > double(in.remaining())) throw bad("a list longer than the file");
                        for (std::uint64_t k = 0; k < std::uint64_t(n); ++k) in.read(p.type);
                    } else {
                        values[i] = in.read(p.type);
                    }
                }
                const openvdb::Vec3f point{float(values[axis[0]]), float(values[axis[1]]), float(values[axis[2]])};
                if (!std::isfinite(point.x()) || !std::isfinite(point.y()) || !std::isfinite(point.z()))
                    throw bad("vertex " + std::to_string(v + 1) + " has a coordinate that is not a number");
                mesh.points.push_back(point);
            }
        } else if (e.name == "face") {
            sawFaces = true;
            int list = -1;
            for (std::size_t i = 0; i < e.properties.size(); ++i)
                if (e.properties[i].isList &&
                    (e.properties[i].name == "vertex_indices" || e.properties[i].name == "vertex_index"))
                    list = int(i);
            if (list < 0) throw bad("the face element has no `vertex_indices` list");
            std::vector<std::uint32_t> polygon;
            for (std::uint64_t f = 0; f < e.count; ++f) {
                for (std::size_t i = 0; i < e.properties.size(); ++i) {
                    const Property& p = e.properties[i];
                    if (!p.isList) {
                        in.read(p.type);
                        continue;
                    }
                    const double n = in.read(p.countType);
                    if (n < 0 || n > double(in.remaining())) throw bad("a list longer than the file");
                    polygon.clear();
                    for (std::uint64_t k = 0; k < std::uint64_t(n); ++k) {
                        const double index = in.read(p.type);
                        if (int(i) != list) continue;
                        if (!(index >= 0 && index < double(vertexCount)))
                            throw bad("face " + std::to_string(f + 1) + " names vertex " +
                                      std::to_string(std::int64_t(index)) + " of " + std::to_string(vertexCount) +
                                      " (vertices come before faces, numbered from 0)");
                        polygon.push_back(std::uint32_t(index));
                    }
                    if (int(i) != list) continue;
                    if (polygon.size() < 3)
                        throw bad("face " + std::to_string(f + 1) + " has " + std::to_string(polygon.size()) +
                                  " corners");
                    for (std::size_t k = 1; k + 1 < polygon.size(); ++k)
                        mesh.triangles.emplace_back(polygon[0], polygon[k], polygon[k + 1]);
                }
            }
        } else {
            for (std::uint64_t item = 0; item < e.count; ++item)
                for (const Property& p : e.properties) {
                    if (!p.isList) {
                        in.read(p.type);
                        continue;
                    }
                    const double n = in.read(p.countType);
                    if (n < 0 || n > double(in.remaining())) throw bad("a list longer than the file");
                    for (std::uint64_t k = 0; k < std::uint64_t(n); ++k) in.read(p.type);
                }
        }
    }
    if (!sawFaces) throw bad("no `face` element (a point cloud is not a part)");
    return mesh;
}

}  // namespace voxlat
