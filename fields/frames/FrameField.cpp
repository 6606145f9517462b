#include "fields/frames/FrameField.h"

#include "fields/core/Dual.h"
#include "fields/core/Scratch.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace voxlat {

namespace {

/// The default reference switches from world x to world y where |ez . x| exceeds this.
constexpr double kNearX = 0.9;
/// A given reference counts as parallel to ez where |x - (x.ez) ez|^2 <= kParallel |x|^2.
constexpr double kParallel = 1e-12;

template <typename T>
using V3 = std::array<T, 3>;

// The few operations Gram-Schmidt needs that differ by number type.
inline double reciprocal(double a)
{
    return 1.0 / a;
}
inline Dual3 reciprocal(const Dual3& a)
{
    return Dual3(1.0) / a;
}
inline Interval reciprocal(Interval a)
{
    return {1.0 / a.hi, 1.0 / a.lo};
}  // a.lo > 0 (checked)
inline double root(double a)
{
    return std::sqrt(a);
}
inline Dual3 root(const Dual3& a)
{
    return sqrt(a);
}
inline Interval root(Interval a)
{
    return sqrt(a);
}
inline bool positive(double a)
{
    return a > 0.0;
}
inline bool positive(const Dual3& a)
{
    return a.v > 0.0;
}
inline bool positive(Interval a)
{
    return a.lo > 0.0;
}
// Entries of a unit vector lie in [-1, 1]; intervals are cut to it (they widen by dependency).
inline double unitEntry(double a)
{
    return a;
}
inline Dual3 unitEntry(const Dual3& a)
{
    return a;
}
inline Interval unitEntry(Interval a)
{
    return {std::max(a.lo, -1.0), std::min(a.hi, 1.0)};
}

template <typename T>
T norm2(const V3<T>& a)
{
    return sqr(a[0]) + sqr(a[1]) + sqr(a[2]);
}

/// v / |v|; false where |v| is not (surely) positive.
template <typename T>
bool normalize(const V3<T>& v, V3<T>& unit)
{
    const T vv = norm2(v);
    if (!positive(vv)) return false;
    const T inv = reciprocal(root(vv));
    for (int a = 0; a < 3; ++a) unit[a] = v[a] * inv;
    return true;
}

/// v / |v| over boxes of vectors: each entry t / sqrt(t^2 + s) (s the other two squares) rises
/// with t and falls with s where t > 0 (rises where t < 0), so its range is taken at the
/// corners: exact for independent entries, where v * (1 / |v|) would count v twice.
inline bool normalize(const V3<Interval>& v, V3<Interval>& unit)
{
    if (!positive(norm2(v))) return false;
    auto f = [](double t, double s) { return t / std::sqrt(t * t + s); };
    for (int a = 0; a < 3; ++a) {
        const Interval t = v[a], s = sqr(v[(a + 1) % 3]) + sqr(v[(a + 2) % 3]);
        unit[a] = unitEntry(Interval(f(t.lo, t.lo > 0 ? s.hi : s.lo), f(t.hi, t.hi > 0 ? s.lo : s.hi)));
    }
    return true;
}

/// Gram-Schmidt in any number type: {ex, ey, ez} from the z direction and the x reference.
/// Returns false where a length is not (surely) positive.
template <typename T>
bool orthonormalFrame(const V3<T>& z, const V3<T>& x, std::array<V3<T>, 3>& axes)
{
    V3<T>& ez = axes[2];
    if (!normalize(z, ez)) return false;
    const T along = x[0] * ez[0] + x[1] * ez[1] + x[2] * ez[2];
    V3<T> w;
    for (int a = 0; a < 3; ++a) w[a] = x[a] - along * ez[a];
    V3<T>& ex = axes[0];
    if (!normalize(w, ex)) return false;
    V3<T>& ey = axes[1];
    ey[0] = unitEntry(ez[1] * ex[2] - ez[2] * ex[1]);
    ey[1] = unitEntry(ez[2] * ex[0] - ez[0] * ex[2]);
    ey[2] = unitEntry(ez[0] * ex[1] - ez[1] * ex[0]);
    return true;
}

Vec3d defaultReference(double ezX)
{
    return std::abs(ezX) > kNearX ? Vec3d(0, 1, 0) : Vec3d(1, 0, 0);
}

/// Whether a point uses its given reference @a x: unless it is (nearly) parallel to the unit z.
bool usesGiven(const Vec3d& ez, const Vec3d& x)
{
    const Vec3d w = x - x.dot(ez) * ez;
    return w.lengthSqr() > kParallel * x.lengthSqr();
}

}  // namespace

