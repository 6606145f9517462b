// Properties of a recipe's result (`voxlat properties`, the `properties:` output): the cell from
// the result's periods or the recipe, materials with units, exact cases through the whole path
// (a solid cell, square columns), symmetry, thread independence and the errors users meet.
#include "TestUtil.h"
#include "engine/core/Format.h"
#include "engine/core/SystemInfo.h"
#include "engine/jobs/Job.h"
#include "engine/parts/MeshReader.h"
#include "engine/properties/MemoryEstimate.h"
#include "mesher/writers/FrameWriters.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <map>
#include <numbers>
#include <sstream>

using namespace voxlat;
using namespace voxlat::test;

namespace {

/// 3 x 3 x 3 X cells of 10 mm in Form 2, up to the fields. The homogenized cell does not depend on
/// the job's voxel (its level is solved on its own voxel model: the same bytes at 0.25 mm and 1 mm),
/// so a 1 mm voxel keeps the frame's own level solve short (the capsule cell at 24 voxels: 2.5 s of
/// CPU at 0.25 mm, 0.4 s at 1 mm).
const std::string kXCellsHead = "material: form2\nvoxel: 1\ndomain: {box: [[0, 0, 0], [30, 30, 30]]}\n";

nlohmann::json propertiesOf(const TempDir& dir, const std::string& name, const std::string& recipe,
                            const std::string& extra = "", int* status = nullptr, std::string* output = nullptr)
{
    const auto path = dir.write(name + ".yaml", recipe);
    const auto json = dir.path / (name + ".json");
    std::string out;
    const int code =
        runCommand(voxlatBinary() + " -q properties " + path.string() + " --json " + json.string() + " " + extra, &out);
    if (status) *status = code;
    if (output) *output = out;
    if (code != 0) return {};
    return nlohmann::json::parse(readFile(json));
}

}  // namespace

TEST(Properties, AWhollySolidCellIsTheIsotropicMaterial)
{
    TempDir dir;
    const auto p = propertiesOf(dir, "solid", R"(material: {E: 1.6 GPa, nu: 0.38}
properties: {cell: [2, 2, 2], origin: [0, 0, 0], resolution: 8}
fields:
  block: {box: [[-1, -1, -1], [3, 3, 3]]}
result: block
)");
    ASSERT_FALSE(p.is_null());
    const double E = 1600, nu = 0.38;
    const double c11 = E * (1 - nu) / ((1 + nu) * (1 - 2 * nu)), c12 = E * nu / ((1 + nu) * (1 - 2 * nu)),
                 c44 = E / (2 * (1 + nu));
    EXPECT_NEAR(p["relative_density"].get<double>(), 1.0, 1e-12);
    for (int i = 0; i < 3; ++i) {
        EXPECT_NEAR(p["C_MPa"][i][i].get<double>(), c11, 1e-5 * c11);
        EXPECT_NEAR(p["C_MPa"][i][(i + 1) % 3].get<double>(), c12, 1e-5 * c11);
        EXPECT_NEAR(p["C_MPa"][i + 3][i + 3].get<double>(), c44, 1e-5 * c11);
        EXPECT_NEAR(p["E_MPa"][i].get<double>(), E, 1e-5 * E);
        EXPECT_NEAR(p["E_ratio"][i].get<double>(), 1.0, 1e-5);
        EXPECT_NEAR(p["conductivity"]["K_ratio"][i][i].get<double>(), 1.0, 1e-6);
    }
    EXPECT_NEAR(p["nu"][0][1].get<double>(), nu, 1e-5);
    EXPECT_EQ(p["material"]["name"], "custom");
}

TEST(Properties, SquareColumnsCarryTheirAreaFractionAlongTheirAxisOnly)
{
    TempDir dir;
    // Columns of side 1 mm along x in a 2 mm cell: E_x = (1/2)^2 E_s, E_y = E_z = 0.
    const auto p = propertiesOf(dir, "columns", R"(material: ti6al4v
properties: {cell: [2, 2, 2], origin: [0, 0, 0], resolution: 16}
fields:
  column: {box: [[-1, 0.5, 0.5], [3, 1.5, 1.5]]}
result: column
)");
    ASSERT_FALSE(p.is_null());
    const double Es = 113800;
    EXPECT_NEAR(p["relative_density"].get<double>(), 0.25, 1e-12);
    EXPECT_NEAR(p["E_MPa"][0].get<double>(), 0.25 * Es, 1e-5 * Es);
    EXPECT_NEAR(p["E_MPa"][1].get<double>(), 0.0, 1e-9 * Es);
    EXPECT_NEAR(p["E_MPa"][2].get<double>(), 0.0, 1e-9 * Es);
    EXPECT_EQ(p["percolates"], nlohmann::json({true, false, false}));
    EXPECT_NEAR(p["conductivity"]["K_ratio"][0][0].get<double>(), 0.25, 1e-6);
    EXPECT_NEAR(p["conductivity"]["K_W_per_mK"][0][0].get<double>(), 0.25 * 6.7, 1e-5);
}

TEST(Properties, AGyroidCellFromItsPeriodsIsCubicSymmetricAndThreadIndependent)
{
    TempDir dir;
    const std::string recipe = R"(material: form2
voxel: 0.25
domain: {box: [[0, 0, 0], [20, 20, 20]]}
fields:
  lattice: {tpms: gyroid, cell: 5, solid: network, level: 0.3}
result: lattice
)";
    const auto one = propertiesOf(dir, "g1", recipe, "--threads 1 --set properties.resolution=20");
    const auto three = propertiesOf(dir, "g3", recipe, "--threads 3 --set properties.resolution=20");
    ASSERT_FALSE(one.is_null());
    EXPECT_EQ(one["cell"]["voxels"], nlohmann::json({20, 20, 20}));
    EXPECT_EQ(one["cell"]["from"], "the result's periods");
    const auto& C = one["C_MPa"];
    for (int i = 0; i < 6; ++i)
        for (int j = 0; j < 6; ++j)
            EXPECT_NEAR(C[i][j].get<double>(), C[j][i].get<double>(), 1e-9 * C[0][0].get<double>());
    EXPECT_NEAR(C[1][1].get<double>(), C[0][0].get<double>(), 1e-6 * C[0][0].get<double>());
    EXPECT_NEAR(C[2][2].get<double>(), C[0][0].get<double>(), 1e-6 * C[0][0].get<double>());
    EXPECT_GT(one["E_MPa"][0].get<double>(), 0.0);
    EXPECT_LT(one["E_MPa"][0].get<double>(), 1600.0 * one["relative_density"].get<double>());  // below Voigt
    EXPECT_TRUE(one.contains("zener_ratio"));
    EXPECT_EQ(one.dump(), three.dump());  // byte-identical for any thread count
}

TEST(Properties, TheRunOutputWritesTheNumbersAndAPicture)
{
    TempDir dir;
    const auto recipe = dir.write("run.yaml", R"(material: {preset: pa12, E: 1500 MPa}
voxel: 0.25
domain: {box: [[0, 0, 0], [10, 10, 10]]}
properties: {resolution: 20}
fields:
  lattice: {tpms: schwarz-p, cell: 5, solid: sheet, level: 0.4}
result: lattice
outputs: {properties: cell.json}
)");
    std::string out;
    ASSERT_EQ(runCommand(voxlatBinary() + " -q run " + recipe.string() + " --out " + (dir.path / "o").string(), &out),
              0)
        << out;
    const auto p = nlohmann::json::parse(readFile(dir.path / "o" / "cell.json"));
    EXPECT_NEAR(p["material"]["E_MPa"].get<double>(), 1500.0, 1e-9);
    EXPECT_TRUE(std::filesystem::exists(dir.path / "o" / "cell.png"));
    const auto report = nlohmann::json::parse(readFile(dir.path / "o" / "report.json"));
    EXPECT_EQ(report["properties"], p);
}

