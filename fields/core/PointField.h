/// @file PointField.h
/// @brief Base for nodes defined by one templated point function: values, Dual3 gradients and
/// Interval bounds all come from Derived::eval<T>(x, y, z).
#pragma once

#include "fields/core/Dual.h"
#include "fields/core/FieldNode.h"

namespace voxlat {

/// CRTP helper: Derived provides `template <class T> T eval(const T& x, const T& y, const T& z) const`.
template <typename Derived>
class PointField : public FieldNode {
public:
    void values(std::span<const Vec3d> points, std::span<double> out) const override
    {
        const auto& self = static_cast<const Derived&>(*this);
        for (std::size_t n = 0; n < points.size(); ++n) out[n] = self.eval(points[n][0], points[n][1], points[n][2]);
    }
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override
    {
        const auto& self = static_cast<const Derived&>(*this);
        for (std::size_t n = 0; n < points.size(); ++n) {
            const Dual3 f =
                self.eval(Dual3(points[n][0], 1, 0, 0), Dual3(points[n][1], 0, 1, 0), Dual3(points[n][2], 0, 0, 1));
            out[n] = f.v;
            grad[n] = Vec3d(f.d[0], f.d[1], f.d[2]);
        }
    }
    Interval bound(const Box3& box) const override
    {
        return static_cast<const Derived&>(*this).eval(
            Interval(box.min[0], box.max[0]), Interval(box.min[1], box.max[1]), Interval(box.min[2], box.max[2]));
    }
};

}  // namespace voxlat
