#include "fields/shapes/SurfaceDistance.h"

#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace voxlat {

SurfaceDistance::SurfaceDistance(std::vector<FieldPtr> operands) : mOperands(std::move(operands))
{
    if (mOperands.empty()) throw std::invalid_argument("SurfaceDistance needs at least one operand");
}

void SurfaceDistance::values(std::span<const Vec3d> points, std::span<double> out) const
{
    std::array<Vec3d, kBatchSize> grad;
    forEachChunk(points.size(), [&](std::size_t begin, std::size_t count) {
        gradients(points.subspan(begin, count), out.subspan(begin, count), std::span<Vec3d>(grad.data(), count));
    });
}

void SurfaceDistance::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    std::array<double, kBatchSize> v;
    std::array<Vec3d, kBatchSize> g;
    forEachChunk(points.size(), [&](std::size_t begin, std::size_t count) {
        const std::span<const Vec3d> p = points.subspan(begin, count);
        for (std::size_t i = 0; i < mOperands.size(); ++i) {
            mOperands[i]->gradients(p, std::span<double>(v.data(), count), std::span<Vec3d>(g.data(), count));
            for (std::size_t k = 0; k < count; ++k) {
                const double length = g[k].length();
                const double d = firstOrderSignedDistance(v[k], length);
                if (i == 0 || d > out[begin + k]) {
                    out[begin + k] = d;
                    grad[begin + k] = length > 0.0 ? g[k] / length : Vec3d(0.0);
                }
            }
        }
    });
}

Interval SurfaceDistance::bound(const Box3&) const
{
    const double inf = std::numeric_limits<double>::infinity();
    return {-inf, inf};
}

}  // namespace voxlat
