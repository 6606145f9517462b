#include "fields/expr/Expression.h"
#include "fields/core/EditDistance.h"

#include "fields/core/Scratch.h"
#include "fields/expr/ExprMath.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <map>
#include <numbers>
#include <sstream>
#include <tuple>
#include <type_traits>

namespace voxlat {

using Op = ExprProgram::Op;
using Instr = ExprProgram::Instr;

namespace {

struct Function {
    const char* name;
    Op op;
    int minArgs, maxArgs;  ///< maxArgs -1: any number (folded left)
};

constexpr Function kFunctions[] = {
    {"sin", Op::Sin, 1, 1},     {"cos", Op::Cos, 1, 1},     {"tan", Op::Tan, 1, 1},
    {"asin", Op::Asin, 1, 1},   {"acos", Op::Acos, 1, 1},   {"atan", Op::Atan, 1, 1},
    {"atan2", Op::Atan2, 2, 2}, {"sinh", Op::Sinh, 1, 1},   {"cosh", Op::Cosh, 1, 1},
    {"tanh", Op::Tanh, 1, 1},   {"abs", Op::Abs, 1, 1},     {"sign", Op::Sign, 1, 1},
    {"floor", Op::Floor, 1, 1}, {"ceil", Op::Ceil, 1, 1},   {"min", Op::Min, 2, -1},
    {"max", Op::Max, 2, -1},    {"sqrt", Op::Sqrt, 1, 1},   {"exp", Op::Exp, 1, 1},
    {"log", Op::Log, 1, 1},     {"pow", Op::Pow, 2, 2},     {"mod", Op::Mod, 2, 2},
    {"hypot", Op::Hypot, 2, 2}, {"clamp", Op::Clamp, 3, 3}, {"smoothstep", Op::Smoothstep, 3, 3},
    {"mix", Op::Mix, 3, 3},
};

struct Constant {
    const char* name;
    double value;
};
constexpr Constant kConstants[] = {{"pi", std::numbers::pi}, {"tau", 2 * std::numbers::pi}, {"e", std::numbers::e}};

const char* opName(Op op)
{
    if (op == Op::Const) return "const";
    if (op == Op::X) return "x";
    if (op == Op::Y) return "y";
    if (op == Op::Z) return "z";
    if (op == Op::Input) return "input";
    if (op == Op::Neg) return "neg";
    if (op == Op::Add) return "add";
    if (op == Op::Sub) return "sub";
    if (op == Op::Mul) return "mul";
    if (op == Op::Div) return "div";
    if (op == Op::PowInt) return "powi";
    for (const Function& f : kFunctions)
        if (f.op == op) return f.name;
    return "?";
}

int arity(Op op)
{
    switch (op) {
        case Op::Const:
        case Op::X:
        case Op::Y:
        case Op::Z:
        case Op::Input:
            return 0;
        case Op::Add:
        case Op::Sub:
        case Op::Mul:
        case Op::Div:
        case Op::Pow:
        case Op::Mod:
        case Op::Min:
        case Op::Max:
        case Op::Atan2:
        case Op::Hypot:
            return 2;
        case Op::Clamp:
        case Op::Smoothstep:
        case Op::Mix:
            return 3;
        default:
            return 1;
    }
}

/// Applies one instruction elementwise over @a n values. Operands are arrays of the same length.
template <typename T>
void apply(const Instr& in, T* o, const T* a, const T* b, const T* c, std::size_t n)
{
    namespace m = exprmath;
    switch (in.op) {
        case Op::Const:
        case Op::X:
        case Op::Y:
        case Op::Z:
        case Op::Input:
            break;  // handled by the caller
        case Op::Neg:
            for (std::size_t i = 0; i < n; ++i) o[i] = -a[i];
            break;
        case Op::Add:
            for (std::size_t i = 0; i < n; ++i) o[i] = a[i] + b[i];
            break;
        case Op::Sub:
            for (std::size_t i = 0; i < n; ++i) o[i] = a[i] - b[i];
            break;
        case Op::Mul:
            for (std::size_t i = 0; i < n; ++i) o[i] = a[i] * b[i];
            break;
        case Op::Div:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::div(a[i], b[i]);
            break;
        case Op::PowInt:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::powInt(a[i], in.n);
            break;
        case Op::Pow:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::pow(a[i], b[i]);
            break;
        case Op::Mod:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::mod(a[i], b[i]);
            break;
        case Op::Min:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::min(a[i], b[i]);
            break;
        case Op::Max:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::max(a[i], b[i]);
            break;
        case Op::Abs:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::abs(a[i]);
            break;
        case Op::Sign:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::sign(a[i]);
            break;
        case Op::Floor:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::floor(a[i]);
            break;
        case Op::Ceil:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::ceil(a[i]);
            break;
        case Op::Sqrt:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::sqrt(a[i]);
            break;
        case Op::Exp:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::exp(a[i]);
            break;
        case Op::Log:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::log(a[i]);
            break;
        case Op::Sin:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::sin(a[i]);
            break;
        case Op::Cos:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::cos(a[i]);
            break;
        case Op::Tan:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::tan(a[i]);
            break;
        case Op::Asin:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::asin(a[i]);
            break;
        case Op::Acos:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::acos(a[i]);
            break;
        case Op::Atan:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::atan(a[i]);
            break;
        case Op::Atan2:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::atan2(a[i], b[i]);
            break;
        case Op::Sinh:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::sinh(a[i]);
            break;
        case Op::Cosh:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::cosh(a[i]);
            break;
        case Op::Tanh:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::tanh(a[i]);
            break;
        case Op::Hypot:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::hypot(a[i], b[i]);
            break;
        case Op::Clamp:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::min(m::max(a[i], b[i]), c[i]);
            break;
        case Op::Smoothstep:
            for (std::size_t i = 0; i < n; ++i) o[i] = m::smoothstep(a[i], b[i], c[i]);
            break;
        case Op::Mix:
            for (std::size_t i = 0; i < n; ++i) o[i] = a[i] + (b[i] - a[i]) * c[i];
            break;
    }
    if constexpr (std::is_same_v<T, Interval>)
        for (std::size_t i = 0; i < n; ++i) o[i] = m::sanitize(o[i]);
}

/// Recursive-descent parser that emits instructions as it goes, folding constants and sharing
/// repeated sub-expressions.
class Compiler {
public:
    Compiler(const std::string& text, const ExprResolver& resolve, std::vector<Instr>& code, int& inputCount)
        : mText(text), mResolve(resolve), mCode(code), mInputCount(inputCount)
    {
    }

