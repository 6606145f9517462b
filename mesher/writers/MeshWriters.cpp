#include "mesher/writers/MeshWriters.h"

#include "mesher/writers/AtomicFile.h"
#include "mesher/writers/Lib3mfPackage.h"

#include <tbb/parallel_pipeline.h>

#include <Model/COM/NMR_DLLInterfaces.h>
#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>

#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string_view>
#include <tuple>
#include <unordered_map>
#include <vector>

namespace voxlat {

namespace {

constexpr std::size_t kStlHeaderSize = 80;
constexpr std::size_t kStlFacetSize = 50;
constexpr std::size_t kStlChunkFacets = 1 << 14;  // ~800 KB per write
/// Items between two checks of the write interrupter in the loops that prepare a file's bytes.
constexpr std::size_t kInterruptEvery = 1 << 16;

// Explicit little-endian encoding keeps the files identical on any host.
void putU32(char* p, std::uint32_t v)
{
    for (int i = 0; i < 4; ++i) p[i] = char((v >> (8 * i)) & 0xFF);
}
void putF32(char* p, float f)
{
    putU32(p, std::bit_cast<std::uint32_t>(f));
}
/// Twelve floats, little-endian, as putF32 writes them one by one (one copy on little-endian hosts).
void putF32s(char* p, const float (&f)[12])
{
    if constexpr (std::endian::native == std::endian::little)
        std::memcpy(p, f, sizeof(f));
    else
        for (int k = 0; k < 12; ++k) putF32(p + 4 * k, f[k]);
}
std::uint32_t getU32(const char* p)
{
    std::uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v |= std::uint32_t(static_cast<unsigned char>(p[i])) << (8 * i);
    return v;
}
float getF32(const char* p)
{
    return std::bit_cast<float>(getU32(p));
}

std::string lowerExtension(const std::string& path)
{
    std::string ext = std::filesystem::path(path).extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    return ext;
}

void checkIndices(const TriangleMesh& mesh)
{
    const std::size_t n = mesh.points.size();
    for (const openvdb::Vec3I& t : mesh.triangles) {
        if (t[0] >= n || t[1] >= n || t[2] >= n) {
            throw std::invalid_argument("mesh triangle refers to a vertex index out of range");
        }
    }
}

void writeOpenMesh(const TriangleMesh& mesh, const std::string& path, const std::string& ext)
{
    checkIndices(mesh);
    using OMesh = OpenMesh::TriMesh_ArrayKernelT<>;
    OMesh om;
    om.reserve(mesh.points.size(), 3 * mesh.triangles.size() / 2, mesh.triangles.size());
    std::vector<OMesh::VertexHandle> handles;
    handles.reserve(mesh.points.size());
    for (const openvdb::Vec3f& p : mesh.points) {
        if (handles.size() % kInterruptEvery == 0) checkWriteInterrupt();
        handles.push_back(om.add_vertex(OMesh::Point(p.x(), p.y(), p.z())));
    }
    for (std::size_t i = 0; i < mesh.triangles.size(); ++i) {
        if (i % kInterruptEvery == 0) checkWriteInterrupt();
        const openvdb::Vec3I& t = mesh.triangles[i];
        if (!om.add_face(handles[t[0]], handles[t[1]], handles[t[2]]).is_valid()) {
            throw std::runtime_error("cannot write '" + path +
                                     "': OpenMesh rejected a non-manifold or degenerate face");
        }
    }
    AtomicFile file(path);
    // OpenMesh writes ASCII unless asked; OBJ is ASCII only, with enough digits to round-trip floats.
    const OpenMesh::IO::Options options =
        ext == ".ply" ? OpenMesh::IO::Options::Binary : OpenMesh::IO::Options::Default;
    // OpenMesh chats on its log streams ("[OBJWriter] : write file"); our callers report instead.
    ::omlog().disable();
    ::omout().disable();
    if (!OpenMesh::IO::write_mesh(om, file.stream(), ext, options, std::numeric_limits<float>::max_digits10)) {
        throw std::runtime_error("OpenMesh failed to write '" + path + "'");
    }
    file.commit();
}

/// A UUID made from the mesh and its metadata (and @a role, so the object, build and item differ):
/// lib3mf stamps random ones, and the same mesh should give the same bytes.
std::string contentUuid(const TriangleMesh& mesh, const MeshMetadata& metadata, std::uint64_t role)
{
    std::uint64_t h[2] = {0xcbf29ce484222325ull ^ role, 0x84222325cbf29ce4ull + role};
    auto mix = [&](std::uint64_t word) {
        h[0] = (h[0] ^ word) * 0x100000001b3ull;
        h[1] = (h[1] ^ (word + 0x9E3779B97F4A7C15ull)) * 0x100000001b3ull;
        h[1] ^= h[1] >> 29;
    };
    for (const auto& [key, value] : metadata)
        for (const std::string* text : {&key, &value})
            for (unsigned char c : *text) mix(c);
    for (const openvdb::Vec3f& p : mesh.points)
        mix(std::uint64_t(std::bit_cast<std::uint32_t>(p[0])) << 32 ^ std::bit_cast<std::uint32_t>(p[1]) ^
            std::uint64_t(std::bit_cast<std::uint32_t>(p[2])) << 16);
    for (const openvdb::Vec3I& t : mesh.triangles) mix(std::uint64_t(t[0]) << 32 ^ t[1] ^ std::uint64_t(t[2]) << 16);
    char text[37];
    // Version 4 and variant bits set, so it reads as any other UUID.
    std::snprintf(text, sizeof text, "%08x-%04x-4%03x-8%03x-%012llx", unsigned(h[0] >> 32),
                  unsigned(h[0] >> 16 & 0xFFFF), unsigned(h[0] & 0xFFF), unsigned(h[1] >> 52 & 0xFFF),
                  static_cast<unsigned long long>(h[1] & 0xFFFFFFFFFFFFull));
    return text;
}

/// Writes @a mesh as a 3MF package through lib3mf: unit millimetre, one mesh object, one build
/// item, @a metadata as the model's metadata. lib3mf packs the model into a buffer, which goes
/// to the file through AtomicFile.
void write3mf(const TriangleMesh& mesh, const std::string& path, const MeshMetadata& metadata)
{
    using namespace NMR;
    checkIndices(mesh);
    if (mesh.points.size() > std::numeric_limits<DWORD>::max() ||
        mesh.triangles.size() > std::numeric_limits<DWORD>::max())
        throw std::invalid_argument("cannot write '" + path +
                                    "': a 3MF mesh holds at most 2^32 - 1 vertices and triangles");
    const Lib3mfPackage package(path, metadata);
    PLib3MFModelMeshObject* objectRaw = package.object();
    std::vector<MODELMESHVERTEX> vertices(mesh.points.size());
    for (std::size_t i = 0; i < mesh.points.size(); ++i) {
        if (i % kInterruptEvery == 0) checkWriteInterrupt();
        for (int k = 0; k < 3; ++k) vertices[i].m_fPosition[k] = mesh.points[i][k];
    }
    std::vector<MODELMESHTRIANGLE> triangles(mesh.triangles.size());
    for (std::size_t i = 0; i < mesh.triangles.size(); ++i) {
        if (i % kInterruptEvery == 0) checkWriteInterrupt();
        for (int k = 0; k < 3; ++k) triangles[i].m_nIndices[k] = DWORD(mesh.triangles[i][k]);
    }
    package.check(lib3mf_meshobject_setgeometry(objectRaw, vertices.data(), DWORD(vertices.size()), triangles.data(),
                                                DWORD(triangles.size())),
                  objectRaw, "store the mesh");
    vertices = {};
    triangles = {};
    package.write({contentUuid(mesh, metadata, 1), contentUuid(mesh, metadata, 2), contentUuid(mesh, metadata, 3)});
}

/// Exact welding key: the bit patterns, with -0 folded onto +0 so equal values weld.
struct PointKey {
    std::array<std::uint32_t, 3> bits;
    bool operator==(const PointKey&) const = default;
};
struct PointKeyHash {
    std::size_t operator()(const PointKey& k) const
    {
        std::uint64_t h = k.bits[0];
        h = h * 0x9E3779B97F4A7C15ull ^ k.bits[1];
        h = h * 0x9E3779B97F4A7C15ull ^ k.bits[2];
        return std::size_t(h ^ (h >> 31));
    }
};

class Welder {
public:
    /// @a expectedPoints sizes the table up front: a closed triangle mesh has about half as
    /// many vertices as triangles.
    Welder(TriangleMesh& mesh, std::size_t expectedPoints) : mMesh(mesh)
    {
        mIndex.reserve(expectedPoints);
        mMesh.points.reserve(expectedPoints);
    }

