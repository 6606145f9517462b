#include "engine/checks/SurfaceThickness.h"

#include <algorithm>
#include <cmath>

namespace voxlat {

std::vector<float> surfaceThickness(const FieldNode& solid, const std::vector<openvdb::Vec3f>& points, double step,
                                    double most)
{
    const std::size_t n = points.size();
    std::vector<Vec3d> at(n), inward(n), grad(n);
    std::vector<double> value(n);
    for (std::size_t i = 0; i < n; ++i) at[i] = Vec3d(points[i].x(), points[i].y(), points[i].z());
    solid.gradients(at, value, grad);
    std::vector<float> chord(n, float(most));
    // Per open point: where the chord entered the solid (t along -gradient; a point a little off
    // the surface, as a decimated mesh's are, enters before or after 0), whether it is inside, and
    // the last sample's value.
    std::vector<double> entry(n, 0.0), previous(n, 0.0);
    std::vector<char> inside(n, 0);
    std::vector<std::size_t> open;
    for (std::size_t i = 0; i < n; ++i) {
        const double length = grad[i].length();
        if (!(length > 0.0) || !std::isfinite(length) || !std::isfinite(value[i])) continue;  // left at `most`
        inward[i] = -grad[i] / length;
        entry[i] = value[i] / length;  // first-order distance to the surface (negative: inside already)
        inside[i] = value[i] <= 0.0;
        previous[i] = value[i];
        open.push_back(i);
    }
    std::vector<Vec3d> batch;
    std::vector<double> out;
    const int steps = int(std::ceil(most / step));
    for (int k = 1; k <= steps && !open.empty(); ++k) {
        const double t = k * step;
        batch.resize(open.size());
        out.resize(open.size());
        for (std::size_t j = 0; j < open.size(); ++j) batch[j] = at[open[j]] + inward[open[j]] * t;
        solid.values(batch, out);
        std::size_t kept = 0;
        for (std::size_t j = 0; j < open.size(); ++j) {
            const std::size_t i = open[j];
            const double v = out[j], p = previous[i];
            // Where the values cross zero between t - step and t.
            const double crossing = t - step + (v != p ? p / (p - v) : 0.0) * step;
            if (!inside[i] && v <= 0.0) {
                inside[i] = 1;
                entry[i] = crossing;
            } else if (inside[i] && v > 0.0) {
                chord[i] = float(std::clamp(crossing - entry[i], 0.0, most));
                continue;
            }
            previous[i] = v;
            open[kept++] = i;
        }
        open.resize(kept);
    }
    return chord;
}

}  // namespace voxlat
