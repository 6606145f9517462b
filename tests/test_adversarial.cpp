// The adversarial pass's defects (issue 40), each on its minimal input: nothing written outside
// where it may go, temporaries no one can hijack, stops that stop, nothing wrong at exit 0,
// estimates before refusals, exit codes as documented.
#include "TestUtil.h"
#include "engine/core/Domain.h"
#include "engine/core/Errors.h"
#include "engine/core/Format.h"
#include "engine/core/JobContext.h"
#include "engine/core/SystemInfo.h"
#include "engine/jobs/Job.h"
#include "engine/jobs/PrinterProfile.h"
#include "engine/jobs/TrialRecipe.h"
#include "engine/recipe/Recipe.h"
#include "mesher/writers/AtomicFile.h"

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/stat.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <thread>

using namespace voxlat;
using namespace voxlat::test;

namespace {

const char* kSmall = R"(voxel: 0.5
domain: {box: [[0, 0, 0], [6, 6, 6]]}
fields:
  lattice: {tpms: gyroid, cell: 6, solid: network, density: 0.30}
result: lattice
outputs: {mesh: part.stl}
)";

Recipe parse(const std::string& text, const TempDir& dir, const std::vector<std::string>& sets = {})
{
    return parseRecipe(text, (dir.path / "r.yaml").string(), dir.path, sets);
}

/// The InputError @a text raises when loaded and built (empty if none).
template <class Error>
std::string errorOf(const std::function<void()>& work)
{
    try {
        work();
    } catch (const Error& e) {
        return e.what();
    }
    return {};
}

/// A process id no process has now (for a temporary "left by a killed run").
long deadPid()
{
    for (long pid = 4000000; pid > 1000; pid -= 7919)
        if (::kill(pid_t(pid), 0) != 0 && errno == ESRCH) return pid;
    return 0;
}

}  // namespace

TEST(Adversarial, TemporariesAreFreshPerWriterAndNeverFollowALink)
{
    TempDir dir;
    const std::string path = (dir.path / "part.stl").string();
    const auto victim = dir.write("victim.txt", "keep me");
    // The next temporary name: plant a symbolic link there, to the victim.
    const std::string probe = temporaryName(path);
    const std::string prefix = probe.substr(0, probe.rfind('-') + 1);
    const long next = std::stol(probe.substr(probe.rfind('-') + 1)) + 1;
    std::filesystem::create_symlink(victim, prefix + std::to_string(next));
    {
        AtomicFile a(path), b(path);
        EXPECT_NE(a.tempPath(), b.tempPath());
        EXPECT_NE(a.tempPath(), prefix + std::to_string(next));
        EXPECT_TRUE(std::filesystem::is_regular_file(std::filesystem::symlink_status(a.tempPath())));
        a.stream() << "first";
        b.stream() << "second";
        a.commit();
        b.commit();
    }
    EXPECT_EQ(readFile(victim), "keep me");
    EXPECT_EQ(readFile(path), "second");
    // Two threads writing one path: each commits a whole file of its own; never one mixed.
    const std::string one(1 << 20, 'a'), two(1 << 19, 'b');
    std::thread t1([&] {
        for (int i = 0; i < 20; ++i) {
            AtomicFile f(path);
            f.stream() << one;
            f.commit();
        }
    });
    std::thread t2([&] {
        for (int i = 0; i < 20; ++i) {
            AtomicFile f(path);
            f.stream() << two;
            f.commit();
        }
    });
    t1.join();
    t2.join();
    const std::string last = readFile(path);
    EXPECT_TRUE(last == one || last == two) << last.size();
}

