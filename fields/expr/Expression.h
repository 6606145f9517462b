/// @file Expression.h
/// @brief User equations: parsed once into a compact instruction list, evaluated over whole
/// batches (one array per register), in doubles (values), intervals (bounds) or Dual3 (gradients).
///
/// The language: numbers, x y z (millimetres), `$name` parameters and other names (resolved by
/// the caller: recipe parameters become constants, field names become inputs), + - * / ^ (or **),
/// % (mod), unary minus, parentheses, and the functions of functionNames(). Constant
/// sub-expressions are folded and repeated sub-expressions computed once. On a regular grid
/// block, sub-expressions that depend on one coordinate only (sin(2*pi*x/cell)) are computed on
/// that axis' 8 values and broadcast, which is what makes a user's TPMS as fast as the built-in one.
#pragma once

#include "fields/core/Dual.h"
#include "fields/core/FieldNode.h"

#include <cstdint>
#include <functional>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

namespace voxlat {

/// An equation that cannot be compiled: what is wrong and the character offset it refers to.
class ExprError : public std::runtime_error {
public:
    ExprError(const std::string& message, std::size_t position, std::string unknownName = {})
        : std::runtime_error(message), mPosition(position), mUnknownName(std::move(unknownName))
    {
    }
    std::size_t position() const { return mPosition; }
    /// The name that could not be resolved, if that is the error ("" otherwise).
    const std::string& unknownName() const { return mUnknownName; }

private:
    std::size_t mPosition;
    std::string mUnknownName;
};

/// What a name in an equation stands for, as answered by the caller while compiling.
struct ExprSymbol {
    enum class Kind { Unknown, Constant, Input };
    Kind kind = Kind::Unknown;
    double value = 0.0;  ///< for Constant
    int input = -1;      ///< for Input: index into the input arrays given to evaluation
};

/// Resolves @a name; @a isParam is true for `$name`. May throw ExprError (position is filled
/// in by the compiler when it is std::string::npos).
using ExprResolver = std::function<ExprSymbol(const std::string& name, bool isParam)>;

/// The line of @a text holding @a position and a caret under it, indented by four spaces.
std::string exprCaret(const std::string& text, std::size_t position);

/// Names of the built-in functions and constants (for suggestions and documentation).
std::vector<std::string> exprFunctionNames();
std::vector<std::string> exprConstantNames();

/// A compiled equation. Immutable and safe to evaluate from many threads at once.
class ExprProgram {
public:
    /// Parses and compiles @a text; throws ExprError with the offending position.
    static ExprProgram compile(const std::string& text, const ExprResolver& resolve);

    /// How many inputs the caller declared (the largest input index + 1).
    int inputCount() const { return mInputCount; }
    /// Number of instructions after folding and sharing (for tests and listings).
    std::size_t size() const { return mCode.size(); }
    /// True if the value does not depend on x, y, z or any input.
    bool isConstant() const;
    /// One instruction per line, for debugging.
    std::string listing() const;

    /// Values at up to kBatchSize @a points; inputs[i] holds the values of input i at them.
    void values(std::span<const Vec3d> points, const double* const* inputs, std::span<double> out) const;
    /// Values on a block of at most kBatchSize points; inputs laid out like @a out.
    void gridValues(const GridBatch& batch, const double* const* inputs, std::span<double> out) const;
    /// Values and gradients at up to kBatchSize points; inputs carry their own gradients.
    void gradients(std::span<const Vec3d> points, const Dual3* const* inputs, std::span<Dual3> out) const;
    /// A conservative bound over @a box given bounds of the inputs over it.
    Interval bound(const Box3& box, const Interval* inputs) const;

    /// Instruction codes (see Expression.cpp for their meaning).
    enum class Op : std::uint8_t {
        Const,
        X,
        Y,
        Z,
        Input,
        Neg,
        Add,
        Sub,
        Mul,
        Div,
        PowInt,
        Pow,
        Mod,
        Min,
        Max,
        Abs,
        Sign,
        Floor,
        Ceil,
        Sqrt,
        Exp,
        Log,
        Sin,
        Cos,
        Tan,
        Asin,
        Acos,
        Atan,
        Atan2,
        Sinh,
        Cosh,
        Tanh,
        Hypot,
        Clamp,
        Smoothstep,
        Mix
    };
    /// One instruction: its result is the register with the instruction's own index.
    struct Instr {
        Op op = Op::Const;
        int a = -1, b = -1, c = -1;  ///< operand registers
        double k = 0.0;              ///< Const: the value
        int n = 0;                   ///< PowInt: the exponent; Input: the input index
        std::uint8_t deps = 0;       ///< bit 0 x, 1 y, 2 z, 3 inputs
    };

private:
    template <typename T>
    void run(int mode, int nx, int ny, int nz, const T* xs, const T* ys, const T* zs, const T* const* inputs,
             T* out) const;

    struct Step {
        int instr;  ///< instruction computed, or -1 for an expansion
        int out;    ///< slot written
        int in[3];  ///< slots read
        std::uint8_t shape;
    };
    struct Plan {
        std::vector<Step> steps;
        std::vector<std::uint8_t> slotShape;
        int resultSlot = -1;
    };
    Plan makePlan(bool grid) const;

    std::vector<Instr> mCode;
    int mInputCount = 0;
    Plan mPointPlan, mGridPlan;
};

}  // namespace voxlat
