/// @file ColumnStencils.cpp
/// @brief Eight-point Lagrange stencils across a plane's columns, with their proven bound.
#include "fields/struts/ColumnStencils.h"

#include "fields/core/PlaneBands.h"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace voxlat {

namespace {

constexpr int kNodes = 8;
constexpr double kFactorial8 = 40320.0;
/// The largest sum of |weights| a stencil may have (ColumnStencils.h).
constexpr double kMaxLebesgue = 2.5;

/// R(b) for b in [i / 64, (i + 1) / 64] (tests/scripts/directional_eighth_bound.py).
constexpr std::array<double, 64> kRayBound{
    145.76, 145.62, 145.19, 144.49, 143.50, 142.24, 140.71, 138.91, 136.86, 134.57, 132.04, 129.29, 126.32,
    123.15, 119.80, 116.28, 112.60, 108.78, 104.84, 100.79, 96.66,  92.46,  88.22,  83.94,  79.66,  75.39,
    71.15,  66.95,  62.81,  58.76,  54.79,  50.93,  47.18,  43.63,  41.89,  40.29,  38.90,  37.63,  36.45,
    35.37,  34.35,  33.40,  32.51,  31.68,  30.88,  30.13,  29.42,  28.75,  28.11,  27.49,  26.91,  26.35,
    25.81,  25.30,  24.81,  24.34,  23.88,  23.45,  23.03,  22.62,  22.23,  21.86,  21.49,  21.14};

/// The stencils for nodes every @a m columns.
ColumnStencils stencilsOf(int nx, int m, double scale, double tolerance)
{
    ColumnStencils s;
    s.stride = m;
    s.first.assign(std::size_t(nx), -1);
    s.weights.assign(std::size_t(nx), {});
    const int last = (nx - 1) / m;  // nodes 0 .. last
    if (m < 2 || last < kNodes - 1) {
        s.stride = 1;
        return s;
    }
    for (int c = 1; c < last * m; ++c) {
        if (c % m == 0) continue;
        // The eight nodes nearest c (four on each side), shifted to stay within 0 .. last.
        const int j = c / m;
        const int f = std::clamp(j - kNodes / 2 + 1, 0, last - kNodes + 1);
        const double x = double(c) / m;  // in node steps
        double product = 1.0;
        for (int l = 0; l < kNodes; ++l) product *= x - (f + l);
        const double k = std::abs(product) * scale;
        if (!(k <= tolerance)) continue;
        std::array<double, 8> w{};
        double lebesgue = 0.0;
        for (int l = 0; l < kNodes; ++l) {
            double num = 1.0, den = 1.0;
            for (int o = 0; o < kNodes; ++o) {
                if (o == l) continue;
                num *= x - (f + o);
                den *= double(l - o);
            }
            w[std::size_t(l)] = num / den;
            lebesgue += std::abs(w[std::size_t(l)]);
        }
        // A cut-off's step at the nodes reaches the column times sum |L_l| (one-sided stencils
        // near the ends: up to 6.3 at m = 2): such columns stay exact.
        if (!(lebesgue <= kMaxLebesgue)) continue;
        s.weights[std::size_t(c)] = w;
        s.first[std::size_t(c)] = f * m;
        s.worst = std::max(s.worst, k);
    }
    return s;
}

}  // namespace

std::size_t ColumnStencils::exactCount() const
{
    return std::size_t(std::count(first.begin(), first.end(), -1));
}

double rayEighthDerivativeBound(double b)
{
    const double t = std::min(std::abs(b), 1.0) * 64.0;
    return kRayBound[std::size_t(std::min(63.0, t))];
}

double segmentEighthDerivativeBound(const GaussianSegment& segment, int axis)
{
    const double sigma = segment.sigma, length = segment.length;
    const double w1 = segment.w0 + segment.slope * length;
    const double wMin = std::min(segment.w0, w1), wMax = std::max(segment.w0, w1);
    if (!(wMin > 0.0) || !(length > 0.0)) return kEighthDerivativeBound;
    const double farEnd = std::exp(-length * length / (16.0 * sigma * sigma));
    const double ramp = std::min(1.0, 2.0 * std::sqrt(std::numbers::pi) * sigma / length);
    const double c8 = rayEighthDerivativeBound(segment.u[axis]) * (1.0 + (wMin * farEnd + (wMax - wMin) * ramp) / wMax);
    return std::min(c8, kEighthDerivativeBound);
}

ColumnStencils columnStencils(int nx, double spacing, double sigma, double tolerance, double eighthBound)
{
    ColumnStencils best;
    best.first.assign(std::size_t(std::max(nx, 0)), -1);
    best.weights.assign(std::size_t(std::max(nx, 0)), {});
    if (!(spacing > 0.0) || !(sigma > 0.0) || !(tolerance > 0.0) || !(eighthBound > 0.0)) return best;
    std::size_t bestExact = best.first.size();
    for (int m = 2; m <= 4; ++m) {
        // K = |prod (x - x_l)| in node steps times (m spacing / sigma)^8 C8 / 8!.
        const double scale = std::pow(m * spacing / sigma, 8) * eighthBound / kFactorial8;
        ColumnStencils s = stencilsOf(nx, m, scale, tolerance);
        if (s.stride > 1 && s.exactCount() < bestExact) {
            bestExact = s.exactCount();
            best = std::move(s);
        }
    }
    return best;
}

void interpolateColumns(const ColumnStencils& stencils, int ny, const std::uint64_t* columnTiles, int tile,
                        double* values)
{
    if (stencils.stride < 2) return;
    const int m = stencils.stride;
    for (std::size_t c = 0; c < stencils.first.size(); ++c) {
        const int f = stencils.first[c];
        if (f < 0) continue;
        const std::array<double, 8>& w = stencils.weights[c];
        const double* node[kNodes];
        for (int l = 0; l < kNodes; ++l) node[l] = values + std::size_t(f + l * m) * ny;
        double* out = values + c * std::size_t(ny);
        // Runs of needed tiles b0..b1: points b0 tile .. (b1 + 1) tile + 1 (evaluate()'s runs).
        forEachTileRun(columnTiles[c], [&](int b0, int b1) {
            const int kHi = std::min(ny - 1, (b1 + 1) * tile + 1);
            for (int k = b0 * tile; k <= kHi; ++k) {
                double v = 0.0;
                for (int l = 0; l < kNodes; ++l) v += w[std::size_t(l)] * node[l][k];
                out[k] = v;
            }
        });
    }
}

}  // namespace voxlat