TEST(Adversarial, TemporariesOfAKilledRunAreNamedNotReused)
{
    TempDir dir;
    const long pid = deadPid();
    ASSERT_NE(pid, 0);
    const auto recipe = dir.write("r.yaml", kSmall);
    const auto out = dir.path / "out";
    std::filesystem::create_directories(out);
    const std::string stale = (out / ("part.stl.tmp-" + std::to_string(pid) + "-0")).string();
    std::ofstream(stale) << "half a file";
    // This process's own temporaries are not stale.
    const std::string mine = (out / ("part.stl.tmp-" + std::to_string(::getpid()) + "-99")).string();
    std::ofstream(mine) << "mine";
    EXPECT_EQ(staleTemporaries((out / "part.stl").string()), std::vector<std::string>{stale});
    std::filesystem::remove(mine);
    std::string text;
    ASSERT_EQ(runCommand(voxlatBinary() + " -q run " + recipe.string() + " --out " + out.string(), &text), 0) << text;
    EXPECT_NE(
        text.find("part.stl.tmp-" + std::to_string(pid) + "-0` is a temporary file left by a run that was killed"),
        std::string::npos)
        << text;
    EXPECT_EQ(readFile(stale), "half a file");
    EXPECT_GT(readFile(out / "part.stl").size(), 84u);
}

TEST(Adversarial, EveryFileACommandWritesIsCheckedBeforeAnyWork)
{
    TempDir dir;
    const auto recipe = dir.write("r.yaml", kSmall);
    const auto fifo = dir.path / "pipe.json";
    ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
    std::string text;
    // properties --json / --png onto a FIFO: refused (exit 2) before the recipe is even read.
    EXPECT_EQ(runCommand(voxlatBinary() + " -q properties " + recipe.string() + " --json " + fifo.string(), &text), 2)
        << text;
    EXPECT_NE(text.find("not a regular file"), std::string::npos) << text;
    EXPECT_TRUE(std::filesystem::is_fifo(fifo));
    EXPECT_EQ(runCommand(voxlatBinary() + " -q properties " + recipe.string() + " --png " + fifo.string(), &text), 2)
        << text;
    EXPECT_TRUE(std::filesystem::is_fifo(fifo));
    EXPECT_EQ(runCommand(voxlatBinary() + " -q properties " + recipe.string() + " --json " +
                             (dir.path / "a.png").string() + " --png " + (dir.path / "a.png").string(),
                         &text),
              2)
        << text;
    // mesh -o with a kind no writer has: refused at once, not after the whole mesh.
    EXPECT_EQ(
        runCommand(voxlatBinary() + " -q mesh " + recipe.string() + " -o " + (dir.path / "x.txt").string(), &text), 2)
        << text;
    EXPECT_NE(text.find(".stl, .3mf, .ply or .obj"), std::string::npos) << text;
    EXPECT_FALSE(std::filesystem::exists(dir.path / "x.txt"));
    // A folder where the mesh's preview goes: refused before the mesh is made, nothing written.
    const auto out = dir.path / "out";
    std::filesystem::create_directories(out / "part.stl.preview.png");
    EXPECT_EQ(runCommand(voxlatBinary() + " -q run " + recipe.string() + " --out " + out.string(), &text), 2) << text;
    EXPECT_NE(text.find("part.stl.preview.png"), std::string::npos) << text;
    EXPECT_FALSE(std::filesystem::exists(out / "part.stl"));
}

TEST(Adversarial, UsageErrorsExit2)
{
    std::string text;
    EXPECT_EQ(runCommand(voxlatBinary() + " run", &text), 2) << text;                     // a missing argument
    EXPECT_EQ(runCommand(voxlatBinary() + " run r.yaml --bogus", &text), 2) << text;      // an unknown option
    EXPECT_EQ(runCommand(voxlatBinary() + " --threads x run r.yaml", &text), 2) << text;  // not a number
    EXPECT_EQ(runCommand(voxlatBinary() + " frobnicate", &text), 2) << text;              // no such command
    EXPECT_EQ(runCommand(voxlatBinary() + " --help", &text), 0) << text;
    EXPECT_EQ(runCommand(voxlatBinary() + " --version", &text), 0) << text;
}

