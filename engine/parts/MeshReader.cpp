#include "engine/parts/MeshReader.h"

#include "engine/core/Errors.h"
#include "engine/core/InputFiles.h"
#include "engine/core/SystemInfo.h"
#include "engine/parts/ObjReader.h"
#include "engine/parts/PlyReader.h"

#include <Model/COM/NMR_DLLInterfaces.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <optional>
#include <sstream>
#include <unordered_map>

namespace voxlat {

namespace {

/// Memory lib3mf takes per byte of decompressed model XML (its text, then vertices and triangles).
constexpr double kBytesPer3mfByte = 1.5;

std::string lower(std::string s)
{
    std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    return s;
}

/// The largest mesh file read (a binary STL of 40 M triangles).
constexpr std::uintmax_t kMaxMeshBytes = std::uintmax_t(2) << 30;

void checkReadable(const std::filesystem::path& path, const std::string& shown)
{
    std::error_code ec;
    if (!std::filesystem::exists(path, ec))
        throw InputError(shown + ": no such file (looked for " + path.string() +
                         "; paths in a recipe are relative to the recipe's folder)");
    if (std::filesystem::is_directory(path, ec)) throw InputError(shown + ": is a folder, not a mesh file");
    // A device (/dev/zero) or a FIFO would be read forever (opening a FIFO blocks): checked first.
    checkInputFile(path, kMaxMeshBytes, "mesh file");
    if (!std::ifstream(path, std::ios::binary))
        throw InputError(shown + ": cannot open the file (check its permissions)");
}

/// A binary STL whose size disagrees with its header, or a file that is neither kind of STL,
/// is refused from its first bytes, before gigabytes are read.
void checkStlHeader(const std::filesystem::path& path, const std::string& shown)
{
    const std::uintmax_t size = std::filesystem::file_size(path);
    std::ifstream in(path, std::ios::binary);
    char head[84] = {};
    in.read(head, sizeof head);
    const std::string start(head, std::size_t(in.gcount()));
    const std::size_t text = start.find_first_not_of(" \t\r\n");
    if (text != std::string::npos && lower(start.substr(text, 5)) == "solid") return;  // ASCII: read line by line
    if (size < 84) return;                                                             // readStl() says what is wrong
    std::uint32_t count = 0;
    for (int i = 0; i < 4; ++i) count |= std::uint32_t(std::uint8_t(head[80 + i])) << (8 * i);
    if (size != 84 + 50 * std::uint64_t(count))
        throw InputError(shown + ": corrupted binary STL: the header says " + std::to_string(count) +
                         " triangles, which take " + std::to_string(84 + 50 * std::uint64_t(count)) +
                         " bytes, but the file has " + std::to_string(size) + " (truncated or damaged)");
}

std::string readBytes(const std::filesystem::path& path, const std::string& shown)
{
    checkReadable(path, shown);
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(shown + ": cannot open the file (check its permissions)");
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

float getF32(const char* p)
{
    std::uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v |= std::uint32_t(std::uint8_t(p[i])) << (8 * i);
    return std::bit_cast<float>(v);
}

void checkFinite(const openvdb::Vec3f& p, const std::string& shown, const std::string& where)
{
    if (!std::isfinite(p.x()) || !std::isfinite(p.y()) || !std::isfinite(p.z()))
        throw InputError(shown + ": corrupted file: a vertex coordinate is not a number (" + where + ")");
}

TriangleMesh readBinaryStl(const std::string& bytes, const std::string& shown)
{
    std::uint32_t count = 0;
    for (int i = 0; i < 4; ++i) count |= std::uint32_t(std::uint8_t(bytes[80 + i])) << (8 * i);
    TriangleMesh m;
    m.points.reserve(std::size_t(count) * 3);
    m.triangles.reserve(count);
    for (std::uint32_t t = 0; t < count; ++t) {
        const char* f = bytes.data() + 84 + std::size_t(t) * 50 + 12;  // skip the normal
        for (int c = 0; c < 3; ++c) {
            openvdb::Vec3f p(getF32(f + 12 * c), getF32(f + 12 * c + 4), getF32(f + 12 * c + 8));
            checkFinite(p, shown, "triangle " + std::to_string(t + 1));
            m.points.push_back(p);
        }
        m.triangles.emplace_back(3 * t, 3 * t + 1, 3 * t + 2);
    }
    return m;
}

TriangleMesh readAsciiStl(const std::string& text, const std::string& shown)
{
    TriangleMesh m;
    std::istringstream in(text);
    std::string line;
    int lineNo = 0, corners = 0;
    while (std::getline(in, line)) {
        ++lineNo;
        std::istringstream words(line);
        std::string word;
        if (!(words >> word)) continue;
        word = lower(word);
        if (word == "vertex") {
            openvdb::Vec3f p;
            if (!(words >> p[0] >> p[1] >> p[2]))
                throw InputError(shown + ":" + std::to_string(lineNo) +
                                 ": corrupted ASCII STL: expected `vertex x y z` (three numbers)");
            checkFinite(p, shown, "line " + std::to_string(lineNo));
            m.points.push_back(p);
            ++corners;
        } else if (word == "endloop") {
            if (corners != 3)
                throw InputError(shown + ":" + std::to_string(lineNo) + ": corrupted ASCII STL: a facet has " +
                                 std::to_string(corners) + " vertices, not 3");
            const auto n = std::uint32_t(m.points.size());
            m.triangles.emplace_back(n - 3, n - 2, n - 1);
            corners = 0;
        } else if (word != "solid" && word != "facet" && word != "outer" && word != "endfacet" && word != "endsolid") {
            throw InputError(shown + ":" + std::to_string(lineNo) +
                             ": corrupted ASCII STL: an unexpected word (expected solid, facet, outer loop, vertex, "
                             "endloop, endfacet or endsolid)");
        }
    }
    if (corners != 0) throw InputError(shown + ": corrupted ASCII STL: the file ends inside a facet (truncated?)");
    return m;
}

TriangleMesh readStl(const std::string& bytes, const std::string& shown, std::string& format)
{
    // A binary STL's size follows from its triangle count; an ASCII one starts with "solid"
    // (some binary files do too, so the size decides first).
    if (bytes.size() >= 84) {
        std::uint32_t count = 0;
        for (int i = 0; i < 4; ++i) count |= std::uint32_t(std::uint8_t(bytes[80 + i])) << (8 * i);
        if (bytes.size() == 84 + 50 * std::uint64_t(count)) {
            format = "binary STL";
            return readBinaryStl(bytes, shown);
        }
    }
    std::size_t start = bytes.find_first_not_of(" \t\r\n");
    if (start != std::string::npos && lower(bytes.substr(start, 5)) == "solid" &&
        bytes.find('\0') == std::string::npos) {
        format = "ASCII STL";
        return readAsciiStl(bytes, shown);
    }
    if (bytes.size() < 84)
        throw InputError(shown + ": corrupted STL: only " + std::to_string(bytes.size()) +
                         " bytes, shorter than a binary STL header (84 bytes), and not ASCII STL");
    std::uint32_t count = 0;
    for (int i = 0; i < 4; ++i) count |= std::uint32_t(std::uint8_t(bytes[80 + i])) << (8 * i);
    throw InputError(shown + ": corrupted binary STL: the header says " + std::to_string(count) +
                     " triangles, which take " + std::to_string(84 + 50 * std::uint64_t(count)) +
                     " bytes, but the file has " + std::to_string(bytes.size()) + " (truncated or damaged)");
}

/// The bytes a 3MF (a zip) holds once decompressed: the sum of its entries' sizes from the
/// zip's central directory (Zip64 too). nullopt where the directory cannot be read (lib3mf then
/// says what is wrong).
std::optional<std::uint64_t> zipUncompressedBytes(const std::filesystem::path& path)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) return std::nullopt;
    in.seekg(0, std::ios::end);
    const std::uint64_t size = std::uint64_t(in.tellg());
    auto readAt = [&](std::uint64_t offset, std::size_t n) {
        std::string bytes(n, '\0');
        if (offset + n > size) return std::string();
        in.seekg(std::streamoff(offset));
        in.read(bytes.data(), std::streamsize(n));
        return in ? bytes : std::string();
    };
    auto u16 = [](const std::string& b, std::size_t i) {
        return std::uint64_t(std::uint8_t(b[i]) | std::uint8_t(b[i + 1]) << 8);
    };
    auto u32 = [&](const std::string& b, std::size_t i) { return u16(b, i) | u16(b, i + 2) << 16; };
    auto u64 = [&](const std::string& b, std::size_t i) { return u32(b, i) | u32(b, i + 4) << 32; };
    // The end of central directory record: in the last 64 KB + 22 bytes.
    const std::uint64_t tail = std::min<std::uint64_t>(size, 65557);
    const std::string end = readAt(size - tail, std::size_t(tail));
    if (end.size() < 22) return std::nullopt;
    std::size_t eocd = std::string::npos;
    for (std::size_t i = end.size() - 22 + 1; i-- > 0;)
        if (u32(end, i) == 0x06054b50) {
            eocd = i;
            break;
        }
    if (eocd == std::string::npos) return std::nullopt;
    std::uint64_t entries = u16(end, eocd + 10), dirSize = u32(end, eocd + 12), dirOffset = u32(end, eocd + 16);
    if ((entries == 0xFFFF || dirSize == 0xFFFFFFFF || dirOffset == 0xFFFFFFFF) && eocd >= 20 &&
        u32(end, eocd - 20) == 0x07064b50) {
        const std::string record = readAt(u64(end, eocd - 20 + 8), 56);
        if (record.size() < 56 || u32(record, 0) != 0x06064b50) return std::nullopt;
        entries = u64(record, 32), dirSize = u64(record, 40), dirOffset = u64(record, 48);
    }
    if (dirSize > size || dirSize > (std::uint64_t(256) << 20)) return std::nullopt;
    const std::string dir = readAt(dirOffset, std::size_t(dirSize));
    if (dir.size() != dirSize) return std::nullopt;
    std::uint64_t total = 0;
    std::size_t at = 0;
    for (std::uint64_t e = 0; e < entries; ++e) {
        if (at + 46 > dir.size() || u32(dir, at) != 0x02014b50) return std::nullopt;
        std::uint64_t bytes = u32(dir, at + 24);
        const std::size_t name = u16(dir, at + 28), extra = u16(dir, at + 30), comment = u16(dir, at + 32);
        if (at + 46 + name + extra > dir.size()) return std::nullopt;
        if (bytes == 0xFFFFFFFF)  // in the Zip64 extra field, first
            for (std::size_t x = at + 46 + name; x + 4 <= at + 46 + name + extra;) {
                const std::size_t id = u16(dir, x), length = u16(dir, x + 2);
                if (id == 0x0001 && length >= 8 && x + 12 <= dir.size()) {
                    bytes = u64(dir, x + 4);
                    break;
                }
                x += 4 + length;
            }
        total += bytes;
        at += 46 + name + extra + comment;
    }
    return total;
}

/// Reads every mesh object of a 3MF's build items (components one level down), in the build's
/// placement.
TriangleMesh read3mf(const std::filesystem::path& path, const std::string& shown, std::optional<double>& unitMm)
{
    using namespace NMR;
    // lib3mf holds the whole decompressed model and its vertices: a small file can stand for
    // gigabytes (9.8 MB of 150 M vertices took 5.8 GB, then bad_alloc). Estimated from the zip's
    // own directory and refused before reading.
    if (const std::optional<std::uint64_t> unpacked = zipUncompressedBytes(path)) {
        const double need = kBytesPer3mfByte * double(*unpacked), have = 0.5 * double(availableMemoryBytes());
        if (need > have)
            throw JobError(shown + ": the 3MF decompresses to " + std::to_string(*unpacked >> 20) +
                           " MB, and reading it needs about " + std::to_string(std::uint64_t(need) >> 20) +
                           " MB, more than the " + std::to_string(std::uint64_t(have) >> 20) +
                           " MB this machine can give: simplify the part, or export it as binary STL");
    }
    PLib3MFModel* model = nullptr;
    if (lib3mf_createmodel(&model) != LIB3MF_OK) throw InputError(shown + ": cannot start the 3MF reader");
    struct Release {
        PLib3MFBase* p;
        ~Release()
        {
            if (p) lib3mf_release(p);
        }
    };
    Release modelGuard{model};
    PLib3MFModelReader* reader = nullptr;
    if (lib3mf_model_queryreader(model, "3mf", &reader) != LIB3MF_OK)
        throw InputError(shown + ": cannot start the 3MF reader");
    Release readerGuard{reader};
    if (lib3mf_reader_readfromfileutf8(reader, path.string().c_str()) != LIB3MF_OK) {
        DWORD code = 0;
        LPCSTR message = nullptr;
        lib3mf_getlasterror(reader, &code, &message);
        throw InputError(shown + ": corrupted 3MF: " + (message ? std::string(message) : "the reader failed") +
                         " (error " + std::to_string(code) + ")");
    }
    DWORD unit = MODELUNIT_MILLIMETER;
    lib3mf_model_getunit(model, &unit);
    switch (unit) {
        case MODELUNIT_MICROMETER:
            unitMm = 0.001;
            break;
        case MODELUNIT_CENTIMETER:
            unitMm = 10.0;
            break;
        case MODELUNIT_INCH:
            unitMm = 25.4;
            break;
        case MODELUNIT_FOOT:
            unitMm = 304.8;
            break;
        case MODELUNIT_METER:
            unitMm = 1000.0;
            break;
        default:
            unitMm = 1.0;
    }

    TriangleMesh m;
    auto addMesh = [&](PLib3MFModelObjectResource* object, const std::array<std::array<double, 4>, 3>& xf) {
        BOOL isMesh = false;
        lib3mf_object_ismeshobject(object, &isMesh);
        if (!isMesh) return false;
        DWORD nv = 0, nt = 0;
        lib3mf_meshobject_getvertexcount(object, &nv);
        lib3mf_meshobject_gettrianglecount(object, &nt);
        std::vector<MODELMESHVERTEX> vertices(nv);
        std::vector<MODELMESHTRIANGLE> triangles(nt);
        if (nv) lib3mf_meshobject_getvertices(object, vertices.data(), nv, nullptr);
        if (nt) lib3mf_meshobject_gettriangleindices(object, triangles.data(), nt, nullptr);
        const auto base = std::uint32_t(m.points.size());
        for (const auto& v : vertices) {
            openvdb::Vec3f p;
            for (int r = 0; r < 3; ++r)
                p[r] = float(xf[r][0] * v.m_fPosition[0] + xf[r][1] * v.m_fPosition[1] + xf[r][2] * v.m_fPosition[2] +
                             xf[r][3]);
            checkFinite(p, shown, "a vertex of a mesh object");
            m.points.push_back(p);
        }
        for (const auto& t : triangles) {
            for (int c = 0; c < 3; ++c)
                if (t.m_nIndices[c] >= nv)
                    throw InputError(shown + ": corrupted 3MF: a triangle refers to vertex " +
                                     std::to_string(t.m_nIndices[c]) + " of " + std::to_string(nv));
            m.triangles.emplace_back(base + t.m_nIndices[0], base + t.m_nIndices[1], base + t.m_nIndices[2]);
        }
        return true;
    };
    // A 3MF transform is a 3x4 matrix, rows first, translation in the last column.
    auto toMatrix = [](const MODELTRANSFORM& t) {
        std::array<std::array<double, 4>, 3> xf{};
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 4; ++c) xf[r][c] = t.m_fFields[r][c];
        return xf;
    };
    auto compose = [](const std::array<std::array<double, 4>, 3>& a, const std::array<std::array<double, 4>, 3>& b) {
        std::array<std::array<double, 4>, 3> r{};  // a after b
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) r[i][j] = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
            r[i][3] = a[i][0] * b[0][3] + a[i][1] * b[1][3] + a[i][2] * b[2][3] + a[i][3];
        }
        return r;
    };

    PLib3MFModelBuildItemIterator* items = nullptr;
    if (lib3mf_model_getbuilditems(model, &items) != LIB3MF_OK) throw InputError(shown + ": corrupted 3MF: no build");
    Release itemsGuard{items};
    BOOL hasNext = false;
    while (lib3mf_builditemiterator_movenext(items, &hasNext) == LIB3MF_OK && hasNext) {
        PLib3MFModelBuildItem* item = nullptr;
        if (lib3mf_builditemiterator_getcurrent(items, &item) != LIB3MF_OK) continue;
        Release itemGuard{item};
        MODELTRANSFORM t;
        lib3mf_builditem_getobjecttransform(item, &t);
        const auto itemXf = toMatrix(t);
        PLib3MFModelObjectResource* object = nullptr;
        if (lib3mf_builditem_getobjectresource(item, &object) != LIB3MF_OK) continue;
        Release objectGuard{object};
        if (addMesh(object, itemXf)) continue;
        BOOL isComponents = false;
        lib3mf_object_iscomponentsobject(object, &isComponents);
        if (!isComponents) continue;
        DWORD count = 0;
        lib3mf_componentsobject_getcomponentcount(object, &count);
        for (DWORD c = 0; c < count; ++c) {
            PLib3MFModelComponent* component = nullptr;
            if (lib3mf_componentsobject_getcomponent(object, c, &component) != LIB3MF_OK) continue;
            Release componentGuard{component};
            MODELTRANSFORM ct;
            lib3mf_component_gettransform(component, &ct);
            PLib3MFModelObjectResource* child = nullptr;
            if (lib3mf_component_getobjectresource(component, &child) != LIB3MF_OK) continue;
            Release childGuard{child};
            addMesh(child, compose(itemXf, toMatrix(ct)));
        }
    }
    return m;
}

