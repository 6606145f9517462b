#include "engine/recipe/RecipeNode.h"

#include "fields/core/EditDistance.h"

#include <yaml-cpp/eventhandler.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <sstream>

namespace voxlat {

RecipeNode::RecipeNode(YAML::Node node, std::shared_ptr<const RecipeSource> source, std::string context)
    : mNode(std::move(node)), mSource(std::move(source)), mContext(std::move(context))
{
}

std::string RecipeNode::where() const
{
    for (const auto& [node, label] : mSource->substituted)
        if (node.is(mNode)) return label;
    for (const YAML::Node& o : mSource->overrides)
        if (o.is(mNode)) return mSource->path + " (from --set)";
    std::string path = mSource->path;
    for (const auto& [node, file] : mSource->included)
        if (node.is(mNode)) {
            path = file;
            break;
        }
    const YAML::Mark mark = mNode.Mark();
    if (mark.is_null() || mark.line < 0) return path;
    return path + ":" + std::to_string(mark.line + 1) + ":" + std::to_string(mark.column + 1);
}

void RecipeNode::fail(const std::string& message) const
{
    throw InputError(where() + ": " + mContext + ": " + message);
}

RecipeNode RecipeNode::operator[](const std::string& key) const
{
    if (!mNode.IsMap()) fail("expected a map with key `" + key + "`");
    YAML::Node child = mNode[key];
    if (!child) fail("missing key `" + key + "`");
    return RecipeNode(child, mSource, mContext + " `" + key + "`");
}

RecipeNode RecipeNode::at(std::size_t index) const
{
    return RecipeNode(mNode[index], mSource, mContext + " item " + std::to_string(index + 1));
}

bool RecipeNode::isNumber() const
{
    if (!mNode.IsScalar()) return false;
    try {
        (void)mNode.as<double>();
        return true;
    } catch (const YAML::Exception&) {
        return false;
    }
}

double RecipeNode::number() const
{
    if (!mNode.IsScalar()) fail("expected a number");
    double v = 0.0;
    try {
        v = mNode.as<double>();
    } catch (const YAML::Exception&) {
        fail("expected a number, got `" + mNode.Scalar() + "`");
    }
    if (!std::isfinite(v)) fail("expected a finite number, got `" + mNode.Scalar() + "`");
    return v;
}

double RecipeNode::positiveNumber() const
{
    const double v = number();
    if (!(v > 0.0)) fail("must be greater than zero, got " + mNode.Scalar());
    return v;
}

int RecipeNode::axis() const
{
    const std::string a = string();
    if (a == "x" || a == "y" || a == "z") return a[0] - 'x';
    fail("the axis is x, y or z, got `" + a + "`");
}

std::string RecipeNode::string() const
{
    if (!mNode.IsScalar()) fail("expected a word or a file name");
    return mNode.Scalar();
}

bool RecipeNode::boolean() const
{
    if (mNode.IsScalar()) {
        try {
            return mNode.as<bool>();
        } catch (const YAML::Exception&) {
        }
    }
    fail("expected true or false");
}

Vec3d RecipeNode::vec3() const
{
    if (!mNode.IsSequence() || mNode.size() != 3) fail("expected a list of three numbers, like [0, 0, 1]");
    return {at(0).number(), at(1).number(), at(2).number()};
}

Vec3d RecipeNode::scalarOrVec3() const
{
    if (mNode.IsScalar()) return Vec3d(number());
    return vec3();
}

Box3 RecipeNode::box() const
{
    if (!mNode.IsSequence() || mNode.size() != 2) fail("expected [[x0, y0, z0], [x1, y1, z1]]");
    Box3 b{at(0).vec3(), at(1).vec3()};
    for (int a = 0; a < 3; ++a)
        if (!(b.max[a] > b.min[a])) fail("the box's second corner must be above the first on every axis");
    return b;
}

void RecipeNode::checkKeys(const std::vector<std::string>& allowed) const
{
    if (!mNode.IsMap()) fail("expected a map");
    for (auto it = mNode.begin(); it != mNode.end(); ++it) {
        const std::string key = it->first.Scalar();
        if (std::find(allowed.begin(), allowed.end(), key) != allowed.end()) continue;
        std::string message = "unknown key `" + key + "`";
        const std::string guess = closestMatch(key, allowed);
        if (!guess.empty()) message += "; did you mean `" + guess + "`?";
        RecipeNode(it->first, mSource, mContext).fail(message + " (valid keys: " + joinWords(allowed) + ")");
    }
}

std::string joinWords(const std::vector<std::string>& words)
{
    std::string s;
    for (const auto& w : words) s += (s.empty() ? "" : ", ") + w;
    return s;
}

std::string closestMatch(const std::string& word, const std::vector<std::string>& candidates)
{
    std::string best;
    std::size_t bestDistance = std::max<std::size_t>(2, word.size() / 3) + 1;
    for (const std::string& c : candidates) {
        if (const std::size_t d = editDistance(word, c); d < bestDistance) {
            bestDistance = d;
            best = c;
        }
    }
    return best;
}

namespace {
/// Counts @a node's expanded nodes into @a count; false once past a limit.
bool countYaml(const YAML::Node& node, int depth, std::size_t& count)
{
    if (++count > kMaxYamlNodes || depth > kMaxYamlDepth) return false;
    if (node.IsMap()) {
        for (auto it = node.begin(); it != node.end(); ++it)
            if (!countYaml(it->first, depth + 1, count) || !countYaml(it->second, depth + 1, count)) return false;
    } else if (node.IsSequence()) {
        for (auto it = node.begin(); it != node.end(); ++it)
            if (!countYaml(*it, depth + 1, count)) return false;
    }
    return true;
}
}  // namespace

void checkYamlSize(const YAML::Node& root, const std::string& name)
{
    std::size_t count = 0;
    if (!countYaml(root, 0, count))
        throw InputError(name + ": the YAML expands to more than " + std::to_string(kMaxYamlNodes) +
                         " nodes or nests deeper than " + std::to_string(kMaxYamlDepth) +
                         " levels (nested aliases?); a recipe is a small map of fields");
}

namespace {

std::string markText(const YAML::Mark& m)
{
    return std::to_string(m.line + 1) + ":" + std::to_string(m.column + 1);
}

/// Refuses a map that gives one key twice (yaml-cpp keeps both; a lookup finds the first, so the
/// second would be ignored without a word).
void checkKeysOnce(const YAML::Node& node, const std::string& name, int depth)
{
    if (depth > kMaxYamlDepth) return;
    if (node.IsMap()) {
        std::map<std::string, YAML::Mark> keys;
        for (auto it = node.begin(); it != node.end(); ++it) {
            if (it->first.IsScalar()) {
                const auto [at, fresh] = keys.emplace(it->first.Scalar(), it->first.Mark());
                if (!fresh)
                    throw InputError(name + ":" + markText(it->first.Mark()) + ": the key `" + it->first.Scalar() +
                                     "` is given twice in one map (first at " + markText(at->second) +
                                     "); only one can count: keep one of them");
            }
            checkKeysOnce(it->second, name, depth + 1);
        }
    } else if (node.IsSequence()) {
        for (auto it = node.begin(); it != node.end(); ++it) checkKeysOnce(*it, name, depth + 1);
    }
}

/// Counts a YAML stream's documents without building them, to refuse a second one. yaml-cpp
/// 0.7's `LoadAll` loops for ever on some malformed streams (a parser that yields an empty document
/// without consuming a token; fixed upstream in yaml-cpp PR #1319, found here by fuzz_profile): an
/// empty document ends the walk here, as it does upstream since that fix.
class DocumentProbe final : public YAML::EventHandler {
public:
    YAML::Mark first;      ///< where the current document's content starts
    bool content = false;  ///< the current document holds more than a null root
    void OnDocumentStart(const YAML::Mark&) override { content = false; }
    void OnDocumentEnd() override {}
    void OnNull(const YAML::Mark&, YAML::anchor_t) override {}
    void OnAlias(const YAML::Mark& mark, YAML::anchor_t) override { seen(mark); }
    void OnScalar(const YAML::Mark& mark, const std::string&, YAML::anchor_t, const std::string&) override
    {
        seen(mark);
    }
    void OnSequenceStart(const YAML::Mark& mark, const std::string&, YAML::anchor_t, YAML::EmitterStyle::value) override
    {
        seen(mark);
    }
    void OnSequenceEnd() override {}
    void OnMapStart(const YAML::Mark& mark, const std::string&, YAML::anchor_t, YAML::EmitterStyle::value) override
    {
        seen(mark);
    }
    void OnMapEnd() override {}

private:
    void seen(const YAML::Mark& mark)
    {
        if (!content) first = mark;
        content = true;
    }
};

/// Refuses a stream with a second document that holds anything: a file holds one recipe, and a
/// second document would be ignored. Throws yaml-cpp's ParserException on a syntax error.
void checkOneDocument(const std::string& text, const std::string& name)
{
    std::istringstream stream(text);
    YAML::Parser parser(stream);
    DocumentProbe probe;
    for (int document = 0; parser.HandleNextDocument(probe); ++document) {
        if (!probe.content) break;  // an empty document: the end (see DocumentProbe)
        if (document > 0)
            throw InputError(name + ":" + markText(probe.first) +
                             ": a second YAML document (after `---`); a file holds one, the rest would be ignored: "
                             "remove the `---` or move that part to a file of its own");
    }
}

}  // namespace

YAML::Node loadYaml(const std::string& text, const std::string& name)
{
    YAML::Node root;
    try {
        checkOneDocument(text, name);
        root = YAML::Load(text);
    } catch (const YAML::ParserException& e) {
        throw InputError(name + ":" + markText(e.mark) + ": not valid YAML: " + e.msg);
    }
    checkYamlSize(root, name);  // bounds the walk below
    checkKeysOnce(root, name, 0);
    return root;
}

}  // namespace voxlat
