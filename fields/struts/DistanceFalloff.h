/// @file DistanceFalloff.h
/// @brief Aether's point and curve fields (metaballs): F(p) = sum_i w_i k(d_i(p)), d_i the
/// distance from p to source i (a point or a polyline), k a falloff of the distance.
#pragma once

#include "fields/struts/StrutIndex.h"

#include <vector>

namespace voxlat {

/// How a source's influence falls off with the distance d.
enum class Falloff {
    Inverse,        ///< k(d) = 1 / d
    InverseSquare,  ///< k(d) = 1 / d^2
    Gaussian,       ///< k(d) = exp(-d^2 / 2 sigma^2)
};

/// One source: a point (one vertex) or a polyline (two or more), and its weight.
struct FalloffSource {
    std::vector<Vec3d> vertices;
    double weight = 1.0;
};

/// The raw field F (larger near the sources). Wrap it in LevelSolid(SolidSide::Above, t) for the
/// solid F >= t, value t - F. The distance to a polyline is the least distance to its segments.
///
/// 1/d and 1/d^2 are infinite on a source: the distance is taken as at least kMinDistance there
/// (k and the gradient stay finite; only points within 1e-6 mm of a source see the clamp).
/// A Gaussian source contributes only where d < r_c = sigma sqrt(2 ln 1e12) (about 7.4 sigma,
/// dropping less than 1e-12 |w| per source): per leaf only the sources that reach it are summed.
/// Every evaluation path applies the same rule and sums in source order, so values, gridValues and
/// bounds agree and results do not depend on threads.
class DistanceFalloff final : public FieldNode {
public:
    /// @a sigma is used by Falloff::Gaussian only (> 0).
    DistanceFalloff(std::vector<FalloffSource> sources, Falloff falloff, double sigma = 0.0);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    /// Analytic: sum_i w_i k'(d_i) (p - q_i) / d_i, q_i the nearest point of source i.
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    /// Gathers the sources that reach the block once (Gaussian), then evaluates its points.
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    /// Per source the box's least and largest distances d_lo, d_hi bound its term between
    /// w k(d_hi) and w k(d_lo) (k falls with d); the terms are summed.
    Interval bound(const Box3& box) const override;

    /// k(d) for this field's falloff (d clamped to kMinDistance for the inverse kinds).
    double kernel(double d) const;
    /// The distance beyond which a source adds nothing: r_c for a Gaussian, else infinity.
    double cutoffRadius() const { return mCutoff; }
    std::size_t sourceCount() const { return mWeights.size(); }

    static constexpr double kMinDistance = 1e-6;  ///< mm

private:
    /// Segment indices that may reach @a box, ascending (all of them unless Gaussian).
    void candidates(const Box3& box, bool exact, std::vector<std::uint32_t>& out) const;
    /// F (and its gradient when @a grad is not null) at @a p from the candidate segments.
    double pointValue(const Vec3d& p, const std::vector<std::uint32_t>& cand, Vec3d* grad) const;

    Falloff mFalloff;
    double mSigma = 0.0, mCutoff = 0.0;
    std::vector<Vec3d> mA, mB;           ///< segments (a == b for a point source)
    std::vector<std::uint32_t> mSource;  ///< the source of each segment (ascending)
    std::vector<double> mWeights;        ///< per source
    std::vector<std::uint32_t> mAll;     ///< 0 .. segments - 1
    StrutIndex mIndex;                   ///< Gaussian: segments with reach r_c
};

}  // namespace voxlat
