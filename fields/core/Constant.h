/// @file Constant.h
/// @brief A field with the same value everywhere (a constant thickness or density).
#pragma once

#include "fields/core/FieldNode.h"

#include <algorithm>

namespace voxlat {

/// value(p) = c everywhere; gradient zero.
class ConstantField final : public FieldNode {
public:
    explicit ConstantField(double value) : mValue(value) {}

    void values(std::span<const Vec3d>, std::span<double> out) const override
    {
        std::fill(out.begin(), out.end(), mValue);
    }
    void gradients(std::span<const Vec3d>, std::span<double> out, std::span<Vec3d> grad) const override
    {
        std::fill(out.begin(), out.end(), mValue);
        std::fill(grad.begin(), grad.end(), Vec3d(0.0));
    }
    void gridValues(const GridBatch&, std::span<double> out) const override
    {
        std::fill(out.begin(), out.end(), mValue);
    }
    Interval bound(const Box3&) const override { return Interval(mValue); }
    double period(int) const override { return kInvariant; }

    double value() const { return mValue; }

private:
    double mValue;
};

}  // namespace voxlat
