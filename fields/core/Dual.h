/// @file Dual.h
/// @brief Forward-mode automatic differentiation in three variables.
///
/// A field equation written once as a template over its number type gives values (double),
/// bounds (Interval) and exact analytic gradients (Dual3) from the same source line.
#pragma once

#include <cmath>

namespace voxlat {

/// A value with its partial derivatives with respect to x, y and z.
struct Dual3 {
    double v = 0.0;
    double d[3] = {0.0, 0.0, 0.0};

    constexpr Dual3() = default;
    constexpr Dual3(double value) : v(value) {}  // NOLINT: constants have zero derivatives
    constexpr Dual3(double value, double dx, double dy, double dz) : v(value), d{dx, dy, dz} {}
};

inline Dual3 operator+(const Dual3& a, const Dual3& b)
{
    return {a.v + b.v, a.d[0] + b.d[0], a.d[1] + b.d[1], a.d[2] + b.d[2]};
}
inline Dual3 operator-(const Dual3& a, const Dual3& b)
{
    return {a.v - b.v, a.d[0] - b.d[0], a.d[1] - b.d[1], a.d[2] - b.d[2]};
}
inline Dual3 operator-(const Dual3& a)
{
    return {-a.v, -a.d[0], -a.d[1], -a.d[2]};
}
inline Dual3 operator*(const Dual3& a, const Dual3& b)
{
    return {a.v * b.v, a.d[0] * b.v + a.v * b.d[0], a.d[1] * b.v + a.v * b.d[1], a.d[2] * b.v + a.v * b.d[2]};
}
inline Dual3 operator*(double s, const Dual3& a)
{
    return {s * a.v, s * a.d[0], s * a.d[1], s * a.d[2]};
}
inline Dual3 operator*(const Dual3& a, double s)
{
    return s * a;
}
inline Dual3 operator+(const Dual3& a, double s)
{
    return {a.v + s, a.d[0], a.d[1], a.d[2]};
}
inline Dual3 operator+(double s, const Dual3& a)
{
    return a + s;
}
inline Dual3 operator-(const Dual3& a, double s)
{
    return {a.v - s, a.d[0], a.d[1], a.d[2]};
}
inline Dual3 operator-(double s, const Dual3& a)
{
    return {s - a.v, -a.d[0], -a.d[1], -a.d[2]};
}
inline Dual3 operator/(const Dual3& a, const Dual3& b)
{
    const double inv = 1.0 / b.v, q = a.v * inv;
    return {q, (a.d[0] - q * b.d[0]) * inv, (a.d[1] - q * b.d[1]) * inv, (a.d[2] - q * b.d[2]) * inv};
}
/// Chain rule helper: f(a) with f'(a) = df.
inline Dual3 chain(const Dual3& a, double f, double df)
{
    return {f, df * a.d[0], df * a.d[1], df * a.d[2]};
}
inline Dual3 sin(const Dual3& a)
{
    return chain(a, std::sin(a.v), std::cos(a.v));
}
inline Dual3 cos(const Dual3& a)
{
    return chain(a, std::cos(a.v), -std::sin(a.v));
}
inline Dual3 exp(const Dual3& a)
{
    const double e = std::exp(a.v);
    return chain(a, e, e);
}
inline Dual3 sqrt(const Dual3& a)
{
    const double s = std::sqrt(a.v);
    return chain(a, s, s > 0 ? 0.5 / s : 0.0);
}
inline Dual3 abs(const Dual3& a)
{
    return a.v < 0 ? -a : a;
}
inline Dual3 sqr(const Dual3& a)
{
    return a * a;
}
inline Dual3 min(const Dual3& a, const Dual3& b)
{
    return a.v <= b.v ? a : b;
}
inline Dual3 max(const Dual3& a, const Dual3& b)
{
    return a.v >= b.v ? a : b;
}

}  // namespace voxlat
