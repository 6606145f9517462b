/// @file GradientShift.h
/// @brief A sheet of a given thickness in millimetres around any field's zero set, made by
/// shifting the field along its unit gradient (seed 004; lattice-reference.md §2).
#pragma once

#include "fields/core/FieldNode.h"

#include <array>
#include <string>

namespace voxlat {

/// How the in-plane and build-direction magnitudes follow a build direction b.
enum class ShiftRotation {
    /// Seed 004: the magnitude vector M = (d, d, l) is rotated by Rodrigues' formula from +z to
    /// b and taken per component in absolute value, M' = |R(b) M|; s = M' (.) n (element-wise).
    Rodrigues,
    /// The magnitude ellipsoid is rotated instead of the vector: s = R diag(d, d, l) R^T n
    /// = d n + (l - d)(n.b) b. Equal to Rodrigues for b = +-z and along the coordinate axes,
    /// continuous for every b and uniform when d = l.
    Tensor,
};

/// Where the shift's magnitudes and build direction come from. Magnitudes are shift lengths in
/// millimetres (half the wall thickness); fields let them vary in space (negative values count
/// as zero). Either `uniform` is set, or `wall` and `layer`.
struct ShiftSpec {
    FieldPtr uniform;                             ///< m: the shift along the unit gradient, the same in every direction
    FieldPtr wall;                                ///< d: the shift in the build plane
    FieldPtr layer;                               ///< l: the shift along the build direction
    Vec3d direction{0.0, 0.0, 1.0};               ///< constant build direction (any length > 0)
    FieldPtr directionGradient;                   ///< or: the unit gradient of this field
    std::array<FieldPtr, 3> directionComponents;  ///< or: (bx, by, bz) from three fields
    ShiftRotation rotation = ShiftRotation::Tensor;
    double scale = 1.0;  ///< multiplies every magnitude (0.5 turns total wall thicknesses into shifts)
    /// One side only (an offset): F(x) = f(x - s(x)), f's zero set moved by s along the unit
    /// gradient. The magnitude keeps its sign (m < 0 moves the set against the gradient).
    bool oneSided = false;
    std::string label = "gradient shift";  ///< names the node in error messages
};

/// The sheet between the two shifted copies of a field f:
///   f+(x) = f(x + s(x)),  f-(x) = f(x - s(x)),  F(x) = max(f-(x), -f+(x)),
/// negative inside (f- <= 0 <= f+), where s(x) is the shift vector built from the unit gradient
/// n(x) = grad f / |grad f| and the magnitudes: s = m n (uniform) or the anisotropic forms of
/// ShiftRotation. Where grad f vanishes the shift is zero. Values are in f's units.
///
/// With ShiftSpec::oneSided, F(x) = f-(x) = f(x - m n(x)) (uniform magnitude m of either sign):
/// the zero set moved m along the unit gradient, to first order in m times the curvature.
///
/// Evaluation works in batches: one gradients() call for n, one values() call on the 2N shifted
/// points. Gradients are exact up to the central difference used for the Jacobian of s:
/// grad F = (I -+ J_s)^T grad f(x -+ s), J_s from s at x +- h e_a (h = 1e-5 mm).
class GradientShift final : public FieldNode {
public:
    GradientShift(FieldPtr field, ShiftSpec spec);

    void values(std::span<const Vec3d> points, std::span<double> out) const override;
    void gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const override;
    /// Uses the child's gridGradients (separable for a TPMS) for the unit gradients.
    void gridValues(const GridBatch& batch, std::span<double> out) const override;
    /// The child's bound over the box grown by the largest shift, folded through max(a, -b).
    Interval bound(const Box3& box) const override;
    /// A period the field and every magnitude and direction field share.
    double period(int axis) const override;

    /// Shift vectors s at @a points (evaluates the child's gradients there).
    void shifts(std::span<const Vec3d> points, std::span<Vec3d> out) const;
    /// An upper bound of |s| over @a box.
    double maxShift(const Box3& box) const;

    /// |R(b) (d, d, l)| per component, R the Rodrigues rotation taking +z to the unit vector @a b.
    /// b = +z gives (d, d, l) exactly (no rotation); b = -z takes the half-turn about x, which
    /// also gives (d, d, l) exactly; near -z the closed form avoids the cancellation in 1 + c.
    static Vec3d rotatedMagnitudes(const Vec3d& b, double d, double l);
    /// The shift vector for unit gradient @a n, unit build direction @a b and magnitudes d, l.
    static Vec3d anisotropicShift(const Vec3d& n, const Vec3d& b, double d, double l, ShiftRotation rotation);

private:
    /// @a n shift vectors from the child's gradients @a grad at @a points (@a points may be empty
    /// when every magnitude and the direction are constants).
    void shiftsFromGradients(std::span<const Vec3d> points, const Vec3d* grad, Vec3d* out, std::size_t n) const;
    /// Sheet values from points and their shift vectors (one child values() call).
    void sheetValues(std::span<const Vec3d> points, const Vec3d* shift, double* out, double* fPlus,
                     double* fMinus) const;

    FieldPtr mField;
    ShiftSpec mSpec;
    bool mConstantMagnitudes = false;  ///< every magnitude and the direction are constants
    Vec3d mConstantM{0.0};             ///< precomputed M' (Rodrigues) when constant
    Vec3d mDirection{0.0, 0.0, 1.0};   ///< normalised constant direction
    double mConstantD = 0.0, mConstantL = 0.0, mConstantUniform = 0.0;
};

}  // namespace voxlat