TEST(Properties, BadInputNamesTheLineAndWritesNothing)
{
    TempDir dir;
    int status = 0;
    std::string out;
    const std::string gyroid = R"(voxel: 0.25
domain: {box: [[0, 0, 0], [10, 10, 10]]}
fields:
  lattice: {tpms: gyroid, cell: 5, solid: network, level: 0.3}
result: lattice
)";
    // No material.
    propertiesOf(dir, "nomaterial", gyroid, "", &status, &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("material"), std::string::npos) << out;
    EXPECT_FALSE(std::filesystem::exists(dir.path / "nomaterial.json"));
    // A modulus without a unit.
    propertiesOf(dir, "nounit", "material: {E: 1600, nu: 0.3}\n" + gyroid, "", &status, &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("nounit.yaml:1:"), std::string::npos) << out;
    EXPECT_NE(out.find("GPa"), std::string::npos) << out;
    // A result with no period and no cell: the axis is named.
    propertiesOf(dir, "noperiod", R"(material: form2
fields:
  ball: {sphere: {center: [0, 0, 0], radius: 3}}
result: ball
)",
                 "", &status, &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("does not repeat along x"), std::string::npos) << out;
    EXPECT_NE(out.find("cell:"), std::string::npos) << out;
    // A cell with no solid.
    propertiesOf(dir, "empty", R"(material: form2
properties: {cell: [2, 2, 2], origin: [10, 10, 10], resolution: 8}
fields:
  ball: {sphere: {center: [0, 0, 0], radius: 3}}
result: ball
)",
                 "", &status, &out);
    EXPECT_EQ(status, 3) << out;
    EXPECT_NE(out.find("no solid"), std::string::npos) << out;
    // A cell that falls apart: a ball inside it touches no neighbour.
    propertiesOf(dir, "apart", R"(material: form2
properties: {cell: [4, 4, 4], origin: [-2, -2, -2], resolution: 16}
fields:
  ball: {sphere: {center: [0, 0, 0], radius: 1}}
result: ball
)",
                 "", &status, &out);
    EXPECT_EQ(status, 3) << out;
    EXPECT_NE(out.find("falls apart"), std::string::npos) << out;
}

TEST(Properties, ASweepPrintsTheModulusAgainstTheSweptValue)
{
    TempDir dir;
    const auto recipe = dir.write("sweep.yaml", R"(material: form2
voxel: 0.25
domain: {box: [[0, 0, 0], [10, 10, 10]]}
properties: {resolution: 20}
fields:
  lattice: {tpms: gyroid, cell: 5, solid: network, level: 0.3}
result: lattice
)");
    std::string out;
    ASSERT_EQ(runCommand(voxlatBinary() + " -q properties " + recipe.string() +
                             " --sweep fields.lattice.level=0.0:0.6:3 --json " + (dir.path / "s.json").string(),
                         &out),
              0)
        << out;
    const auto s = nlohmann::json::parse(readFile(dir.path / "s.json"));
    ASSERT_EQ(s["sweep"].size(), 3u);
    // A higher level grows the network: density and modulus rise together.
    double lastDensity = 0, lastModulus = 0;
    for (const auto& row : s["sweep"]) {
        EXPECT_GT(row["properties"]["relative_density"].get<double>(), lastDensity);
        EXPECT_GT(row["properties"]["E_MPa"][2].get<double>(), lastModulus);
        lastDensity = row["properties"]["relative_density"].get<double>();
        lastModulus = row["properties"]["E_MPa"][2].get<double>();
    }
    EXPECT_NE(out.find("E_z/E_s"), std::string::npos);
}

namespace {

/// `voxlat run` of @a recipe into dir/name/; its report.json (empty on failure).
nlohmann::json runReport(const TempDir& dir, const std::string& name, const std::string& recipe, int* status = nullptr,
                         std::string* output = nullptr)
{
    const auto path = dir.write(name + ".yaml", recipe);
    std::string out;
    const int code =
        runCommand(voxlatBinary() + " -q run " + path.string() + " --out " + (dir.path / name).string(), &out);
    if (status) *status = code;
    if (output) *output = out;
    if (code != 0) return {};
    return nlohmann::json::parse(readFile(dir.path / name / "report.json"));
}

/// A gyroid's recipe up to its fields, homogenized at 32 voxels (16 under the sanitizers).
const std::string kGyroidHead = std::string(R"(material: form2
voxel: 0.25
domain: {box: [[0, 0, 0], [10, 10, 10]]}
properties: {resolution: )") + (kSanitized ? "16" : "32") +
                                R"(}
fields:
)";

}  // namespace

TEST(PropertyDesign, StiffnessSolvesTheDensityAndAnIndependentHomogenizationMeetsTheTarget)
{
    TempDir dir;
    for (const std::string target : {"{E: 40 MPa, axis: z}", "{E_ratio: 0.025}"}) {
        const std::string name = target[1] == 'E' && target[2] == ':' ? "absolute" : "ratio";
        const auto report =
            runReport(dir, name,
                      kGyroidHead + "  lattice: {tpms: gyroid, cell: 5, solid: network, stiffness: " + target +
                          "}\nresult: lattice\noutputs: {properties: p.json}\n");
        ASSERT_FALSE(report.is_null()) << target;
        const auto& s = report["design"]["lattice"]["stiffness"];
        EXPECT_EQ(s["axis"], "z");
        EXPECT_NEAR(s["target_E_MPa"].get<double>(), 40.0, 1e-9);
        EXPECT_EQ(report["fields"]["lattice"]["stiffness"], s);  // also next to the solved level
        const double rho = s["density"].get<double>();
        EXPECT_GT(rho, 0.1);
        EXPECT_LT(rho, 0.3);
        // The job's own homogenization of its result is the search's last word.
        const auto p = nlohmann::json::parse(readFile(dir.path / name / "p.json"));
        EXPECT_NEAR(p["E_MPa"][2].get<double>(), s["achieved_E_MPa"].get<double>(), 1e-9 * 40.0);
        // Re-measured independently: the solved density written in, no stiffness key at all.
        char density[40];
        std::snprintf(density, sizeof density, "%.17g", rho);
        const auto again =
            propertiesOf(dir, name + "_again",
                         kGyroidHead + "  lattice: {tpms: gyroid, cell: 5, solid: network, density: " + density +
                             "}\nresult: lattice\n");
        ASSERT_FALSE(again.is_null());
        EXPECT_NEAR(again["E_MPa"][2].get<double>(), 40.0, 0.01 * 40.0) << target;
    }
}

TEST(PropertyDesign, BadStiffnessAndOptimizeKeysNameTheLine)
{
    TempDir dir;
    int status = 0;
    std::string out;
    // Both density and stiffness.
    runReport(
        dir, "both",
        kGyroidHead + "  lattice: {tpms: gyroid, cell: 5, density: 0.2, stiffness: {E: 40 MPa}}\nresult: lattice\n",
        &status, &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("both.yaml:6:"), std::string::npos) << out;
    EXPECT_NE(out.find("not both"), std::string::npos) << out;
    EXPECT_FALSE(std::filesystem::exists(dir.path / "both" / "report.json"));
    // Above the solid's modulus (form2: 1.6 GPa).
    runReport(dir, "stiff",
              kGyroidHead + "  lattice: {tpms: gyroid, cell: 5, stiffness: {E: 2 GPa}}\nresult: lattice\n", &status,
              &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("stiff.yaml:6:"), std::string::npos) << out;
    EXPECT_NE(out.find("not below the solid"), std::string::npos) << out;
    // No material.
    runReport(dir, "nomaterial",
              "voxel: 0.25\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n"
              "  lattice: {tpms: gyroid, cell: 5, stiffness: {E: 40 MPa}}\nresult: lattice\n",
              &status, &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("nomaterial.yaml:4:"), std::string::npos) << out;
    EXPECT_NE(out.find("material"), std::string::npos) << out;
    // Neither or both of E and E_ratio; an unknown axis.
    runReport(dir, "neither",
              kGyroidHead + "  lattice: {tpms: gyroid, cell: 5, stiffness: {axis: z}}\nresult: lattice\n", &status,
              &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("E_ratio"), std::string::npos) << out;
    runReport(dir, "axis",
              kGyroidHead + "  lattice: {tpms: gyroid, cell: 5, stiffness: {E: 40 MPa, axis: w}}\nresult: lattice\n",
              &status, &out);
    EXPECT_EQ(status, 2) << out;
    // optimize: without a density.
    runReport(dir, "nodensity", kGyroidHead + R"(  lattice:
    struts: {cell: x, size: 5}
    kernel: {gaussian: {sigma: 0.5}}
    radius: 0.5
    optimize: {sigma: [0.4, 1.2]}
result: lattice
)",
              &status, &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("nodensity.yaml:10:"), std::string::npos) << out;
    EXPECT_NE(out.find("density"), std::string::npos) << out;
}