    std::uint32_t add(const openvdb::Vec3f& p)
    {
        PointKey key;
        for (int i = 0; i < 3; ++i) key.bits[i] = std::bit_cast<std::uint32_t>(p[i] == 0.0f ? 0.0f : p[i]);
        const auto [it, inserted] = mIndex.try_emplace(key, std::uint32_t(mMesh.points.size()));
        if (inserted) mMesh.points.push_back(p);
        return it->second;
    }

private:
    TriangleMesh& mMesh;
    std::unordered_map<PointKey, std::uint32_t, PointKeyHash> mIndex;
};

void parseAsciiStl(const std::string& text, const std::string& path, TriangleMesh& mesh)
{
    Welder welder(mesh, 0);
    std::vector<std::uint32_t> corners;
    const char* p = text.c_str();
    const char* end = p + text.size();
    auto skipSpace = [&] {
        while (p < end && std::isspace(static_cast<unsigned char>(*p))) ++p;
    };
    while (true) {
        skipSpace();
        if (p >= end) break;
        const char* word = p;
        while (p < end && !std::isspace(static_cast<unsigned char>(*p))) ++p;
        if (std::string_view(word, std::size_t(p - word)) != "vertex") continue;
        openvdb::Vec3f v;
        for (int i = 0; i < 3; ++i) {
            char* next = nullptr;
            v[i] = std::strtof(p, &next);
            if (next == p) throw std::runtime_error("malformed vertex in ASCII STL '" + path + "'");
            p = next;
        }
        corners.push_back(welder.add(v));
    }
    if (corners.size() % 3 != 0) throw std::runtime_error("ASCII STL '" + path + "' has a partial facet");
    for (std::size_t i = 0; i < corners.size(); i += 3)
        mesh.triangles.emplace_back(corners[i], corners[i + 1], corners[i + 2]);
}

}  // namespace

namespace {

constexpr int kFacetBatch = 64;

/// Normals (as floats), lengths of the unnormalised normals (twice the areas) and volume terms
/// (six times the signed volume of the tetrahedron with @a ref) of @a n <= kFacetBatch triangles
/// given as nine coordinate arrays (a.x, a.y, a.z, b.x, ... c.z, each kFacetBatch long): the
/// double operations of OpenVDB's cross(), length() and dot() in the same order, laid out so the
/// loop vectorises (built for AVX2 too and picked at load time, without FMA either way; this file
/// is built without errno from sqrt and without traps, either of which would keep the loop
/// scalar), so the bits are those of the scalar expressions.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
__attribute__((target_clones("avx2", "default")))
#endif
void facetTerms(const double* __restrict c, int n, double rx, double ry, double rz, float* __restrict normal,
                double* __restrict length, double* __restrict volume)
{
    const double *ax = c, *ay = c + kFacetBatch, *az = c + 2 * kFacetBatch;
    const double *bx = c + 3 * kFacetBatch, *by = c + 4 * kFacetBatch, *bz = c + 5 * kFacetBatch;
    const double *cx = c + 6 * kFacetBatch, *cy = c + 7 * kFacetBatch, *cz = c + 8 * kFacetBatch;
    for (int i = 0; i < n; ++i) {
        const double ux = bx[i] - ax[i], uy = by[i] - ay[i], uz = bz[i] - az[i];
        const double vx = cx[i] - ax[i], vy = cy[i] - ay[i], vz = cz[i] - az[i];
        const double nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
        const double len = std::sqrt(nx * nx + ny * ny + nz * nz);
        length[i] = len;
        const double pax = ax[i] - rx, pay = ay[i] - ry, paz = az[i] - rz;
        const double pbx = bx[i] - rx, pby = by[i] - ry, pbz = bz[i] - rz;
        const double pcx = cx[i] - rx, pcy = cy[i] - ry, pcz = cz[i] - rz;
        volume[i] = pax * (pby * pcz - pbz * pcy) + pay * (pbz * pcx - pbx * pcz) + paz * (pbx * pcy - pby * pcx);
        // Divide always (by 1 for a triangle without area), then select.
        const bool positive = len > 0.0;
        const double divisor = positive ? len : 1.0;
        const double qx = nx / divisor, qy = ny / divisor, qz = nz / divisor;
        normal[i] = float(positive ? qx : 0.0);
        normal[kFacetBatch + i] = float(positive ? qy : 0.0);
        normal[2 * kFacetBatch + i] = float(positive ? qz : 0.0);
    }
}

/// Binary STL facets of @a count triangles at @a p (kStlFacetSize bytes each): the unit normal
/// computed in double, then the corners; @a triangle(i) gives triangle i's three corners. With
/// @a sum, adds their area and volume terms (about @a ref) in triangle order, as
/// TriangleMesh::measure() takes them. writeStl() and StlStreamWriter share it: one set of bytes.
template <class Corners>
void formatFacets(std::size_t count, const Corners& triangle, char* p, const openvdb::Vec3d& ref,
                  TriangleMesh::Measures* sum)
{
    double coords[9 * kFacetBatch];
    float normal[3 * kFacetBatch];
    double length[kFacetBatch], volume[kFacetBatch];
    for (std::size_t start = 0; start < count; start += kFacetBatch) {
        const int n = int(std::min<std::size_t>(kFacetBatch, count - start));
        for (int i = 0; i < n; ++i) {
            const auto [a, b, c] = triangle(start + std::size_t(i));
            for (int k = 0; k < 3; ++k) {
                coords[k * kFacetBatch + i] = a[k];
                coords[(3 + k) * kFacetBatch + i] = b[k];
                coords[(6 + k) * kFacetBatch + i] = c[k];
            }
        }
        facetTerms(coords, n, ref[0], ref[1], ref[2], normal, length, volume);
        for (int i = 0; i < n; ++i, p += kStlFacetSize) {
            if (sum) {
                sum->area += length[i];
                sum->volume += volume[i];
            }
            // The corners as given (floats), not converted back from the doubles: the same values.
            const auto [a, b, c] = triangle(start + std::size_t(i));
            float facet[12];
            for (int k = 0; k < 3; ++k) {
                facet[k] = normal[k * kFacetBatch + i];
                facet[3 + k] = a[k];
                facet[6 + k] = b[k];
                facet[9 + k] = c[k];
            }
            putF32s(p, facet);
            p[48] = p[49] = 0;
        }
    }
}

/// The 84 bytes before the facets: title, then the triangle count.
void writeStlHeader(std::ostream& out, std::uint64_t triangles)
{
    if (triangles > std::numeric_limits<std::uint32_t>::max()) {
        throw std::invalid_argument("binary STL holds at most 2^32 - 1 triangles");
    }
    char header[kStlHeaderSize + 4];
    std::memset(header, ' ', kStlHeaderSize);
    const std::string_view title = "voxlat binary STL";
    std::memcpy(header, title.data(), title.size());
    putU32(header + kStlHeaderSize, std::uint32_t(triangles));
    out.write(header, sizeof(header));
}

}  // namespace

StlStreamWriter::StlStreamWriter(const std::string& path, const openvdb::Vec3d& reference)
    : mFile(std::make_unique<AtomicFile>(path)), mReference(reference)
{
    writeStlHeader(mFile->stream(), 0);
}

StlStreamWriter::~StlStreamWriter() = default;

TriangleMesh::Measures StlStreamWriter::format(std::span<const std::array<openvdb::Vec3f, 3>> triangles,
                                               std::vector<char>& bytes) const
{
    bytes.resize(triangles.size() * kStlFacetSize);
    TriangleMesh::Measures sum;
    formatFacets(
        triangles.size(),
        [&](std::size_t i) {
            const auto& t = triangles[i];
            return std::tie(t[0], t[1], t[2]);
        },
        bytes.data(), mReference, &sum);
    return sum;
}

void StlStreamWriter::write(const std::vector<char>& bytes, const TriangleMesh::Measures& terms)
{
    mFile->stream().write(bytes.data(), std::streamsize(bytes.size()));
    mTerms.volume += terms.volume;
    mTerms.area += terms.area;
}

TriangleMesh::Measures StlStreamWriter::commit(std::uint64_t triangles)
{
    std::ostream& out = mFile->stream();
    const std::streampos end = out.tellp();
    out.seekp(0);
    writeStlHeader(out, triangles);
    out.seekp(end);
    mFile->commit();
    return {mTerms.volume / 6.0, 0.5 * mTerms.area};
}

StreamedStl writeMarchingCubesStl(const openvdb::FloatGrid& grid, float isoValue, const std::string& path,
                                  const openvdb::Vec3d& reference, ProgressFn progress, MarchingCubesStats* stats)
{
    StlStreamWriter writer(path, reference);
    TriangleStream stream;
    std::vector<std::vector<char>> bytes(stream.slots);
    std::vector<TriangleMesh::Measures> terms(stream.slots);
    stream.format = [&](std::size_t, std::size_t slot, std::span<const TriangleCorners> triangles) {
        terms[slot] = writer.format(triangles, bytes[slot]);
    };
    stream.write = [&](std::size_t, std::size_t slot) { writer.write(bytes[slot], terms[slot]); };
    StreamedStl made;
    made.counts = marchingCubesStreamed(grid, isoValue, stream, std::move(progress), stats);
    made.measures = writer.commit(made.counts.triangles);
    return made;
}

void writeStl(const TriangleMesh& mesh, const std::string& path, TriangleMesh::Measures* measures)
{
    checkIndices(mesh);
    AtomicFile file(path);
    std::ostream& out = file.stream();
    writeStlHeader(out, mesh.triangles.size());

    // Facets are formatted in parallel, chunk by chunk, and written in order: the bytes are the
    // same for any thread count, and formatting (normals) overlaps the writing. At most kTokens
    // chunks are in flight and they leave the pipeline in order, so chunk i can reuse the buffer
    // of chunk i - kTokens: the buffers are allocated (and their pages touched) once.
    constexpr std::size_t kTokens = 8;
    constexpr std::size_t kPrefetchAhead = 16;
    const std::size_t chunks = (mesh.triangles.size() + kStlChunkFacets - 1) / kStlChunkFacets;
    std::vector<std::vector<char>> buffers(std::min(kTokens, chunks));
    // Volume and area terms as TriangleMesh::measure() takes them, summed per chunk.
    std::vector<TriangleMesh::Measures> sums(measures ? chunks : 0);
    const openvdb::Vec3d ref =
        mesh.triangles.empty() ? openvdb::Vec3d(0.0) : openvdb::Vec3d(mesh.points[mesh.triangles.front()[0]]);
    auto formatChunk = [&](std::size_t index) {
        const std::size_t begin = index * kStlChunkFacets;
        const std::size_t count = std::min(kStlChunkFacets, mesh.triangles.size() - begin);
        std::vector<char>& chunk = buffers[index % kTokens];
        chunk.resize(count * kStlFacetSize);
        TriangleMesh::Measures sum;
        formatFacets(
            count,
            [&](std::size_t k) {
                const std::size_t i = begin + k;
                // A triangle's corners can be vertices of a neighbouring block, far off in the
                // array: ask for those of a later triangle now so their loads do not stall this one.
                if (i + kPrefetchAhead < begin + count) {
                    const openvdb::Vec3I& ahead = mesh.triangles[i + kPrefetchAhead];
                    for (int c = 0; c < 3; ++c) __builtin_prefetch(&mesh.points[ahead[c]]);
                }
                const openvdb::Vec3I& t = mesh.triangles[i];
                return std::tie(mesh.points[t[0]], mesh.points[t[1]], mesh.points[t[2]]);
            },
            chunk.data(), ref, measures ? &sum : nullptr);
        if (measures) sums[index] = sum;
        return index;
    };
    std::size_t next = 0;
    auto nextChunk = [&](tbb::flow_control& fc) -> std::size_t {
        if (next == chunks) fc.stop();
        return next++;
    };
    auto writeChunk = [&](std::size_t index) {
        const std::vector<char>& chunk = buffers[index % kTokens];
        out.write(chunk.data(), std::streamsize(chunk.size()));
    };
    tbb::parallel_pipeline(kTokens,
                           tbb::make_filter<void, std::size_t>(tbb::filter_mode::serial_in_order, nextChunk) &
                               tbb::make_filter<std::size_t, std::size_t>(tbb::filter_mode::parallel, formatChunk) &
                               tbb::make_filter<std::size_t, void>(tbb::filter_mode::serial_in_order, writeChunk));
    file.commit();
    if (measures) {
        TriangleMesh::Measures total;
        for (const TriangleMesh::Measures& m : sums) {
            total.volume += m.volume;
            total.area += m.area;
        }
        *measures = {total.volume / 6.0, 0.5 * total.area};
    }
}

void writeMesh(const TriangleMesh& mesh, const std::string& path, std::optional<TriangleMesh::Measures>* measures,
               const MeshMetadata& metadata)
{
    const std::string ext = lowerExtension(path);
    if (ext == ".stl") {
        TriangleMesh::Measures m;
        writeStl(mesh, path, measures ? &m : nullptr);
        if (measures) *measures = m;
    } else if (ext == ".3mf") {
        write3mf(mesh, path, metadata);
    } else if (ext == ".ply" || ext == ".obj") {
        writeOpenMesh(mesh, path, ext);
    } else {
        throw std::invalid_argument("cannot write mesh '" + path + "': unsupported extension '" + ext +
                                    "' (supported: .stl, .3mf, .ply, .obj)");
    }
}

TriangleMesh readStl(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) throw std::runtime_error("cannot open STL file '" + path + "'");
    std::string data;
    in.seekg(0, std::ios::end);
    data.resize(std::size_t(std::max<std::streamoff>(in.tellg(), 0)));
    in.seekg(0, std::ios::beg);
    in.read(data.data(), std::streamsize(data.size()));
    if (!in) throw std::runtime_error("cannot read STL file '" + path + "'");