TEST(Adversarial, ACancelWhileWritingKeepsTheOldFile)
{
    TempDir dir;
    const auto path = dir.path / "part.stl";
    std::ofstream(path) << "the user's old file";
    JobContext context;
    // Cancelled once the mesh is made: the cancel comes while the file is written.
    context.setProgressCallback([&](const std::string& stage, std::uint64_t done, std::uint64_t total) {
        if (stage.find("mesh") != std::string::npos && done >= total) context.cancel();
    });
    Job job(parse(kSmall, dir), &context);
    EXPECT_THROW(job.writeMesh(path, MeshOptions{}), Cancelled);
    EXPECT_EQ(readFile(path), "the user's old file");
    EXPECT_EQ(listFolder(dir.path), std::vector<std::string>{"part.stl"});
}

TEST(Adversarial, DuplicateKeysSecondDocumentsAndIgnoredSetsAreRefused)
{
    TempDir dir;
    auto inputError = [&](const std::string& text, const std::vector<std::string>& sets = {}) {
        return errorOf<InputError>([&] { parse(text, dir, sets); });
    };
    std::string e = inputError("voxel: 0.25\nvoxel: 5\n" + std::string(kSmall).substr(11));
    EXPECT_NE(e.find("r.yaml:2:1"), std::string::npos) << e;
    EXPECT_NE(e.find("given twice"), std::string::npos) << e;
    e = inputError(std::string(kSmall) + "---\nvoxel: 5\n");
    EXPECT_NE(e.find("r.yaml:8:"), std::string::npos) << e;
    EXPECT_NE(e.find("second YAML document"), std::string::npos) << e;
    // A duplicate inside a field's map, and in an included file.
    e = inputError("voxel: 0.5\nfields:\n  a: {sphere: {radius: 1}, sphere: {radius: 2}}\nresult: a\n");
    EXPECT_NE(e.find("r.yaml:3:"), std::string::npos) << e;
    dir.write("lib.yaml", "fields:\n  s: {sphere: {radius: 1}}\n  s: {sphere: {radius: 2}}\n");
    e = inputError("include: lib.yaml\nvoxel: 0.5\nresult: s\n");
    EXPECT_NE(e.find("lib.yaml:3:"), std::string::npos) << e;
    // --set include=FILE is applied (a missing file is refused, not ignored).
    e = inputError(kSmall, {"include=missing.yaml"});
    EXPECT_NE(e.find("missing.yaml"), std::string::npos) << e;
    // A printer profile: one document, no duplicate keys.
    const auto profile = dir.write("p.yaml", "name: P\nname: Q\n");
    e = errorOf<InputError>([&] { loadPrinterProfile(profile.string(), ""); });
    EXPECT_NE(e.find("p.yaml:2:1"), std::string::npos) << e;
}

// yaml-cpp 0.7's LoadAll loops for ever (and grows a vector until memory runs out) on streams whose
// parser yields empty documents without consuming a token (yaml-cpp PR #1319); fuzz_profile found a
// printer profile doing it. These end with a clear error, or as the one document they hold.
TEST(Adversarial, StreamsThatLoopedYamlCppsLoadAllEnd)
{
    TempDir dir;
    for (const std::string text : {"\n,\n    ", ",", "# a recipe\n,\n"})
        EXPECT_THROW((void)parse(text, dir), InputError) << text;
    // The same through the printer profile loader, where the fuzzer found it.
    dir.write("p.yaml", "# a profile\n,\n");
    EXPECT_THROW((void)loadPrinterProfile((dir.path / "p.yaml").string(), "test"), InputError);
    // One document and empty ones after it still load, and a second one is still refused.
    EXPECT_NO_THROW((void)parse(std::string(kSmall) + "---\n", dir));
}