TEST(PropertyDesign, OptimizePicksTheStiffestSigmaAndReportsTheCapsuleBaseline)
{
    TempDir dir;
    // X cells of 5 mm, 3 x 3 x 3; the middle cell is homogenized (it sees all its neighbours), at
    // 20 voxels (12 and a 0.5 mm job voxel under the sanitizers).
    const std::string head = std::string(R"(material: form2
voxel: )") + (kSanitized ? "0.5" : "0.25") +
                             R"(
domain: {box: [[0, 0, 0], [15, 15, 15]]}
properties: {cell: [5, 5, 5], origin: [5, 5, 5], resolution: )" +
                             (kSanitized ? "12" : "20") + R"(}
fields:
  lattice:
    struts: {cell: x, size: 5}
    density: 0.2
)";
    const auto report =
        runReport(dir, "opt",
                  head +
                      "    kernel: {gaussian: {sigma: 0.3}}\n"
                      "    optimize: {sigma: [0.2, 0.8], axis: z, samples: 4, tolerance: 0.05}\nresult: lattice\n");
    ASSERT_FALSE(report.is_null());
    const auto& o = report["design"]["lattice"]["optimize"];
    const double sigma = o["sigma"].get<double>(), E = o["E_MPa"].get<double>();
    EXPECT_GE(sigma, 0.2);
    EXPECT_LE(sigma, 0.8);
    for (const auto& t : o["trials"]) EXPECT_LE(t["E_MPa"].get<double>(), E);
    EXPECT_GE(o["trials"].size(), 6u);  // the sweep and the refinement
    // Independently: the chosen sigma, the ends of the range and the capsule lattice.
    auto modulus = [&](const std::string& name, const std::string& kernel) {
        int status = 0;
        const auto p = propertiesOf(dir, name, head + "    kernel: " + kernel + "\nresult: lattice\n", "", &status);
        EXPECT_TRUE(status == 0 || status == 3) << kernel;  // 3: the cell falls apart, no stiffness
        return p.is_null() ? 0.0 : p["E_MPa"][2].get<double>();
    };
    char chosen[80];
    std::snprintf(chosen, sizeof chosen, "{gaussian: {sigma: %.17g}}", sigma);
    EXPECT_NEAR(modulus("chosen", chosen), E, 1e-9 * E);
    EXPECT_GE(E, modulus("low", "{gaussian: {sigma: 0.2}}"));
    EXPECT_GE(E, modulus("high", "{gaussian: {sigma: 0.8}}"));
    const double capsule = modulus("capsule", "capsule");
    EXPECT_NEAR(o["capsule_E_MPa"].get<double>(), capsule, 1e-9 * capsule);
    EXPECT_NEAR(o["ratio_to_capsule"].get<double>(), E / capsule, 1e-9);
    // `voxlat properties` says which sigma it chose, and the capsule baseline.
    {
        int status = 0;
        std::string out;
        propertiesOf(dir, "said",
                     head +
                         "    kernel: {gaussian: {sigma: 0.3}}\n"
                         "    optimize: {sigma: [0.2, 0.8], axis: z, samples: 4, tolerance: 0.05}\nresult: lattice\n",
                     "", &status, &out);
        ASSERT_EQ(status, 0) << out;
        EXPECT_NE(out.find("optimize lattice: sigma " + formatNumber(sigma) + " mm"), std::string::npos) << out;
        EXPECT_NE(out.find("capsule joints " + formatNumber(capsule) + " MPa"), std::string::npos) << out;
    }
    // `optimize: off` (from --set) keeps the sigma as written.
    const auto off = propertiesOf(dir, "off",
                                  head +
                                      "    kernel: {gaussian: {sigma: 0.3}}\n"
                                      "    optimize: {sigma: [0.2, 0.8]}\nresult: lattice\n",
                                  "--set fields.lattice.optimize=off");
    ASSERT_FALSE(off.is_null());
    EXPECT_EQ(off["E_MPa"][2].get<double>(), modulus("written", "{gaussian: {sigma: 0.3}}"));
}

TEST(PropertyDesign, GyroidModulusConvergesWithResolution)
{
    // The gyroid network at level 0 holds exactly half the voxels at every resolution (it is its
    // own complement shifted by half a cell), so what changes with resolution is the voxel
    // model's shape alone. E_z at 16, 24, 32, 48, 64 voxels a cell: each change smaller than the
    // one before, the last below 0.1 %.
    TempDir dir;
    const std::string recipe = R"(material: form2
voxel: 0.25
domain: {box: [[0, 0, 0], [5, 5, 5]]}
fields:
  lattice: {tpms: gyroid, cell: 5, solid: network, level: 0}
result: lattice
)";
    // Under the sanitizers: 16, 24 and 32 voxels, the changes shrinking; the 0.1 % in Release only.
    std::vector<double> E;
    std::string sequence;
    for (int n : {16, 24, 32, 48, 64}) {
        if (kSanitized && n > 32) break;
        const auto p =
            propertiesOf(dir, "g" + std::to_string(n), recipe, "--set properties.resolution=" + std::to_string(n));
        ASSERT_FALSE(p.is_null());
        EXPECT_NEAR(p["relative_density"].get<double>(), 0.5, 1e-12);
        E.push_back(p["E_MPa"][2].get<double>());
        sequence += std::to_string(n) + ": " + std::to_string(E.back()) + " MPa  ";
    }
    for (std::size_t k = 2; k < E.size(); ++k)
        EXPECT_LT(std::abs(E[k] - E[k - 1]), std::abs(E[k - 1] - E[k - 2])) << sequence;
    if (!kSanitized) {
        EXPECT_LT(std::abs(E[4] - E[3]), 1e-3 * E[4]) << sequence;
    }
    std::printf("E_z by resolution: %s\n", sequence.c_str());
}

TEST(Properties, AFrameOfIdenticalCellsTakesItsCellFromTheRepeatingInterior)
{
    // A finite frame has no period, yet deeper inside its box than the struts reach every cell is
    // the same: with no `properties: cell`, the cell comes from there, and it must be exactly the
    // cell a user would name (the middle one of 3 x 3 x 3), for both kernels.
    TempDir dir;
    const std::string head = "material: form2\nvoxel: 0.5\ndomain: {box: [[0, 0, 0], [30, 30, 30]]}\n";
    const std::string given = "properties: {cell: [10, 10, 10], origin: [10, 10, 10], resolution: 16}\n";
    const std::string implicit = "properties: {resolution: 16}\n";
    for (const std::string lattice :
         {"  lattice: {struts: {cell: x, size: 10}, kernel: {gaussian: {sigma: 0.8}}, density: 0.1}\n",
          "  lattice: {struts: {cell: x, size: 10}, kernel: capsule, radius: 1.2}\n"}) {
        const std::string body = "fields:\n" + lattice + "result: lattice\n";
        int status = 0;
        std::string out;
        const auto a = propertiesOf(dir, "given", head + given + body, "", &status, &out);
        ASSERT_EQ(status, 0) << out;
        const auto b = propertiesOf(dir, "interior", head + implicit + body, "", &status, &out);
        ASSERT_EQ(status, 0) << out;
        EXPECT_EQ(b["cell"]["from"], "the frame's repeating interior");
        EXPECT_EQ(a["cell"]["origin"], b["cell"]["origin"]);
        EXPECT_EQ(a["cell"]["size"], b["cell"]["size"]);
        EXPECT_EQ(a["C_MPa"], b["C_MPa"]);
        EXPECT_GT(b["E_MPa"][2].get<double>(), 0.0);
    }
    // Two cells along z: no whole cell lies deeper than the struts reach, so the frame's cell is
    // repeated (the infinite lattice): the same cell as the middle one of 3 x 3 x 3.
    int status = 0;
    std::string out;
    const std::string gaussian = "kernel: {gaussian: {sigma: 0.8}}, density: 0.1}\nresult: lattice\n";
    const auto shortFrame = propertiesOf(dir, "short",
                                         "material: form2\nvoxel: 0.5\nproperties: {resolution: 16}\nfields:\n  "
                                         "lattice: {struts: {cell: x, size: 10, count: [3, 3, 2]}, " +
                                             gaussian,
                                         "", &status, &out);
    ASSERT_EQ(status, 0) << out;
    EXPECT_EQ(shortFrame["cell"]["from"], "the frame's cell, repeated (the infinite lattice of that cell)");
    const auto middle = propertiesOf(dir, "middle",
                                     "material: form2\nvoxel: 0.5\nproperties: {resolution: 16}\nfields:\n  "
                                     "lattice: {struts: {cell: x, size: 10, count: 3}, " +
                                         gaussian,
                                     "", &status, &out);
    ASSERT_EQ(status, 0) << out;
    EXPECT_EQ(middle["relative_density"], shortFrame["relative_density"]);
    for (int i = 0; i < 6; ++i)
        EXPECT_NEAR(shortFrame["C_MPa"][i][i].get<double>(), middle["C_MPa"][i][i].get<double>(),
                    1e-9 * middle["C_MPa"][0][0].get<double>());
}

