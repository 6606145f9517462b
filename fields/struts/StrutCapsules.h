/// @file StrutCapsules.h
/// @brief The conventional strut solid: exact round struts (a sphere at each end, a cone
/// between), joined by a hard union or a smooth blend.
#pragma once

#include "fields/struts/StrutIndex.h"

#include <vector>

namespace voxlat {

/// One round strut: segment [a, b] with radius ra at a and rb at b (linear in between).
struct CapsuleStrut {
    Vec3d a{0.0}, b{0.0};
    double ra = 0.0, rb = 0.0;
};

/// Exact signed distance of a round cone (the convex hull of the end spheres); with equal radii
/// a capsule. Negative inside. @a grad (optional) receives its gradient (unit length).
double roundConeDistance(const Vec3d& p, const CapsuleStrut& s, Vec3d* grad = nullptr);

/// min over struts of roundConeDistance (blend = 0: a hard union, exact outside the solid), or
/// the polynomial smooth minimum folded in strut index order (blend > 0: joints rounded over
/// about `blend` millimetres). Values are capped at clampDistance(): far from every strut the
/// field is that constant, which keeps evaluation local. The field is 1-Lipschitz.
class StrutCapsules final : public FieldNode {
public:
    StrutCapsules(const std::vector<CapsuleStrut>& struts, double blend, double clampDistance);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;

    double clampDistance() const { return mClamp; }

private:
    double pointValue(const Vec3d& p, const std::vector<std::uint32_t>& cand, Vec3d* grad) const;

    std::vector<CapsuleStrut> mStruts;
    std::vector<double> mReachSqr;
    std::vector<double> mRMax;
    double mBlend, mClamp;
    StrutIndex mIndex;
};

}  // namespace voxlat
