/// @file GaussianTable.h
/// @brief A tabulated erf integral and Gaussian for the fast (per-leaf) strut convolution path.
///
/// In units of sigma (y = x / sigma) the segment integral needs
///   U(y) = int_0^y exp(-t^2 / 2) dt = sqrt(pi / 2) erf(y / sqrt 2)   and   g(y) = exp(-y^2 / 2) = U'(y).
/// Both are stored at nodes y_i = i / 128 on [0, 9] with their derivatives (U' = g, g' = -y g) and
/// interpolated by cubic Hermite polynomials, whose error is at most delta^4 / 384 max |f''''|
/// (delta = 1/128): U'''' = -(y^3 - 3y) g, |U''''| <= 1.38, so |U - U~| <= 1.4e-11; g'''' =
/// (y^4 - 6y^2 + 3) g, |g''''| <= 3, so |g - g~| <= 2.92e-11. Beyond y = 9, U equals sqrt(pi / 2)
/// and g is below 2.6e-18 (returned as 0) to double precision. The strut convolution's cut-off
/// already drops up to 1e-4 of a strut's peak (sqrt(2 pi) = 2.5 in these units), so the table adds
/// nothing visible; tests check the bound against std::erf and std::exp.
#pragma once

#include <array>
#include <cmath>
#include <numbers>

namespace voxlat {

class GaussianTable {
public:
    static constexpr int kPerUnit = 128;
    static constexpr double kEnd = 9.0;
    static constexpr int kNodes = int(kEnd * kPerUnit) + 2;
    /// The documented interpolation error bounds (see the file).
    static constexpr double kErfIntegralError = 1.4e-11;
    static constexpr double kGaussianError = 2.92e-11;
    static constexpr double kDelta = 1.0 / kPerUnit;
    static constexpr double kHalfRootTwoPi = 1.2533141373155003;  // sqrt(pi / 2)

    static const GaussianTable& instance()
    {
        static const GaussianTable table;
        return table;
    }

    /// U(y) for any y (odd function) and g(y) (even), interpolated.
    void evaluate(double y, double& u, double& g) const
    {
        const double a = std::abs(y);
        if (!(a < kEnd)) {
            u = std::copysign(kHalfRootTwoPi, y);
            g = 0.0;
            return;
        }
        const Span h = span(a);
        u = std::copysign(h.h00 * h.p->u + h.h10 * h.p->g + h.h01 * h.q->u + h.h11 * h.q->g, y);
        g = h.h00 * h.p->g + h.h10 * h.p->dg + h.h01 * h.q->g + h.h11 * h.q->dg;
    }

    /// U(y) only.
    double erfIntegral(double y) const
    {
        const double a = std::abs(y);
        if (!(a < kEnd)) return std::copysign(kHalfRootTwoPi, y);
        const Span h = span(a);
        return std::copysign(h.h00 * h.p->u + h.h10 * h.p->g + h.h01 * h.q->u + h.h11 * h.q->g, y);
    }

    /// The nodes as kNodes triples (U, g, g') at y = i kDelta: for vector code that gathers them
    /// (StrutRows.h), which must interpolate exactly as span() and evaluate() do.
    const double* nodeData() const { return &mNodes[0].u; }

private:
    struct Node {
        double u, g, dg;
    };
    static_assert(sizeof(Node) == 3 * sizeof(double), "nodeData() reads the nodes as packed triples");

    /// The two nodes around a (0 <= a < kEnd) and the cubic Hermite weights of their values and
    /// slopes (slopes per node spacing).
    struct Span {
        const Node* p;
        const Node* q;
        double h00, h10, h01, h11;
    };
    Span span(double a) const
    {
        const double s = a * kPerUnit;
        const int i = int(s);
        const double t = s - i;
        const double t2 = t * t, t3 = t2 * t;
        return {&mNodes[i],       &mNodes[i + 1],    2 * t3 - 3 * t2 + 1, (t3 - 2 * t2 + t) * kDelta,
                -2 * t3 + 3 * t2, (t3 - t2) * kDelta};
    }

    GaussianTable()
    {
        for (int i = 0; i < kNodes; ++i) {
            const double y = i * kDelta;
            const double g = std::exp(-0.5 * y * y);
            mNodes[i] = {kHalfRootTwoPi * std::erf(y / std::numbers::sqrt2), g, -y * g};
        }
    }

    std::array<Node, kNodes> mNodes;
};

}  // namespace voxlat