FrameField::FrameField(std::shared_ptr<const VectorField> z, std::shared_ptr<const VectorField> x, std::string label)
    : mZ(std::move(z)), mX(std::move(x)), mLabel(std::move(label))
{
}

void FrameField::zeroDirection(const Vec3d& p) const
{
    std::ostringstream msg;
    msg << mLabel << ": the cells' z direction is zero (or not finite) at (" << p[0] << ", " << p[1] << ", " << p[2]
        << "): give a direction field that is non-zero everywhere in the domain";
    throw std::domain_error(msg.str());
}

void FrameField::framesFromVectors(std::size_t n, const Vec3d* z, const Vec3d* x, const Vec3d* points, Mat3d* out) const
{
    for (std::size_t i = 0; i < n; ++i) {
        const double len = z[i].length();
        if (!(len > 0.0) || !std::isfinite(len)) zeroDirection(points[i]);
        const Vec3d ez = z[i] / len;
        const Vec3d ref = x && usesGiven(ez, x[i]) ? x[i] : defaultReference(ez[0]);
        std::array<V3<double>, 3> axes{};
        // Cannot fail for a finite non-zero z: the reference chosen keeps a part orthogonal to it.
        if (!orthonormalFrame<double>({z[i][0], z[i][1], z[i][2]}, {ref[0], ref[1], ref[2]}, axes))
            zeroDirection(points[i]);
        for (int axis = 0; axis < 3; ++axis)
            for (int row = 0; row < 3; ++row) out[i](row, axis) = axes[axis][row];
    }
}

void FrameField::frames(std::span<const Vec3d> points, std::span<Mat3d> out) const
{
    forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
        ScratchLease scratch(6 * n);
        Vec3d* z = scratch.as<Vec3d>();
        Vec3d* x = z + n;
        mZ->directions(points.subspan(b, n), std::span<Vec3d>(z, n));
        if (mX) mX->directions(points.subspan(b, n), std::span<Vec3d>(x, n));
        framesFromVectors(n, z, mX ? x : nullptr, points.data() + b, out.data() + b);
    });
}

void FrameField::gridFrames(const GridBatch& batch, std::span<Mat3d> out) const
{
    const std::size_t n = batch.size();
    ScratchLease scratch(10 * n);
    Vec3d* z = scratch.as<Vec3d>();
    Vec3d* x = z + n;
    Vec3d* points = x + n;
    double* c = scratch.data() + 9 * n;
    for (int a = 0; a < 3; ++a) {
        mZ->component(a)->gridValues(batch, std::span<double>(c, n));
        for (std::size_t i = 0; i < n; ++i) z[i][a] = c[i];
        if (!mX) continue;
        mX->component(a)->gridValues(batch, std::span<double>(c, n));
        for (std::size_t i = 0; i < n; ++i) x[i][a] = c[i];
    }
    std::size_t i = 0;
    for (int ix = 0; ix < batch.nx; ++ix)
        for (int iy = 0; iy < batch.ny; ++iy)
            for (int iz = 0; iz < batch.nz; ++iz) points[i++] = batch.point(ix, iy, iz);
    framesFromVectors(n, z, mX ? x : nullptr, points, out.data());
}