    int compile()
    {
        skipSpace();
        if (mPos >= mText.size()) throw ExprError("the equation is empty", 0);
        const int root = parseAdditive();
        skipSpace();
        if (mPos < mText.size()) {
            if (mText[mPos] == ')') throw ExprError("unexpected `)`: there is no `(` to close", mPos);
            throw ExprError(
                std::string("unexpected `") + mText[mPos] + "` after a complete expression; missing an operator?",
                mPos);
        }
        return root;
    }

private:
    void skipSpace()
    {
        while (mPos < mText.size() && std::isspace(static_cast<unsigned char>(mText[mPos]))) ++mPos;
    }
    bool accept(const char* token)
    {
        skipSpace();
        const std::size_t len = std::strlen(token);
        if (mText.compare(mPos, len, token) != 0) return false;
        mPos += len;
        return true;
    }
    static bool isNameStart(char c) { return std::isalpha(static_cast<unsigned char>(c)) || c == '_'; }
    static bool isNameChar(char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_'; }

    int emit(Instr in)
    {
        const int n = arity(in.op);
        const int ops[3] = {in.a, in.b, in.c};
        bool allConst = n > 0;
        in.deps = 0;
        for (int i = 0; i < n; ++i) {
            in.deps |= mCode[ops[i]].deps;
            allConst = allConst && mCode[ops[i]].op == Op::Const;
        }
        if (in.op == Op::X) in.deps = 1;
        if (in.op == Op::Y) in.deps = 2;
        if (in.op == Op::Z) in.deps = 4;
        if (in.op == Op::Input) in.deps = 8;
        if (allConst) {
            double va = mCode[in.a].k, vb = in.b >= 0 ? mCode[in.b].k : 0.0, vc = in.c >= 0 ? mCode[in.c].k : 0.0;
            double result = 0.0;
            apply<double>(in, &result, &va, &vb, &vc, 1);
            Instr k;
            k.op = Op::Const;
            k.k = result;
            return emit(k);
        }
        // Commutative operations in a canonical order, so a*b and b*a are shared.
        if ((in.op == Op::Add || in.op == Op::Mul || in.op == Op::Min || in.op == Op::Max || in.op == Op::Hypot) &&
            in.a > in.b)
            std::swap(in.a, in.b);
        std::uint64_t kBits;
        std::memcpy(&kBits, &in.k, sizeof kBits);
        const auto key = std::make_tuple(int(in.op), in.a, in.b, in.c, kBits, in.n);
        if (auto it = mShared.find(key); it != mShared.end()) return it->second;
        mCode.push_back(in);
        const int index = int(mCode.size()) - 1;
        mShared.emplace(key, index);
        return index;
    }
    int constant(double v)
    {
        Instr k;
        k.op = Op::Const;
        k.k = v;
        return emit(k);
    }
    int unary(Op op, int a)
    {
        Instr in;
        in.op = op;
        in.a = a;
        return emit(in);
    }
    int binary(Op op, int a, int b)
    {
        Instr in;
        in.op = op;
        in.a = a;
        in.b = b;
        return emit(in);
    }

    int parseAdditive()
    {
        int left = parseMultiplicative();
        for (;;) {
            if (accept("+"))
                left = binary(Op::Add, left, parseMultiplicative());
            else if (accept("-"))
                left = binary(Op::Sub, left, parseMultiplicative());
            else
                return left;
        }
    }
    int parseMultiplicative()
    {
        int left = parseUnary();
        for (;;) {
            skipSpace();
            if (mText.compare(mPos, 2, "**") == 0) return left;  // handled by parsePower
            if (accept("*"))
                left = binary(Op::Mul, left, parseUnary());
            else if (accept("/"))
                left = binary(Op::Div, left, parseUnary());
            else if (accept("%"))
                left = binary(Op::Mod, left, parseUnary());
            else
                return left;
        }
    }
    /// Each nesting (a sign, a power, a parenthesis) is one level of the parser's recursion: a
    /// limit keeps a hostile equation (10,000 parentheses) from overflowing the stack.
    static constexpr int kMaxNesting = 256;
    struct Nesting {
        Compiler& c;
        explicit Nesting(Compiler& compiler) : c(compiler)
        {
            if (++c.mDepth > kMaxNesting)
                throw ExprError("the equation nests deeper than " + std::to_string(kMaxNesting) +
                                    " levels (parentheses, signs, powers); write it flatter or split it into fields",
                                c.mPos);
        }
        ~Nesting() { --c.mDepth; }
    };

    int parseUnary()
    {
        const Nesting nesting(*this);
        if (accept("-")) return unary(Op::Neg, parseUnary());
        if (accept("+")) return parseUnary();
        return parsePower();
    }
    int parsePower()
    {
        const int base = parsePrimary();
        if (accept("^") || accept("**")) {
            const int exponent = parseUnary();  // right-associative: 2^3^2 = 2^9, 2^-1 allowed
            const Instr& e = mCode[exponent];
            if (e.op == Op::Const && e.k == std::floor(e.k) && std::abs(e.k) <= 64) {
                Instr in;
                in.op = Op::PowInt;
                in.a = base;
                in.n = int(e.k);
                return emit(in);
            }
            return binary(Op::Pow, base, exponent);
        }
        return base;
    }

    int parsePrimary()
    {
        skipSpace();
        if (mPos >= mText.size())
            throw ExprError("the equation ends too early: expected a number, a name or `(`", mPos);
        const char ch = mText[mPos];
        if (ch == '(') {
            const Nesting nesting(*this);
            const std::size_t open = mPos++;
            const int inner = parseAdditive();
            if (!accept(")"))
                throw ExprError("expected `)` to close the `(` at character " + std::to_string(open + 1),
                                std::min(mPos, mText.size()));
            return inner;
        }
        if (std::isdigit(static_cast<unsigned char>(ch)) || ch == '.') return parseNumber();
        if (ch == '$') return parseParameter();
        if (isNameStart(ch)) return parseName();
        throw ExprError(std::string("unexpected `") + ch + "`: expected a number, a name or `(`", mPos);
    }

    int parseNumber()
    {
        const std::size_t start = mPos;
        while (mPos < mText.size() && std::isdigit(static_cast<unsigned char>(mText[mPos]))) ++mPos;
        if (mPos < mText.size() && mText[mPos] == '.') ++mPos;
        while (mPos < mText.size() && std::isdigit(static_cast<unsigned char>(mText[mPos]))) ++mPos;
        if (mPos < mText.size() && (mText[mPos] == 'e' || mText[mPos] == 'E')) {
            std::size_t p = mPos + 1;
            if (p < mText.size() && (mText[p] == '+' || mText[p] == '-')) ++p;
            if (p < mText.size() && std::isdigit(static_cast<unsigned char>(mText[p]))) {
                mPos = p;
                while (mPos < mText.size() && std::isdigit(static_cast<unsigned char>(mText[mPos]))) ++mPos;
            }
        }
        const std::string token = mText.substr(start, mPos - start);
        if (token == ".") throw ExprError("a lone `.` is not a number", start);
        const double value = std::strtod(token.c_str(), nullptr);
        if (!std::isfinite(value))
            throw ExprError("the number `" + token + "` is past the largest double (1.8e308)", start);
        return constant(value);
    }

    int parseParameter()
    {
        const std::size_t start = mPos++;
        const bool braced = mPos < mText.size() && mText[mPos] == '{';
        if (braced) ++mPos;
        const std::size_t nameStart = mPos;
        if (mPos >= mText.size() || !isNameStart(mText[mPos]))
            throw ExprError("expected a parameter name after `$`, like $cell", start);
        while (mPos < mText.size() && isNameChar(mText[mPos])) ++mPos;
        const std::string name = mText.substr(nameStart, mPos - nameStart);
        if (braced) {
            if (mPos >= mText.size() || mText[mPos] != '}') throw ExprError("expected `}` after ${" + name, mPos);
            ++mPos;
        }
        return symbol(name, true, start);
    }

    int parseName()
    {
        const std::size_t start = mPos;
        while (mPos < mText.size() && isNameChar(mText[mPos])) ++mPos;
        // A component of a vector field: name.x, name.y, name.z.
        if (mPos + 1 < mText.size() && mText[mPos] == '.' && isNameStart(mText[mPos + 1])) {
            ++mPos;
            while (mPos < mText.size() && isNameChar(mText[mPos])) ++mPos;
        }
        const std::string name = mText.substr(start, mPos - start);
        skipSpace();
        const bool call = mPos < mText.size() && mText[mPos] == '(';
        const Function* fn = nullptr;
        for (const Function& f : kFunctions)
            if (name == f.name) fn = &f;
        if (call) {
            if (!fn) {
                std::string best;
                std::size_t bestDistance = std::max<std::size_t>(2, name.size() / 3) + 1;
                for (const Function& f : kFunctions)
                    if (const std::size_t d = editDistance(name, f.name); d < bestDistance) {
                        bestDistance = d;
                        best = f.name;
                    }
                throw ExprError(
                    "unknown function `" + name + "`" + (best.empty() ? "" : "; did you mean `" + best + "`?"), start);
            }
            return parseCall(*fn, start);
        }
        if (fn) throw ExprError("`" + name + "` is a function: write " + name + "(...)", start);
        if (name == "x") return leaf(Op::X);
        if (name == "y") return leaf(Op::Y);
        if (name == "z") return leaf(Op::Z);
        for (const Constant& c : kConstants)
            if (name == c.name) return constant(c.value);
        return symbol(name, false, start);
    }

    int leaf(Op op)
    {
        Instr in;
        in.op = op;
        return emit(in);
    }

    int symbol(const std::string& name, bool isParam, std::size_t at)
    {
        ExprSymbol s;
        try {
            s = mResolve ? mResolve(name, isParam) : ExprSymbol{};
        } catch (const ExprError& e) {
            if (e.position() != std::string::npos) throw;
            throw ExprError(e.what(), at, e.unknownName());
        }
        switch (s.kind) {
            case ExprSymbol::Kind::Constant:
                return constant(s.value);
            case ExprSymbol::Kind::Input: {
                Instr in;
                in.op = Op::Input;
                in.n = s.input;
                mInputCount = std::max(mInputCount, s.input + 1);
                return emit(in);
            }
            case ExprSymbol::Kind::Unknown:
                break;
        }
        if (isParam) throw ExprError("unknown parameter `$" + name + "`", at, "$" + name);
        throw ExprError("unknown name `" + name + "`", at, name);
    }

    int parseCall(const Function& fn, std::size_t start)
    {
        accept("(");
        std::vector<int> args;
        skipSpace();
        if (!accept(")")) {
            for (;;) {
                args.push_back(parseAdditive());
                if (accept(",")) continue;
                if (accept(")")) break;
                throw ExprError(std::string("expected `,` or `)` in the arguments of `") + fn.name + "`",
                                std::min(mPos, mText.size()));
            }
        }
        const int count = int(args.size());
        if (count < fn.minArgs || (fn.maxArgs >= 0 && count > fn.maxArgs)) {
            const std::string wanted =
                fn.maxArgs < 0 ? "at least " + std::to_string(fn.minArgs) : std::to_string(fn.minArgs);
            throw ExprError("`" + std::string(fn.name) + "` takes " + wanted + " argument" +
                                (fn.minArgs == 1 ? "" : "s") + ", got " + std::to_string(count),
                            start);
        }
        if (fn.maxArgs < 0) {
            int acc = args[0];
            for (int i = 1; i < count; ++i) acc = binary(fn.op, acc, args[i]);
            return acc;
        }
        if (fn.op == Op::Pow) {
            const Instr& e = mCode[args[1]];
            if (e.op == Op::Const && e.k == std::floor(e.k) && std::abs(e.k) <= 64) {
                Instr in;
                in.op = Op::PowInt;
                in.a = args[0];
                in.n = int(e.k);
                return emit(in);
            }
        }
        Instr in;
        in.op = fn.op;
        in.a = args[0];
        if (count > 1) in.b = args[1];
        if (count > 2) in.c = args[2];
        return emit(in);
    }

    int mDepth = 0;
    const std::string& mText;
    const ExprResolver& mResolve;
    std::vector<Instr>& mCode;
    int& mInputCount;
    std::size_t mPos = 0;
    std::map<std::tuple<int, int, int, int, std::uint64_t, int>, int> mShared;
};

/// Shapes of a register on a grid block: a bit per axis the values vary along (0 = one value,
/// 7 = the whole block). On arbitrary points a register is either constant (0) or full (7).
constexpr std::uint8_t kFull = 7;

std::size_t shapeLength(std::uint8_t shape, int nx, int ny, int nz, bool grid)
{
    if (!grid) return shape ? std::size_t(nx) : 1;
    return std::size_t((shape & 1) ? nx : 1) * ((shape & 2) ? ny : 1) * ((shape & 4) ? nz : 1);
}

/// Copies @a in (shape @a from) into @a out (shape @a to, a superset of axes), broadcasting.
template <typename T>
void expand(const T* in, std::uint8_t from, T* out, std::uint8_t to, int nx, int ny, int nz, bool grid)
{
    const std::size_t n = shapeLength(to, nx, ny, nz, grid);
    if (from == 0) {
        std::fill(out, out + n, in[0]);
        return;
    }
    const int ni = (to & 1) ? nx : 1, nj = (to & 2) ? ny : 1, nk = (to & 4) ? nz : 1;
    const std::size_t sk = (from & 4) ? 1 : 0;
    const std::size_t sj = (from & 2) ? ((from & 4) ? nz : 1) : 0;
    const std::size_t si = (from & 1) ? std::size_t((from & 2) ? ny : 1) * ((from & 4) ? nz : 1) : 0;
    // Rows along z are either one repeated value or a contiguous run of the source.
    for (int i = 0; i < ni; ++i)
        for (int j = 0; j < nj; ++j) {
            T* row = out + (std::size_t(i) * nj + j) * nk;
            const T* src = in + i * si + j * sj;
            if (sk == 0)
                std::fill(row, row + nk, src[0]);
            else
                std::copy(src, src + nk, row);
        }
}

}  // namespace

std::string exprCaret(const std::string& text, std::size_t position)
{
    position = std::min(position, text.size());
    const std::size_t lineStart = text.rfind('\n', position == 0 ? 0 : position - 1);
    const std::size_t begin = (lineStart == std::string::npos || position == 0) ? 0 : lineStart + 1;
    std::size_t end = text.find('\n', begin);
    if (end == std::string::npos) end = text.size();
    std::string line = text.substr(begin, end - begin);
    std::replace(line.begin(), line.end(), '\t', ' ');
    return "    " + line + "\n    " + std::string(position - begin, ' ') + "^";
}

std::vector<std::string> exprFunctionNames()
{
    std::vector<std::string> names;
    for (const Function& f : kFunctions) names.emplace_back(f.name);
    return names;
}

std::vector<std::string> exprConstantNames()
{
    std::vector<std::string> names{"x", "y", "z"};
    for (const Constant& c : kConstants) names.emplace_back(c.name);
    return names;
}

ExprProgram ExprProgram::compile(const std::string& text, const ExprResolver& resolve)
{
    ExprProgram p;
    std::vector<Instr> code;
    const int root = Compiler(text, resolve, code, p.mInputCount).compile();
    // Keep only what the result needs (folding leaves dead constants behind), in order.
    std::vector<char> live(code.size(), 0);
    live[root] = 1;
    for (int i = root; i >= 0; --i) {
        if (!live[i]) continue;
        for (int o : {code[i].a, code[i].b, code[i].c})
            if (o >= 0) live[o] = 1;
    }
    std::vector<int> remap(code.size(), -1);
    for (int i = 0; i <= root; ++i) {
        if (!live[i]) continue;
        Instr in = code[i];
        for (int* o : {&in.a, &in.b, &in.c})
            if (*o >= 0) *o = remap[*o];
        remap[i] = int(p.mCode.size());
        p.mCode.push_back(in);
    }
    p.mPointPlan = p.makePlan(false);
    p.mGridPlan = p.makePlan(true);
    return p;
}

bool ExprProgram::isConstant() const
{
    return mCode.back().deps == 0;
}

std::string ExprProgram::listing() const
{
    std::ostringstream s;
    for (std::size_t i = 0; i < mCode.size(); ++i) {
        const Instr& in = mCode[i];
        s << "r" << i << " = " << opName(in.op);
        if (in.op == Op::Const) s << " " << in.k;
        if (in.op == Op::Input || in.op == Op::PowInt) s << " " << in.n;
        for (int o : {in.a, in.b, in.c})
            if (o >= 0) s << " r" << o;
        s << "\n";
    }
    return s.str();
}

ExprProgram::Plan ExprProgram::makePlan(bool grid) const
{
    Plan plan;
    auto shapeOf = [&](const Instr& in) -> std::uint8_t {
        if (in.deps == 0) return 0;
        if (!grid || (in.deps & 8)) return kFull;
        return in.deps & 7;
    };
    std::map<std::pair<int, int>, int> slotOf;  // (register, shape) -> slot
    auto newSlot = [&](std::uint8_t shape) {
        plan.slotShape.push_back(shape);
        return int(plan.slotShape.size()) - 1;
    };
    for (int r = 0; r < int(mCode.size()); ++r) {
        const Instr& in = mCode[r];
        const std::uint8_t shape = shapeOf(in);
        Step step{r, -1, {-1, -1, -1}, shape};
        const int ops[3] = {in.a, in.b, in.c};
        for (int i = 0; i < 3; ++i) {
            if (ops[i] < 0) continue;
            const std::uint8_t from = shapeOf(mCode[ops[i]]);
            auto key = std::make_pair(ops[i], int(shape));
            auto it = slotOf.find(key);
            if (it == slotOf.end()) {
                // Broadcast the operand to this instruction's shape once; later users share it.
                const int src = slotOf.at({ops[i], int(from)});
                const int dst = newSlot(shape);
                plan.steps.push_back({-1, dst, {src, -1, -1}, shape});
                it = slotOf.emplace(key, dst).first;
            }
            step.in[i] = it->second;
        }
        step.out = newSlot(shape);
        slotOf[{r, int(shape)}] = step.out;
        plan.steps.push_back(step);
    }
    plan.resultSlot = slotOf.at({int(mCode.size()) - 1, int(shapeOf(mCode.back()))});
    return plan;
}

template <typename T>
void ExprProgram::run(int mode, int nx, int ny, int nz, const T* xs, const T* ys, const T* zs, const T* const* inputs,
                      T* out) const
{
    const bool grid = mode == 1;
    const Plan& plan = grid ? mGridPlan : mPointPlan;
    const std::size_t slots = plan.slotShape.size();
    std::size_t total = 0;
    for (std::uint8_t s : plan.slotShape) total += shapeLength(s, nx, ny, nz, grid);
    const std::size_t pointerDoubles = (slots * sizeof(T*) + sizeof(double) - 1) / sizeof(double);
    ScratchLease scratch(pointerDoubles + total * (sizeof(T) / sizeof(double)));
    const T** ptr = reinterpret_cast<const T**>(scratch.data());
    T* storage = reinterpret_cast<T*>(scratch.data() + pointerDoubles);
    std::size_t offset = 0;
    for (std::size_t s = 0; s < slots; ++s) {
        ptr[s] = storage + offset;
        offset += shapeLength(plan.slotShape[s], nx, ny, nz, grid);
    }
    for (const Step& step : plan.steps) {
        T* dst = const_cast<T*>(ptr[step.out]);
        if (step.instr < 0) {
            const std::uint8_t from = plan.slotShape[step.in[0]];
            expand(ptr[step.in[0]], from, dst, step.shape, nx, ny, nz, grid);
            continue;
        }
        const Instr& in = mCode[step.instr];
        switch (in.op) {
            case Op::Const:
                dst[0] = T(in.k);
                break;
            case Op::X:
                ptr[step.out] = xs;
                break;
            case Op::Y:
                ptr[step.out] = ys;
                break;
            case Op::Z:
                ptr[step.out] = zs;
                break;
            case Op::Input:
                ptr[step.out] = inputs[in.n];
                break;
            default:
                apply<T>(in, dst, ptr[step.in[0]], step.in[1] >= 0 ? ptr[step.in[1]] : nullptr,
                         step.in[2] >= 0 ? ptr[step.in[2]] : nullptr, shapeLength(step.shape, nx, ny, nz, grid));
        }
    }
    expand(ptr[plan.resultSlot], plan.slotShape[plan.resultSlot], out, kFull, nx, ny, nz, grid);
}

void ExprProgram::values(std::span<const Vec3d> points, const double* const* inputs, std::span<double> out) const
{
    const std::size_t n = points.size();
    ScratchLease coords(3 * n);
    double* xs = coords.data();
    double* ys = xs + n;
    double* zs = ys + n;
    for (std::size_t i = 0; i < n; ++i) {
        xs[i] = points[i][0];
        ys[i] = points[i][1];
        zs[i] = points[i][2];
    }
    run<double>(0, int(n), 1, 1, xs, ys, zs, inputs, out.data());
}

void ExprProgram::gridValues(const GridBatch& batch, const double* const* inputs, std::span<double> out) const
{
    ScratchLease coords(std::size_t(batch.nx + batch.ny + batch.nz));
    double* xs = coords.data();
    double* ys = xs + batch.nx;
    double* zs = ys + batch.ny;
    for (int i = 0; i < batch.nx; ++i) xs[i] = batch.origin[0] + i * batch.spacing[0];
    for (int j = 0; j < batch.ny; ++j) ys[j] = batch.origin[1] + j * batch.spacing[1];
    for (int k = 0; k < batch.nz; ++k) zs[k] = batch.origin[2] + k * batch.spacing[2];
    run<double>(1, batch.nx, batch.ny, batch.nz, xs, ys, zs, inputs, out.data());
}

void ExprProgram::gradients(std::span<const Vec3d> points, const Dual3* const* inputs, std::span<Dual3> out) const
{
    const std::size_t n = points.size();
    ScratchLease coords(3 * n * (sizeof(Dual3) / sizeof(double)));
    Dual3* xs = coords.as<Dual3>();
    Dual3* ys = xs + n;
    Dual3* zs = ys + n;
    for (std::size_t i = 0; i < n; ++i) {
        xs[i] = Dual3(points[i][0], 1, 0, 0);
        ys[i] = Dual3(points[i][1], 0, 1, 0);
        zs[i] = Dual3(points[i][2], 0, 0, 1);
    }
    run<Dual3>(0, int(n), 1, 1, xs, ys, zs, inputs, out.data());
}

Interval ExprProgram::bound(const Box3& box, const Interval* inputs) const
{
    const Interval x(box.min[0], box.max[0]), y(box.min[1], box.max[1]), z(box.min[2], box.max[2]);
    ScratchLease pointers(std::size_t(std::max(mInputCount, 1)));
    const Interval** in = reinterpret_cast<const Interval**>(pointers.data());
    for (int i = 0; i < mInputCount; ++i) in[i] = inputs + i;
    Interval result;
    run<Interval>(0, 1, 1, 1, &x, &y, &z, in, &result);
    return result;
}

}  // namespace voxlat
