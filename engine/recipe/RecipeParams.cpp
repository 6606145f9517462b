#include "engine/recipe/RecipeParams.h"

#include "engine/core/InputFiles.h"

#include "engine/recipe/Recipe.h"
#include "engine/recipe/Sha256.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <sstream>

namespace voxlat {

namespace {

const std::vector<std::string> kIncludeKeys{"params", "fields", "include"};
const std::vector<std::string> kParamKeys{"default", "min", "max", "doc"};

void collect(const YAML::Node& node, const std::string& file, std::vector<std::pair<YAML::Node, std::string>>& out)
{
    out.emplace_back(node, file);
    if (node.IsMap())
        for (auto it = node.begin(); it != node.end(); ++it) {
            out.emplace_back(it->first, file);
            collect(it->second, file, out);
        }
    else if (node.IsSequence())
        for (auto it = node.begin(); it != node.end(); ++it) collect(*it, file, out);
}

bool isName(const std::string& s)
{
    if (s.empty() || !(std::isalpha(static_cast<unsigned char>(s[0])) || s[0] == '_')) return false;
    return std::all_of(s.begin(), s.end(),
                       [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_'; });
}

bool isNumber(const YAML::Node& n)
{
    if (!n.IsScalar() || n.Tag() == "!") return false;
    try {
        n.as<double>();
        return true;
    } catch (const YAML::Exception&) {
        return false;
    }
}

bool isBoolean(const YAML::Node& n)
{
    if (!n.IsScalar() || n.Tag() == "!") return false;
    const std::string& s = n.Scalar();
    return s == "true" || s == "false";
}

ParamKind kindOf(const YAML::Node& n)
{
    if (n.IsSequence()) return ParamKind::List;
    if (isNumber(n)) return ParamKind::Number;
    if (isBoolean(n)) return ParamKind::Boolean;
    return ParamKind::Text;
}

const char* kindName(ParamKind k)
{
    switch (k) {
        case ParamKind::Number:
            return "a number";
        case ParamKind::Boolean:
            return "true or false";
        case ParamKind::Text:
            return "a word";
        case ParamKind::List:
            return "a list";
    }
    return "?";
}

/// The value node of parameter @a entry (short form `name: value`, long form `{default: ...}`).
YAML::Node valueOf(const YAML::Node& entry)
{
    return entry.IsMap() ? entry["default"] : entry;
}

/// The parameter a whole scalar refers to (`$name` or `${name}`), or "".
std::string wholeReference(const std::string& s)
{
    if (s.size() < 2 || s[0] != '$') return "";
    if (s[1] == '{') return (s.back() == '}' && isName(s.substr(2, s.size() - 3))) ? s.substr(2, s.size() - 3) : "";
    return isName(s.substr(1)) ? s.substr(1) : "";
}

class Substituter {
public:
    Substituter(const std::map<std::string, YAML::Node>& values, const std::map<std::string, ParamDecl>& declared,
                const std::shared_ptr<RecipeSource>& source)
        : mValues(values), mDeclared(declared), mSource(source)
    {
    }

    /// Substitutes below @a node; @a top skips the root's own `params:` block.
    void walk(YAML::Node node, bool equation, bool top = false)
    {
        if (node.IsMap()) {
            for (auto it = node.begin(); it != node.end(); ++it) {
                const std::string key = it->first.Scalar();
                if (top && key == "params") continue;
                const bool eq = key == "expr" || key == "vector";
                if (it->second.IsScalar()) {
                    if (auto replaced = substitute(it->second, eq)) it->second = *replaced;
                } else {
                    walk(it->second, eq);
                }
            }
        } else if (node.IsSequence()) {
            for (std::size_t i = 0; i < node.size(); ++i) {
                YAML::Node item = node[i];
                if (item.IsScalar()) {
                    if (auto replaced = substitute(item, equation)) node[i] = *replaced;
                } else {
                    walk(item, equation);
                }
            }
        }
    }

private:
    [[noreturn]] void unknown(const YAML::Node& at, const std::string& name) const
    {
        std::vector<std::string> names;
        for (const auto& [n, v] : mValues) names.push_back(n);
        std::string message = "unknown parameter `$" + name + "`";
        const std::string guess = closestMatch(name, names);
        if (!guess.empty()) message += "; did you mean `$" + guess + "`?";
        message += names.empty() ? " (declare it under `params:`, e.g. `params: {" + name + ": 1}`)"
                                 : " (parameters: " + joinWords(names) + ")";
        RecipeNode(at, mSource, "parameter reference").fail(message);
    }

    std::optional<YAML::Node> substitute(const YAML::Node& scalar, bool equation)
    {
        const std::string& text = scalar.Scalar();
        if (text.find('$') == std::string::npos) return std::nullopt;
        if (const std::string name = wholeReference(text); !name.empty()) {
            auto it = mValues.find(name);
            if (it == mValues.end()) unknown(scalar, name);
            YAML::Node copy = YAML::Clone(it->second);
            const std::string useSite = RecipeNode(scalar, mSource, "").where();
            mSource->substituted.emplace_back(
                copy, useSite + " (`$" + name + "`, declared at " + mDeclared.at(name).where + ")");
            return copy;
        }
        if (equation) return std::nullopt;  // equations read `$name` themselves, with carets
        // ${name} inside text: file names like part_${cell}.stl.
        std::string out;
        std::size_t pos = 0;
        bool changed = false;
        while (pos < text.size()) {
            const std::size_t open = text.find("${", pos);
            if (open == std::string::npos) break;
            const std::size_t close = text.find('}', open);
            if (close == std::string::npos) break;
            const std::string name = text.substr(open + 2, close - open - 2);
            if (!isName(name)) break;
            auto it = mValues.find(name);
            if (it == mValues.end()) unknown(scalar, name);
            if (!it->second.IsScalar())
                RecipeNode(scalar, mSource, "parameter reference")
                    .fail("`${" + name + "}` inside text needs a single value, but the parameter is a list");
            out += text.substr(pos, open - pos) + it->second.Scalar();
            pos = close + 1;
            changed = true;
        }
        if (!changed) return std::nullopt;
        out += text.substr(pos);
        YAML::Node replaced(out);
        mSource->substituted.emplace_back(replaced, RecipeNode(scalar, mSource, "").where());
        return replaced;
    }

    const std::map<std::string, YAML::Node>& mValues;
    const std::map<std::string, ParamDecl>& mDeclared;
    std::shared_ptr<RecipeSource> mSource;
};

void mergeFile(YAML::Node root, const std::filesystem::path& file, RecipeSource& source)
{
    const auto included = std::make_shared<RecipeSource>();
    included->path = file.string();
    YAML::Node sub = loadYaml(readInputFile(file, std::uintmax_t(16) << 20, "included file"), file.string());
    if (!sub.IsMap()) throw InputError(file.string() + ":1:1: an included file is a map with `params:` and `fields:`");
    const RecipeNode top(sub, included, "included file");
    top.checkKeys(kIncludeKeys);
    mergeIncludes(sub, file.string(), file.parent_path(), source);  // nested includes first
    for (const char* block : {"params", "fields"}) {
        if (!sub[block]) continue;
        const RecipeNode from = top[block];
        if (!from.isMap()) from.fail("expected a map of names");
        if (!root[block]) root[block] = YAML::Node(YAML::NodeType::Map);
        YAML::Node into = root[block];
        for (auto it = sub[block].begin(); it != sub[block].end(); ++it) {
            const std::string name = it->first.Scalar();
            if (into[name]) {
                if (std::string(block) == "params") continue;  // the including recipe's default wins
                RecipeNode(it->first, included, "included file")
                    .fail("field `" + name + "` is also defined by the recipe that includes this file; rename one");
            }
            into[name] = it->second;
            collect(it->second, file.string(), source.included);
            source.included.emplace_back(it->first, file.string());
        }
    }
}

}  // namespace

void mergeIncludes(YAML::Node root, const std::string& path, const std::filesystem::path& folder, RecipeSource& source)
{
    if (!root.IsMap() || !root["include"]) return;
    const auto here = std::make_shared<RecipeSource>();
    here->path = path;
    const RecipeNode list(root["include"], here, "`include`");
    std::vector<RecipeNode> names;
    if (list.isScalar())
        names.push_back(list);
    else if (list.isSequence())
        for (std::size_t i = 0; i < list.size(); ++i) names.push_back(list.at(i));
    else
        list.fail("expected a file name or a list of file names, like [cells.yaml]");
    static thread_local std::vector<std::filesystem::path> chain;  // files being included, outermost first
    std::error_code ec;
    const bool outermost = chain.empty();
    if (outermost) chain.push_back(std::filesystem::weakly_canonical(std::filesystem::absolute(path, ec), ec));
    try {
        for (const RecipeNode& name : names) {
            const std::string text = name.string();
            const std::filesystem::path p =
                std::filesystem::path(text).is_absolute() ? std::filesystem::path(text) : folder / text;
            const std::string ext = p.extension().string();
            if (ext != ".yaml" && ext != ".yml")
                name.fail("an included file is a recipe library ending in .yaml or .yml, got `" + text + "`");
            if (!std::filesystem::is_regular_file(p, ec))
                name.fail("cannot find `" + p.string() + "` (paths are relative to the including file's folder)");
            const std::filesystem::path canonical = std::filesystem::weakly_canonical(p, ec);
            if (std::find(chain.begin(), chain.end(), canonical) != chain.end()) {
                std::string cycle;
                for (const auto& c : chain) cycle += c.filename().string() + " -> ";
                name.fail("includes form a cycle: " + cycle + canonical.filename().string());
            }
            chain.push_back(canonical);
            mergeFile(root, p, source);
            chain.pop_back();
        }
    } catch (...) {
        chain.clear();
        throw;
    }
    if (outermost) chain.clear();
    root.remove("include");
}

std::map<std::string, ParamDecl> declaredParams(const YAML::Node& root, const std::shared_ptr<RecipeSource>& source)
{
    std::map<std::string, ParamDecl> out;
    if (!root.IsMap() || !root["params"]) return out;
    const RecipeNode params(root["params"], source, "`params`");
    if (!params.isMap()) params.fail("expected a map of parameters with defaults, like `params: {cell: 8, t: 0.3}`");
    for (auto it = root["params"].begin(); it != root["params"].end(); ++it) {
        const std::string name = it->first.Scalar();
        const RecipeNode entry(it->second, source, "parameter `" + name + "`");
        if (!isName(name))
            RecipeNode(it->first, source, "`params`")
                .fail("parameter names are letters, digits and _ (starting with a letter), got `" + name + "`");
        ParamDecl d;
        // (Assigning to a yaml-cpp node would overwrite the tree, so the value is chosen once.)
        if (entry.isMap()) entry.checkKeys(kParamKeys);
        const YAML::Node value = entry.isMap() ? entry["default"].yaml() : it->second;
        if (entry.isMap()) {
            if (entry.has("min")) d.min = entry["min"].number();
            if (entry.has("max")) d.max = entry["max"].number();
        } else if (!entry.isScalar() && !entry.isSequence()) {
            entry.fail("expected a default value (a number, a word or a list) or {default: ..., min: ..., max: ...}");
        }
        d.kind = kindOf(value);
        if ((d.min || d.max) && d.kind != ParamKind::Number) entry.fail("`min:` and `max:` need a number default");
        d.where = RecipeNode(value, source, "").where();
        out[name] = d;
    }
    return out;
}

std::string routeAssignment(const YAML::Node& root, const std::string& assignment, const std::string& path,
                            const std::vector<std::string>& topKeys)
{
    const auto eq = assignment.find('=');
    if (eq == std::string::npos || eq == 0) return assignment;  // applyOverride explains the form
    const std::string key = assignment.substr(0, eq);
    if (key.find('.') != std::string::npos) return assignment;
    if (std::find(topKeys.begin(), topKeys.end(), key) != topKeys.end()) return assignment;
    const YAML::Node params = root["params"];
    if (params && params.IsMap() && params[key]) {
        const bool longForm = params[key].IsMap();
        return "params." + key + (longForm ? ".default" : "") + assignment.substr(eq);
    }
    std::vector<std::string> names;
    if (params && params.IsMap())
        for (auto it = params.begin(); it != params.end(); ++it) names.push_back(it->first.Scalar());
    std::string message = path + ": --set " + assignment + ": no parameter or top-level key `" + key + "`";
    std::vector<std::string> candidates = names;
    candidates.insert(candidates.end(), topKeys.begin(), topKeys.end());
    const std::string guess = closestMatch(key, candidates);
    if (!guess.empty()) message += "; did you mean `" + guess + "`?";
    message += names.empty() ? " (the recipe declares no `params:`; use a key path such as fields.NAME.KEY)"
                             : " (parameters: " + joinWords(names) + "; or a key path such as fields.NAME.KEY)";
    throw InputError(message);
}

std::map<std::string, YAML::Node> substituteParams(YAML::Node root, const std::shared_ptr<RecipeSource>& source,
                                                   const std::map<std::string, ParamDecl>& declared)
{
    std::map<std::string, YAML::Node> values;
    if (root["params"]) {
        for (auto it = root["params"].begin(); it != root["params"].end(); ++it) {
            const std::string name = it->first.Scalar();
            const YAML::Node value = valueOf(it->second);
            const RecipeNode v(value, source, "parameter `" + name + "`");
            const auto found = declared.find(name);
            if (found == declared.end()) v.fail("the recipe declares no parameter `" + name + "` under `params:`");
            const ParamDecl& d = found->second;
            if (!value) RecipeNode(it->second, source, "parameter `" + name + "`").fail("missing key `default`");
            const ParamKind k = kindOf(value);
            const bool ok = d.kind == k || (d.kind == ParamKind::Text && k != ParamKind::List);
            if (!ok)
                v.fail(std::string("expected ") + kindName(d.kind) + " like its default (declared at " + d.where +
                       "), got `" + (value.IsScalar() ? value.Scalar() : std::string("a list")) + "`");
            if (d.kind == ParamKind::Number) {
                const double x = v.number();
                if (d.min && x < *d.min)
                    v.fail("must be at least " + std::to_string(*d.min) + ", got " + value.Scalar());
                if (d.max && x > *d.max)
                    v.fail("must be at most " + std::to_string(*d.max) + ", got " + value.Scalar());
            }
            values[name] = value;
        }
    }
    Substituter(values, declared, source).walk(root, false, true);
    return values;
}

namespace {
nlohmann::json toJson(const YAML::Node& node)
{
    if (node.IsMap()) {
        nlohmann::json o = nlohmann::json::object();
        for (auto it = node.begin(); it != node.end(); ++it) o[it->first.Scalar()] = toJson(it->second);
        return o;
    }
    if (node.IsSequence()) {
        nlohmann::json a = nlohmann::json::array();
        for (auto it = node.begin(); it != node.end(); ++it) a.push_back(toJson(*it));
        return a;
    }
    if (!node.IsScalar()) return nullptr;
    const std::string& s = node.Scalar();
    if (node.Tag() == "!") return s;  // quoted: always text
    if (s == "true") return true;
    if (s == "false") return false;
    if (s == "null" || s == "~") return nullptr;
    // Integers stay integers; other numbers go through double (so 0.10 and 0.1 hash the same).
    char* end = nullptr;
    const long long i = std::strtoll(s.c_str(), &end, 10);
    if (!s.empty() && end == s.c_str() + s.size()) return i;
    if (isNumber(node)) {
        const double d = node.as<double>();
        // 5.0 and 5 are the same number: integral values are written as integers.
        if (std::isfinite(d) && d == std::floor(d) && std::abs(d) < 9.0e15) return static_cast<long long>(d);
        if (std::isfinite(d)) return d;
    }
    return s;
}
}  // namespace

nlohmann::json canonicalRecipe(const Recipe& recipe)
{
    nlohmann::json j = toJson(recipe.root);
    if (!recipe.params.empty()) {
        nlohmann::json p = nlohmann::json::object();
        for (const auto& [name, value] : recipe.params) p[name] = toJson(value);
        j["params"] = p;
    }
    j.erase("include");
    return j;
}

std::string recipeHash(const Recipe& recipe)
{
    return sha256Hex(canonicalRecipe(recipe).dump());
}

}  // namespace voxlat
