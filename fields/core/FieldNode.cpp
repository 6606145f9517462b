#include "fields/core/FieldNode.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace voxlat {

void FieldNode::gridValues(const GridBatch& batch, std::span<double> out) const
{
    std::vector<Vec3d> points;
    points.reserve(batch.size());
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j)
            for (int k = 0; k < batch.nz; ++k) points.push_back(batch.point(i, j, k));
    values(points, out);
}

void FieldNode::gridGradients(const GridBatch& batch, std::span<double> out, std::span<Vec3d> grad) const
{
    std::vector<Vec3d> points;
    points.reserve(batch.size());
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j)
            for (int k = 0; k < batch.nz; ++k) points.push_back(batch.point(i, j, k));
    gradients(points, out, grad);
}

void FieldNode::gridValuesShifted(const GridBatch& batch, std::span<const Vec3d> shift, std::span<double> plus,
                                  std::span<double> minus) const
{
    const std::size_t n = batch.size();
    std::vector<Vec3d> points(2 * n);
    std::size_t m = 0;
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j)
            for (int k = 0; k < batch.nz; ++k, ++m) {
                const Vec3d p = batch.point(i, j, k);
                points[m] = p + shift[m];
                points[n + m] = p - shift[m];
            }
    std::vector<double> values(2 * n);
    this->values(points, values);
    std::copy(values.begin(), values.begin() + n, plus.begin());
    std::copy(values.begin() + n, values.end(), minus.begin());
}

double FieldNode::value(const Vec3d& p) const
{
    double v = 0.0;
    values(std::span<const Vec3d>(&p, 1), std::span<double>(&v, 1));
    return v;
}

std::pair<double, Vec3d> FieldNode::valueAndGradient(const Vec3d& p) const
{
    double v = 0.0;
    Vec3d g(0.0);
    gradients(std::span<const Vec3d>(&p, 1), std::span<double>(&v, 1), std::span<Vec3d>(&g, 1));
    return {v, g};
}

double commonPeriod(double a, double b)
{
    if (a == FieldNode::kNoPeriod || b == FieldNode::kNoPeriod) return FieldNode::kNoPeriod;
    if (std::isinf(a)) return b;
    if (std::isinf(b)) return a;
    const double small = std::min(a, b), large = std::max(a, b);
    const double ratio = large / small;
    return std::abs(ratio - std::round(ratio)) <= 1e-9 * ratio ? large : FieldNode::kNoPeriod;
}

Interval lipschitzBound(const FieldNode& node, const Box3& box, double lipschitz)
{
    const double c = node.value(box.center());
    const double r = lipschitz * box.radius();
    return {c - r, c + r};
}

}  // namespace voxlat
