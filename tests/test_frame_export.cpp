// Frame export (issue 19): `outputs: {frame: F}` as CSV, OBJ and a 3MF beam lattice; the CSV read
// back as a wireframe gives the same mesh bytes; radii at the solved level; the errors. And the
// one-sided offset of a network in millimetres, measured against the original surface.
#include "TestUtil.h"
#include "engine/jobs/Job.h"
#include "mesher/writers/FrameWriters.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <fstream>

using namespace voxlat;
using namespace voxlat::test;

namespace {

int runIn(const TempDir& dir, const std::string& name, const std::string& text, const std::string& out,
          std::string* output = nullptr)
{
    const auto recipe = dir.write(name, text);
    return runCommand(voxlatBinary() + " -q run " + recipe.string() + " --out " + (dir.path / out).string(), output);
}

std::vector<std::vector<double>> readCsvRows(const std::filesystem::path& p, std::string& header)
{
    std::ifstream in(p);
    std::getline(in, header);
    std::vector<std::vector<double>> rows;
    for (std::string line; std::getline(in, line);) {
        std::vector<double> row;
        std::stringstream s(line);
        for (std::string c; std::getline(s, c, ',');) row.push_back(std::stod(c));
        rows.push_back(row);
    }
    return rows;
}

}  // namespace

TEST(FrameExport, GradedRadiiStayWithinMinAndMaxPastTheDomain)
{
    // 2 mm cells laid past a 0.2 mm thin domain: their far nodes lie 10 box heights away. Radii
    // graded over the box (u, v, w in [0, 1]) must stay within [min, max] at every strut end,
    // and the slice of such a plate must show its struts.
    TempDir dir;
    for (const std::string preset : {"spherical", "centred", "cylindrical", "linear"}) {
        const std::string recipe =
            "voxel: 0.05\ndomain: {box: [[0, 0, 0], [8, 14, 0.2]]}\nfields:\n"
            "  lattice: {struts: {cell: bcc, size: 2}, kernel: capsule, radius: {gradient: " +
            preset +
            ", min: 0.15, max: 0.3, axis: z}}\nresult: lattice\n"
            "outputs: {frame: frame.csv}\n";
        std::string log;
        ASSERT_EQ(runIn(dir, preset + ".yaml", recipe, preset, &log), 0) << log;
        std::string header;
        const auto rows = readCsvRows(dir.path / preset / "frame.csv", header);
        ASSERT_GT(rows.size(), 100u) << preset;
        double lo = 1e9, hi = 0.0;
        for (const auto& row : rows) {
            lo = std::min({lo, row[6], row[7]});
            hi = std::max({hi, row[6], row[7]});
        }
        EXPECT_GE(lo, 0.15 - 1e-12) << preset;
        EXPECT_LE(hi, 0.3 + 1e-12) << preset;
    }
}

TEST(FrameExport, CsvReadBackAsAWireframeGivesTheSameMesh)
{
    TempDir dir;
    // Round struts whose radii differ end to end (a gradient along z), so direction matters.
    const std::string head = "voxel: 0.1\ndomain: {box: [[-0.5, -0.5, -0.5], [8.5, 8.5, 8.5]]}\nfields:\n";
    const std::string original =
        head +
        "  lattice: {struts: {cell: octet, size: 4, count: 2, origin: [0, 0, 0]}, kernel: capsule, "
        "radius: {gradient: linear, min: 0.3, max: 0.6, axis: z}}\nresult: lattice\n"
        "outputs: {mesh: a.stl, frame: [frame.csv, frame.obj, frame.3mf]}\n";
    std::string log;
    ASSERT_EQ(runIn(dir, "a.yaml", original, "a", &log), 0) << log;
    std::string header;
    const auto rows = readCsvRows(dir.path / "a" / "frame.csv", header);
    EXPECT_EQ(header, "x1,y1,z1,x2,y2,z2,r1,r2");
    Job job(parseRecipe(original, "a.yaml", dir.path));
    const BeamFrame frame = job.frame();
    ASSERT_EQ(rows.size(), frame.struts.size());
    for (std::size_t j = 0; j < rows.size(); ++j) {
        ASSERT_EQ(rows[j].size(), 8u);
        const Vec3d a = frame.nodes[frame.struts[j][0]], b = frame.nodes[frame.struts[j][1]];
        for (int k = 0; k < 3; ++k) {
            EXPECT_EQ(rows[j][k], a[k]);
            EXPECT_EQ(rows[j][3 + k], b[k]);
        }
        // The linear gradient: r = 0.3 + 0.3 z / 8 at each end (level 0: the radius itself).
        EXPECT_NEAR(rows[j][6], 0.3 + 0.3 * a[2] / 8.0, 1e-12);
        EXPECT_NEAR(rows[j][7], 0.3 + 0.3 * b[2] / 8.0, 1e-12);
    }
    // Re-read as a wireframe (radii from the file): the very same STL bytes.
    std::filesystem::copy_file(dir.path / "a" / "frame.csv", dir.path / "frame.csv");
    const std::string reread = head +
                               "  lattice: {struts: {wireframe: frame.csv}, kernel: capsule}\nresult: lattice\n"
                               "outputs: {mesh: b.stl}\n";
    ASSERT_EQ(runIn(dir, "b.yaml", reread, "b", &log), 0) << log;
    const std::string meshA = readFile(dir.path / "a" / "a.stl"), meshB = readFile(dir.path / "b" / "b.stl");
    EXPECT_GT(meshA.size(), 100000u);
    EXPECT_TRUE(meshA == meshB) << "the re-read frame gives a different mesh";

    // The 3MF read back through lib3mf: beams and radii (nodes in single precision).
    const BeamFrame beams = readBeamLattice3mf((dir.path / "a" / "frame.3mf").string());
    ASSERT_EQ(beams.struts.size(), frame.struts.size());
    ASSERT_EQ(beams.nodes.size(), frame.nodes.size());
    for (std::size_t j = 0; j < beams.struts.size(); ++j)
        for (int e = 0; e < 2; ++e) {
            EXPECT_EQ(beams.struts[j][e], frame.struts[j][e]);
            EXPECT_NEAR(beams.radii[j][e], rows[j][6 + e], 1e-6);
            EXPECT_NEAR((beams.nodes[beams.struts[j][e]] - frame.nodes[frame.struts[j][e]]).length(), 0.0, 1e-5);
        }
    // The OBJ: one `v` per node, one `l` per strut.
    const std::string obj = readFile(dir.path / "a" / "frame.obj");
    std::size_t v = 0, l = 0;
    std::istringstream objLines(obj);
    for (std::string line; std::getline(objLines, line);) {
        v += line.rfind("v ", 0) == 0;
        l += line.rfind("l ", 0) == 0;
    }
    EXPECT_EQ(v, frame.nodes.size());
    EXPECT_EQ(l, frame.struts.size());
}