TEST(Properties, TheCellHoldsTheDensityAskedAtEveryResolution)
{
    // Issue 37: a capsule X cell at density 0.1 gave voxel models of 0.093 to 0.118 at
    // resolutions 40 to 96 (the level was solved over the frame's box, and the voxels alias with
    // the struts). The cell's level is now solved on the voxel model itself.
    // Under the sanitizers: 16 voxels (the capsule's raised to 17 to hold the density) and 24.
    TempDir dir;
    const std::string& head = kXCellsHead;
    const int last = kSanitized ? 24 : 48;
    for (const std::string kernel : {std::string("capsule"), std::string("{gaussian: {sigma: 0.8}}")}) {
        for (int n : {kSanitized ? 16 : 40, last}) {
            if (kernel != "capsule" && n != last) continue;  // the Gaussian at one resolution suffices
            const std::string resolution = "--set properties.resolution=" + std::to_string(n);
            int status = 0;
            std::string out;
            const auto p = propertiesOf(dir, "x" + std::to_string(n),
                                        head + "fields:\n  lattice: {struts: {cell: x, size: 10}, kernel: " + kernel +
                                            ", density: 0.1}\nresult: lattice\n",
                                        resolution, &status, &out);
            ASSERT_EQ(status, 0) << out;
            EXPECT_EQ(p["relative_density_target"].get<double>(), 0.1);
            EXPECT_LT(std::abs(p["relative_density"].get<double>() / 0.1 - 1.0), 0.005) << kernel << " " << n;
            std::printf("%s at %d voxels: cell density %.5f, E_z %.4f MPa\n", kernel.c_str(), n,
                        p["relative_density"].get<double>(), p["E_MPa"][2].get<double>());
            if (n != last) continue;
            // The cell's level, written into the recipe as `level:` (a capsule's radius offset, a
            // Gaussian lattice's iso-value t), with the cell's corner, is the same voxel model.
            char level[64], origin[200];
            std::snprintf(level, sizeof level, "%.17g", p["level"].get<double>());
            const auto& o = p["cell"]["origin"];
            std::snprintf(origin, sizeof origin, "properties: {cell: [10, 10, 10], origin: [%.17g, %.17g, %.17g]}\n",
                          o[0].get<double>(), o[1].get<double>(), o[2].get<double>());
            const auto again =
                propertiesOf(dir, "x" + std::to_string(n) + "level",
                             head + origin + "fields:\n  lattice: {struts: {cell: x, size: 10}, kernel: " + kernel +
                                 ", level: " + level + "}\nresult: lattice\n",
                             resolution, &status, &out);
            ASSERT_EQ(status, 0) << out;
            EXPECT_NEAR(again["relative_density"].get<double>(), p["relative_density"].get<double>(), 2e-5);
            EXPECT_NEAR(again["E_MPa"][2].get<double>(), p["E_MPa"][2].get<double>(),
                        2e-3 * p["E_MPa"][2].get<double>());
        }
    }
}

TEST(Properties, DongsGridExampleAsAPlainOneCellRecipe)
{
    // Dong, Tang & Zhao (2019), the simple-cubic "grid" cell as a user writes it: one cell of
    // 1 mm filling a 1 mm domain, struts of radius 0.1 along its edges, 40^3 voxels, lambda 115.4,
    // mu 79.6. Published: density 0.0855, C11 7.1876, C12 0.3875, C44 0.1489. The one-cell frame
    // is homogenized as its cell repeated, without `properties: {cell, origin}`.
    const double lambda = 115.4, mu = 79.6;
    char material[160];
    std::snprintf(material, sizeof material, "material: {E: %.17g MPa, nu: %.17g}\n",
                  mu * (3 * lambda + 2 * mu) / (lambda + mu), lambda / (2 * (lambda + mu)));
    TempDir dir;
    int status = 0;
    std::string out;
    const auto p =
        propertiesOf(dir, "dong",
                     std::string(material) +
                         "voxel: 0.025\ndomain: {box: [[0, 0, 0], [1, 1, 1]]}\nproperties: {resolution: 40}\nfields:\n"
                         "  grid: {struts: {cell: grid, size: 1}, kernel: capsule, radius: 0.1}\n"
                         "result: grid\n",
                     "", &status, &out);
    ASSERT_EQ(status, 0) << out;
    EXPECT_EQ(p["cell"]["voxels"], nlohmann::json({40, 40, 40}));
    EXPECT_EQ(p["cell"]["from"], "the frame's cell, repeated (the infinite lattice of that cell)");
    auto rel = [](double a, double b) { return std::abs(a - b) / b; };
    const auto& C = p["C_MPa"];
    EXPECT_LT(rel(p["relative_density"].get<double>(), 0.0855), 1e-3) << p.dump();
    EXPECT_LT(rel(C[0][0].get<double>(), 7.1876), 1e-3) << p.dump();
    EXPECT_LT(rel(C[0][1].get<double>(), 0.3875), 1e-3) << p.dump();
    EXPECT_LT(rel(C[3][3].get<double>(), 0.1489), 1e-3) << p.dump();
}

TEST(Properties, TheReportsSolvedLevelPastedIntoTheRecipeGivesTheSameBytes)
{
    // Issue 37: every value report.json gives under a recipe key's name means what the key means.
    // For each shipped recipe whose lattice solves its level from one `density:` (no search keys),
    // the report's `level` replaces `density:` in the recipe text and the outputs are the same
    // bytes (at a coarser voxel, the same for both runs, to keep the test short; not coarser under
    // the sanitizers: at 0.8 mm a shipped lattice's 0.85 mm struts are under two voxels, exit 3).
    TempDir dir;
    int checked = 0;
    for (const auto& entry : std::filesystem::directory_iterator(sourceDir() / "data/recipes")) {
        if (entry.path().extension() != ".yaml") continue;
        const std::string text = readFile(entry.path());
        if (text.find("optimize:") != std::string::npos || text.find("stiffness:") != std::string::npos ||
            text.find("infill:") != std::string::npos || text.find("outputs:") == std::string::npos)
            continue;
        // Exactly one `density: <number>`.
        std::size_t at = std::string::npos, count = 0;
        for (std::size_t p = text.find("density: "); p != std::string::npos; p = text.find("density: ", p + 1))
            if (std::isdigit(static_cast<unsigned char>(text[p + 9]))) at = p, ++count;
        if (count != 1) continue;
        const std::size_t end = text.find_first_not_of("0123456789.", at + 9);
        const std::string stem = entry.path().stem().string();
        const std::string coarse = " --set voxel=0.4 --no-preview";
        std::string out;
        const auto first = dir.path / (stem + "-density");
        ASSERT_EQ(
            runCommand(voxlatBinary() + " -q run " + entry.path().string() + coarse + " --out " + first.string(), &out),
            0)
            << out;
        const auto report = nlohmann::json::parse(readFile(first / "report.json"));
        std::string field;
        for (const auto& [name, f] : report["fields"].items())
            if (f.contains("target_density")) field = name;
        ASSERT_FALSE(field.empty()) << stem;
        char level[64];
        std::snprintf(level, sizeof level, "level: %.17g", report["fields"][field]["level"].get<double>());
        const std::string pasted = text.substr(0, at) + level + text.substr(end);
        const auto recipe = dir.write(stem + "-level.yaml", pasted);
        const auto second = dir.path / (stem + "-level");
        ASSERT_EQ(
            runCommand(voxlatBinary() + " -q run " + recipe.string() + coarse + " --out " + second.string(), &out), 0)
            << stem << ": " << out;
        int files = 0;
        for (const auto& made : std::filesystem::directory_iterator(first)) {
            // The report and its page carry timings and the recipe's path.
            if (made.path().filename() == "report.json" || made.path().filename() == "report.html") continue;
            const auto other = second / made.path().filename();
            if (made.path().extension() == ".3mf") {
                // A 3MF carries the recipe it was made from (metadata): compare what it holds.
                if (made.path().filename().string().find("frame") != std::string::npos) {
                    const BeamFrame a = readBeamLattice3mf(made.path().string()),
                                    b = readBeamLattice3mf(other.string());
                    EXPECT_TRUE(a.nodes == b.nodes && a.struts == b.struts && a.radii == b.radii) << stem;
                } else {
                    const TriangleMesh a = readPartMesh(made.path(), "a").mesh, b = readPartMesh(other, "b").mesh;
                    EXPECT_TRUE(a.points == b.points && a.triangles == b.triangles) << stem;
                }
            } else {
                EXPECT_TRUE(readFile(made.path()) == readFile(other))
                    << stem << ": " << made.path().filename() << " differs with " << level;
            }
            ++files;
        }
        EXPECT_GT(files, 0) << stem;
        ++checked;
    }
    EXPECT_GE(checked, 5);  // gyroid (and its tolerance, orientation and equation variants), BCC, octet
}

