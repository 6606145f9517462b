// Property checks shared by the field tests: gradients against central differences of the
// node's own values, bounds that contain every sampled value.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/shapes/Boolean.h"
#include "fields/shapes/BoxField.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <functional>
#include <memory>
#include <random>
#include <vector>

namespace voxlat::test {

/// @a f passed through, its gridValues() batches and bound() calls counted (meets() passed on).
struct CountedField final : FieldNode {
    FieldPtr f;
    mutable std::atomic<int> batches{0}, bounds{0};
    /// Called with each batch (from the evaluating threads) when set.
    std::function<void(const GridBatch&)> seen;
    explicit CountedField(FieldPtr field) : f(std::move(field)) {}
    void values(std::span<const Vec3d> p, std::span<double> out) const override { f->values(p, out); }
    void gradients(std::span<const Vec3d> p, std::span<double> out, std::span<Vec3d> g) const override
    {
        f->gradients(p, out, g);
    }
    void gridValues(const GridBatch& batch, std::span<double> out) const override
    {
        ++batches;
        if (seen) seen(batch);
        f->gridValues(batch, out);
    }
    Interval bound(const Box3& box) const override
    {
        ++bounds;
        return f->bound(box);
    }
    bool meets(const Box3& box, const Interval& band) const override { return f->meets(box, band); }
};

/// Exact signed distance to an axis-aligned box (the test's own).
inline double boxDistance(const Vec3d& p, const Box3& b)
{
    Vec3d q;
    for (int a = 0; a < 3; ++a) q[a] = std::abs(p[a] - b.center()[a]) - 0.5 * b.extent()[a];
    const Vec3d outside(std::max(q.x(), 0.0), std::max(q.y(), 0.0), std::max(q.z(), 0.0));
    return outside.length() + std::min(std::max({q.x(), q.y(), q.z()}), 0.0);
}

/// @a f clipped to @a box (what a Job meshes: the result intersected with its domain).
inline FieldPtr clipped(FieldPtr f, const Box3& box)
{
    return std::make_shared<BooleanField>(BooleanOp::Intersection,
                                          std::vector<FieldPtr>{f, std::make_shared<BoxField>(box)});
}

inline std::vector<Vec3d> randomPoints(std::size_t n, double lo, double hi, unsigned seed)
{
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(lo, hi);
    std::vector<Vec3d> p(n);
    for (auto& v : p) v = Vec3d(u(rng), u(rng), u(rng));
    return p;
}

/// gradients() against central differences (step @a h) of values(), and the values of
/// gradients() against values().
inline void expectGradientsMatchFiniteDifferences(const FieldNode& f, const std::vector<Vec3d>& pts, double tol,
                                                  double h = 1e-5)
{
    std::vector<double> v(pts.size());
    std::vector<Vec3d> g(pts.size());
    f.gradients(pts, v, g);
    for (std::size_t n = 0; n < pts.size(); ++n) {
        EXPECT_NEAR(v[n], f.value(pts[n]), 1e-12);
        for (int a = 0; a < 3; ++a) {
            Vec3d p1 = pts[n], p0 = pts[n];
            p1[a] += h;
            p0[a] -= h;
            const double fd = (f.value(p1) - f.value(p0)) / (2 * h);
            EXPECT_NEAR(g[n][a], fd, tol * (1 + std::abs(fd))) << "axis " << a << " at " << pts[n];
        }
    }
}

/// bound() over random boxes (corners in [lo, hi]^3, sides up to @a boxSize) contains the values
/// at random points inside each box.
inline void expectBoundsContainValues(const FieldNode& f, double lo, double hi, double boxSize, unsigned seed)
{
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> corner(lo, hi), side(0.01, boxSize), t(0.0, 1.0);
    for (int trial = 0; trial < 100; ++trial) {
        const Vec3d min(corner(rng), corner(rng), corner(rng));
        const Box3 box{min, min + Vec3d(side(rng), side(rng), side(rng))};
        const Interval b = f.bound(box);
        std::vector<Vec3d> pts(100);
        for (auto& p : pts) p = box.min + Vec3d(t(rng), t(rng), t(rng)) * box.extent();
        std::vector<double> v(pts.size());
        f.values(pts, v);
        for (double x : v) {
            EXPECT_LE(b.lo, x + 1e-12);
            EXPECT_GE(b.hi, x - 1e-12);
        }
    }
}

/// A stack of sixteen leaves (8 x 8 x 128 points from @a origin, @a spacing apart) with every
/// other leaf unread: @a f's gridValues gives each read leaf's points values()'s doubles, bit for
/// bit, and the unread leaves zero (pointValuesBySlab's contract).
inline void expectStackLeafByLeaf(const FieldNode& f, const Vec3d& origin, double spacing)
{
    GridBatch stack;
    stack.origin = origin;
    stack.spacing = Vec3d(spacing);
    stack.nz = 128;
    stack.unread = 0xAAAAu;  // leaves 1, 3, .., 15
    std::vector<double> grid(stack.size(), -7.0), point(stack.size());
    std::vector<Vec3d> points;
    for (int i = 0; i < stack.nx; ++i)
        for (int j = 0; j < stack.ny; ++j)
            for (int k = 0; k < stack.nz; ++k) points.push_back(stack.point(i, j, k));
    f.gridValues(stack, grid);
    f.values(points, point);
    int nonZero = 0;
    for (std::size_t n = 0; n < points.size(); ++n) {
        const int leaf = int(n % 128) / 8;
        if (leaf % 2 == 1) {
            ASSERT_EQ(grid[n], 0.0) << "unread leaf " << leaf;
        } else {
            ASSERT_EQ(grid[n], point[n]) << "at " << points[n];
            nonZero += point[n] != 0.0;
        }
    }
    EXPECT_GT(nonZero, 0);
}

}  // namespace voxlat::test