    TriangleMesh mesh;
    // The size test comes first: binary files may also begin with "solid".
    if (data.size() >= kStlHeaderSize + 4) {
        const std::uint64_t count = getU32(data.data() + kStlHeaderSize);
        if (data.size() == kStlHeaderSize + 4 + count * kStlFacetSize) {
            Welder welder(mesh, count / 2 + 3);
            mesh.triangles.reserve(count);
            const char* p = data.data() + kStlHeaderSize + 4;
            for (std::uint64_t i = 0; i < count; ++i, p += kStlFacetSize) {
                std::uint32_t idx[3];
                for (int k = 0; k < 3; ++k) {
                    const char* q = p + 12 + 12 * k;
                    idx[k] = welder.add(openvdb::Vec3f(getF32(q), getF32(q + 4), getF32(q + 8)));
                }
                mesh.triangles.emplace_back(idx[0], idx[1], idx[2]);
            }
            return mesh;
        }
    }
    const std::size_t start = data.find_first_not_of(" \t\r\n");
    if (start == std::string::npos || data.compare(start, 5, "solid") != 0) {
        throw std::runtime_error("'" + path + "' is neither binary nor ASCII STL");
    }
    parseAsciiStl(data, path, mesh);
    return mesh;
}

}  // namespace voxlat
