#include "engine/checks/Traps.h"

#include "fields/core/BlockLattice.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace voxlat {

namespace {

/// The samples open to the outside (1) or not (0, solid or a closed cavity), as a field: +1 and -1
/// at the nearest sample, +1 beyond the sampled box.
class OpenSpace final : public FieldNode {
public:
    OpenSpace(const Box3& box, double spacing, std::array<std::int64_t, 3> n, std::vector<std::uint8_t> open)
        : mBox(box), mSpacing(spacing), mN(n), mOpen(std::move(open))
    {
    }
    void values(std::span<const Vec3d> points, std::span<double> out) const override
    {
        for (std::size_t i = 0; i < points.size(); ++i) out[i] = at(points[i]);
    }
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override
    {
        for (std::size_t i = 0; i < points.size(); ++i) {
            out[i] = at(points[i]);
            for (int a = 0; a < 3; ++a) {
                Vec3d d(0.0);
                d[a] = mSpacing;
                grad[i][a] = (at(points[i] + d) - at(points[i] - d)) / (2.0 * mSpacing);
            }
        }
    }
    Interval bound(const Box3&) const override { return Interval(-1.0, 1.0); }

private:
    double at(const Vec3d& p) const
    {
        std::array<std::int64_t, 3> c{};
        for (int a = 0; a < 3; ++a) {
            c[a] = std::int64_t(std::floor((p[a] - mBox.min[a]) / mSpacing));
            if (c[a] < 0 || c[a] >= mN[a]) return 1.0;
        }
        return mOpen[std::size_t((c[0] * mN[1] + c[1]) * mN[2] + c[2])] ? 1.0 : -1.0;
    }
    Box3 mBox;
    double mSpacing;
    std::array<std::int64_t, 3> mN;
    std::vector<std::uint8_t> mOpen;
};

}  // namespace