void FrameField::frameDerivatives(std::span<const Vec3d> points, std::span<Mat3d> out,
                                  std::span<std::array<Mat3d, 3>> derivative) const
{
    forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
        // Components and their gradients: z in [0, 3n), x in [3n, 6n).
        ScratchLease values(6 * n);
        ScratchLease gradients(18 * n);
        double* c = values.data();
        Vec3d* g = gradients.as<Vec3d>();
        const auto span = points.subspan(b, n);
        for (int a = 0; a < 3; ++a) {
            mZ->component(a)->gradients(span, std::span<double>(c + a * n, n), std::span<Vec3d>(g + a * n, n));
            if (mX)
                mX->component(a)->gradients(span, std::span<double>(c + (3 + a) * n, n),
                                            std::span<Vec3d>(g + (3 + a) * n, n));
        }
        auto dual = [&](int slot, std::size_t i) {
            const Vec3d& d = g[slot * n + i];
            return Dual3(c[slot * n + i], d[0], d[1], d[2]);
        };
        for (std::size_t i = 0; i < n; ++i) {
            const Vec3d zv(c[i], c[n + i], c[2 * n + i]);
            const double len = zv.length();
            if (!(len > 0.0) || !std::isfinite(len)) zeroDirection(points[b + i]);
            V3<Dual3> ref;
            const Vec3d xv = mX ? Vec3d(c[3 * n + i], c[4 * n + i], c[5 * n + i]) : Vec3d(0.0);
            if (mX && usesGiven(zv / len, xv)) {
                ref = {dual(3, i), dual(4, i), dual(5, i)};
            } else {
                const Vec3d d = defaultReference(zv[0] / len);
                ref = {Dual3(d[0]), Dual3(d[1]), Dual3(d[2])};
            }
            std::array<V3<Dual3>, 3> axes{};
            if (!orthonormalFrame<Dual3>({dual(0, i), dual(1, i), dual(2, i)}, ref, axes)) zeroDirection(points[b + i]);
            Mat3d& r = out[b + i];
            std::array<Mat3d, 3>& dr = derivative[b + i];
            for (int axis = 0; axis < 3; ++axis)
                for (int row = 0; row < 3; ++row) {
                    r(row, axis) = axes[axis][row].v;
                    for (int k = 0; k < 3; ++k) dr[k](row, axis) = axes[axis][row].d[k];
                }
        }
    });
}

std::optional<FrameBound> FrameField::bound(const Box3& box) const
{
    V3<Interval> z;
    for (int a = 0; a < 3; ++a) z[a] = mZ->component(a)->bound(box);
    const Interval zz = norm2(z);
    if (!(zz.lo > 0.0) || !std::isfinite(zz.hi)) return std::nullopt;
    std::array<V3<Interval>, 3> axes;
    FrameBound result;
    bool first = true;
    auto add = [&](const V3<Interval>& ref) {
        if (!orthonormalFrame<Interval>(z, ref, axes)) return false;
        for (int axis = 0; axis < 3; ++axis)
            for (int row = 0; row < 3; ++row)
                result[row][axis] = first ? axes[axis][row] : hull(result[row][axis], axes[axis][row]);
        first = false;
        return true;
    };
    if (mX) {
        // The given reference: Gram-Schmidt fails (no bound) unless x surely keeps a part
        // orthogonal to ez; every point of the box uses it when that part is surely above the
        // parallel threshold, otherwise some may use the default (added below).
        V3<Interval> x;
        for (int a = 0; a < 3; ++a) x[a] = mX->component(a)->bound(box);
        if (!add(x)) return std::nullopt;
        V3<Interval> w;
        const Interval along = x[0] * axes[2][0] + x[1] * axes[2][1] + x[2] * axes[2][2];
        for (int a = 0; a < 3; ++a) w[a] = x[a] - along * axes[2][a];
        if (norm2(w).lo > kParallel * norm2(x).hi) return result;
    }
    // The default reference: world x, world y, or either where |ez_x| may cross the threshold.
    const Interval ezX = abs(reciprocal(root(zz)) * z[0]);
    constexpr double margin = 1e-9;
    if (ezX.lo <= kNearX + margin && !add({Interval(1.0), Interval(0.0), Interval(0.0)})) return std::nullopt;
    if (ezX.hi >= kNearX - margin && !add({Interval(0.0), Interval(1.0), Interval(0.0)})) return std::nullopt;
    return result;
}

}  // namespace voxlat