namespace {

/// properties() of @a recipe in this process, without the conductivity (the stiffness alone).
nlohmann::json stiffnessOnly(const std::string& recipe)
{
    Recipe r = parseRecipe(recipe, "cell.yaml", ".");
    r.properties.conductivity = false;
    Job job(std::move(r));
    return job.properties();
}

}  // namespace

TEST(Properties, TheDefaultResolutionIsConvergedWithinTwoPercent)
{
    // Issue 37: with no `resolution:` the cell is homogenized at 24, 34, 48, ... voxels until
    // Richardson extrapolation of E over the last three puts E within 2 % of its limit. Checked
    // against a 128-voxel reference for the capsule X cell and the Gaussian X cell (sigma 0.8),
    // both at density 0.1 (10 mm cells, Form 2).
    // Under the sanitizers: the capsule cell alone, converged to 30 % at 24, 34, 48 voxels (E_x's
    // estimate there is 21 %; at 20 % the ladder went on to 96), and no 128-voxel reference.
    TempDir dir;
    const std::string& head = kXCellsHead;
    const double tolerance = kSanitized ? 0.3 : 0.02;
    for (const std::string kernel : {std::string("capsule"), std::string("{gaussian: {sigma: 0.8}}")}) {
        if (kSanitized && kernel != "capsule") continue;
        const std::string body = "fields:\n  lattice: {struts: {cell: x, size: 10}, kernel: " + kernel +
                                 ", density: 0.1}\nresult: lattice\n";
        const auto p =
            stiffnessOnly(head + (kSanitized ? "properties: {convergence: 0.3, max_resolution: 48}\n" : "") + body);
        const auto& c = p["convergence"];
        ASSERT_GE(c["resolutions"].size(), 3u) << c.dump();
        EXPECT_EQ(c["resolutions"][0], 24);
        EXPECT_EQ(c["E_MPa"].size(), c["resolutions"].size());
        EXPECT_LE(c["estimated_error"].get<double>(), tolerance) << c.dump();
        EXPECT_EQ(p["cell"]["voxels"][0], c["resolutions"].back());
        EXPECT_LT(std::abs(p["relative_density"].get<double>() / 0.1 - 1.0), 0.005);
        if (kSanitized) continue;
        const auto reference = stiffnessOnly(head + "properties: {resolution: 128}\n" + body);
        for (int a = 0; a < 3; ++a) {
            const double E = p["E_MPa"][a].get<double>(), ref = reference["E_MPa"][a].get<double>();
            EXPECT_LT(std::abs(E / ref - 1.0), 0.02) << kernel << " axis " << a << ": " << E << " vs " << ref;
        }
        std::printf("%s: default %d voxels, E_z %.4f MPa (estimated error %.3f %%), 128 voxels %.4f MPa (%+.2f %%)\n",
                    kernel.c_str(), c["resolutions"].back().get<int>(), p["E_MPa"][2].get<double>(),
                    100.0 * c["estimated_error"].get<double>(), reference["E_MPa"][2].get<double>(),
                    100.0 * (p["E_MPa"][2].get<double>() / reference["E_MPa"][2].get<double>() - 1.0));
    }
    // A budget too small to converge: the numbers in a warning, and the finest result.
    const auto report = runReport(dir, "small",
                                  head +
                                      "properties: {max_resolution: 48, convergence: 0.001}\nfields:\n"
                                      "  lattice: {struts: {cell: x, size: 10}, kernel: capsule, density: 0.1}\n"
                                      "result: lattice\noutputs: {properties: p.json}\n");
    ASSERT_FALSE(report.is_null());
    EXPECT_EQ(report["properties"]["convergence"]["resolutions"], nlohmann::json({24, 34, 48}));
    bool warned = false;
    for (const auto& w : report["warnings"])
        if (w["code"] == "not_converged") {
            warned = true;
            EXPECT_NE(w["message"].get<std::string>().find("at 24, 34, 48 voxels"), std::string::npos) << w.dump();
        }
    EXPECT_TRUE(warned) << report["warnings"].dump();
}

TEST(Properties, TheDensityCurveAndItsGibsonAshbyFitTellBendingFromStretching)
{
    // Issue 37: `voxlat properties R --curve density=FROM:TO:COUNT` homogenizes the cell at each
    // density and fits E/E_s = C rho^n per axis. A BCC cell bends (n near 2 or above: the joints
    // stiffen it further as the density rises), an octet cell stretches (n near 1).
    // Under the sanitizers: 16 voxels, and the exponents and the fit's misfit (which need 32) are
    // not checked.
    TempDir dir;
    const int resolution = kSanitized ? 16 : 32;
    std::map<std::string, double> exponent;
    for (const std::string cell : {"bcc", "octet"}) {
        const auto recipe =
            dir.write(cell + ".yaml",
                      "material: form2\nvoxel: 0.25\ndomain: {box: [[0, 0, 0], [5, 5, 5]]}\n"
                      "properties: {resolution: " +
                          std::to_string(resolution) + "}\nfields:\n  lattice: {struts: {cell: " + cell +
                          ", size: 5}, kernel: capsule, density: 0.1}\nresult: lattice\n");
        const auto json = dir.path / (cell + "-curve.json");
        std::string out;
        ASSERT_EQ(runCommand(voxlatBinary() + " -q properties " + recipe.string() +
                                 " --curve density=0.1:0.3:3 --json " + json.string(),
                             &out),
                  0)
            << out;
        EXPECT_NE(out.find("Gibson-Ashby"), std::string::npos) << out;
        const auto c = nlohmann::json::parse(readFile(json));
        ASSERT_EQ(c["curve"].size(), 3u);
        const double targets[3] = {0.1, 0.2, 0.3};
        for (int k = 0; k < 3; ++k) {
            const auto& p = c["curve"][k];
            EXPECT_NEAR(p["relative_density_target"].get<double>(), targets[k], 1e-12);
            EXPECT_LT(std::abs(p["relative_density"].get<double>() / targets[k] - 1.0), 0.005);
            for (const char* key : {"C_MPa", "E_MPa", "G_MPa", "K_ratio"}) EXPECT_TRUE(p.contains(key)) << key;
            if (k > 0) {
                EXPECT_GT(p["E_MPa"][2].get<double>(), c["curve"][k - 1]["E_MPa"][2].get<double>());
            }
        }
        // The fit, recomputed here from the curve's own points.
        const auto& g = c["gibson_ashby"];
        for (int a = 0; a < 3; ++a) {
            const double x0 = std::log(c["curve"][0]["relative_density"].get<double>()),
                         x2 = std::log(c["curve"][2]["relative_density"].get<double>());
            const double y0 = std::log(c["curve"][0]["E_ratio"][a].get<double>()),
                         y2 = std::log(c["curve"][2]["E_ratio"][a].get<double>());
            EXPECT_NEAR(g["n"][a].get<double>(), (y2 - y0) / (x2 - x0), 0.1);  // the chord, for 3 points
        }
        if (!kSanitized) {
            EXPECT_LT(g["max_relative_error"].get<double>(), 0.1);  // bcc at 16 voxels: 14 %
        }
        exponent[cell] = g["n"][2].get<double>();
        std::printf("%s: n = %.3f, C = %.4f, largest misfit %.2f %%\n", cell.c_str(), g["n"][2].get<double>(),
                    g["C"][2].get<double>(), 100.0 * g["max_relative_error"].get<double>());
    }
    if (kSanitized) return;
    EXPECT_GT(exponent["bcc"], 1.8);
    EXPECT_LT(exponent["bcc"], 3.0);
    EXPECT_GT(exponent["octet"], 0.9);
    EXPECT_LT(exponent["octet"], 1.6);
    EXPECT_GT(exponent["bcc"] - exponent["octet"], 0.8);
}