TEST(Adversarial, NonFiniteInputsAreRefusedWithTheirLine)
{
    TempDir dir;
    dir.write("rod.csv", "0,0,0,5,nan,5\n");
    std::string e = errorOf<InputError>([&] {
        Job job(
            parse("voxel: 0.5\nfields:\n  rod: {struts: {wireframe: rod.csv}, kernel: {gaussian: {sigma: 0.5}}, "
                  "level: 0.1}\nresult: rod\n",
                  dir));
    });
    EXPECT_NE(e.find("rod.csv:1"), std::string::npos) << e;
    EXPECT_NE(e.find("finite"), std::string::npos) << e;
    // A number past the largest double in an equation.
    e = errorOf<InputError>([&] {
        Job job(
            parse("voxel: 0.5\ndomain: {box: [[0, 0, 0], [4, 4, 4]]}\nfields:\n  f: {expr: \"1e999 + x\"}\n"
                  "result: f\n",
                  dir));
    });
    EXPECT_NE(e.find("1e999"), std::string::npos) << e;
    // A modulus no material has, a scale a double cannot keep.
    e = errorOf<InputError>([&] { parse(std::string(kSmall) + "material: {E: 1e308 GPa, nu: 0.3}\n", dir); });
    EXPECT_NE(e.find("r.yaml:7:"), std::string::npos) << e;
    e = errorOf<InputError>([&] {
        Job job(
            parse("voxel: 0.5\nfields:\n  s: {sphere: {radius: 1}}\n  t: {scale: 1e-300, field: s}\nresult: t\n", dir));
    });
    EXPECT_NE(e.find("scale factors"), std::string::npos) << e;
}

TEST(Adversarial, ResultsThatCannotBeRightFailTheirCheck)
{
    TempDir dir;
    // A field infinite everywhere would be culled as empty: a failed check, not an empty part.
    std::string e = errorOf<JobError>([&] {
        Job job(parse("voxel: 0.5\ndomain: {box: [[0, 0, 0], [4, 4, 4]]}\nfields:\n  f: {expr: \"1/0\"}\nresult: f\n",
                      dir));
        job.solveLevels();
    });
    EXPECT_NE(e.find("not a finite number"), std::string::npos) << e;
    // A cell of 1e300 mm holds no surface in the domain: its density cannot be reached.
    e = errorOf<JobError>([&] {
        std::string text = kSmall;
        text.replace(text.find("cell: 6"), 7, "cell: 1e300");
        Job job(parse(text, dir));
        job.solveLevels();
    });
    EXPECT_NE(e.find("not the 0.3 asked"), std::string::npos) << e;
    // A part far from the origin against its voxel: refused with the limit.
    e = errorOf<InputError>([&] {
        Job job(
            parse("voxel: 0.5\ndomain: {box: [[1e9, 0, 0], [1000000004, 4, 4]]}\nfields:\n  s: {sphere: {radius: "
                  "1, center: [1e9, 2, 2]}}\nresult: s\n",
                  dir));
    });
    EXPECT_NE(e.find("from the origin"), std::string::npos) << e;
    EXPECT_NE(e.find("r.yaml:2:"), std::string::npos) << e;  // at the recipe's `domain:`
    EXPECT_NE(e.find(formatNumber(kMaxVoxelsFromOrigin)), std::string::npos) << e;
}

TEST(Adversarial, PropertiesRefuseACellThatIsNotAPeriodAndUnreachableTolerances)
{
    TempDir dir;
    const std::string base = std::string(kSmall) + "material: form2\n";
    std::string e = errorOf<InputError>([&] { parse(base + "properties: {tolerance: 1e-15}\n", dir); });
    EXPECT_NE(e.find("r.yaml:8:"), std::string::npos) << e;
    EXPECT_NE(e.find("1e-10"), std::string::npos) << e;
    e = errorOf<InputError>([&] {
        JobContext context;
        Job job(parse(base + "properties: {cell: [3, 6, 6]}\n", dir), &context);
        job.properties();
    });
    EXPECT_NE(e.find("r.yaml:8:"), std::string::npos) << e;
    EXPECT_NE(e.find("not a whole number of the result's period"), std::string::npos) << e;
    // A resolution whose solve cannot fit in memory: refused with the estimate before sampling.
    const double need = 512.0 * 512.0 * 512.0 * 150.0;
    if (need > 0.7 * double(availableMemoryBytes())) {
        e = errorOf<JobError>([&] {
            JobContext context;
            Job job(parse(base + "properties: {resolution: 512}\n", dir), &context);
            job.properties();
        });
        EXPECT_NE(e.find("needs about"), std::string::npos) << e;
    }
}

