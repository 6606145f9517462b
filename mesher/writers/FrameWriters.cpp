#include "mesher/writers/FrameWriters.h"

#include "mesher/writers/AtomicFile.h"
#include "mesher/writers/Lib3mfPackage.h"

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <memory>
#include <stdexcept>

namespace voxlat {

namespace {

void checkFrame(const BeamFrame& frame, const std::string& path)
{
    if (frame.radii.size() != frame.struts.size())
        throw std::invalid_argument("cannot write '" + path + "': one pair of radii per strut");
    for (const auto& s : frame.struts)
        for (const int i : s)
            if (i < 0 || std::size_t(i) >= frame.nodes.size())
                throw std::invalid_argument("cannot write '" + path +
                                            "': a strut refers to a node that does not exist");
}

/// 17 significant digits: every double reads back to the same bits.
std::string number(double v)
{
    char text[32];
    std::snprintf(text, sizeof text, "%.17g", v);
    return text;
}

void write3mfBeams(const BeamFrame& frame, const std::string& path,
                   const std::vector<std::pair<std::string, std::string>>& metadata)
{
    using namespace NMR;
    if (frame.nodes.size() > std::numeric_limits<DWORD>::max() ||
        frame.struts.size() > std::numeric_limits<DWORD>::max())
        throw std::invalid_argument("cannot write '" + path + "': a 3MF beam lattice holds at most 2^32 - 1 beams");
    const Lib3mfPackage package(path, metadata);
    PLib3MFModelMeshObject* objectRaw = package.object();
    auto check = [&](LIB3MFRESULT result, PLib3MFBase* owner, const char* what) { package.check(result, owner, what); };
    // One vertex at a time: lib3mf's setgeometry refuses a mesh without triangles.
    for (const Vec3d& p : frame.nodes) {
        MODELMESHVERTEX vertex;
        for (int k = 0; k < 3; ++k) vertex.m_fPosition[k] = float(p[k]);
        check(lib3mf_meshobject_addvertex(objectRaw, &vertex, nullptr), objectRaw, "store a node");
    }
    std::vector<MODELMESHBEAM> beams(frame.struts.size());
    double smallest = std::numeric_limits<double>::infinity(), shortest = smallest;
    for (std::size_t j = 0; j < frame.struts.size(); ++j) {
        for (int e = 0; e < 2; ++e) {
            beams[j].m_nIndices[e] = DWORD(frame.struts[j][e]);
            beams[j].m_dRadius[e] = frame.radii[j][e];
            beams[j].m_eCapMode[e] = MODELBEAMLATTICECAPMODE_SPHERE;
            smallest = std::min(smallest, frame.radii[j][e]);
        }
        shortest = std::min(shortest, (frame.nodes[frame.struts[j][1]] - frame.nodes[frame.struts[j][0]]).length());
    }
    // The lattice's default radius and minimum length: every beam gives its own radii, and the
    // minimum length must not reject any of them.
    if (!frame.struts.empty()) {
        check(lib3mf_meshobject_setbeamlattice_radius(objectRaw, smallest), objectRaw, "set the default radius");
        check(lib3mf_meshobject_setbeamlattice_minlength(objectRaw, std::min(1e-4, 0.5 * shortest)), objectRaw,
              "set the minimum length");
        check(lib3mf_meshobject_setbeamlattice_capmode(objectRaw, MODELBEAMLATTICECAPMODE_SPHERE), objectRaw,
              "set the cap mode");
        check(lib3mf_meshobject_setbeamindices(objectRaw, beams.data(), DWORD(beams.size())), objectRaw,
              "store the beams");
    }
    // Fixed UUIDs: the same frame gives the same bytes.
    package.write({"6f0b1c2e-5a1d-4c3b-8e2f-000000000001", "6f0b1c2e-5a1d-4c3b-8e2f-000000000002",
                   "6f0b1c2e-5a1d-4c3b-8e2f-000000000003"});
}

}  // namespace

void writeFrame(const BeamFrame& frame, const std::string& path,
                const std::vector<std::pair<std::string, std::string>>& metadata)
{
    checkFrame(frame, path);
    std::string ext = std::filesystem::path(path).extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    if (ext == ".3mf") {
        write3mfBeams(frame, path, metadata);
        return;
    }
    if (ext != ".csv" && ext != ".obj")
        throw std::invalid_argument("cannot write '" + path + "': a frame file ends in .csv, .obj or .3mf");
    AtomicFile file(path);
    std::ostream& out = file.stream();
    if (ext == ".csv") {
        out << "x1,y1,z1,x2,y2,z2,r1,r2\n";
        for (std::size_t j = 0; j < frame.struts.size(); ++j) {
            const Vec3d& a = frame.nodes[frame.struts[j][0]];
            const Vec3d& b = frame.nodes[frame.struts[j][1]];
            out << number(a[0]) << ',' << number(a[1]) << ',' << number(a[2]) << ',' << number(b[0]) << ','
                << number(b[1]) << ',' << number(b[2]) << ',' << number(frame.radii[j][0]) << ','
                << number(frame.radii[j][1]) << '\n';
        }
    } else {
        out << "# voxlat strut frame: " << frame.nodes.size() << " nodes, " << frame.struts.size()
            << " struts; each `l` is followed by its radii (mm) at its two ends\n";
        for (const Vec3d& p : frame.nodes)
            out << "v " << number(p[0]) << ' ' << number(p[1]) << ' ' << number(p[2]) << '\n';
        for (std::size_t j = 0; j < frame.struts.size(); ++j)
            out << "l " << frame.struts[j][0] + 1 << ' ' << frame.struts[j][1] + 1 << "\n# r "
                << number(frame.radii[j][0]) << ' ' << number(frame.radii[j][1]) << '\n';
    }
    file.commit();
}

BeamFrame readBeamLattice3mf(const std::string& path)
{
    using namespace NMR;
    auto check = [&](LIB3MFRESULT result, const char* what) {
        if (result != LIB3MF_OK) throw std::runtime_error("cannot read '" + path + "': lib3mf failed to " + what);
    };
    PLib3MFModel* modelRaw = nullptr;
    check(lib3mf_createmodel(&modelRaw), "create a model");
    const Lib3mfHandle model(modelRaw);
    PLib3MFModelReader* readerRaw = nullptr;
    check(lib3mf_model_queryreader(modelRaw, "3mf", &readerRaw), "start the reader");
    const Lib3mfHandle reader(readerRaw);
    check(lib3mf_reader_readfromfileutf8(readerRaw, path.c_str()), "read the file");
    PLib3MFModelResourceIterator* itRaw = nullptr;
    check(lib3mf_model_getmeshobjects(modelRaw, &itRaw), "list the mesh objects");
    const Lib3mfHandle it(itRaw);
    BOOL has = false;
    check(lib3mf_resourceiterator_movenext(itRaw, &has), "find a mesh object");
    if (!has) throw std::runtime_error("cannot read '" + path + "': no mesh object");
    PLib3MFModelResource* objectRaw = nullptr;
    check(lib3mf_resourceiterator_getcurrent(itRaw, &objectRaw), "get the mesh object");
    const Lib3mfHandle object(objectRaw);
    DWORD vertexCount = 0, beamCount = 0;
    check(lib3mf_meshobject_getvertexcount(objectRaw, &vertexCount), "count the vertices");
    check(lib3mf_meshobject_getbeamcount(objectRaw, &beamCount), "count the beams");
    BeamFrame frame;
    std::vector<MODELMESHVERTEX> vertices(vertexCount);
    if (vertexCount)
        check(lib3mf_meshobject_getvertices(objectRaw, vertices.data(), vertexCount, nullptr), "read the vertices");
    for (const MODELMESHVERTEX& v : vertices)
        frame.nodes.emplace_back(v.m_fPosition[0], v.m_fPosition[1], v.m_fPosition[2]);
    for (DWORD j = 0; j < beamCount; ++j) {
        MODELMESHBEAM beam;
        check(lib3mf_meshobject_getbeam(objectRaw, j, &beam), "read a beam");
        frame.struts.push_back({int(beam.m_nIndices[0]), int(beam.m_nIndices[1])});
        frame.radii.push_back({beam.m_dRadius[0], beam.m_dRadius[1]});
    }
    return frame;
}

}  // namespace voxlat
