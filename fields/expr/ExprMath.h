/// @file ExprMath.h
/// @brief The functions of the equation language for the three number types an equation is
/// evaluated in: double (values), Interval (conservative bounds) and Dual3 (exact gradients).
///
/// Every Interval function returns an interval containing the exact image of its arguments
/// (possibly infinite where the function has a pole inside); every Dual3 function applies the
/// chain rule with the analytic derivative (zero for the piecewise constant floor, ceil, sign).
#pragma once

#include "fields/core/Dual.h"
#include "fields/core/Interval.h"

#include <cmath>
#include <limits>
#include <numbers>

namespace voxlat::exprmath {

inline constexpr double kInf = std::numeric_limits<double>::infinity();
inline constexpr double kPi = std::numbers::pi;

// ---- double --------------------------------------------------------------------------------

inline double div(double a, double b)
{
    return a / b;
}
inline double sign(double a)
{
    return a > 0 ? 1.0 : (a < 0 ? -1.0 : 0.0);
}
/// GLSL mod: a - b * floor(a / b); the result has the sign of b.
inline double mod(double a, double b)
{
    return a - b * std::floor(a / b);
}
/// a^n by repeated squaring, so x^2 is exactly x*x.
inline double powInt(double a, int n)
{
    const bool invert = n < 0;
    unsigned e = invert ? unsigned(-n) : unsigned(n);
    double result = 1.0, base = a;
    while (e) {
        if (e & 1u) result *= base;
        e >>= 1u;
        if (e) base *= base;
    }
    return invert ? 1.0 / result : result;
}
/// Hermite step from 0 at e0 to 1 at e1 (a plain step when e0 == e1).
inline double smoothstep(double e0, double e1, double x)
{
    if (e0 == e1) return x < e0 ? 0.0 : 1.0;
    double t = (x - e0) / (e1 - e0);
    t = t < 0 ? 0.0 : (t > 1 ? 1.0 : t);
    return t * t * (3.0 - 2.0 * t);
}

// ---- Interval --------------------------------------------------------------------------------

/// Replaces NaN ends (from inf - inf or 0 * inf) by the whole line, keeping the bound safe.
inline Interval sanitize(Interval a)
{
    if (std::isnan(a.lo) || std::isnan(a.hi)) return {-kInf, kInf};
    return a;
}
inline Interval div(Interval a, Interval b)
{
    if (b.lo > 0 || b.hi < 0) return a * Interval(std::min(1.0 / b.lo, 1.0 / b.hi), std::max(1.0 / b.lo, 1.0 / b.hi));
    return {-kInf, kInf};
}
inline Interval powInt(Interval a, int n)
{
    if (n == 0) return Interval(1.0);
    if (n < 0) return div(Interval(1.0), powInt(a, -n));
    if (n % 2 == 0) {
        const Interval m = abs(a);
        return {powInt(m.lo, n), powInt(m.hi, n)};
    }
    return {powInt(a.lo, n), powInt(a.hi, n)};
}
inline Interval log(Interval a)
{
    if (a.hi <= 0) return {-kInf, kInf};  // no real value: the evaluator reports the NaN
    return {a.lo > 0 ? std::log(a.lo) : -kInf, std::log(a.hi)};
}
inline Interval pow(Interval a, Interval b)
{
    // Real powers are defined for a >= 0: a^b = exp(b log a), both monotone pieces.
    if (a.hi < 0) return {-kInf, kInf};
    const Interval clamped(std::max(a.lo, 0.0), a.hi);
    return sanitize(exp(sanitize(b * log(clamped))));
}
inline Interval tan(Interval a)
{
    if (a.width() >= kPi) return {-kInf, kInf};
    const double k = std::ceil((a.lo - kPi / 2) / kPi);  // first pole at or above lo
    if (kPi / 2 + k * kPi <= a.hi) return {-kInf, kInf};
    return {std::tan(a.lo), std::tan(a.hi)};
}
inline double clampUnit(double v)
{
    return v < -1 ? -1.0 : (v > 1 ? 1.0 : v);
}
inline Interval asin(Interval a)
{
    return {std::asin(clampUnit(a.lo)), std::asin(clampUnit(a.hi))};
}
inline Interval acos(Interval a)
{
    return {std::acos(clampUnit(a.hi)), std::acos(clampUnit(a.lo))};
}
inline Interval atan(Interval a)
{
    return {std::atan(a.lo), std::atan(a.hi)};
}
inline Interval sinh(Interval a)
{
    return {std::sinh(a.lo), std::sinh(a.hi)};
}
inline Interval cosh(Interval a)
{
    const Interval m = abs(a);
    return {std::cosh(m.lo), std::cosh(m.hi)};
}
inline Interval tanh(Interval a)
{
    return {std::tanh(a.lo), std::tanh(a.hi)};
}
inline Interval sign(Interval a)
{
    return {sign(a.lo), sign(a.hi)};
}
inline Interval floor(Interval a)
{
    return {std::floor(a.lo), std::floor(a.hi)};
}
inline Interval ceil(Interval a)
{
    return {std::ceil(a.lo), std::ceil(a.hi)};
}
/// The angle of (x, y): over a box that neither holds the origin nor crosses the branch cut
/// (the negative x axis) the extremes are at the corners; otherwise the whole range.
inline Interval atan2(Interval y, Interval x)
{
    const bool holdsOrigin = x.lo <= 0 && x.hi >= 0 && y.lo <= 0 && y.hi >= 0;
    const bool crossesCut = x.lo < 0 && y.lo < 0 && y.hi >= 0;
    if (holdsOrigin || crossesCut) return {-kPi, kPi};
    const double c[4] = {std::atan2(y.lo, x.lo), std::atan2(y.lo, x.hi), std::atan2(y.hi, x.lo),
                         std::atan2(y.hi, x.hi)};
    return {std::min(std::min(c[0], c[1]), std::min(c[2], c[3])), std::max(std::max(c[0], c[1]), std::max(c[2], c[3]))};
}
inline Interval mod(Interval a, Interval b)
{
    if (b.lo == b.hi && b.lo != 0) {
        const double q = std::floor(a.lo / b.lo);
        if (std::floor(a.hi / b.lo) == q) return {a.lo - b.lo * q, a.hi - b.lo * q};  // one branch: slope 1
        return {std::min(0.0, b.lo), std::max(0.0, b.lo)};
    }
    const double m = std::max(std::abs(b.lo), std::abs(b.hi));
    return {-m, m};
}
inline Interval smoothstep(Interval e0, Interval e1, Interval x)
{
    // With fixed edges the step is monotone in x; otherwise it is somewhere in [0, 1].
    if (e0.lo != e0.hi || e1.lo != e1.hi) return {0.0, 1.0};
    const double a = smoothstep(e0.lo, e1.lo, x.lo), b = smoothstep(e0.lo, e1.lo, x.hi);
    return {std::min(a, b), std::max(a, b)};
}

// ---- Dual3 -----------------------------------------------------------------------------------

inline Dual3 div(const Dual3& a, const Dual3& b)
{
    return a / b;
}
inline Dual3 powInt(const Dual3& a, int n)
{
    return chain(a, powInt(a.v, n), n == 0 ? 0.0 : n * powInt(a.v, n - 1));
}
inline Dual3 log(const Dual3& a)
{
    return chain(a, std::log(a.v), 1.0 / a.v);
}
inline Dual3 pow(const Dual3& a, const Dual3& b)
{
    const double p = std::pow(a.v, b.v);
    if (b.d[0] == 0 && b.d[1] == 0 && b.d[2] == 0) return chain(a, p, b.v * std::pow(a.v, b.v - 1.0));
    const double la = std::log(a.v);
    Dual3 r(p);
    for (int i = 0; i < 3; ++i) r.d[i] = p * (b.d[i] * la + b.v * a.d[i] / a.v);
    return r;
}
inline Dual3 tan(const Dual3& a)
{
    const double t = std::tan(a.v);
    return chain(a, t, 1.0 + t * t);
}
inline Dual3 asin(const Dual3& a)
{
    return chain(a, std::asin(a.v), 1.0 / std::sqrt(1.0 - a.v * a.v));
}
inline Dual3 acos(const Dual3& a)
{
    return chain(a, std::acos(a.v), -1.0 / std::sqrt(1.0 - a.v * a.v));
}
inline Dual3 atan(const Dual3& a)
{
    return chain(a, std::atan(a.v), 1.0 / (1.0 + a.v * a.v));
}
inline Dual3 sinh(const Dual3& a)
{
    return chain(a, std::sinh(a.v), std::cosh(a.v));
}
inline Dual3 cosh(const Dual3& a)
{
    return chain(a, std::cosh(a.v), std::sinh(a.v));
}
inline Dual3 tanh(const Dual3& a)
{
    const double t = std::tanh(a.v);
    return chain(a, t, 1.0 - t * t);
}
inline Dual3 sign(const Dual3& a)
{
    return Dual3(sign(a.v));
}
inline Dual3 floor(const Dual3& a)
{
    return Dual3(std::floor(a.v));
}
inline Dual3 ceil(const Dual3& a)
{
    return Dual3(std::ceil(a.v));
}
inline Dual3 atan2(const Dual3& y, const Dual3& x)
{
    const double r2 = x.v * x.v + y.v * y.v;
    Dual3 r(std::atan2(y.v, x.v));
    if (r2 > 0)
        for (int i = 0; i < 3; ++i) r.d[i] = (x.v * y.d[i] - y.v * x.d[i]) / r2;
    return r;
}
inline Dual3 mod(const Dual3& a, const Dual3& b)
{
    const double q = std::floor(a.v / b.v);
    return a - q * b;
}
inline Dual3 smoothstep(const Dual3& e0, const Dual3& e1, const Dual3& x)
{
    if (e0.v == e1.v) return Dual3(x.v < e0.v ? 0.0 : 1.0);
    const Dual3 t = (x - e0) / (e1 - e0);
    if (t.v <= 0) return Dual3(0.0);
    if (t.v >= 1) return Dual3(1.0);
    return t * t * (3.0 - 2.0 * t);
}

}  // namespace voxlat::exprmath