TEST(Adversarial, JobsThatCannotFitAreRefusedWithTheEstimate)
{
    TempDir dir;
    // A mesh tolerance far below the voxel: refused before any work, with the limit.
    std::string e = errorOf<JobError>([&] {
        Job job(parse(kSmall, dir));
        MeshOptions options;
        options.tolerance = 1e-6;
        options.project = true;
        job.mesh(options);
    });
    EXPECT_NE(e.find("times the triangles of marching cubes"), std::string::npos) << e;
    EXPECT_NE(e.find("use a tolerance of at least 0.0005 mm"), std::string::npos) << e;
    // A display no layer of which fits in memory.
    const auto profile = dir.write("huge.yaml", readFile(sourceDir() / "data" / "printers" / "sl1s.yaml"));
    {
        std::string text = readFile(profile);
        const auto x = text.find("pixels_x:");
        text.replace(x, text.find_first_of(",}\n", x) - x, "pixels_x: 1000000");
        const auto y = text.find("pixels_y:");
        text.replace(y, text.find_first_of(",}\n", y) - y, "pixels_y: 1000000");
        dir.write("huge.yaml", text);
    }
    e = errorOf<InputError>([&] { loadPrinterProfile(profile.string(), ""); });
    EXPECT_NE(e.find("huge.yaml:"), std::string::npos) << e;
    EXPECT_NE(e.find("1e+12 pixels"), std::string::npos) << e;
    // Many points with a falloff that reaches everywhere.
    {
        std::ofstream points(dir.path / "points.csv");
        for (int i = 0; i < 100001; ++i) points << i % 10 << "," << i / 10 % 10 << "," << i / 100 << "\n";
    }
    e = errorOf<JobError>([&] {
        Job job(
            parse("voxel: 0.5\ndomain: {box: [[0, 0, 0], [4, 4, 4]]}\nfields:\n  f: {points: {file: points.csv, "
                  "falloff: inverse}, level: 1}\nresult: f\n",
                  dir));
    });
    EXPECT_NE(e.find("100001 points"), std::string::npos) << e;
    // A 3MF whose directory says it decompresses to a terabyte: refused before lib3mf reads it.
    {
        std::string zip;
        auto u16 = [&](unsigned v) { zip += char(v & 0xff), zip += char(v >> 8 & 0xff); };
        auto u32 = [&](std::uint32_t v) { u16(v & 0xffff), u16(v >> 16); };
        auto u64 = [&](std::uint64_t v) { u32(std::uint32_t(v)), u32(std::uint32_t(v >> 32)); };
        const std::string name = "3D/3dmodel.model";
        u32(0x04034b50), u16(45), u16(0), u16(0), u16(0), u16(0), u32(0), u32(0), u32(0), u16(name.size()), u16(0);
        zip += name;
        const std::uint32_t directory = std::uint32_t(zip.size());
        u32(0x02014b50), u16(45), u16(45), u16(0), u16(0), u16(0), u16(0), u32(0), u32(0), u32(0xFFFFFFFF);
        u16(name.size()), u16(12), u16(0), u16(0), u16(0), u32(0), u32(0);
        zip += name;
        u16(0x0001), u16(8), u64(std::uint64_t(1) << 40);
        const std::uint32_t size = std::uint32_t(zip.size()) - directory;
        u32(0x06054b50), u16(0), u16(0), u16(1), u16(1), u32(size), u32(directory), u16(0);
        dir.write("big.3mf", zip);
    }
    e = errorOf<JobError>([&] { Job job(parse("voxel: 0.5\nfields:\n  part: {mesh: big.3mf}\nresult: part\n", dir)); });
    EXPECT_NE(e.find("decompresses to 1048576 MB"), std::string::npos) << e;
}

