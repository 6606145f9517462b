/// @file TpmsEquations.h
/// @brief Level-set approximations of the triply periodic minimal surfaces (reference §1).
///
/// Each equation is written once over a number type T (double, Interval or Dual3) in terms of
/// the trigonometric terms of the scaled coordinates X = 2*pi*x/cell, so the same line gives
/// values, bounds and analytic gradients.
#pragma once

#include "fields/core/Dual.h"
#include "fields/core/Interval.h"

#include <cmath>
#include <string>
#include <string_view>
#include <vector>

namespace voxlat {

/// sin, cos, sin 2, cos 2 of one scaled coordinate.
template <typename T>
struct TrigTerms {
    T s, c, s2, c2;
};

/// Trigonometric terms of X (intervals: sin/cos of 2X directly, as the identities would widen the
/// bound). Values and gradients take trigTermsFrom() with batched sines and cosines.
template <typename T>
TrigTerms<T> trigTerms(const T& x)
{
    return {sin(x), cos(x), sin(2.0 * x), cos(2.0 * x)};
}
/// The terms from @a s = sin X and @a c = cos X (sinCosBatch), the double angles by identity.
inline TrigTerms<double> trigTermsFrom(double s, double c)
{
    return {s, c, 2.0 * s * c, c * c - s * s};
}
/// Dual numbers by the same identities from @a s = sin(x.v) and @a c = cos(x.v): one sine and one
/// cosine per coordinate instead of a sine and a cosine for each of the four terms, as the
/// generic trigTerms would take.
inline TrigTerms<Dual3> trigTermsFrom(double s, double c, const Dual3& x)
{
    const double s2 = 2.0 * s * c, c2 = c * c - s * s;
    auto withSlope = [&](double value, double slope) {
        return Dual3(value, slope * x.d[0], slope * x.d[1], slope * x.d[2]);
    };
    return {withSlope(s, c), withSlope(c, -s), withSlope(s2, 2.0 * c2), withSlope(c2, -2.0 * s2)};
}

enum class TpmsType { Gyroid, SchwarzP, SchwarzD, IWP, Neovius, FischerKochS, Lidinoid, SplitP, FRD };

/// Evaluates surface @a type from the terms of X, Y and Z.
template <typename T>
T tpmsEquation(TpmsType type, const TrigTerms<T>& x, const TrigTerms<T>& y, const TrigTerms<T>& z)
{
    switch (type) {
        case TpmsType::Gyroid:
            return x.s * y.c + y.s * z.c + z.s * x.c;
        case TpmsType::SchwarzP:
            return x.c + y.c + z.c;
        case TpmsType::SchwarzD:
            return x.s * y.s * z.s + x.s * y.c * z.c + x.c * y.s * z.c + x.c * y.c * z.s;
        case TpmsType::IWP:
            return 2.0 * (x.c * y.c + y.c * z.c + z.c * x.c) - (x.c2 + y.c2 + z.c2);
        case TpmsType::Neovius:
            return 3.0 * (x.c + y.c + z.c) + 4.0 * x.c * y.c * z.c;
        case TpmsType::FischerKochS:
            return x.c2 * y.s * z.c + x.c * y.c2 * z.s + x.s * y.c * z.c2;
        case TpmsType::Lidinoid:
            return (x.s2 * y.c * z.s + y.s2 * z.c * x.s + z.s2 * x.c * y.s) -
                   (x.c2 * y.c2 + y.c2 * z.c2 + z.c2 * x.c2) + 0.3;
        case TpmsType::SplitP:
            return 1.1 * (x.s2 * y.c * z.s + y.s2 * z.c * x.s + z.s2 * x.c * y.s) -
                   0.2 * (x.c2 * y.c2 + y.c2 * z.c2 + z.c2 * x.c2) - 0.4 * (x.c2 + y.c2 + z.c2);
        case TpmsType::FRD:
            return 8.0 * x.c * y.c * z.c + x.c2 * y.c2 * z.c2 - (x.c2 * y.c2 + y.c2 * z.c2 + z.c2 * x.c2);
    }
    return T(0.0);
}

/// Recipe name of each surface ("gyroid", "schwarz-p", ...).
std::string_view tpmsName(TpmsType type);
/// Parses a recipe name; returns false if unknown.
bool parseTpmsType(std::string_view name, TpmsType& type);
/// All recipe names, for error messages.
std::vector<std::string> tpmsNames();
/// The level range over which the surface exists (reference §1 table).
Interval tpmsLevelRange(TpmsType type);

}  // namespace voxlat