namespace {

/// A small reader of a CalculiX/Abaqus deck's `*MATERIAL` / `*ELASTIC, TYPE=ANISO` card: the
/// material's name and its 6x6 stiffness in voxlat's Voigt order (xx, yy, zz, yz, xz, xy).
struct MaterialCard {
    std::string name;
    std::array<std::array<double, 6>, 6> C{};
    int constants = 0;
};

MaterialCard readMaterialCard(const std::string& text)
{
    MaterialCard card;
    std::istringstream in(text);
    std::string line;
    bool elastic = false;
    std::vector<double> d;
    while (std::getline(in, line)) {
        if (line.rfind("**", 0) == 0) continue;  // a comment
        std::string upper = line;
        for (char& c : upper) c = char(std::toupper(static_cast<unsigned char>(c)));
        upper.erase(std::remove(upper.begin(), upper.end(), ' '), upper.end());
        if (upper.rfind("*MATERIAL,NAME=", 0) == 0) {
            card.name = upper.substr(15);
            elastic = false;
        } else if (upper.rfind("*ELASTIC,TYPE=ANISO", 0) == 0) {
            elastic = true;
        } else if (!upper.empty() && upper[0] == '*') {
            elastic = false;
        } else if (elastic) {
            std::istringstream values(line);
            std::string v;
            while (std::getline(values, v, ',')) d.push_back(std::stod(v));
        }
    }
    card.constants = int(d.size());
    constexpr int kVoigt[6] = {0, 1, 2, 5, 4, 3};  // 11, 22, 33, 12, 13, 23
    std::size_t k = 0;
    for (int j = 0; j < 6; ++j)
        for (int i = 0; i <= j && k < d.size(); ++i, ++k)
            card.C[kVoigt[i]][kVoigt[j]] = card.C[kVoigt[j]][kVoigt[i]] = d[k];
    return card;
}

}  // namespace

TEST(Properties, TheMaterialCardReadsBackAsTheCellsStiffness)
{
    // `properties: {export: cell.inp}` writes the homogenized C as a CalculiX/Abaqus card; read
    // back by a parser of its own, it is the C of the cell's report. Columns along x, 1 mm of a
    // 2 mm cell: E_x = E_s / 4 and nothing across, so the shear order (12, 13, 23) shows.
    TempDir dir;
    const auto report = runReport(dir, "card", R"(material: {E: 2 GPa, nu: 0.3}
properties: {cell: [2, 2, 2], origin: [0, 0, 0], resolution: 8, export: cell.inp}
fields:
  column: {box: [[-1, 0.5, 0.5], [3, 1.5, 1.5]]}
result: column
outputs: {properties: cell.json}
)");
    ASSERT_FALSE(report.is_null());
    const std::string text = readFile(dir.path / "card" / "cell.inp");
    EXPECT_NE(text.find("units: MPa"), std::string::npos) << text;
    const MaterialCard card = readMaterialCard(text);
    EXPECT_EQ(card.name, "COLUMN_CELL");
    EXPECT_EQ(card.constants, 21);
    const auto p = nlohmann::json::parse(readFile(dir.path / "card" / "cell.json"));
    for (int i = 0; i < 6; ++i)
        for (int j = 0; j < 6; ++j)
            EXPECT_NEAR(card.C[i][j], p["C_MPa"][i][j].get<double>(), 1e-9 * 2000 + 1e-9 * std::abs(card.C[i][j]))
                << i << "," << j;
    EXPECT_NEAR(card.C[0][0], 500.0, 1e-3);  // E_s / 4 along the columns (no Poisson coupling across)
    bool listed = false;
    for (const auto& o : report["outputs"])
        listed = listed || o.get<std::string>().find("cell.inp") != std::string::npos;
    EXPECT_TRUE(listed);
    // Not an .inp name: refused with the line.
    int status = 0;
    std::string out;
    runReport(dir, "bad",
              "material: form2\nproperties: {cell: [2, 2, 2], export: cell.txt}\nfields:\n  c: {box: [[0, 0, 0], [1, "
              "1, 1]]}\nresult: c\n",
              &status, &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("bad.yaml:2:"), std::string::npos) << out;
}

TEST(Properties, DensityOfCellSolvesTheJobsLevelOnThePeriodicCell)
{
    // `density_of: cell`: the printed lattice's level is solved so that the periodic cell (the
    // frame's middle one) holds the density, the cell `voxlat properties` homogenizes; with
    // `density_of: frame` on a frame laid as written (`edges: frame`) the frame box holds it and the
    // interior cell of a Gaussian X lattice is heavier. A frame laid past the domain and cut by it
    // (`edges: cut`, the default, issue 42) has no light edge cells: its box holds the cell's
    // density too.
    // Under the sanitizers the cell has 32 voxels instead of 64: its level is then 0.6 % off the
    // frame's (solved at the job's voxel), so the agreement asked there is 1 %, not 0.5 %.
    TempDir dir;
    const double agree = kSanitized ? 0.01 : 0.005;
    std::map<std::string, nlohmann::json> reports;
    for (const std::string of : {"frame", "cell", "cut"}) {
        const std::string keys = of == "cut" ? "}, kernel: {gaussian: {sigma: 0.8}}, density: 0.1"
                                             : ", edges: frame}, kernel: {gaussian: {sigma: 0.8}}, density: 0.1, "
                                               "density_of: " +
                                                   of;
        reports[of] =
            runReport(dir, of,
                      "material: form2\nvoxel: 0.25\ndomain: {box: [[0, 0, 0], [30, 30, 30]]}\n"
                      "properties: {resolution: " +
                          std::string(kSanitized ? "32" : "64") + "}\nfields:\n  lattice: {struts: {cell: x, size: 10" +
                          keys + "}\nresult: lattice\noutputs: {properties: p.json}\n");
        ASSERT_FALSE(reports[of].is_null()) << of;
    }
    EXPECT_LT(std::abs(reports["cut"]["fields"]["lattice"]["level"].get<double>() /
                           reports["cut"]["properties"]["level"].get<double>() -
                       1.0),
              agree);
    auto level = [&](const std::string& of) { return reports[of]["fields"]["lattice"]["level"].get<double>(); };
    auto cellLevel = [&](const std::string& of) { return reports[of]["properties"]["level"].get<double>(); };
    // The cell's own level (solved on its voxel model) is the same for both: the lattice asked.
    EXPECT_NEAR(cellLevel("cell"), cellLevel("frame"), 1e-12);
    EXPECT_LT(std::abs(level("cell") / cellLevel("cell") - 1.0), agree)
        << level("cell") << " vs the voxel cell's " << cellLevel("cell");
    EXPECT_GT(std::abs(level("frame") / cellLevel("frame") - 1.0), 0.02)
        << level("frame") << " vs the voxel cell's " << cellLevel("frame");
    std::printf("iso-value t: frame %.5f, cell %.5f, the voxel cell's %.5f\n", level("frame"), level("cell"),
                cellLevel("cell"));
    // Refused where no periodic cell is known, naming the line.
    int status = 0;
    std::string out;
    runReport(dir, "few",
              "voxel: 0.25\nfields:\n  lattice: {struts: {cell: x, size: 10, count: [3, 3, 2]}, kernel: capsule, "
              "density: 0.1, density_of: cell}\nresult: lattice\n",
              &status, &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("few.yaml:3:"), std::string::npos) << out;
    EXPECT_NE(out.find("along z"), std::string::npos) << out;
}