TEST(Adversarial, TrialJobsStopWithTheirParent)
{
    // Trial jobs (optimize:, stiffness:, a frame's repeated cell, the pieces advice) keep their
    // own context; a SIGTERM during `optimize:` once ran on for minutes. Their progress checks
    // look at the parent's cancel.
    JobContext parent, trial;
    followCancel(trial, &parent);
    StageProgress stage(&trial, "trial", 100);
    stage.add();
    parent.cancel();
    std::this_thread::sleep_for(std::chrono::milliseconds(150));  // the next progress tick
    EXPECT_THROW(
        {
            stage.add();
            stage.add();
        },
        Cancelled);
    // Already cancelled: the trial starts cancelled.
    JobContext late;
    followCancel(late, &parent);
    EXPECT_TRUE(late.cancelled());
}

TEST(Adversarial, CommandLineNumbersKeepTheirDigits)
{
    // --layer went through std::to_string: 0.0000004 became "0.000000" (refused as zero) and
    // 0.0123456 became 0.012346. Both ends of the layer range show the digits as given.
    TempDir dir;
    const auto recipe = dir.write("r.yaml", kSmall);
    std::string text;
    EXPECT_EQ(runCommand(voxlatBinary() + " -q slice " + recipe.string() + " --printer sl1s -o " +
                             (dir.path / "a.sl1s").string() + " --layer 0.0000004",
                         &text),
              2)
        << text;
    EXPECT_NE(text.find("a layer of 4e-07 mm"), std::string::npos) << text;
    EXPECT_EQ(runCommand(voxlatBinary() + " -q slice " + recipe.string() + " --printer sl1s -o " +
                             (dir.path / "a.sl1s").string() + " --layer 10.0000001",
                         &text),
              2)
        << text;
    EXPECT_NE(text.find("a layer of 10.0000001 mm"), std::string::npos) << text;
    EXPECT_TRUE(listFolder(dir.path) == std::vector<std::string>{"r.yaml"});
}

TEST(Adversarial, ALongWriteChecksItsInterrupterEveryChunkAndKeepsTheOldFile)
{
    // A write of 16 MB whose job is cancelled after its third chunk: it stops within one more
    // chunk (64 KB), not at the end, and the old file stays, with no temporary.
    TempDir dir;
    const auto path = dir.write("big.bin", "old");
    JobContext context;
    int calls = 0;
    std::size_t written = 0;
    {
        OutputTransaction transaction([&] {
            if (++calls == 3) context.cancel();
            context.checkCancelled();
        });
        EXPECT_THROW(
            {
                AtomicFile file(path.string());
                const std::string block(1000, 'x');
                for (int i = 0; i < 16000; ++i, written += block.size()) file.stream() << block;
                file.commit();
            },
            Cancelled);
    }
    EXPECT_EQ(calls, 3);
    EXPECT_LE(written, 3 * kWriteChunkBytes + 1000);
    EXPECT_EQ(readFile(path), "old");

    // Writes larger than a chunk (a streamed STL's) skip the buffer: every byte still lands in
    // order, and the interrupter is still called once per full chunk.
    {
        const std::size_t c = kWriteChunkBytes;
        std::string expected;
        std::uint32_t state = 38;
        auto bytes = [&](std::size_t n) {
            std::string s(n, '\0');
            for (char& ch : s) ch = char((state = state * 1664525u + 1013904223u) >> 24);
            return s;
        };
        int chunkCalls = 0;
        const auto big = dir.path / "large.bin";
        {
            OutputTransaction transaction([&] { ++chunkCalls; });
            AtomicFile file(big.string());
            for (const std::size_t n : {std::size_t(10), 3 * c + 5, std::size_t(7), 2 * c, c, std::size_t(1)}) {
                const std::string s = bytes(n);
                file.stream().write(s.data(), std::streamsize(s.size()));
                expected += s;
            }
            file.commit();
            transaction.commit();
        }
        const std::string written = readFile(big);
        EXPECT_EQ(written.size(), expected.size());
        EXPECT_TRUE(written == expected) << "the bytes differ";
        EXPECT_EQ(std::size_t(chunkCalls), expected.size() / c);
    }
    EXPECT_EQ(temporariesUnder(dir.path), std::vector<std::string>{});

    // Each mesh format (STL formatted in parallel, OBJ and PLY through OpenMesh, 3MF packed by
    // lib3mf) stops on a cancel made before it starts, the old file kept.
    TriangleMesh mesh;
    for (int i = 0; i < 4000; ++i) {
        const float x = float(i % 64), y = float(i / 64);
        const auto base = std::uint32_t(mesh.points.size());
        mesh.points.insert(mesh.points.end(), {{x, y, 0.0f}, {x + 0.5f, y, 0.0f}, {x, y + 0.5f, 0.0f}});
        mesh.triangles.push_back({base, base + 1, base + 2});
    }
    JobContext cancelled;
    cancelled.cancel();
    for (const std::string name : {"m.stl", "m.obj", "m.ply", "m.3mf"}) {
        const auto file = dir.write(name, "old");
        OutputTransaction transaction([&] { cancelled.checkCancelled(); });
        EXPECT_THROW(writeMesh(mesh, file.string()), Cancelled) << name;
        EXPECT_EQ(readFile(file), "old") << name;
    }
    EXPECT_EQ(temporariesUnder(dir.path), std::vector<std::string>{});
    // Not cancelled, the same writes go through.
    for (const std::string name : {"m.stl", "m.obj", "m.ply", "m.3mf"}) {
        JobContext fine;
        OutputTransaction transaction([&] { fine.checkCancelled(); });
        writeMesh(mesh, (dir.path / name).string());
        transaction.commit();
        EXPECT_NE(readFile(dir.path / name), "old") << name;
    }
}