std::vector<Trap> findTraps(const FieldNode& solid, const Box3& box, double spacing, const JobContext* context,
                            std::shared_ptr<const FieldNode>* openSpace, const Vec3d& up, double* lowestSolid)
{
    BlockLattice lattice;
    lattice.base = box.min;
    lattice.step = Vec3d(spacing);
    lattice.offset = Vec3d(0.5);
    for (int a = 0; a < 3; ++a) lattice.count[a] = std::max(1, int(std::ceil(box.extent()[a] / spacing - 1e-9)));
    const std::int64_t nx = lattice.count[0], ny = lattice.count[1], nz = lattice.count[2];
    const std::size_t total = std::size_t(nx * ny * nz);
    // 0 solid, 1 void not yet reached, 2 void reached (from outside or by a labelled cavity).
    std::vector<std::uint8_t> state(total, 0);
    // Per block, the lowest height along @a up of a solid sample (joined in block order below).
    std::vector<double> blockLowest(lowestSolid ? lattice.blockCount() : 0, std::numeric_limits<double>::infinity());
    {
        StageProgress progress(context, "looking for resin traps", lattice.blockCount());
        sampleBlocks(solid, lattice,
                     [&](std::size_t block, const GridBatch& batch, const std::array<int, 3>& first,
                         std::span<const double> values) {
                         std::size_t n = 0;
                         double lowest = std::numeric_limits<double>::infinity();
                         for (int i = 0; i < batch.nx; ++i)
                             for (int j = 0; j < batch.ny; ++j)
                                 for (int k = 0; k < batch.nz; ++k, ++n) {
                                     const bool isVoid = values[n] >= 0.0;
                                     state[std::size_t(((first[0] + i) * ny + (first[1] + j)) * nz + first[2] + k)] =
                                         isVoid ? 1 : 0;
                                     if (lowestSolid && !isVoid)
                                         lowest = std::min(lowest, batch.point(i, j, k).dot(up));
                                 }
                         if (lowestSolid) blockLowest[block] = lowest;
                         progress.add();
                     });
    }
    if (lowestSolid) {
        *lowestSolid = std::numeric_limits<double>::infinity();
        for (double l : blockLowest) *lowestSolid = std::min(*lowestSolid, l);
    }
    auto index = [&](std::int64_t i, std::int64_t j, std::int64_t k) { return std::size_t((i * ny + j) * nz + k); };
    std::vector<std::size_t> queue;
    // Visits the void region of @a seed (marking it reached), calling visit(index) on each sample.
    auto flood = [&](std::size_t seed, auto&& visit) {
        queue.clear();
        state[seed] = 2;
        queue.push_back(seed);
        for (std::size_t q = 0; q < queue.size(); ++q) {
            const std::size_t s = queue[q];
            visit(s);
            const std::int64_t k = std::int64_t(s % std::size_t(nz)), j = std::int64_t(s / std::size_t(nz)) % ny,
                               i = std::int64_t(s / std::size_t(nz * ny));
            const std::int64_t step[6][3] = {{-1, 0, 0}, {1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}, {0, 0, 1}};
            for (const auto& d : step) {
                const std::int64_t a = i + d[0], b = j + d[1], c = k + d[2];
                if (a < 0 || b < 0 || c < 0 || a >= nx || b >= ny || c >= nz) continue;
                const std::size_t t = index(a, b, c);
                if (state[t] == 1) {
                    state[t] = 2;
                    queue.push_back(t);
                }
            }
        }
    };
    // Everything the faces' void reaches is open to the outside.
    for (std::int64_t i = 0; i < nx; ++i)
        for (std::int64_t j = 0; j < ny; ++j)
            for (std::int64_t k = 0; k < nz; ++k) {
                const bool face = i == 0 || j == 0 || k == 0 || i == nx - 1 || j == ny - 1 || k == nz - 1;
                if (face && state[index(i, j, k)] == 1) flood(index(i, j, k), [](std::size_t) {});
            }
    if (context) context->checkCancelled();
    if (openSpace) {
        std::vector<std::uint8_t> open(total);
        for (std::size_t s = 0; s < total; ++s) open[s] = state[s] == 2;
        *openSpace =
            std::make_shared<OpenSpace>(box, spacing, std::array<std::int64_t, 3>{nx, ny, nz}, std::move(open));
    }
    auto centre = [&](std::size_t s) {
        const std::int64_t k = std::int64_t(s % std::size_t(nz)), j = std::int64_t(s / std::size_t(nz)) % ny,
                           i = std::int64_t(s / std::size_t(nz * ny));
        return Vec3d(box.min.x() + (double(i) + 0.5) * spacing, box.min.y() + (double(j) + 0.5) * spacing,
                     box.min.z() + (double(k) + 0.5) * spacing);
    };
    std::vector<Trap> traps;
    std::vector<std::size_t> members;
    for (std::size_t s = 0; s < total; ++s) {
        if (state[s] != 1) continue;
        members.clear();
        Vec3d sum(0.0);
        flood(s, [&](std::size_t t) {
            members.push_back(t);
            sum += centre(t);
        });
        Trap trap;
        trap.samples = members.size();
        trap.volumeMm3 = double(members.size()) * spacing * spacing * spacing;
        trap.centroid = sum / double(members.size());
        // Heights along @a up; samples within a thousandth of a sample of the lowest tie (an
        // oblique direction rounds the heights of one layer of samples apart).
        double lowestHeight = std::numeric_limits<double>::infinity(), nearest = lowestHeight;
        for (const std::size_t t : members) lowestHeight = std::min(lowestHeight, centre(t).dot(up));
        for (const std::size_t t : members) {
            const Vec3d p = centre(t);
            if (p.dot(up) > lowestHeight + 1e-3 * spacing) continue;
            const Vec3d off = p - trap.centroid;
            const double d = (off - off.dot(up) * up).lengthSqr();
            if (d < nearest) {
                nearest = d;
                trap.lowest = p;
            }
        }
        traps.push_back(trap);
    }
    std::stable_sort(traps.begin(), traps.end(), [](const Trap& a, const Trap& b) { return a.samples > b.samples; });
    return traps;
}

}  // namespace voxlat