namespace voxlat::exprmath {

// Uniform names for the three number types, so one templated loop serves them all.
#define VOXLAT_EXPR_FORWARD1(name)    \
    inline double name(double a)      \
    {                                 \
        return std::name(a);          \
    }                                 \
    inline Interval name(Interval a)  \
    {                                 \
        return voxlat::name(a);       \
    }                                 \
    inline Dual3 name(const Dual3& a) \
    {                                 \
        return voxlat::name(a);       \
    }
VOXLAT_EXPR_FORWARD1(sin)
VOXLAT_EXPR_FORWARD1(cos)
VOXLAT_EXPR_FORWARD1(exp)
VOXLAT_EXPR_FORWARD1(sqrt)
VOXLAT_EXPR_FORWARD1(abs)
#undef VOXLAT_EXPR_FORWARD1
// Plain double versions under the same names, so the templated evaluation loop calls one name
// for every number type.
#define VOXLAT_EXPR_DOUBLE1(name) \
    inline double name(double a)  \
    {                             \
        return std::name(a);      \
    }
VOXLAT_EXPR_DOUBLE1(tan)
VOXLAT_EXPR_DOUBLE1(asin)
VOXLAT_EXPR_DOUBLE1(acos)
VOXLAT_EXPR_DOUBLE1(atan)
VOXLAT_EXPR_DOUBLE1(sinh)
VOXLAT_EXPR_DOUBLE1(cosh)
VOXLAT_EXPR_DOUBLE1(tanh)
VOXLAT_EXPR_DOUBLE1(log)
VOXLAT_EXPR_DOUBLE1(floor)
VOXLAT_EXPR_DOUBLE1(ceil)
#undef VOXLAT_EXPR_DOUBLE1
inline double pow(double a, double b)
{
    return std::pow(a, b);
}
inline double atan2(double y, double x)
{
    return std::atan2(y, x);
}
inline double min(double a, double b)
{
    return a <= b ? a : b;
}
inline double max(double a, double b)
{
    return a >= b ? a : b;
}
inline Interval min(Interval a, Interval b)
{
    return voxlat::min(a, b);
}
inline Interval max(Interval a, Interval b)
{
    return voxlat::max(a, b);
}
inline Dual3 min(const Dual3& a, const Dual3& b)
{
    return voxlat::min(a, b);
}
inline Dual3 max(const Dual3& a, const Dual3& b)
{
    return voxlat::max(a, b);
}
/// sqrt(a^2 + b^2), written the same way for every number type so values agree to the bit.
inline double hypot(double a, double b)
{
    return std::sqrt(a * a + b * b);
}
inline Interval hypot(Interval a, Interval b)
{
    return voxlat::sqrt(sqr(a) + sqr(b));
}
inline Dual3 hypot(const Dual3& a, const Dual3& b)
{
    return voxlat::sqrt(a * a + b * b);
}

}  // namespace voxlat::exprmath
