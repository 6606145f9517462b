/// @file IsoRadius.h
/// @brief A Gaussian convolution field F re-expressed in millimetres: the radius an isolated
/// infinite strut of peak P would have at iso-value F,
///   rho(F) = sigma * sqrt(2 ln(P / F)),
/// a monotone (decreasing) map, so {F >= t} = {rho <= rho(t)} and quantiles carry over.
///
/// Why: across a strut F falls like exp(-r^2 / (2 sigma^2)), so marching cubes' linear
/// interpolation of F places the surface measurably off (about +1.5 % of the volume at 0.1 mm
/// voxels, sigma 0.5, r 0.9). rho equals r along an isolated strut, so the interpolation is
/// exact there and nearly so everywhere. Values are capped at rhoMax (where F is below
/// P exp(-rhoMax^2 / (2 sigma^2)), including F = 0 far from every strut); where joints sum
/// above P the value continues as -sigma sqrt(2 ln(F / P)), so the map stays strictly monotone.
#pragma once

#include "fields/core/FieldNode.h"
#include "fields/core/PlaneBands.h"

namespace voxlat {

class IsoRadius final : public FieldNode, public PlaneBands {
public:
    IsoRadius(FieldPtr convolution, double peak, double sigma, double rhoMax);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    Interval bound(const Box3& box) const override;
    /// The convolution's planeValues with the band mapped to F (rho is decreasing, so the sides
    /// swap), widened by 1e-9 of sigma against rounding; gridValues when it has none. Where the
    /// convolution's plane values are approximate (PlaneBands::planeTolerance() > 0) the open
    /// tiles' values are mapped in single precision (radiiSingle).
    void planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                     std::span<signed char> side, std::span<const TileNeed> need) const override;

    /// rho(F) (capped) and its inverse, F(rho) = P exp(-sign(rho) rho^2 / (2 sigma^2)).
    double radiusOf(double f) const;
    double valueOf(double rho) const;
    /// radiusOf() of every value in place, the same doubles (its divisions and square roots in
    /// loops of their own, apart from the logarithm's calls).
    void radii(std::span<double> values) const;
    /// radiusOf() of every value in place in single precision (IsoRadiusSingle.h: within about
    /// 1e-7 of sigma of it), the same doubles on every CPU.
    void radiiSingle(std::span<double> values) const;
    /// Whether planeValues maps its open tiles with radiiSingle.
    bool planeSingle() const;

private:
    FieldPtr mF;
    double mPeak, mSigma, mRhoMax, mFMin;
};

}  // namespace voxlat
