#include "fields/maps/VectorField.h"

#include <cmath>
#include <vector>

namespace voxlat {

VectorField::VectorField(std::array<FieldPtr, 3> components) : mComponents(std::move(components)) {}

void VectorField::directions(std::span<const Vec3d> points, std::span<Vec3d> out) const
{
    std::vector<double> c(std::min(points.size(), kBatchSize));
    forEachChunk(points.size(), [&](std::size_t begin, std::size_t count) {
        for (int a = 0; a < 3; ++a) {
            mComponents[a]->values(points.subspan(begin, count), std::span<double>(c.data(), count));
            for (std::size_t n = 0; n < count; ++n) out[begin + n][a] = c[n];
        }
    });
}

void VectorField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    std::vector<Vec3d> v(points.size());
    directions(points, v);
    for (std::size_t n = 0; n < points.size(); ++n) out[n] = v[n].length();
}

void VectorField::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    // |v| has gradient (J^T v) / |v| where J holds the components' gradients as rows.
    const std::size_t n = points.size();
    std::vector<double> c(3 * n);
    std::vector<Vec3d> g(3 * n);
    for (int a = 0; a < 3; ++a)
        mComponents[a]->gradients(points, std::span<double>(c.data() + a * n, n),
                                  std::span<Vec3d>(g.data() + a * n, n));
    for (std::size_t i = 0; i < n; ++i) {
        const double len = std::sqrt(c[i] * c[i] + c[n + i] * c[n + i] + c[2 * n + i] * c[2 * n + i]);
        out[i] = len;
        grad[i] = len > 0 ? (c[i] * g[i] + c[n + i] * g[n + i] + c[2 * n + i] * g[2 * n + i]) / len : Vec3d(0.0);
    }
}

Interval VectorField::bound(const Box3& box) const
{
    return sqrt(sqr(mComponents[0]->bound(box)) + sqr(mComponents[1]->bound(box)) + sqr(mComponents[2]->bound(box)));
}

}  // namespace voxlat
