#include "fields/frames/ParametricSurface.h"

#include <stdexcept>

namespace voxlat {

ParametricSurface::ParametricSurface(std::array<std::shared_ptr<const ExprProgram>, 3> coordinates)
    : mCoordinates(std::move(coordinates))
{
    for (const auto& c : mCoordinates)
        if (!c || c->inputCount() > 2)
            throw std::invalid_argument("ParametricSurface: each coordinate is an equation in u and v only");
}

Vec3d ParametricSurface::point(double u, double v) const
{
    const Vec3d origin(0.0);
    const double* inputs[2] = {&u, &v};
    Vec3d p;
    for (int a = 0; a < 3; ++a) {
        double out = 0.0;
        mCoordinates[a]->values(std::span<const Vec3d>(&origin, 1), inputs, std::span<double>(&out, 1));
        p[a] = out;
    }
    return p;
}

void ParametricSurface::values(std::span<const Vec3d>, std::span<double>) const
{
    throw std::logic_error("ParametricSurface: a surface is not a scalar field (the recipe builder refuses this use)");
}

void ParametricSurface::gradients(std::span<const Vec3d>, std::span<double>, std::span<Vec3d>) const
{
    throw std::logic_error("ParametricSurface: a surface is not a scalar field (the recipe builder refuses this use)");
}

Interval ParametricSurface::bound(const Box3&) const
{
    throw std::logic_error("ParametricSurface: a surface is not a scalar field (the recipe builder refuses this use)");
}

}  // namespace voxlat