TEST(FrameExport, RadiiAreAtTheSolvedLevel)
{
    // Capsules with a density: every radius is the solved level (a uniform radius offset).
    Job capsules(
        parseRecipe("voxel: 0.1\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n"
                    "  l: {struts: {cell: bcc, size: 5, count: 2}, kernel: capsule, density: 0.1}\n"
                    "result: l\n",
                    "c.yaml", "."));
    const BeamFrame c = capsules.frame();
    const double level = capsules.report()["fields"]["l"]["level"].get<double>();
    ASSERT_GT(level, 0.1);
    for (const auto& r : c.radii) {
        EXPECT_DOUBLE_EQ(r[0], level);
        EXPECT_DOUBLE_EQ(r[1], level);
    }
    // Gaussian convolution with radius R at the default level: an isolated strut's radius is R.
    // At iso-value t = 0.5 every squared radius grows by 2 sigma^2 ln 2.
    for (const double t : {1.0, 0.5}) {
        Job gauss(
            parseRecipe("voxel: 0.2\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n"
                        "  l: {struts: {cell: bcc, size: 5, count: 2}, kernel: {gaussian: {sigma: 0.5}}, "
                        "radius: 0.6, level: " +
                            std::to_string(t) + "}\nresult: l\n",
                        "g.yaml", "."));
        const BeamFrame g = gauss.frame();
        ASSERT_FALSE(g.radii.empty());
        const double expected = std::sqrt(0.36 + 2 * 0.25 * std::log(1 / t));
        for (const auto& r : g.radii) {
            EXPECT_NEAR(r[0], expected, 1e-9);
            EXPECT_NEAR(r[1], expected, 1e-9);
        }
    }
}

TEST(FrameExport, WithoutStrutsIsAnErrorNamingTheLine)
{
    TempDir dir;
    std::string out;
    const int status = runIn(dir, "r.yaml",
                             "voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n"
                             "  g: {tpms: gyroid, cell: 5}\nresult: g\noutputs:\n  mesh: g.stl\n  frame: g.csv\n",
                             "out", &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("r.yaml:8:"), std::string::npos) << out;
    EXPECT_NE(out.find("has none"), std::string::npos) << out;
    EXPECT_FALSE(std::filesystem::exists(dir.path / "out" / "g.stl"));
    EXPECT_FALSE(std::filesystem::exists(dir.path / "out" / "g.csv"));
    // A frame file of another kind names its line too.
    const int bad = runIn(dir, "s.yaml",
                          "voxel: 0.5\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n"
                          "  l: {struts: {cell: bcc, size: 5}, kernel: capsule, radius: 0.5}\nresult: l\n"
                          "outputs: {frame: l.stl}\n",
                          "out2", &out);
    EXPECT_EQ(bad, 2) << out;
    EXPECT_NE(out.find("s.yaml:6:"), std::string::npos) << out;
    EXPECT_NE(out.find("a frame file ends in .csv"), std::string::npos) << out;
}
