#include "fields/shapes/BoxField.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace voxlat {

void BoxField::gridValues(const GridBatch& batch, std::span<double> out) const
{
    // Per axis: q = |x - c| - h and its positive part o, from the same coordinates eval() sees
    // (batch.point's origin + index * spacing).
    auto axis = [&](int a, int n, std::vector<double>& q, std::vector<double>& o) {
        q.resize(std::size_t(n));
        o.resize(std::size_t(n));
        for (int i = 0; i < n; ++i) {
            q[std::size_t(i)] = std::abs((batch.origin[a] + i * batch.spacing[a]) - mCenter[a]) - mHalf[a];
            o[std::size_t(i)] = std::max(q[std::size_t(i)], 0.0);
        }
    };
    thread_local std::vector<double> qx, ox, qy, oy, qz, oz;
    axis(0, batch.nx, qx, ox);
    axis(1, batch.ny, qy, oy);
    axis(2, batch.nz, qz, oz);
    std::size_t n = 0;
    for (int i = 0; i < batch.nx; ++i)
        for (int j = 0; j < batch.ny; ++j) {
            const double xx = ox[std::size_t(i)] * ox[std::size_t(i)], yy = oy[std::size_t(j)] * oy[std::size_t(j)];
            const double xy = xx + yy;
            const double qi = qx[std::size_t(i)], qj = qy[std::size_t(j)];
            for (int k = 0; k < batch.nz; ++k, ++n) {
                const double qk = qz[std::size_t(k)];
                // eval(): sqrt(ox ox + oy oy + oz oz) + min(max(qx, max(qy, qz)), 0), same order.
                out[n] = std::sqrt(xy + oz[std::size_t(k)] * oz[std::size_t(k)]) +
                         std::min(std::max(qi, std::max(qj, qk)), 0.0);
            }
        }
}

}  // namespace voxlat
