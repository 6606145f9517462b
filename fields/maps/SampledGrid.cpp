#include "fields/maps/SampledGrid.h"

#include <algorithm>
#include <stdexcept>

namespace voxlat {

SampledGridField::SampledGridField(std::array<std::vector<double>, 3> coords, std::vector<double> values)
    : mCoords(std::move(coords)), mValues(std::move(values))
{
    std::size_t n = 1;
    for (const auto& c : mCoords) {
        if (c.empty()) throw std::invalid_argument("sampled grid: an axis without coordinates");
        for (std::size_t i = 1; i < c.size(); ++i)
            if (!(c[i] > c[i - 1])) throw std::invalid_argument("sampled grid: coordinates must increase");
        n *= c.size();
    }
    if (mValues.size() != n) throw std::invalid_argument("sampled grid: value count does not match the axes");
    const auto [lo, hi] = std::minmax_element(mValues.begin(), mValues.end());
    mMin = *lo;
    mMax = *hi;
}

void SampledGridField::locate(int a, double u, std::size_t& i, double& t, bool& inside) const
{
    const auto& c = mCoords[a];
    inside = false;
    if (c.size() == 1 || u <= c.front()) {
        i = 0;
        t = 0.0;
        return;
    }
    if (u >= c.back()) {
        i = c.size() - 2;
        t = 1.0;
        return;
    }
    i = std::size_t(std::upper_bound(c.begin(), c.end(), u) - c.begin()) - 1;
    t = (u - c[i]) / (c[i + 1] - c[i]);
    inside = true;
}

void SampledGridField::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    for (std::size_t n = 0; n < points.size(); ++n) {
        std::size_t idx[3];
        double t[3];
        bool inside[3];
        for (int a = 0; a < 3; ++a) locate(a, points[n][a], idx[a], t[a], inside[a]);
        double value = 0.0;
        Vec3d g(0.0);
        // Sum over the cell's corners (2 per used axis) with linear weights.
        for (int corner = 0; corner < 8; ++corner) {
            std::size_t c[3];
            double w = 1.0, dw[3] = {1.0, 1.0, 1.0};
            bool skip = false;
            for (int a = 0; a < 3; ++a) {
                const int bit = (corner >> a) & 1;
                if (mCoords[a].size() == 1) {
                    if (bit) skip = true;
                    c[a] = 0;
                    continue;
                }
                c[a] = idx[a] + bit;
                const double wa = bit ? t[a] : 1.0 - t[a];
                const double da = inside[a] ? (bit ? 1.0 : -1.0) / (mCoords[a][idx[a] + 1] - mCoords[a][idx[a]]) : 0.0;
                for (int b = 0; b < 3; ++b) dw[b] *= (a == b ? da : wa);
                w *= wa;
            }
            if (skip) continue;
            const double v = at(c[0], c[1], c[2]);
            value += w * v;
            for (int a = 0; a < 3; ++a)
                if (mCoords[a].size() > 1) g[a] += dw[a] * v;
        }
        out[n] = value;
        grad[n] = g;
    }
}

void SampledGridField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    std::vector<Vec3d> unused(points.size());
    gradients(points, out, unused);
}

Interval SampledGridField::bound(const Box3& box) const
{
    std::size_t lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
        const auto& c = mCoords[a];
        // Nodes of every cell that meets [min, max] along this axis.
        const auto first = std::upper_bound(c.begin(), c.end(), box.min[a]) - c.begin();
        const auto last = std::lower_bound(c.begin(), c.end(), box.max[a]) - c.begin();
        lo[a] = std::size_t(std::max<std::ptrdiff_t>(0, first - 1));
        hi[a] = std::size_t(std::min<std::ptrdiff_t>(std::ptrdiff_t(c.size()) - 1, last));
    }
    if ((hi[0] - lo[0] + 1) * (hi[1] - lo[1] + 1) * (hi[2] - lo[2] + 1) > 4096) return {mMin, mMax};
    Interval r(at(lo[0], lo[1], lo[2]));
    for (std::size_t i = lo[0]; i <= hi[0]; ++i)
        for (std::size_t j = lo[1]; j <= hi[1]; ++j)
            for (std::size_t k = lo[2]; k <= hi[2]; ++k) r = hull(r, Interval(at(i, j, k)));
    return r;
}

}  // namespace voxlat