TEST(Adversarial, ASecondSignalRemovesTemporaryFoldersWithTheirFiles)
{
    // A slice folder's temporary (layers written into it) is registered as a folder: the second
    // signal's clean-up removes it with everything inside, subfolders included.
    TempDir dir;
    const auto folder = dir.path / "layers.tmp-1-0";
    std::filesystem::create_directories(folder / "sub");
    for (int i = 0; i < 300; ++i) std::ofstream(folder / ("layer" + std::to_string(i) + ".png")) << "png";
    std::ofstream(folder / "sub" / "deep.txt") << "x";
    registerTemporary(folder.string(), true);
    removeTemporaries();
    unregisterTemporary(folder.string());
    EXPECT_FALSE(std::filesystem::exists(folder));
    EXPECT_EQ(listFolder(dir.path), std::vector<std::string>{});
}

TEST(Adversarial, AMeshBeyondItsToleranceIsWarnedWithNumbersAndFailsWhenStrict)
{
    // Two crossed cylinders: their union's crease is left flat (a vertex cannot sit on both), so
    // the mesh strays about 0.1 mm at 0.25 mm voxels, past a tolerance of 0.01 mm.
    TempDir dir;
    const std::string recipe = R"(voxel: 0.25
domain: {box: [[-6, -6, -6], [6, 6, 6]]}
fields:
  a: {cylinder: {radius: 2, height: 10, axis: [1, 0, 0]}}
  b: {cylinder: {radius: 2, height: 10, axis: [0, 1, 0]}}
  u: {union: [a, b]}
result: u
)";
    auto run = [&](const std::string& name, const std::string& outputs, std::string* text,
                   const std::string& extra = "") {
        const auto path = dir.write(name + ".yaml", recipe + outputs);
        return runCommand(voxlatBinary() + " -q run " + path.string() + " --no-html --no-preview --out " +
                              (dir.path / name).string() + extra,
                          text);
    };
    std::string text;
    ASSERT_EQ(run("warn", "outputs: {mesh: {file: u.stl, tolerance: 0.01}}\n", &text), 0) << text;
    const auto report = nlohmann::json::parse(readFile(dir.path / "warn" / "report.json"));
    nlohmann::json warning;
    for (const auto& w : report["warnings"])
        if (w["code"] == "mesh_tolerance") warning = w;
    ASSERT_FALSE(warning.is_null()) << report["warnings"].dump();
    const double stray = report["mesh"]["deviation"]["max_mm"].get<double>();
    EXPECT_GT(stray, 0.01);
    EXPECT_EQ(warning["max_mm"].get<double>(), stray);
    EXPECT_EQ(warning["tolerance_mm"].get<double>(), 0.01);
    // The fixes: a tolerance the mesh meets, and a voxel that shrinks the stray below the
    // tolerance if it shrinks in proportion (with a margin).
    EXPECT_GE(warning["suggested_tolerance_mm"].get<double>(), stray);
    EXPECT_LE(warning["suggested_tolerance_mm"].get<double>(), 1.1 * stray);
    EXPECT_LE(warning["suggested_voxel_mm"].get<double>(), 0.25 * 0.01 / stray);
    EXPECT_NE(warning["message"].get<std::string>().find("use `voxel: " +
                                                         formatNumber(warning["suggested_voxel_mm"].get<double>())),
              std::string::npos)
        << warning["message"];
    EXPECT_EQ(report["mesh"]["tolerance_missed"]["suggested_voxel_mm"], warning["suggested_voxel_mm"]);
    // The stray does shrink with the voxel: at half the voxel it is smaller.
    ASSERT_EQ(run("half", "outputs: {mesh: {file: u.stl, tolerance: 0.01}}\n", &text, " --set voxel=0.125"), 0) << text;
    const double halfStray =
        nlohmann::json::parse(readFile(dir.path / "half" / "report.json"))["mesh"]["deviation"]["max_mm"].get<double>();
    EXPECT_LT(halfStray, 0.7 * stray);
    // `strict: on`: the same miss fails the job, exit 3, with the numbers, and nothing is written.
    EXPECT_EQ(run("strict", "outputs: {mesh: {file: u.stl, tolerance: 0.01, strict: on}}\n", &text), 3) << text;
    EXPECT_NE(text.find("strays up to " + formatNumber(stray) + " mm"), std::string::npos) << text;
    EXPECT_NE(text.find("or a tolerance of at least"), std::string::npos) << text;
    EXPECT_EQ(listFolder(dir.path / "strict"), std::vector<std::string>{});
    // Met, strict passes: a tolerance above the stray.
    EXPECT_EQ(run("met", "outputs: {mesh: {file: u.stl, tolerance: 0.2, strict: on}}\n", &text), 0) << text;
    // `strict` without a tolerance is bad input at its line.
    EXPECT_EQ(run("bad", "outputs: {mesh: {file: u.stl, strict: on}}\n", &text), 2) << text;
    EXPECT_NE(text.find("bad.yaml:8:"), std::string::npos) << text;
}