TEST(PropertyDesign, SearchTrialsRunAtTheConvergedResolution)
{
    // With no `resolution:` anywhere, a stiffness or sigma search homogenizes its trials at the
    // resolution the convergence check chooses at its first trial that carries load (the same
    // policy as `voxlat properties`), reported with that check's numbers.
    // Under the sanitizers the stiffness search stops at 10 % (fewer trials) instead of 1 %, the
    // sigma search's refinement at 0.3 mm instead of 0.1 (two golden-section steps fewer), and
    // the job's voxel is 0.5 mm (the homogenized cells do not depend on it).
    TempDir dir;
    const double tolerance = kSanitized ? 0.1 : 0.01;
    const std::string gyroid = std::string(R"(material: form2
voxel: )") + (kSanitized ? "0.5" : "0.25") +
                               R"(
domain: {box: [[0, 0, 0], [10, 10, 10]]}
properties: {max_resolution: 48}
fields:
  lattice: {tpms: gyroid, cell: 5, solid: network, stiffness: {E: 40 MPa, axis: z, tolerance: )" +
                               (kSanitized ? "0.1" : "0.01") + R"(}}
result: lattice
outputs: {properties: p.json}
)";
    const auto report = runReport(dir, "stiff", gyroid);
    ASSERT_FALSE(report.is_null());
    const auto& s = report["design"]["lattice"]["stiffness"];
    EXPECT_NE(s["resolution_from"].get<std::string>().find("convergence"), std::string::npos) << s.dump();
    ASSERT_TRUE(s.contains("convergence")) << s.dump();
    EXPECT_EQ(s["resolution"], s["convergence"]["resolutions"].back());
    // (At most 48 voxels here, to keep the test short: the check's own estimate bounds the error.)
    const double estimated = s["estimated_error"].get<double>();
    EXPECT_GT(estimated, 0.0) << s.dump();
    // The job's own homogenization of the result, converged on its own ladder, meets the target
    // within the search's tolerance and the convergence error.
    const auto p = nlohmann::json::parse(readFile(dir.path / "stiff" / "p.json"));
    const double E = p["E_MPa"][2].get<double>();
    EXPECT_LE(std::abs(E / 40.0 - 1.0), tolerance + estimated) << E;
    std::printf("stiffness at the converged resolution %d: E_z %.4f MPa (target 40, estimated error %.4f)\n",
                s["resolution"].get<int>(), E, estimated);

    // `optimize:`: every trial at one resolution, the convergence check's; an independent
    // homogenization at that resolution of the chosen sigma gives the search's modulus.
    const std::string head = std::string(R"(material: form2
voxel: )") + (kSanitized ? "0.5" : "0.25") +
                             R"(
domain: {box: [[0, 0, 0], [15, 15, 15]]}
properties: {cell: [5, 5, 5], origin: [5, 5, 5], max_resolution: 48}
fields:
  lattice:
    struts: {cell: x, size: 5}
    density: 0.2
)";
    const auto opt = runReport(dir, "opt",
                               head +
                                   "    kernel: {gaussian: {sigma: 0.3}}\n"
                                   "    optimize: {sigma: [0.2, 0.8], axis: z, samples: 3, tolerance: " +
                                   std::string(kSanitized ? "0.3" : "0.1") + ", baseline: false}\nresult: lattice\n");
    ASSERT_FALSE(opt.is_null());
    const auto& o = opt["design"]["lattice"]["optimize"];
    ASSERT_TRUE(o.contains("convergence")) << o.dump();
    const int resolution = o["resolution"].get<int>();
    EXPECT_EQ(resolution, o["convergence"]["resolutions"].back().get<int>());
    char chosen[160];
    std::snprintf(chosen, sizeof chosen, "    kernel: {gaussian: {sigma: %.17g}}\nresult: lattice\n",
                  o["sigma"].get<double>());
    std::string fixed = head;
    fixed.replace(fixed.find("max_resolution: 48"), 18, "resolution: " + std::to_string(resolution));
    const auto again = propertiesOf(dir, "again", fixed + chosen);
    ASSERT_FALSE(again.is_null());
    EXPECT_NEAR(again["E_MPa"][2].get<double>(), o["E_MPa"].get<double>(), 1e-9 * o["E_MPa"].get<double>());
}

TEST(Properties, DensityOfCellOnATpmsHoldsTheDensityInOnePeriod)
{
    // A gyroid network of 10 mm cells in a 13 mm box (one cell and 0.3 of the next): `density:`
    // over the box (`frame`, the default) is not the density of the periodic cell; `density_of:
    // cell` solves the level over one period. Reference: the solid share of one period at the
    // job's level, counted on a 160^3 lattice of points (under the sanitizers 80^3, and the cell
    // homogenized at 24 voxels instead of 48).
    TempDir dir;
    std::map<std::string, double> inCell;
    for (const std::string of : {"frame", "cell"}) {
        const std::string text =
            "material: form2\nvoxel: 0.25\ndomain: {box: [[0, 0, 0], [13, 13, 13]]}\n"
            "properties: {resolution: " +
            std::string(kSanitized ? "24" : "48") +
            "}\nfields:\n  lattice: {tpms: gyroid, cell: 10, solid: "
            "network, density: 0.3, density_of: " +
            of + "}\nresult: lattice\noutputs: {properties: p.json}\n";
        const auto report = runReport(dir, of, text);
        ASSERT_FALSE(report.is_null()) << of;
        if (of == "cell") {
            EXPECT_NE(report["fields"]["lattice"]["density_measured_on"].get<std::string>().find("one period"),
                      std::string::npos);
        }
        Recipe r = parseRecipe(text, of + ".yaml", dir.path.string());
        Job job(std::move(r));
        job.solveLevels();
        const FieldPtr f = job.field("lattice");
        const int n = kSanitized ? 80 : 160;
        std::vector<Vec3d> points;
        std::vector<double> values(std::size_t(n) * n);
        std::int64_t solid = 0;
        for (int i = 0; i < n; ++i) {
            points.clear();
            for (int j = 0; j < n; ++j)
                for (int k = 0; k < n; ++k)
                    points.emplace_back((i + 0.5) * 10.0 / n, (j + 0.5) * 10.0 / n, (k + 0.5) * 10.0 / n);
            f->values(points, values);
            for (double v : values) solid += v < 0.0;
        }
        inCell[of] = double(solid) / double(std::int64_t(n) * n * n);
        // The homogenized cell holds the density asked either way (its level solved on its voxels).
        const auto p = nlohmann::json::parse(readFile(dir.path / of / "p.json"));
        EXPECT_LT(std::abs(p["relative_density"].get<double>() / 0.3 - 1.0), 0.005);
    }
    std::printf("one period's density: density_of frame %.5f, cell %.5f (asked 0.3)\n", inCell["frame"],
                inCell["cell"]);
    EXPECT_LT(std::abs(inCell["cell"] / 0.3 - 1.0), 0.002) << inCell["cell"];
    EXPECT_GT(std::abs(inCell["frame"] / 0.3 - 1.0), 0.005) << inCell["frame"];
    // Refused where the cells change from place to place, naming the line.
    int status = 0;
    std::string out;
    runReport(dir, "oriented",
              "voxel: 0.25\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n  lattice: {tpms: gyroid, cell: 5, "
              "density: 0.3, density_of: cell, frame: {cylinder: {center: [5, 5, 0], axis: [0, 0, 1], around: "
              "6}}}\nresult: lattice\n",
              &status, &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("oriented.yaml:4:"), std::string::npos) << out;
    runReport(dir, "graded",
              "voxel: 0.25\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nfields:\n  lattice: {tpms: gyroid, cell: 5, "
              "density: {ramp: {axis: z, from: 0.2, to: 0.4}}, density_of: cell}\nresult: lattice\n",
              &status, &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("graded.yaml:4:"), std::string::npos) << out;
}

