/// @file Interval.h
/// @brief Conservative interval arithmetic used to bound a field over a box.
///
/// What it guarantees: every operation returns the exact image of its arguments computed in
/// ordinary round-to-nearest double arithmetic, without outward rounding. Each end is therefore
/// within a few units in the last place (relative 1e-15 per operation, growing with the length of
/// the expression) of the exact image's end, and may lie that little inside it. The engine only
/// uses bounds to cull regions far from a level (boxes grown by a voxel, levels compared with
/// margins of a voxel's change), where such an error cannot change a decision; code that needs a
/// rigorous enclosure must widen the result (e.g. by std::nextafter on each end) itself.
#pragma once

#include <algorithm>
#include <cmath>
#include <numbers>

namespace voxlat {

/// A closed interval [lo, hi]; lo <= hi always.
struct Interval {
    double lo = 0.0;
    double hi = 0.0;

    constexpr Interval() = default;
    constexpr Interval(double v) : lo(v), hi(v) {}  // NOLINT: implicit from a constant
    constexpr Interval(double l, double h) : lo(l), hi(h) {}

    constexpr double width() const { return hi - lo; }
    constexpr bool contains(double v) const { return lo <= v && v <= hi; }
};

inline Interval operator+(Interval a, Interval b)
{
    return {a.lo + b.lo, a.hi + b.hi};
}
inline Interval operator-(Interval a, Interval b)
{
    return {a.lo - b.hi, a.hi - b.lo};
}
inline Interval operator-(Interval a)
{
    return {-a.hi, -a.lo};
}
inline Interval operator*(Interval a, Interval b)
{
    const double p1 = a.lo * b.lo, p2 = a.lo * b.hi, p3 = a.hi * b.lo, p4 = a.hi * b.hi;
    return {std::min(std::min(p1, p2), std::min(p3, p4)), std::max(std::max(p1, p2), std::max(p3, p4))};
}
inline Interval operator*(double s, Interval a)
{
    return s >= 0 ? Interval{s * a.lo, s * a.hi} : Interval{s * a.hi, s * a.lo};
}
inline Interval operator*(Interval a, double s)
{
    return s * a;
}
inline Interval operator+(Interval a, double s)
{
    return {a.lo + s, a.hi + s};
}
inline Interval operator+(double s, Interval a)
{
    return a + s;
}
inline Interval operator-(Interval a, double s)
{
    return {a.lo - s, a.hi - s};
}
inline Interval operator-(double s, Interval a)
{
    return {s - a.hi, s - a.lo};
}
inline Interval& operator+=(Interval& a, Interval b)
{
    return a = a + b;
}

inline Interval min(Interval a, Interval b)
{
    return {std::min(a.lo, b.lo), std::min(a.hi, b.hi)};
}
inline Interval max(Interval a, Interval b)
{
    return {std::max(a.lo, b.lo), std::max(a.hi, b.hi)};
}
inline Interval abs(Interval a)
{
    if (a.lo >= 0) return a;
    if (a.hi <= 0) return -a;
    return {0.0, std::max(-a.lo, a.hi)};
}
inline double sqr(double v)
{
    return v * v;
}
inline Interval sqr(Interval a)
{
    const Interval m = abs(a);
    return {m.lo * m.lo, m.hi * m.hi};
}
inline Interval sqrt(Interval a)
{
    return {std::sqrt(std::max(0.0, a.lo)), std::sqrt(std::max(0.0, a.hi))};
}
inline Interval exp(Interval a)
{
    return {std::exp(a.lo), std::exp(a.hi)};
}
/// Union hull of two intervals.
inline Interval hull(Interval a, Interval b)
{
    return {std::min(a.lo, b.lo), std::max(a.hi, b.hi)};
}

/// cos over an interval: the endpoint values, widened to +-1 where an extremum k*pi lies inside.
inline Interval cos(Interval a)
{
    constexpr double pi = std::numbers::pi;
    if (a.width() >= 2 * pi) return {-1.0, 1.0};
    const double c1 = std::cos(a.lo), c2 = std::cos(a.hi);
    Interval r{std::min(c1, c2), std::max(c1, c2)};
    // Maxima at 2k*pi, minima at (2k+1)*pi.
    const double kMax = std::ceil(a.lo / (2 * pi));
    if (2 * pi * kMax <= a.hi) r.hi = 1.0;
    const double kMin = std::ceil((a.lo - pi) / (2 * pi));
    if (2 * pi * kMin + pi <= a.hi) r.lo = -1.0;
    return r;
}
inline Interval sin(Interval a)
{
    return cos(a - std::numbers::pi / 2);
}

}  // namespace voxlat