TEST(Adversarial, AnAbsurdSigmaRangeIsRefusedAtItsLine)
{
    // `optimize: {sigma: [0.3, 1e6]}` once picked sigma = 250 000 mm with a solid cell, then (with
    // the density check) ran for minutes on its first trial: a kernel far wider than the struts
    // gathers the struts of millions of cells per point. A sigma wider than the longest strut is
    // refused, at once, at the line that asks for it.
    TempDir dir;
    const std::string head = R"(material: form2
voxel: 0.25
domain: {box: [[0, 0, 0], [10, 10, 10]]}
properties: {cell: [5, 5, 5], origin: [5, 5, 5], resolution: 16}
fields:
  lattice:
    struts: {cell: x, size: 5}
    density: 0.2
)";
    for (const std::string& tail : {std::string("    kernel: {gaussian: {sigma: 1e6}}\n"),
                                    std::string("    kernel: {gaussian: {sigma: 0.3}}\n"
                                                "    optimize: {sigma: [0.3, 1e6], axis: z, samples: 3}\n")}) {
        const auto path = dir.write("r.yaml", head + tail + "result: lattice\n");
        std::string text;
        const auto start = std::chrono::steady_clock::now();
        EXPECT_EQ(runCommand(voxlatBinary() + " -q properties " + path.string(), &text), 2) << text;
        EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(), 20.0);
        EXPECT_NE(text.find("r.yaml:"), std::string::npos) << text;
        EXPECT_NE(text.find("wider than the frame's longest strut"), std::string::npos) << text;
    }
}