TEST(Properties, AGradedLatticeExportsOneMaterialPerSlab)
{
    // A gyroid graded along z from 0.2 to 0.4 over 20 mm, cells of 5 mm: four slabs, one
    // material each, the cell homogenized at the slab's mean target density (a linear ramp: its
    // value at the slab's middle), each card equal to an independent homogenization of the
    // uniform lattice at that density (at 24 voxels, 16 under the sanitizers).
    TempDir dir;
    const std::string head =
        "material: form2\nvoxel: 0.25\ndomain: {box: [[0, 0, 0], [10, 10, 20]]}\n"
        "properties: {resolution: " +
        std::string(kSanitized ? "16" : "24") + ", export: graded.inp}\nfields:\n";
    const auto report =
        runReport(dir, "graded",
                  head +
                      "  lattice: {tpms: gyroid, cell: 5, solid: network, density: {ramp: {axis: z, from: 0.2, to: "
                      "0.4}}}\nresult: lattice\n");
    ASSERT_FALSE(report.is_null());
    const std::string text = readFile(dir.path / "graded" / "graded.inp");
    // Split at each card's first comment line.
    std::vector<std::string> cards;
    for (std::size_t at = text.find("** voxlat"); at != std::string::npos;) {
        const std::size_t next = text.find("** voxlat", at + 1);
        cards.push_back(text.substr(at, next == std::string::npos ? std::string::npos : next - at));
        at = next;
    }
    ASSERT_EQ(cards.size(), 4u) << text;
    double previous = 0.0;
    for (int s = 0; s < 4; ++s) {
        const MaterialCard card = readMaterialCard(cards[s]);
        EXPECT_EQ(card.name, "LATTICE_SLAB" + std::to_string(s + 1));
        EXPECT_EQ(card.constants, 21);
        const std::string region = "** region: z from " + formatNumber(5.0 * s) + " to " + formatNumber(5.0 * s + 5.0);
        EXPECT_NE(cards[s].find(region), std::string::npos) << cards[s];
        const double rho = 0.2 + 0.2 * (5.0 * s + 2.5) / 20.0;
        const auto& row = report["material_cards"]["slabs"][s];
        EXPECT_NEAR(row["target_density"].get<double>(), rho, 1e-3);
        char density[40];
        std::snprintf(density, sizeof density, "%.17g", row["target_density"].get<double>());
        const auto uniform = propertiesOf(
            dir, "uniform" + std::to_string(s),
            "material: form2\nvoxel: 0.25\ndomain: {box: [[0, 0, 0], [10, 10, 10]]}\nproperties: "
            "{resolution: " +
                std::string(kSanitized ? "16" : "24") +
                "}\nfields:\n  lattice: {tpms: gyroid, cell: 5, solid: network, density: " + std::string(density) +
                "}\nresult: lattice\n");
        ASSERT_FALSE(uniform.is_null());
        EXPECT_LT(std::abs(uniform["relative_density"].get<double>() / rho - 1.0), 0.01);
        for (int i = 0; i < 6; ++i)
            for (int j = 0; j < 6; ++j)
                EXPECT_NEAR(card.C[i][j], uniform["C_MPa"][i][j].get<double>(),
                            1e-6 * uniform["C_MPa"][0][0].get<double>())
                    << s << ": " << i << "," << j;
        EXPECT_GT(card.C[2][2], previous);  // stiffer as the density rises
        previous = card.C[2][2];
    }
    // A density that varies across the slabs: refused with the reason, nothing written.
    int status = 0;
    std::string out;
    runReport(dir, "across",
              head +
                  "  ball: {sphere: {center: [5, 5, 10], radius: 2}}\n  rho: {distance-ramp: {field: ball, from: "
                  "0.4, to: 0.2, over: 6}}\n  lattice: {tpms: gyroid, cell: 5, solid: network, density: rho}\n"
                  "result: lattice\n",
              &status, &out);
    EXPECT_EQ(status, 2) << out;
    EXPECT_NE(out.find("across.yaml:4:"), std::string::npos) << out;
    EXPECT_NE(out.find("varies across"), std::string::npos) << out;
    EXPECT_FALSE(std::filesystem::exists(dir.path / "across" / "report.json"));
}

TEST(Properties, TheMemoryEstimateBoundsTheSolvesPeakAndRefusesWhatCannotFit)
{
    // The estimate `voxlat properties` refuses a resolution by (MemoryEstimate.h) against the
    // solve's measured peak: a gyroid network at 20 % and at 80 % solid, homogenized by
    // voxlat_homogenize_cell in a process of its own (its peak resident size above the cell it
    // read, /proc/self/clear_refs then VmHWM). The estimate is at least the peak and at most twice
    // it. Under the sanitizers (their shadow memory and quarantine inflate the peak) 16 voxels,
    // and no bound is checked.
    TempDir dir;
    const int n = kSanitized ? 16 : 40;
    const std::string driver =
        (std::filesystem::path(voxlatBinary()).parent_path() / "voxlat_homogenize_cell").string();
    for (const double share : {0.2, 0.8}) {
        // The gyroid's values at the voxel centres; the share lowest are solid.
        std::vector<double> g(std::size_t(n) * n * n);
        for (int z = 0; z < n; ++z)
            for (int y = 0; y < n; ++y)
                for (int x = 0; x < n; ++x) {
                    const double X = 2.0 * std::numbers::pi * (x + 0.5) / n, Y = 2.0 * std::numbers::pi * (y + 0.5) / n,
                                 Z = 2.0 * std::numbers::pi * (z + 0.5) / n;
                    g[x + std::size_t(n) * (y + std::size_t(n) * z)] =
                        std::sin(X) * std::cos(Y) + std::sin(Y) * std::cos(Z) + std::sin(Z) * std::cos(X);
                }
        std::vector<double> sorted = g;
        const std::size_t k = std::size_t(share * double(g.size()));
        std::nth_element(sorted.begin(), sorted.begin() + std::ptrdiff_t(k), sorted.end());
        VoxelCell cell;
        cell.nx = cell.ny = cell.nz = n;
        cell.hx = cell.hy = cell.hz = 1.0 / n;
        std::string text = std::to_string(n) + " " + std::to_string(n) + " " + std::to_string(n) + " " +
                           std::to_string(1.0 / n) + " 1600 0.38\n";
        for (const double v : g) {
            cell.solid.push_back(v < sorted[k] ? 1 : 0);
            text += v < sorted[k] ? '1' : '0';
        }
        const auto path = dir.write("cell" + std::to_string(int(100 * share)) + ".txt", text);
        std::string out;
        ASSERT_EQ(runCommand(driver + " --tolerance 1e-6 " + path.string(), &out), 0) << out;
        const auto result = nlohmann::json::parse(out);
        const double measured = result["peak_growth_bytes"].get<double>(), estimate = homogenizationBytes(cell);
        std::printf("%d voxels at %.0f %% solid (%lld nodes): estimate %.1f MB, measured peak %.1f MB (%.2fx)\n", n,
                    100.0 * share, static_cast<long long>(cellNodes(cell)), estimate / 1048576.0, measured / 1048576.0,
                    estimate / measured);
        if (kSanitized) continue;
        EXPECT_GE(estimate, measured) << share;
        EXPECT_LE(estimate, 2.0 * measured) << share;
    }
    // A resolution whose solve cannot fit: exit 3 with the estimate and the limit, before the
    // cell is sampled at it (a dense gyroid at 512 voxels: about 1450 bytes a voxel).
    const double need = homogenizationBytes(512.0 * 512.0 * 512.0, 0.5 * 512.0 * 512.0 * 512.0);
    if (need > 0.7 * double(availableMemoryBytes())) {
        int status = 0;
        std::string out;
        propertiesOf(dir, "huge",
                     "material: form2\nvoxel: 0.5\ndomain: {box: [[0, 0, 0], [5, 5, 5]]}\n"
                     "properties: {resolution: 512}\nfields:\n  lattice: {tpms: gyroid, cell: 5, solid: network, "
                     "density: 0.8}\nresult: lattice\n",
                     "", &status, &out);
        EXPECT_EQ(status, 3) << out;
        EXPECT_NE(out.find("needs about"), std::string::npos) << out;
        EXPECT_NE(out.find("MB this machine can give"), std::string::npos) << out;
    }
}
