#include "engine/properties/HexElement.h"

#include <cmath>

namespace voxlat::homogenization {

namespace {

/// Gradients of the 8 shape functions at the 8 Gauss points of a box, and the point weight.
struct ShapeGradients {
    double grad[8][8][3];  // [gauss point][node][axis]
    double weight;
};

ShapeGradients shapeGradients(double hx, double hy, double hz)
{
    ShapeGradients s{};
    // Gauss points of [0, 1]: 1/2 -+ 1/(2 sqrt 3), weight 1/2 each.
    const double g[2] = {0.5 - 0.5 / std::sqrt(3.0), 0.5 + 0.5 / std::sqrt(3.0)};
    const double h[3] = {hx, hy, hz};
    for (int q = 0; q < 8; ++q) {
        const double xi[3] = {g[q & 1], g[(q >> 1) & 1], g[(q >> 2) & 1]};
        for (int a = 0; a < 8; ++a) {
            const int c[3] = {a & 1, (a >> 1) & 1, (a >> 2) & 1};
            double n1[3], d1[3];  // 1D shape value and derivative per axis
            for (int k = 0; k < 3; ++k) {
                n1[k] = c[k] ? xi[k] : 1.0 - xi[k];
                d1[k] = (c[k] ? 1.0 : -1.0) / h[k];
            }
            s.grad[q][a][0] = d1[0] * n1[1] * n1[2];
            s.grad[q][a][1] = n1[0] * d1[1] * n1[2];
            s.grad[q][a][2] = n1[0] * n1[1] * d1[2];
        }
    }
    s.weight = hx * hy * hz / 8.0;
    return s;
}

/// Exactly symmetric: the operator built from it is then symmetric to rounding, which CG needs.
void symmetrize(std::vector<double>& m, int n)
{
    for (int i = 0; i < n; ++i)
        for (int j = i + 1; j < n; ++j) m[i * n + j] = m[j * n + i] = 0.5 * (m[i * n + j] + m[j * n + i]);
}

}  // namespace

std::array<std::array<double, 6>, 6> isotropicStiffness(double E, double nu)
{
    const double lambda = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
    const double mu = E / (2.0 * (1.0 + nu));
    std::array<std::array<double, 6>, 6> C{};
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) C[i][j] = lambda;
        C[i][i] = lambda + 2.0 * mu;
        C[i + 3][i + 3] = mu;
    }
    return C;
}

std::vector<double> elasticElementMatrix(double hx, double hy, double hz, double E, double nu)
{
    const ShapeGradients s = shapeGradients(hx, hy, hz);
    const auto C = isotropicStiffness(E, nu);
    std::vector<double> ke(24 * 24, 0.0);
    for (int q = 0; q < 8; ++q) {
        double B[6][24] = {};
        for (int a = 0; a < 8; ++a) {
            const double* g = s.grad[q][a];
            B[0][3 * a + 0] = g[0];
            B[1][3 * a + 1] = g[1];
            B[2][3 * a + 2] = g[2];
            B[3][3 * a + 1] = g[2];
            B[3][3 * a + 2] = g[1];
            B[4][3 * a + 0] = g[2];
            B[4][3 * a + 2] = g[0];
            B[5][3 * a + 0] = g[1];
            B[5][3 * a + 1] = g[0];
        }
        double CB[6][24] = {};
        for (int i = 0; i < 6; ++i)
            for (int k = 0; k < 6; ++k)
                for (int j = 0; j < 24; ++j) CB[i][j] += C[i][k] * B[k][j];
        for (int i = 0; i < 24; ++i)
            for (int j = 0; j < 24; ++j) {
                double v = 0.0;
                for (int k = 0; k < 6; ++k) v += B[k][i] * CB[k][j];
                ke[i * 24 + j] += s.weight * v;
            }
    }
    symmetrize(ke, 24);
    return ke;
}

std::vector<double> conductionElementMatrix(double hx, double hy, double hz, double k)
{
    const ShapeGradients s = shapeGradients(hx, hy, hz);
    std::vector<double> ke(8 * 8, 0.0);
    for (int q = 0; q < 8; ++q)
        for (int a = 0; a < 8; ++a)
            for (int b = 0; b < 8; ++b) {
                const double* ga = s.grad[q][a];
                const double* gb = s.grad[q][b];
                ke[a * 8 + b] += s.weight * k * (ga[0] * gb[0] + ga[1] * gb[1] + ga[2] * gb[2]);
            }
    symmetrize(ke, 8);
    return ke;
}

std::vector<double> unitLoadField(int D, int loadCase, double hx, double hy, double hz)
{
    std::vector<double> u(8 * D, 0.0);
    for (int a = 0; a < 8; ++a) {
        const double x[3] = {(a & 1) * hx, ((a >> 1) & 1) * hy, ((a >> 2) & 1) * hz};
        if (D == 1) {
            u[a] = x[loadCase];
            continue;
        }
        double eps[3][3] = {};
        if (loadCase < 3) {
            eps[loadCase][loadCase] = 1.0;
        } else {
            // Voigt 3: yz, 4: xz, 5: xy; engineering shear 1 is a tensor shear of 1/2.
            const int i = loadCase == 3 ? 1 : 0;
            const int j = loadCase == 5 ? 1 : 2;
            eps[i][j] = eps[j][i] = 0.5;
        }
        for (int d = 0; d < 3; ++d) u[3 * a + d] = eps[d][0] * x[0] + eps[d][1] * x[1] + eps[d][2] * x[2];
    }
    return u;
}

}  // namespace voxlat::homogenization