struct Vec3fHash {
    std::size_t operator()(const openvdb::Vec3f& p) const
    {
        std::size_t h = 0;
        for (int i = 0; i < 3; ++i)
            h = h * 0x9E3779B97F4A7C15ull ^ std::bit_cast<std::uint32_t>(p[i] == 0.0f ? 0.0f : p[i]);
        return h;
    }
};

}  // namespace

void weldVertices(TriangleMesh& mesh)
{
    std::unordered_map<openvdb::Vec3f, std::uint32_t, Vec3fHash> index;
    index.reserve(mesh.points.size());
    std::vector<openvdb::Vec3f> points;
    std::vector<std::uint32_t> remap(mesh.points.size());
    for (std::size_t i = 0; i < mesh.points.size(); ++i) {
        openvdb::Vec3f p = mesh.points[i];
        for (int a = 0; a < 3; ++a)
            if (p[a] == 0.0f) p[a] = 0.0f;  // -0 and +0 are one place
        const auto [it, added] = index.emplace(p, std::uint32_t(points.size()));
        if (added) points.push_back(p);
        remap[i] = it->second;
    }
    for (auto& t : mesh.triangles)
        for (int c = 0; c < 3; ++c) t[c] = t[c] < remap.size() ? remap[t[c]] : t[c];
    mesh.points = std::move(points);
}

PartMesh readPartMesh(const std::filesystem::path& path, const std::string& shown)
{
    const std::string ext = lower(path.extension().string());
    PartMesh part;
    if (ext == ".stl") {
        checkReadable(path, shown);
        checkStlHeader(path, shown);
        part.mesh = readStl(readBytes(path, shown), shown, part.format);
    } else if (ext == ".ply") {
        part.format = "PLY";
        part.mesh = readPly(readBytes(path, shown), shown);
    } else if (ext == ".obj") {
        part.format = "OBJ";
        part.mesh = readObj(readBytes(path, shown), shown);
    } else if (ext == ".3mf") {
        checkReadable(path, shown);
        part.format = "3MF";
        part.mesh = read3mf(path, shown, part.fileUnitMm);
    } else {
        throw InputError(shown + ": unknown mesh format `" + ext + "` (readable: .stl, .obj, .ply, .3mf)");
    }
    if (part.mesh.triangles.empty()) throw InputError(shown + ": the file holds no triangles (" + part.format + ")");
    weldVertices(part.mesh);
    return part;
}

}  // namespace voxlat
