#include "engine/checks/SheetWalls.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace voxlat {

namespace {

/// The root of @a f between @a a (f <= 0) and @a b (f > 0), to 1e-6 of the units of a and b.
template <typename F>
double bisect(F&& f, double a, double b)
{
    for (int i = 0; i < 60 && std::abs(b - a) > 1e-6; ++i) {
        const double m = 0.5 * (a + b);
        (f(m) <= 0.0 ? a : b) = m;
    }
    return 0.5 * (a + b);
}

}  // namespace

SheetWallStats measureSheetWalls(const FieldNode& mid, const FieldNode& sheet, const Box3& box, double expected,
                                 int lines)
{
    std::vector<double> walls;
    const Vec3d e = box.extent();
    constexpr int kSteps = 64;
    const double step = expected / 16.0, reach = 4.0 * expected;
    for (int i = 0; i < lines; ++i)
        for (int j = 0; j < lines; ++j) {
            const double x = box.min.x() + (i + 0.5) / lines * e.x(), y = box.min.y() + (j + 0.5) / lines * e.y();
            auto at = [&](double z) { return Vec3d(x, y, z); };
            double z0 = box.min.z(), f0 = mid.value(at(z0));
            for (int k = 1; k <= kSteps; ++k) {
                const double z1 = box.min.z() + double(k) / kSteps * e.z(), f1 = mid.value(at(z1));
                if ((f0 <= 0.0) != (f1 <= 0.0)) {
                    const double sign = f0 <= 0.0 ? 1.0 : -1.0;
                    const double z = bisect([&](double z) { return sign * mid.value(at(z)); }, z0, z1);
                    const Vec3d p = at(z);
                    Vec3d n = mid.valueAndGradient(p).second;
                    const double length = n.length();
                    if (length > 0.0) {
                        n /= length;
                        // Each face: from inside the sheet (its mid-surface) out to where it is left.
                        double chord = 0.0;
                        bool closed = sheet.value(p) <= 0.0;
                        for (const double side : {1.0, -1.0}) {
                            auto g = [&](double s) { return sheet.value(p + side * s * n); };
                            double s = 0.0;
                            while (closed && s < reach && g(s + step) <= 0.0) s += step;
                            if (!(s < reach)) closed = false;
                            if (closed) chord += bisect(g, s, s + step);
                        }
                        if (closed) walls.push_back(chord);
                    }
                }
                z0 = z1;
                f0 = f1;
            }
        }
    SheetWallStats stats;
    stats.samples = walls.size();
    if (walls.empty()) return stats;
    std::sort(walls.begin(), walls.end());
    double sum = 0.0;
    for (const double w : walls) sum += w;
    stats.mean = sum / double(walls.size());
    stats.p01 = walls[std::size_t(0.01 * double(walls.size() - 1))];
    stats.min = walls.front();
    stats.max = walls.back();
    return stats;
}

}  // namespace voxlat
