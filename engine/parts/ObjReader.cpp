#include "engine/parts/ObjReader.h"

#include "engine/core/Errors.h"

#include <charconv>
#include <cmath>
#include <cstdint>
#include <string_view>
#include <vector>

namespace voxlat {

namespace {

bool isSpace(char c)
{
    return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v';
}

/// The next whitespace-separated token of @a line from @a pos (empty at the end).
std::string_view nextToken(std::string_view line, std::size_t& pos)
{
    while (pos < line.size() && isSpace(line[pos])) ++pos;
    const std::size_t start = pos;
    while (pos < line.size() && !isSpace(line[pos])) ++pos;
    return line.substr(start, pos - start);
}

class ObjParser {
public:
    ObjParser(const std::string& shown) : mShown(shown) {}

    void parseLine(std::string_view line, std::uint64_t number)
    {
        mLine = number;
        if (const std::size_t hash = line.find('#'); hash != std::string_view::npos) line = line.substr(0, hash);
        std::size_t pos = 0;
        const std::string_view keyword = nextToken(line, pos);
        if (keyword == "v")
            readVertex(line, pos);
        else if (keyword == "f")
            readFace(line, pos);
        // Anything else (texture and normal vertices, groups, materials, lines, points) does
        // not change the solid.
    }

    TriangleMesh take() { return std::move(mMesh); }

private:
    [[noreturn]] void fail(const std::string& why) const
    {
        throw InputError(mShown + ":" + std::to_string(mLine) + ": corrupted OBJ: " + why);
    }

    void readVertex(std::string_view line, std::size_t& pos)
    {
        openvdb::Vec3f p;
        for (int a = 0; a < 3; ++a) {
            const std::string_view token = nextToken(line, pos);
            double v = 0.0;
            const auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), v);
            if (token.empty() || ec != std::errc() || end != token.data() + token.size())
                fail(std::string("a vertex (`v`) needs three numbers x y z; coordinate ") + "xyz"[a] +
                     (token.empty() ? " is missing" : " is not a number"));
            if (!std::isfinite(v) || std::abs(v) > 3.0e38)
                fail(std::string("vertex coordinate ") + "xyz"[a] + " is not a finite number");
            p[a] = float(v);
        }
        mMesh.points.push_back(p);
    }

    /// The vertex a face corner names: the number before its first '/'.
    std::uint32_t corner(std::string_view token) const
    {
        const std::string_view index = token.substr(0, token.find('/'));
        long long i = 0;
        const auto [end, ec] = std::from_chars(index.data(), index.data() + index.size(), i);
        if (index.empty() || ec != std::errc() || end != index.data() + index.size())
            fail("a face corner must start with a vertex number (`f 1 2 3` or `f 1/1/1 2/2/2 3/3/3`)");
        const long long n = static_cast<long long>(mMesh.points.size());
        const long long resolved = i > 0 ? i - 1 : n + i;  // negative: counted back from the last vertex
        if (i == 0 || resolved < 0 || resolved >= n)
            fail("a face refers to vertex " + std::to_string(i) + ", but " + std::to_string(n) +
                 " vertices are defined before it (vertices count from 1)");
        return std::uint32_t(resolved);
    }

    void readFace(std::string_view line, std::size_t& pos)
    {
        mCorners.clear();
        for (std::string_view token = nextToken(line, pos); !token.empty(); token = nextToken(line, pos))
            mCorners.push_back(corner(token));
        if (mCorners.size() < 3)
            fail("a face (`f`) needs at least three corners, got " + std::to_string(mCorners.size()));
        for (std::size_t k = 1; k + 1 < mCorners.size(); ++k)
            mMesh.triangles.emplace_back(mCorners[0], mCorners[k], mCorners[k + 1]);
    }

    const std::string& mShown;
    std::uint64_t mLine = 0;
    TriangleMesh mMesh;
    std::vector<std::uint32_t> mCorners;
};

}  // namespace

TriangleMesh readObj(const std::string& bytes, const std::string& shown)
{
    if (bytes.find('\0') != std::string::npos)
        throw InputError(shown + ": corrupted OBJ: OBJ is text, and this file holds binary bytes");
    ObjParser parser(shown);
    std::uint64_t number = 0;
    std::size_t start = 0;
    while (start < bytes.size()) {
        std::size_t end = bytes.find('\n', start);
        if (end == std::string::npos) end = bytes.size();
        parser.parseLine(std::string_view(bytes).substr(start, end - start), ++number);
        start = end + 1;
    }
    return parser.take();
}

}  // namespace voxlat
