#include "fields/struts/StrutConvolution.h"

#include "fields/struts/ColumnStencils.h"
#include "fields/struts/StrutRows.h"
#include "fields/struts/TileBounds.h"

#include <algorithm>
#include <array>
#include <bit>
#include <limits>
#include <numbers>
#include <stdexcept>

namespace voxlat {

StrutConvolution::StrutConvolution(const std::vector<ConvolutionStrut>& struts, double eps,
                                   const std::function<void()>& interrupt)
    : mEps(eps), mCoarse(std::make_unique<CoarseNodes>())
{
    if (!(eps > 0.0 && eps < 1.0)) throw std::invalid_argument("the convolution cut-off eps must be in (0, 1)");
    std::vector<Vec3d> a, b;
    std::vector<double> reach;
    for (auto* v : {&a, &b, &mEnd}) v->reserve(struts.size());
    for (auto* v : {&reach, &mCutoffSqr, &mPeak, &mWMin}) v->reserve(struts.size());
    mSegments.reserve(struts.size());
    for (const ConvolutionStrut& s : struts) {
        if (interrupt && (a.size() & 0x3fff) == 0) interrupt();
        if (!(s.sigma > 0.0)) throw std::invalid_argument("sigma must be greater than zero");
        if (!((s.b - s.a).length() > 0.0)) throw std::invalid_argument("a strut has zero length");
        if (!(s.w0 > 0.0 && s.w1 > 0.0)) throw std::invalid_argument("strut weights must be greater than zero");
        mSegments.emplace_back(s.a, s.b, s.sigma, s.w0, s.w1);
        for (int axis = 0; axis < 3; ++axis)
            mEighthBoundAxes[std::size_t(axis)] =
                std::max(mEighthBoundAxes[std::size_t(axis)], segmentEighthDerivativeBound(mSegments.back(), axis));
        mSigmaMin = std::min(mSigmaMin, s.sigma);
        mEnd.push_back(s.b);
        const double rc = gaussianCutoffRadius(s.sigma, eps);
        mCutoffSqr.push_back(rc * rc);
        mPeak.push_back(std::max(s.w0, s.w1) * s.sigma * kSqrtTwoPi);
        mWMin.push_back(std::min(s.w0, s.w1));
        a.push_back(s.a);
        b.push_back(s.b);
        reach.push_back(rc);
    }
    if (interrupt) interrupt();
    mIndex = StrutIndex(a, b, reach);
}

double StrutConvolution::pointValue(const Vec3d& p, const std::vector<std::uint32_t>& cand) const
{
    double sum = 0.0;
    for (const std::uint32_t j : cand) {
        const GaussianSegment& s = mSegments[j];
        double h, r2;
        if (s.distanceSqr(p, h, r2) >= mCutoffSqr[j]) continue;
        sum += s.value(h, r2);
    }
    return sum;
}

void StrutConvolution::values(std::span<const Vec3d> points, std::span<double> out) const
{
    std::vector<std::uint32_t> cand;
    for (std::size_t n = 0; n < points.size(); ++n) {
        mIndex.candidates(Box3{points[n], points[n]}, cand);
        out[n] = pointValue(points[n], cand);
    }
}

void StrutConvolution::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    std::vector<std::uint32_t> cand;
    for (std::size_t n = 0; n < points.size(); ++n) {
        mIndex.candidates(Box3{points[n], points[n]}, cand);
        double sum = 0.0;
        Vec3d g(0.0);
        for (const std::uint32_t j : cand) {
            const GaussianSegment& s = mSegments[j];
            double h, r2;
            if (s.distanceSqr(points[n], h, r2) >= mCutoffSqr[j]) continue;
            Vec3d gj;
            sum += s.valueAndGradient(points[n], gj);
            g += gj;
        }
        out[n] = sum;
        grad[n] = g;
    }
}

namespace {

/// The part of the plane z = @a z within @a reach of the segment @a s lies within [xLo, xHi] x
/// [yLo, yHi]: a point of the plane within reach of the segment is within reach of a segment point
/// q with |q.z - z| < reach, so within reach in x and in y of that part of the segment. False when
/// that part is empty (the segment stays farther than reach from the plane).
bool planeSpan(const GaussianSegment& s, double reach, double z, double& xLo, double& xHi, double& yLo, double& yHi)
{
    const double dz = z - s.a.z();
    double h0 = 0.0, h1 = s.length;
    if (s.u.z() != 0.0) {
        double t0 = (dz - reach) / s.u.z(), t1 = (dz + reach) / s.u.z();
        if (t0 > t1) std::swap(t0, t1);
        h0 = std::max(h0, t0);
        h1 = std::min(h1, t1);
        if (!(h0 <= h1)) return false;
    } else if (!(std::abs(dz) < reach)) {
        return false;
    }
    auto span = [&](int axis, double& lo, double& hi) {
        const double e0 = s.a[axis] + h0 * s.u[axis], e1 = s.a[axis] + h1 * s.u[axis];
        lo = std::min(e0, e1) - reach;
        hi = std::max(e0, e1) + reach;
    };
    span(0, xLo, xHi);
    span(1, yLo, yHi);
    return true;
}

/// The reach of a cut-off radius @a rc for planeSpan: a margin of 1e-6 rc, far above any
/// rounding, so every point left out by it fails the exact cut-off test.
double cutoffReach(double rc)
{
    return rc * (1.0 + 1e-6) + 1e-12;
}

/// The columns (x index i) of a plane batch (nz = 1) that may hold points within the part
/// [@a xLo, @a xHi] x [@a yLo, @a yHi] of the plane within a strut's reach (planeSpan); false when
/// none may.
bool planeColumns(double xLo, double xHi, double yLo, double yHi, const GridBatch& batch, int& iFirst, int& iLast)
{
    const double by0 = batch.origin.y(), by1 = batch.origin.y() + (batch.ny - 1) * batch.spacing.y();
    if (yHi < std::min(by0, by1) || yLo > std::max(by0, by1)) return false;
    const double ox = batch.origin.x(), dx = batch.spacing.x();
    if (!(dx > 0.0)) {
        iFirst = 0;
        iLast = batch.nx - 1;
        return ox >= xLo && ox <= xHi;
    }
    iFirst = int(std::clamp(std::ceil((xLo - ox) / dx), 0.0, double(batch.nx)));
    iLast = int(std::clamp(std::floor((xHi - ox) / dx), -1.0, double(batch.nx - 1)));
    return iFirst <= iLast;
}

/// The cubic Taylor polynomial of J(h) = w0 I0(h) + k I1(h) (GaussianSegment) about @a h:
/// c = {J, J', J'' / 2, J''' / 6}. With e0 = g(h), eL = g(L - h), g(t) = exp(-t^2 / 2 sigma^2):
/// I0' = e0 - eL, I1' = I0 - L eL, e0' = -h / sigma^2 e0, eL' = (L - h) / sigma^2 eL,
/// e0'' = (h^2 / sigma^4 - 1 / sigma^2) e0, eL'' = ((L - h)^2 / sigma^4 - 1 / sigma^2) eL.
void taylorOfJ(const GaussianSegment& s, double h, double c[4])
{
    const double s2 = s.sigma * s.sigma, inv2s2 = 0.5 / s2, invS2 = 1.0 / (s.sigma * std::numbers::sqrt2);
    const double L = s.length, m = L - h;
    const double i0 = s.sigma * std::sqrt(std::numbers::pi / 2.0) * erfSum(m * invS2, h * invS2);
    const double e0 = std::exp(-h * h * inv2s2), eL = std::exp(-m * m * inv2s2);
    const double e0d = -h / s2 * e0, eLd = m / s2 * eL;
    const double e0dd = (h * h / (s2 * s2) - 1.0 / s2) * e0, eLdd = (m * m / (s2 * s2) - 1.0 / s2) * eL;
    const double i0d = e0 - eL, i0dd = e0d - eLd, i0ddd = e0dd - eLdd;
    const double i1 = s2 * (e0 - eL) + h * i0;
    const double i1d = i0 - L * eL, i1dd = i0d - L * eLd, i1ddd = i0dd - L * eLdd;
    c[0] = s.w0 * i0 + s.slope * i1;
    c[1] = s.w0 * i0d + s.slope * i1d;
    c[2] = 0.5 * (s.w0 * i0dd + s.slope * i1dd);
    c[3] = (s.w0 * i0ddd + s.slope * i1ddd) / 6.0;
}

/// gauss[k] = exp(-r2(k) / 2 sigma^2) for k = kLo..kHi (and up to three points past kHi), from @a e
/// at kLo and @a ratio = exp(-(r2(kLo + 1) - r2(kLo)) / 2 sigma^2): four interleaved recurrences
/// E(k + 4) = E(k) R4(k), R4(k + 4) = R4(k) q^16 (q = exp(-2 c / 2 sigma^2), r2(k) = r0 + (b - c) k +
/// c k^2); a few ulps of drift over a row.
void rowGaussiansFrom(double e, double ratio, double q, double q16, int kLo, int kHi, double* gauss)
{
    double ratios[7], lanes[4], steps[4];
    ratios[0] = ratio;
    for (int m = 1; m < 7; ++m) ratios[m] = ratios[m - 1] * q;
    lanes[0] = e;
    for (int l = 1; l < 4; ++l) lanes[l] = lanes[l - 1] * ratios[l - 1];
    for (int l = 0; l < 4; ++l) steps[l] = ((ratios[l] * ratios[l + 1]) * ratios[l + 2]) * ratios[l + 3];
    if (hasAvx2Rows())
        fillGaussiansAvx2(lanes, steps, q16, kHi - kLo + 1, gauss + kLo);
    else
        fillGaussiansScalar(lanes, steps, q16, kHi - kLo + 1, gauss + kLo);
}

/// rowGaussiansFrom with its two exponentials taken at kLo.
void rowGaussians(double r0, double b, double c, double inv2s2, double q, double q16, int kLo, int kHi, double* gauss)
{
    const double k0 = kLo;
    rowGaussiansFrom(std::exp(-(r0 + k0 * (b - c) + k0 * k0 * c) * inv2s2), std::exp(-(b + 2.0 * c * k0) * inv2s2), q,
                     q16, kLo, kHi, gauss);
}

/// Lower bounds of erf(x) and exp(-x) from tables, for planeValues' inside proofs: erf at the
/// node at or nearer zero than |x| (erf is odd and increasing; 1/128 apart, so at most 0.9 % of a
/// unit below it), exp at the node at or above x (1/256 apart: at most 0.4 % below it), each
/// table value 1e-12 below the library's. A tile's lower bound needs one erf pair and one
/// exponential per strut and tile near the strut: the library's calls cost more than the pixels
/// the proofs saved.
class LowerTables {
public:
    static const LowerTables& instance()
    {
        static const LowerTables tables;
        return tables;
    }
    double erfBelow(double x) const
    {
        const double at = std::abs(x) * kErfSteps;
        if (x >= 0.0) return mErf[at < double(kErfSize - 1) ? std::size_t(at) : std::size_t(kErfSize - 1)];
        if (!(at < double(kErfSize - 1))) return -1.0;
        return -mErfAbove[std::size_t(at)];  // -erf at the node at or beyond |x|
    }
    double expBelow(double x) const  ///< a lower bound of exp(-x), x >= 0
    {
        const double at = x * kExpSteps;
        if (!(at < double(kExpSize - 1))) return 0.0;
        return mExp[std::size_t(at)];  // the node above x: exp there
    }

private:
    static constexpr int kErfSteps = 128, kErfSize = 6 * kErfSteps + 1;
    static constexpr int kExpSteps = 256, kExpSize = 12 * kExpSteps + 1;
    LowerTables()
    {
        for (int k = 0; k < kErfSize; ++k) {
            mErf[std::size_t(k)] = std::erf(double(k) / kErfSteps) * (1.0 - 1e-12);
            mErfAbove[std::size_t(k)] = std::min(1.0, std::erf(double(k + 1) / kErfSteps) * (1.0 + 1e-12));
        }
        for (int k = 0; k < kExpSize; ++k) mExp[std::size_t(k)] = std::exp(-double(k + 1) / kExpSteps) * (1.0 - 1e-12);
    }
    double mErf[kErfSize], mErfAbove[kErfSize], mExp[kExpSize];
};

}  // namespace

double StrutConvolution::coarseBound(double voxel) const
{
    return mSegments.empty() ? 0.0 : coarseNodesBound(2.0 * voxel, mSigmaMin, mEighthBoundAxes);
}

bool StrutConvolution::coarseServes(const GridBatch& batch) const
{
    if (!(mGridTolerance > 0.0) || !batch.onLattice || batch.exact || mSegments.empty()) return false;
    const double spacing = batch.spacing.x(), voxel = batch.voxel();
    if (!(voxel > 0.0) || batch.spacing.y() != spacing || batch.spacing.z() != spacing ||
        !(std::abs(spacing - voxel * batch.latticeStride) <= 1e-9 * spacing))
        return false;
    // A strided batch (the density solve's coarse pass) is served where every point is a node:
    // an even stride from a voxel of even index along each axis.
    if (batch.latticeStride != 1 &&
        (batch.latticeStride % 2 != 0 ||
         std::any_of(batch.latticeIndex.begin(), batch.latticeIndex.end(), [](int i) { return i % 2 != 0; })))
        return false;
    // The origin is the lattice's voxel centre up to rounding (a stack's leaves at origin + 8 m
    // voxels), else a node moved the batch: a billionth of a voxel, far below any move a node
    // makes on purpose and far above the roundings of coordinates.
    const Vec3d centre = batch.latticeMin + voxel * Vec3d(batch.latticeIndex[0] + 0.5, batch.latticeIndex[1] + 0.5,
                                                          batch.latticeIndex[2] + 0.5);
    for (int axis = 0; axis < 3; ++axis)
        if (!(std::abs(centre[axis] - batch.origin[axis]) <= 1e-9 * voxel)) return false;
    return servedBound(voxel) > 0.0;
}

double StrutConvolution::servedBound(double voxel) const
{
    if (!(mGridTolerance > 0.0)) return 0.0;
    const double bound = coarseBound(voxel);
    return bound <= mGridTolerance ? bound : 0.0;
}

std::size_t StrutConvolution::coarseBytes() const
{
    return mCoarse->bytes();
}

void StrutConvolution::gridValues(const GridBatch& batch, std::span<double> out) const
{
    if (coarseServes(batch)) {
        mCoarse->interpolate(
            batch, out, [this](const GridBatch& nodes, std::span<double> values) { exactGridValues(nodes, values); });
        return;
    }
    exactGridValues(batch, out);
}

void StrutConvolution::exactGridValues(const GridBatch& batch, std::span<double> out) const
{
    thread_local std::vector<std::uint32_t> cand;
    mIndex.gather(batch.bounds(), cand);
    evaluate(batch, out, cand, nullptr, 0);
}

void StrutConvolution::evaluate(const GridBatch& batch, std::span<double> out, const std::vector<std::uint32_t>& cand,
                                const std::uint64_t* columnTiles, int tile, const double* spans) const
{
    constexpr int kShortRow = 16;  // the longest rows counted as a pixel's sub-samples
    std::fill(out.begin(), out.begin() + batch.size(), 0.0);
    // A plane's column that makes no points (planeValues: interpolated, or far from every open
    // tile): its rows are empty, and neither their ranges nor their tables are sought.
    auto makesNoPoints = [columnTiles](int i) { return columnTiles && columnTiles[i] == 0; };
    // A plane's columns that make points are a few of its columns (every fourth where
    // planeValues interpolates the others): pointColumn[i] is the first of them at or after
    // column i (nx: none), so the loops over a strut's columns below visit only those, not the
    // columns between them (the same rows and sums; a third of the rows' set-up went to walking
    // past empty columns on W10's plate).
    thread_local std::vector<int> pointColumn;
    if (columnTiles) {
        pointColumn.resize(std::size_t(batch.nx) + 1);
        pointColumn[std::size_t(batch.nx)] = batch.nx;
        for (int i = batch.nx - 1; i >= 0; --i)
            pointColumn[std::size_t(i)] = columnTiles[i] != 0 ? i : pointColumn[std::size_t(i) + 1];
    }
    // Rows run along z (k, the fastest index). A plane of points (nz = 1, a slicer's layer) has
    // rows of one point, where the row machinery below costs more than the point: there the rows
    // run along y instead. The batch is seen with y and z swapped (the output's layout, i * ny + j,
    // is the swapped batch's (i * 1 + 0) * ny + j), and so are the struts' coordinates; distances
    // and h do not change, only their rounding.
    const bool swapped = batch.nz == 1 && batch.ny > 1;
    auto seen = [swapped](const Vec3d& v) { return swapped ? Vec3d(v.x(), v.z(), v.y()) : v; };
    const Vec3d origin = seen(batch.origin), spacing = seen(batch.spacing);
    // A plane batch whose points lie within 0.1 sigma of its centre along a strut (a pixel's
    // sub-samples; struts nearly across the plane) takes J(h) from its cubic Taylor polynomial
    // about the centre instead of the table: J'''' = int w(s) g''''(s - h) ds, so |J''''| <=
    // wMax int |g''''| <= wMax sqrt(2 pi) sqrt(24) / sigma^3 (Cauchy-Schwarz on the Hermite
    // polynomial He4), and the remainder is at most 0.512 wMax rho^4 / sigma^3 <= 2.1e-5 of the
    // strut's peak wMax sigma sqrt(2 pi) at rho = 0.1 sigma: below the 1e-4 the cut-off drops.
    const Box3 box = batch.bounds();
    const Vec3d centre = box.center(), halfExtent = 0.5 * (box.max - box.min);
    const int nx = batch.nx, ny = swapped ? 1 : batch.ny, nz = swapped ? batch.ny : batch.nz;
    auto pointAt = [&](int i, int jj, int k) {
        return Vec3d(origin.x() + i * spacing.x(), origin.y() + jj * spacing.y(), origin.z() + k * spacing.z());
    };
    thread_local std::vector<double> gauss, nodeValue, nodeSlope;
    gauss.resize(std::size_t(nz) + 4);  // rowGaussians writes up to three points past a row
    struct RowRange {
        int kLo, kHi, n0;
        double tau;
        int phase = 0;             ///< the row's phase of a table of several nodes per step (below)
        int inLo = 1, inHi = 0;    ///< points at least a step inside the capsule's range (to prove)
        std::uint64_t needed = 0;  ///< a plane's row: its column's needed tiles that the row meets
    };
    thread_local std::vector<RowRange> rows;
    // The tiles (bits of columnTiles) that a row's points kLo..kHi or their one-point halo meet:
    // tiles (kLo - 2) / tile .. kHi / tile, with shifts for a tile of a power of two (a division
    // per row and strut was a visible share of the rows' set-up).
    const int tileShift = tile > 0 && (tile & (tile - 1)) == 0 ? std::countr_zero(unsigned(tile)) : -1;
    auto tilesMet = [tile, tileShift](int kLo, int kHi) {
        const int bLo = std::max(0, tileShift >= 0 ? (kLo - 2) >> tileShift : (kLo - 2) / tile);
        const int bHi = std::min(63, tileShift >= 0 ? kHi >> tileShift : kHi / tile);
        return (bHi == 63 ? ~std::uint64_t(0) : (std::uint64_t(1) << (bHi + 1)) - 1) & ~((std::uint64_t(1) << bLo) - 1);
    };
    thread_local std::vector<double> rangeLo, rangeHi;
    thread_local std::vector<int> rangeColumns;
    const bool avx2 = hasAvx2Rows();
    // The tabled rows in eight lanes where the CPU has AVX-512 (the same doubles; the other
    // row loops stay four lanes wide).
    const bool avx512 = avx2 && hasAvx512Rows();
    const double dx = spacing.x(), dy = spacing.y(), dz = spacing.z();
    std::size_t candIndex = 0;
    // Strut-outer, point-inner: each point still sums its struts in ascending index order. Along
    // a row (k) h is linear and r^2 quadratic in k, so exp(-r^2 / 2 sigma^2) follows from two
    // exponentials per row by the recurrence E(k+1) = E(k) R(k), R(k+1) = R(k) Q (a few ulps of
    // drift over a row); the erf sum comes from GaussianTable (error below 1e-10 of a peak).
    for (const std::uint32_t j : cand) {
        const GaussianSegment& s = mSegments[j];
        const double rc2 = mCutoffSqr[j];
        const double* planeSpanOf = spans ? spans + 4 * candIndex++ : nullptr;
        // A plane batch (a slicer's layer) sees a strut only near where it crosses the plane:
        // the columns beyond its reach there are left out before their rows' ranges are sought
        // (the gather's bins hold every strut whose box meets the batch's, most of them not
        // within reach of the plane). Their points would all fail the cut-off test: the same sums.
        // The part of the plane within the strut's reach (planeSpan; planeValues' own, @a spans).
        int iFirst = 0, iLast = nx - 1;
        double span[4] = {0.0, 0.0, 0.0, 0.0};
        if (batch.nz == 1) {
            if (planeSpanOf)
                std::copy(planeSpanOf, planeSpanOf + 4, span);
            else if (!planeSpan(s, cutoffReach(std::sqrt(rc2)), batch.origin.z(), span[0], span[1], span[2], span[3]))
                continue;
            if (!planeColumns(span[0], span[1], span[2], span[3], batch, iFirst, iLast)) continue;
        }
        const double sigma = s.sigma, invSigma = 1.0 / sigma, inv2s2 = 0.5 / (sigma * sigma);
        const double length = s.length, w0 = s.w0, slope = s.slope, s2 = sigma * sigma;
        const Vec3d sa = seen(s.a), u = seen(s.u);
        const Vec3d d0 = origin - sa;
        const double hz = dz * u.z();
        // r^2(k) = r0 + b k + c k^2 along a row; Q = exp(-2 c / 2 sigma^2).
        const double c = dz * dz - hz * hz;
        const double q = std::exp(-2.0 * c * inv2s2);
        const double q2 = q * q, q4 = q2 * q2, q8 = q4 * q4, q16 = q8 * q8;
        // Rows nearly parallel to the strut get no analytic range (r^2 barely changes along them).
        const bool ranged = c > 1e-9 * dz * dz;
        const StrutRowConstants constants{sa.x(), sa.y(),   sa.z(), u.x(), u.y(), u.z(), length,
                                          sigma,  invSigma, s2,     w0,    slope, rc2};
        const double rho = halfExtent.x() * std::abs(s.u.x()) + halfExtent.y() * std::abs(s.u.y()) +
                           halfExtent.z() * std::abs(s.u.z());
        const bool taylor = batch.nz == 1 && rho <= 0.1 * sigma;
        double coefficients[4] = {0.0, 0.0, 0.0, 0.0};
        const double hc = (centre - s.a).dot(s.u);
        if (taylor) taylorOfJ(s, hc, coefficients);
        const bool shortRows = taylor && nz <= kShortRow;
        // The rounding bound of the proofs below (cutoffRoundoff): every point and the strut lie
        // within reach of the strut's start, every coordinate within coord of zero.
        const double reach = (centre - s.a).length() + halfExtent.length() + length;
        double coord = 0.0;
        for (int axis = 0; axis < 3; ++axis)
            coord = std::max({coord, std::abs(box.min[axis]), std::abs(box.max[axis]), std::abs(s.a[axis]),
                              std::abs(mEnd[j][axis])});
        const double roundoff = cutoffRoundoff(reach, coord);
        // A pixel's sub-samples (short rows) wholly within the strut's cut-off take no test: the
        // centre's distance, with the rounding bound of cutoffRoundoff on it and on every point's,
        // plus the half diagonal, below (1 - 1e-7) of the cut-off.
        bool wholeInside = false;
        if (shortRows) {
            double hCentre, r2Centre;
            const double farthest =
                std::sqrt(s.distanceSqr(centre, hCentre, r2Centre) + roundoff) + halfExtent.length();
            wholeInside =
                2.0 * roundoff < rc2 * 1e-7 && farthest * farthest * (1.0 + 1e-12) + roundoff < rc2 * (1.0 - 1e-7);
        }
        // The analytic range is only a filter: points within a step of its ends, and all points
        // between, still take the exact cut-off test, so the same points count as before.
        const double rcWide2 = rc2 * (1.0 + 1e-9) + 1e-300;
        const CapsuleRows capsule(u.x(), u.y(), u.z(), length, dz, rcWide2);
        // A plane's rows (one per column), a block's (a row per column and y): their ranges four
        // columns at a time (the same doubles), at column i - iFirst of row jj's run of columns.
        // The next column at or after i whose rows a loop over the strut's columns visits:
        // every column where pass 1 writes every row (short rows, whose Gaussians step across
        // every column) or nothing says which make points.
        const bool skipColumns = columnTiles && !shortRows;
        auto columnFrom = [skipColumns](int i) { return skipColumns ? pointColumn[std::size_t(i)] : i; };
        const bool vectorRanges = avx2 && ranged && !shortRows && iFirst <= iLast;
        const std::size_t rangeRun = std::size_t(iLast - iFirst + 1) + 4;
        if (vectorRanges && columnTiles && ny == 1) {
            // A plane's columns that make points (columnTiles: every third where planeValues
            // interpolates the others), four at a time: each column's range is the same doubles.
            rangeLo.resize(rangeRun);
            rangeHi.resize(rangeRun);
            rangeColumns.clear();
            for (int i = columnFrom(iFirst); i <= iLast; i = columnFrom(i + 1))
                if (!makesNoPoints(i)) rangeColumns.push_back(i);
            for (std::size_t m = 0; m < rangeColumns.size(); m += 4) {
                double x[4], lo[4], hi[4];
                const std::size_t count = std::min<std::size_t>(4, rangeColumns.size() - m);
                for (std::size_t l = 0; l < 4; ++l) x[l] = d0.x() + rangeColumns[m + std::min(l, count - 1)] * dx;
                capsuleRowRangesAvx2(capsule, x, d0.y(), d0.z(), lo, hi);
                for (std::size_t l = 0; l < count; ++l) {
                    rangeLo[std::size_t(rangeColumns[m + l] - iFirst)] = lo[l];
                    rangeHi[std::size_t(rangeColumns[m + l] - iFirst)] = hi[l];
                }
            }
        } else if (vectorRanges) {
            const std::size_t count = std::size_t(iLast - iFirst + 1);
            rangeLo.resize(rangeRun * std::size_t(ny));
            rangeHi.resize(rangeRun * std::size_t(ny));
            for (int jj = 0; jj < ny; ++jj) {
                const double py = ny == 1 ? d0.y() : d0.y() + jj * dy;
                for (std::size_t m = 0; m < count; m += 4) {
                    double x[4];
                    for (int l = 0; l < 4; ++l) x[l] = d0.x() + (iFirst + int(m) + l) * dx;
                    capsuleRowRangesAvx2(capsule, x, py, d0.z(), rangeLo.data() + jj * rangeRun + m,
                                         rangeHi.data() + jj * rangeRun + m);
                }
            }
        }
        // Pass 1: each row's range of points (kLo > kHi: none). Only the columns iFirst..iLast
        // are read after it, but by the short rows' Gaussians across every column; of a plane's,
        // only the columns that make points (the others' rows are neither written nor read).
        rows.resize(std::size_t(nx) * ny);
        for (int i = shortRows ? 0 : columnFrom(iFirst); i <= (shortRows ? nx - 1 : iLast);
             i = shortRows ? i + 1 : columnFrom(i + 1)) {
            const double px = d0.x() + i * dx;
            if (i < iFirst || i > iLast || makesNoPoints(i)) {
                for (int jj = 0; jj < ny; ++jj) rows[std::size_t(i) * ny + jj] = RowRange{1, 0, 0, 0.0};
                continue;
            }
            for (int jj = 0; jj < ny; ++jj) {
                const double py = d0.y() + jj * dy;
                RowRange& r = rows[std::size_t(i) * ny + jj];
                r.kLo = 0;
                r.kHi = nz - 1;
                r.inLo = 1;
                r.inHi = 0;
                if (shortRows) {
                    // A few points per row (a pixel's sub-samples): their own cut-off tests are
                    // cheaper than the row's range.
                } else if (ranged) {
                    double tLo, tHi;
                    if (vectorRanges) {
                        tLo = rangeLo[std::size_t(jj) * rangeRun + std::size_t(i - iFirst)];
                        tHi = rangeHi[std::size_t(jj) * rangeRun + std::size_t(i - iFirst)];
                    } else {
                        capsuleRowRange(capsule, px, py, d0.z(), tLo, tHi);
                    }
                    if (!(tLo <= tHi)) {
                        r.kLo = 1;
                        r.kHi = 0;
                        continue;
                    }
                    r.kLo = int(std::clamp(std::floor(std::max(tLo, -1.0)) - 1.0, 0.0, double(nz)));
                    r.kHi = int(std::min(double(nz - 1), std::ceil(std::min(tHi, double(nz))) + 1.0));
                    r.inLo = int(std::clamp(std::ceil(std::max(tLo, -2.0)) + 1.0, 0.0, double(nz)));
                    r.inHi = int(std::clamp(std::floor(std::min(tHi, double(nz + 1))) - 1.0, -1.0, double(nz - 1)));
                } else {
                    // Skip rows whose every point is beyond the cut-off (centre distance test).
                    const double rowHalf = 0.5 * (nz - 1) * dz;
                    const Vec3d mid(px, py, d0.z() + rowHalf);
                    const double hm = std::clamp(mid.dot(u), 0.0, length);
                    if ((mid - hm * u).length() - rowHalf >= std::sqrt(rc2)) {
                        r.kLo = 1;
                        r.kHi = 0;
                    }
                }
                // A plane's row that meets none of the tiles its column needs is made by nobody
                // (pass 2 tests the part of it within the strut's reach of the plane, inside this
                // range): it takes no nodes of the table either.
                if (columnTiles && r.kLo <= r.kHi) {
                    r.needed = columnTiles[i] & tilesMet(r.kLo, r.kHi);
                    if (r.needed == 0) {
                        r.kLo = 1;
                        r.kHi = 0;
                    }
                }
            }
        }
        // Long rows along which h advances by at most 0.1 sigma per point take J(h) from a table of
        // the strut's own, with nodes one step of h apart (StrutRowTable): a row's points then
        // sit at one fraction tau between consecutive nodes, so the Hermite weights are the row's
        // and the nodes are read in order, instead of two GaussianTable look-ups per point. Its
        // error is at most delta^4 / 384 max |J''''| <= 0.0128 (delta / sigma)^4 of the strut's
        // peak (|J''''| as above): 1.3e-6 of it at delta = 0.1 sigma.
        // The table spans the batch's range of h: at most eight rows' worth of nodes (struts nearly
        // across the rows, whose h barely steps along them, keep the per-point look-ups).
        // A block's rows (not a plane's: a slicer's bytes stay) along which h steps by more than
        // 0.1 sigma take a table of m = ceil(|hz| / 0.1 sigma) nodes per step (at most
        // kRowPhases): delta = hz / m <= 0.1 sigma, the same bound. Point k of a row then sits at
        // node n0 + m k + tau, so the nodes are kept in m phases (phase p: the nodes whose index is
        // p modulo m), a row reads its own phase and the next one's, each in order. (Struts at 35
        // degrees or more from the rows, a BCC cell's diagonals along z at sigma = 5 voxels, were
        // all untabled.) The table's nodes are the rows' h range over delta whatever m is, against
        // two look-ups per point untabled: sixteen phases table steps of up to 1.6 sigma, voxels
        // down to sigma / 1.6 (four, up to 0.4 sigma, left untabled the rows of grids under 2.5
        // voxels per sigma and of the density solve's coarse samples, three to five voxels apart;
        // with the stacks a frame's own density lattice now takes (Job::solveLevels), a W2g
        // cylinder frame at 0.2 mm 2.20-2.64 -> 1.38-1.58 s, those rows a quarter of its CPU).
        constexpr int kRowPhases = 16;
        const double spread = std::abs(dx * u.x()) * (nx - 1) + std::abs(dy * u.y()) * (ny - 1);
        const int phases = batch.nz > 1 && hz != 0.0 && std::abs(hz) <= 0.1 * kRowPhases * sigma
                               ? std::max(1, int(std::ceil(std::abs(hz) / (0.1 * sigma))))
                               : 1;
        const bool tabled = !taylor && ranged && nz >= 16 && hz != 0.0 && std::abs(hz) <= 0.1 * sigma * phases &&
                            spread <= 8.0 * nz * std::abs(hz);
        // A plane's rows (a slicer's layer: nz = 1) take their table from every second node where
        // two steps stay within 0.15 sigma (planeNodesFromEven: the odd nodes at most
        // 0.0128 (2 hz / sigma)^4 <= 6.5e-6 of the peak off, the row's own 1.3e-6 on top): half
        // the table's erf and exponential look-ups, a plane's rows reading a hundred nodes each
        // strut (a plane has one phase). A block's grids (the mesher's) keep every node.
        const bool halvedNodes = tabled && batch.nz == 1 && 2.0 * std::abs(hz) <= 0.15 * sigma;
        int nodeLo = 0;
        std::size_t phaseStride = 0;
        if (tabled) {
            // h at a row's point 0 is hRow (below); nodes h0 + n hz, with h0 one node past the
            // hRow of the batch's first or last row: a plane's rows (one per column) then all have
            // n0 + tau of at least about 1 (but for halvedNodes, below). A block's rows (ny > 1) whose hRow grows along
            // one of x and y and falls along the other reach past both: their n0 may be negative, and the table spans
            // whichever nodes the rows read (nLo..nHi), of any sign. A plane's table taken from its even nodes
            // (halvedNodes) has its nodes at n hz from the strut's start (h0 = 0), so its nodes, even and odd, are the
            // same for every plane that reads them (a stack's and its blocks' alone, to the rows' own rounding).
            const double hFirst = d0.x() * u.x() + d0.y() * u.y() + d0.z() * u.z();
            const double hLast = hFirst + (nx - 1) * dx * u.x() + (ny - 1) * dy * u.y();
            const double h0 = halvedNodes ? 0.0 : (hz > 0.0 ? std::min(hFirst, hLast) : std::max(hFirst, hLast)) - hz;
            int nLo = std::numeric_limits<int>::max(), nHi = std::numeric_limits<int>::min();
            for (int i = columnFrom(iFirst); i <= iLast; i = columnFrom(i + 1)) {
                if (makesNoPoints(i)) continue;  // empty rows (pass 1)
                for (int jj = 0; jj < ny; ++jj) {
                    RowRange& r = rows[std::size_t(i) * ny + jj];
                    if (r.kLo > r.kHi) continue;
                    const double hRow = (d0.x() + i * dx) * u.x() + (d0.y() + jj * dy) * u.y() + d0.z() * u.z();
                    if (phases == 1) {
                        const double at = (hRow - h0) / hz;
                        r.n0 = int(std::floor(at));
                        r.tau = at - r.n0;
                        r.phase = 0;
                    } else {
                        // Node n = m q + p of step hz / m: phase p, index q.
                        const double at = (hRow - h0) / (hz / phases);
                        const int n = int(std::floor(at));
                        r.tau = at - n;
                        // q = floor(n / m), p = n - m q: a shift for m = 2 or 4, a division by a
                        // constant (a multiply) for m = 3, not two divisions per row; past
                        // four, one division rounded towards minus infinity.
                        const int index = phases == 2   ? n >> 1
                                          : phases == 4 ? n >> 2
                                          : phases == 3 ? (n >= 0 ? n / 3 : -((2 - n) / 3))
                                          : n >= 0      ? n / phases
                                                        : -((phases - 1 - n) / phases);
                        r.phase = n - phases * index;
                        r.n0 = index;
                    }
                    // A plane's row reads nodes only at the points of its needed runs (pass 2:
                    // within the first run's start and the last one's end, fillLo..fillHi there,
                    // whose tiles are a subset of these): the nodes past them are not made. A
                    // node's value hangs on its index alone (h0 + n hz), not on the table's span.
                    int needLo = r.kLo, needHi = r.kHi;
                    if (columnTiles) {
                        needLo = std::max(r.kLo, std::countr_zero(r.needed) * tile);
                        needHi = std::min(r.kHi, (64 - std::countl_zero(r.needed)) * tile + 1);
                    }
                    nLo = std::min(nLo, r.n0 + needLo);
                    nHi = std::max(nHi, r.n0 + needHi + 1);
                }
            }
            if (nLo <= nHi) {
                nodeLo = nLo;
                const std::size_t count = std::size_t(nHi - nLo + 1);
                // Margin: the four-lane loop reads up to four nodes past a row's last point.
                phaseStride = count + 8;
                // Only the margin past the nodes made is zeroed (the nodes are all written below):
                // the same table as zeroing it all first.
                nodeValue.resize(phaseStride * std::size_t(phases));
                nodeSlope.resize(phaseStride * std::size_t(phases));
                const std::size_t written = avx2 ? (count + 3) / 4 * 4 : count;
                for (int p = 0; p < phases; ++p) {
                    // Phase p's nodes h0 + (m q + p) hz / m, q = nLo.., with slopes of their step hz / m.
                    const double from = phases == 1 ? h0 : h0 + p * (hz / phases);
                    double* value = nodeValue.data() + std::size_t(p) * phaseStride;
                    double* slope = nodeSlope.data() + std::size_t(p) * phaseStride;
                    // A plane's table (one phase) from its even nodes alone, the odd ones by the
                    // Hermite cubic of the two even nodes beside them: the nodes the four-lane
                    // form writes (written), each the same whichever span holds it.
                    if (halvedNodes)
                        planeNodesFromEven(constants, from, hz, nLo, int(written), avx2, value, slope);
                    else if (avx2)
                        strutRowNodesAvx2(constants, from, hz, nLo, int(count), value, slope);
                    else
                        strutRowNodesScalar(constants, from, hz, nLo, int(count), value, slope);
                    if (phases > 1)
                        for (std::size_t m = 0; m < count; ++m) slope[m] /= phases;
                    std::fill(value + written, value + phaseStride, 0.0);
                    std::fill(slope + written, slope + phaseStride, 0.0);
                }
            }
        }
        // Pass 2: the rows' Gaussians and J. Short rows (a pixel's sub-samples, every row whole,
        // one row per column) take their Gaussians by recurrence across the columns: r2(i + 1, k) -
        // r2(i, k) is linear in i and in k, so with S(i, k) = exp(-(r2(i + 1, k) - r2(i, k)) / 2
        // sigma^2), G(i + 1, k) = G(i, k) S(i, k), S(i + 1, k) = S(i, k) Qx and S(0, k) = S(0, 0) T^k:
        // five exponentials per strut and batch, not two per column.
        const bool acrossColumns = shortRows && ny == 1 && nz <= kShortRow;
        double columnGauss[kShortRow + 4], columnStep[kShortRow], columnQ = 0.0;
        if (acrossColumns) {
            const double hRow0 = d0.x() * u.x() + d0.y() * u.y() + d0.z() * u.z();
            const double r00 = d0.x() * d0.x() + d0.y() * d0.y() + d0.z() * d0.z() - hRow0 * hRow0;
            const double ux2 = 1.0 - u.x() * u.x();
            double e = std::exp(-r00 * inv2s2), ratio = std::exp(-(2.0 * (d0.z() * dz - hRow0 * hz) + c) * inv2s2);
            double step = std::exp(-(2.0 * dx * (d0.x() - u.x() * hRow0) + dx * dx * ux2) * inv2s2);
            const double across = std::exp(2.0 * hz * dx * u.x() * inv2s2);
            columnQ = std::exp(-2.0 * dx * dx * ux2 * inv2s2);
            for (int k = 0; k < nz; ++k) {
                columnGauss[k] = e;
                columnStep[k] = step;
                e *= ratio;
                ratio *= q;
                step *= across;
            }
        }
        // Long rows of a plane batch (one row per column) take their Gaussians' four-lane seeds
        // (rowGaussiansFrom's lanes and steps at a start k0 shared by the strut's rows: the first
        // point of any of them) from recurrences across the columns, not from two exponentials
        // and a chain of products per row. Lane l holds E_l = exp(-r2(i, k0 + l) / 2 sigma^2), its
        // row step P_l = exp(-(r2(i, k0 + l + 4) - r2(i, k0 + l)) / 2 sigma^2) and its column step
        // S_l = exp(-(r2(i + 1, k0 + l) - r2(i, k0 + l)) / 2 sigma^2); r2 is quadratic in i and k
        // with a constant cross term, so E_l(i + 1) = E_l(i) S_l(i), S_l(i + 1) = S_l(i) Qx and
        // P_l(i + 1) = P_l(i) T^4 (Qx = exp(-2 dx^2 (1 - u_x^2) / 2 sigma^2), T = exp(2 dx u_x hz /
        // 2 sigma^2)). The seeds are taken afresh every kSeedSpan columns, so each carries at
        // most about kSeedSpan^2 / 2 + 2 kSeedSpan roundings more than a row's own (a few 1e-14
        // relative; rowGaussiansFrom's recurrences then start at k0, not at the row's first
        // point). Only where r2 / 2 sigma^2 stays below 600 over the rows' rectangle (r2 is
        // convex: its corners), so no Gaussian a row reads underflows.
        constexpr int kSeedSpan = 16;
        bool seeded = false;
        int k0 = 0, seedBase = -1, seedAt = -1;
        double seedE[4] = {}, seedS[4] = {}, seedP[4] = {}, seedQx = 0.0, seedT = 0.0, seedT4 = 0.0;
        int kSeedEnd = nz - 1;
        if (!acrossColumns && ny == 1 && batch.nz == 1) {
            // k0 and the seeds' columns come from the batch and the strut alone (the part of the
            // plane within reach of the strut, planeSpan; a grid of columns from iFirst), never
            // from which rows a band needs: planeValues gives gridValues' doubles.
            // (span: planeSpan's, found above: a plane batch that reaches here has one.)
            {
                const double yLo = span[2], yHi = span[3];
                const double oy = batch.origin.y(), sy = batch.spacing.y();
                k0 = int(std::clamp(std::floor((yLo - oy) / sy) - 1.0, 0.0, double(nz - 1)));
                kSeedEnd = int(std::clamp(std::ceil((yHi - oy) / sy) + 1.0, double(k0), double(nz - 1)));
                auto r2At = [&](int i, int k) {
                    const double x = d0.x() + i * dx, y = d0.y(), zz = d0.z() + k * dz;
                    const double h = x * u.x() + y * u.y() + zz * u.z();
                    return x * x + y * y + zz * zz - h * h;
                };
                const double worst = std::max(std::max(r2At(iFirst, k0), r2At(iFirst, kSeedEnd + 4)),
                                              std::max(r2At(iLast, k0), r2At(iLast, kSeedEnd + 4)));
                seeded = worst * inv2s2 < 600.0;
                seedQx = std::exp(-2.0 * dx * dx * (1.0 - u.x() * u.x()) * inv2s2);
                seedT = std::exp(2.0 * hz * dx * u.x() * inv2s2);
                seedT4 = std::exp(8.0 * hz * dx * u.x() * inv2s2);
            }
        }
        // The lanes and steps of column i (columns are visited in increasing order).
        auto seedsAt = [&](int i) {
            const int base = iFirst + (i - iFirst) / kSeedSpan * kSeedSpan;
            if (seedBase != base) {
                const double x = d0.x() + base * dx;
                const double hRow = x * u.x() + d0.y() * u.y() + d0.z() * u.z();
                const double r0 = x * x + d0.y() * d0.y() + d0.z() * d0.z() - hRow * hRow;
                const double b = 2.0 * (d0.z() * dz - hRow * hz) + c;
                const double kk = k0;
                // rowGaussiansFrom's lanes and steps at k0.
                double ratios[7];
                ratios[0] = std::exp(-(b + 2.0 * c * kk) * inv2s2);
                for (int m = 1; m < 7; ++m) ratios[m] = ratios[m - 1] * q;
                seedE[0] = std::exp(-(r0 + kk * (b - c) + kk * kk * c) * inv2s2);
                for (int l = 1; l < 4; ++l) seedE[l] = seedE[l - 1] * ratios[l - 1];
                for (int l = 0; l < 4; ++l) seedP[l] = ((ratios[l] * ratios[l + 1]) * ratios[l + 2]) * ratios[l + 3];
                // S_l = S_0 T^l: D_l = D_0 - 2 l hz dx u_x.
                const double across =
                    2.0 * dx * (x - u.x() * hRow) + dx * dx * (1.0 - u.x() * u.x()) - 2.0 * hz * dx * u.x() * kk;
                seedS[0] = std::exp(-across * inv2s2);
                for (int l = 1; l < 4; ++l) seedS[l] = seedS[l - 1] * seedT;
                seedBase = seedAt = base;
            }
            for (; seedAt < i; ++seedAt)
                for (int l = 0; l < 4; ++l) {
                    seedE[l] *= seedS[l];
                    seedS[l] *= seedQx;
                    seedP[l] *= seedT4;
                }
        };
        // A block's long rows (a stack of leaves: ny > 1, rows along z of 16 points or more) take
        // their Gaussians' four-lane seeds from recurrences across y within a column of rows, as a
        // plane's do across x: lane l at k0 + l (k0 the column's first point of any row) holds E_l,
        // its row step P_l and its step across y S_l; r2 is quadratic in jj and k with a constant
        // cross term, so E_l(jj + 1) = E_l(jj) S_l(jj), S_l(jj + 1) = S_l(jj) Qy and P_l(jj + 1) =
        // P_l(jj) Ty^4 (Qy = exp(-2 dy^2 (1 - u_y^2) / 2 sigma^2), Ty = exp(2 dy u_y hz / 2 sigma^2)).
        // Three exponentials per column and three per strut, not two per row: at most ny - 1 steps
        // across y and (nz / 4) along a row, a few 1e-15 relative. Only where r2 / 2 sigma^2 stays
        // below 600 over the column's rows (r2 is convex: its corners), so no Gaussian underflows.
        const bool blockSeeds = !acrossColumns && !seeded && ny > 1 && batch.nz >= 16;
        double ySeedQ = 0.0, ySeedT4 = 0.0, ySeedT = 0.0;
        if (blockSeeds) {
            ySeedQ = std::exp(-2.0 * dy * dy * (1.0 - u.y() * u.y()) * inv2s2);
            ySeedT = std::exp(2.0 * hz * dy * u.y() * inv2s2);
            ySeedT4 = std::exp(8.0 * hz * dy * u.y() * inv2s2);
        }
        // Columns beyond the strut's reach have no row (only the columns' Gaussians across
        // them step through every column).
        const int iBegin = acrossColumns ? 0 : iFirst, iEnd = acrossColumns ? nx - 1 : iLast;
        for (int i = columnFrom(iBegin); i <= iEnd; i = columnFrom(i + 1)) {
            std::size_t n = std::size_t(i) * ny * nz;
            const double px = d0.x() + i * dx;
            if (acrossColumns && i > 0)
                for (int k = 0; k < nz; ++k) {
                    columnGauss[k] *= columnStep[k];
                    columnStep[k] *= columnQ;
                }
            if (makesNoPoints(i)) continue;  // empty rows (pass 1), skipped before they are read
            // The column's seeds (blockSeeds), at its row colRow.
            bool columnSeeded = false;
            int colK0 = 0, colRow = 0;
            double colE[4] = {}, colS[4] = {}, colP[4] = {};
            if (blockSeeds) {
                int kFirst = nz, kLast = -1;
                for (int jj = 0; jj < ny; ++jj) {
                    const RowRange& range = rows[std::size_t(i) * ny + jj];
                    if (range.kLo > range.kHi) continue;
                    kFirst = std::min(kFirst, range.kLo);
                    kLast = std::max(kLast, range.kHi);
                }
                auto r2At = [&](int jj, int k) {
                    const double y = d0.y() + jj * dy, zz = d0.z() + k * dz;
                    const double h = px * u.x() + y * u.y() + zz * u.z();
                    return px * px + y * y + zz * zz - h * h;
                };
                if (kFirst <= kLast && std::max(std::max(r2At(0, kFirst), r2At(0, kLast + 4)),
                                                std::max(r2At(ny - 1, kFirst), r2At(ny - 1, kLast + 4))) *
                                               inv2s2 <
                                           600.0) {
                    // rowGaussiansFrom's lanes and steps at (jj, k) = (0, kFirst).
                    const double hRow = px * u.x() + d0.y() * u.y() + d0.z() * u.z();
                    const double r0 = px * px + d0.y() * d0.y() + d0.z() * d0.z() - hRow * hRow;
                    const double b = 2.0 * (d0.z() * dz - hRow * hz) + c;
                    const double kk = kFirst;
                    double ratios[7];
                    ratios[0] = std::exp(-(b + 2.0 * c * kk) * inv2s2);
                    for (int m = 1; m < 7; ++m) ratios[m] = ratios[m - 1] * q;
                    colE[0] = std::exp(-(r0 + kk * (b - c) + kk * kk * c) * inv2s2);
                    for (int l = 1; l < 4; ++l) colE[l] = colE[l - 1] * ratios[l - 1];
                    for (int l = 0; l < 4; ++l) colP[l] = ((ratios[l] * ratios[l + 1]) * ratios[l + 2]) * ratios[l + 3];
                    // S_l = S_0 Ty^l: D_l = D_0 - 2 l hz dy u_y.
                    const double across = 2.0 * dy * (d0.y() - u.y() * hRow) + dy * dy * (1.0 - u.y() * u.y()) -
                                          2.0 * hz * dy * u.y() * kk;
                    colS[0] = std::exp(-across * inv2s2);
                    for (int l = 1; l < 4; ++l) colS[l] = colS[l - 1] * ySeedT;
                    colK0 = kFirst;
                    columnSeeded = true;
                }
            }
            for (int jj = 0; jj < ny; ++jj, n += nz) {
                const RowRange& range = rows[std::size_t(i) * ny + jj];
                // Seeded rows start and end within the strut's reach of the plane (k0..kSeedEnd):
                // the points outside it fail the cut-off test.
                const int kLo = seeded ? std::max(range.kLo, k0) : range.kLo;
                const int kHi = seeded ? std::min(range.kHi, kSeedEnd) : range.kHi;
                if (kLo > kHi) continue;
                // A plane's needed points (planeValues): the runs of tiles its column needs, each
                // with its one-point halo; rows that meet none take no Gaussians.
                // (Pass 1 kept the column's needed tiles that the row's range meets: only a seeded
                // row cut to the strut's reach of the plane masks them again.)
                std::uint64_t needed = 0;
                if (columnTiles) {
                    needed = kLo == range.kLo && kHi == range.kHi ? range.needed : range.needed & tilesMet(kLo, kHi);
                    if (needed == 0) continue;
                }
                // The points the row's needed runs hold lie within fillLo..fillHi (the first run's
                // start, the last run's end): only those take Gaussians. The runs outside the
                // row's tiles (tilesMet) would hold none of its points, so they are left out of
                // needed: the same parts as before, without walking the column's other runs.
                int fillLo = kLo, fillHi = kHi;
                if (columnTiles) {
                    fillLo = std::max(kLo, std::countr_zero(needed) * tile);
                    fillHi = std::min(kHi, (64 - std::countl_zero(needed)) * tile + 1);
                }
                const double py = d0.y() + jj * dy;
                const double hRow = px * u.x() + py * u.y() + d0.z() * u.z();
                const double b = 2.0 * (d0.z() * dz - hRow * hz) + c;  // r^2(1) - r^2(0)
                const Vec3d rowStart = pointAt(i, jj, 0);
                StrutRow row{rowStart.x(), rowStart.y(), rowStart.z(), dz, kLo, kHi};
                if (wholeInside) {
                    row.inLo = kLo;
                    row.inHi = kHi;
                }
                // A tabled row's points a step or more inside the capsule's range skip their
                // cut-off test where both ends of that run are proven within it. Only runs of
                // provenRun points or more among the points read: the proof (two distances,
                // scalar) costs about what the tests of three groups of lanes do (12 points in
                // four lanes, 24 in eight), and skips only tests that pass (the same sums either way).
                const int provenRun = avx512 ? 32 : 16;
                if (tabled && range.inLo <= range.inHi &&
                    std::min(range.inHi, fillHi) - std::max(range.inLo, fillLo) + 1 >= provenRun &&
                    provenWithinCutoff(constants, row, range.inLo, range.inHi, roundoff)) {
                    row.inLo = range.inLo;
                    row.inHi = range.inHi;
                }
                // The recurrence's factors stay well inside double range for ordinary batches;
                // otherwise every point takes its own exponential.
                const double* g = gauss.data();
                // A seeded tabled row (AVX2) takes its Gaussians from the seeds' lanes as its
                // kernel steps them (addStrutRowTabledSeededAvx2): the doubles the fill below
                // would write, without the array.
                bool fused = false;
                GaussianLanes fusedLanes;
                if (std::abs(b * inv2s2) < 200.0 && std::abs(c * inv2s2) * nz < 200.0) {
                    if (acrossColumns) {
                        g = columnGauss;
                    } else if (columnSeeded) {
                        for (; colRow < jj; ++colRow)
                            for (int l = 0; l < 4; ++l) {
                                colE[l] *= colS[l];
                                colS[l] *= ySeedQ;
                                colP[l] *= ySeedT4;
                            }
                        if (avx2)
                            fillGaussiansAvx2(colE, colP, q16, kHi - colK0 + 1, gauss.data() + colK0, kLo - colK0);
                        else
                            fillGaussiansScalar(colE, colP, q16, kHi - colK0 + 1, gauss.data() + colK0, kLo - colK0);
                    } else if (seeded && tabled && avx2) {
                        seedsAt(i);
                        fused = true;
                        for (int l = 0; l < 4; ++l) {
                            fusedLanes.e[l] = seedE[l];
                            fusedLanes.r[l] = seedP[l];
                        }
                        fusedLanes.q16 = q16;
                        fusedLanes.k = k0;
                    } else if (seeded) {
                        seedsAt(i);
                        // The recurrences stepped from k0, written from fillLo's group: the same
                        // doubles at every point read.
                        if (avx2)
                            fillGaussiansAvx2(seedE, seedP, q16, fillHi - k0 + 1, gauss.data() + k0, fillLo - k0);
                        else
                            fillGaussiansScalar(seedE, seedP, q16, fillHi - k0 + 1, gauss.data() + k0, fillLo - k0);
                    } else {
                        // Started at kLo (its doubles hang on it), stopped at fillHi.
                        const double r0 = (px * px + py * py) + d0.z() * d0.z() - hRow * hRow;
                        rowGaussians(r0, b, c, inv2s2, q, q16, kLo, fillHi, gauss.data());
                    }
                } else {
                    for (int k = fillLo; k <= fillHi; ++k) {
                        double h, r2;
                        s.distanceSqr(seen(pointAt(i, jj, k)), h, r2);
                        gauss[k] = std::exp(-r2 * inv2s2);
                    }
                }
                double tw[4] = {0.0, 0.0, 0.0, 0.0};
                if (tabled) {
                    const double t = range.tau, t2 = t * t, t3 = t2 * t;
                    tw[0] = 2 * t3 - 3 * t2 + 1;
                    tw[1] = t3 - 2 * t2 + t;
                    tw[2] = -2 * t3 + 3 * t2;
                    tw[3] = t3 - t2;
                }
                // The points k = part.kLo..part.kHi of the row: each point's sum does not depend on
                // which others are made.
                auto add = [&](const StrutRow& part) __attribute__((always_inline))
                {
                    if (taylor) {
                        if (avx2)
                            addStrutRowTaylorAvx2(constants, part, coefficients, hc, g, out.data() + n);
                        else
                            addStrutRowTaylorScalar(constants, part, coefficients, hc, g, out.data() + n);
                    } else if (tabled) {
                        // The row's phase, and the next one's nodes (phase 0's from one index on, after
                        // the last phase; one table: value + 1).
                        const std::size_t at = std::size_t(range.phase) * phaseStride;
                        const std::size_t next = range.phase + 1 < phases ? at + phaseStride : 1;
                        const StrutRowTable table{nodeValue.data() + at,
                                                  nodeSlope.data() + at,
                                                  range.n0 - nodeLo,
                                                  tw[0],
                                                  tw[1],
                                                  tw[2],
                                                  tw[3],
                                                  nodeValue.data() + next,
                                                  nodeSlope.data() + next};
                        if (fused && avx512)
                            addStrutRowTabledSeededAvx512(constants, part, table, fusedLanes, out.data() + n);
                        else if (fused)
                            addStrutRowTabledSeededAvx2(constants, part, table, fusedLanes, out.data() + n);
                        else if (avx512)
                            addStrutRowTabledAvx512(constants, part, table, g, out.data() + n);
                        else if (avx2)
                            addStrutRowTabledAvx2(constants, part, table, g, out.data() + n);
                        else
                            addStrutRowTabledScalar(constants, part, table, g, out.data() + n);
                    } else if (avx2) {
                        addStrutRowAvx2(constants, part, g, out.data() + n);
                    } else {
                        addStrutRowScalar(constants, part, g, out.data() + n);
                    }
                };
                if (!columnTiles) {
                    add(row);
                    continue;
                }
                // Runs of needed tiles b0..b1: points b0 tile .. (b1 + 1) tile + 1.
                forEachTileRun(needed, [&](int b0, int b1) {
                    StrutRow part = row;
                    part.kLo = std::max(kLo, b0 * tile);
                    part.kHi = std::min(kHi, (b1 + 1) * tile + 1);
                    if (part.kLo <= part.kHi) add(part);
                });
            }
        }
    }
}

void StrutConvolution::planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                                   std::span<signed char> side, std::span<const TileNeed> need) const
{
    const PlaneTiles tiles = PlaneTiles::of(plane, tile);
    const bool seenAlongY = plane.ny > 1;  // evaluate() runs a plane's rows along y
    if (tiles.nx == 0 || tiles.ny > 64 || !seenAlongY || !(plane.spacing.x() > 0.0) || !(plane.spacing.y() > 0.0)) {
        gridValues(plane, out);
        std::fill(side.begin(), side.begin() + tiles.size(), static_cast<signed char>(0));
        return;
    }
    thread_local std::vector<std::uint32_t> cand;
    thread_local std::vector<double> upper, lower, peaks;
    thread_local std::vector<std::uint64_t> columnTiles, openTiles;
    thread_local std::vector<int> reach;
    reach.clear();
    // The struts whose bins meet the block, kept where their reach of the plane meets it (the
    // test evaluate() makes first, planeSpan): a superset of gather()'s, whose exact distance
    // tests cost more than the struts they leave out (those add nothing at any point here).
    mIndex.candidates(plane.bounds(), cand);
    const double dx = plane.spacing.x(), dy = plane.spacing.y(), z = plane.origin.z();
    const double px0 = plane.origin.x(), px1 = px0 + (plane.nx - 1) * dx;
    const double py0 = plane.origin.y(), py1 = py0 + (plane.ny - 1) * dy;
    thread_local std::vector<double> spans;
    spans.clear();
    std::size_t kept = 0;
    for (const std::uint32_t j : cand) {
        double xLo, xHi, yLo, yHi;
        if (!planeSpan(mSegments[j], cutoffReach(std::sqrt(mCutoffSqr[j])), z, xLo, xHi, yLo, yHi)) continue;
        if (xHi < px0 || xLo > px1 || yHi < py0 || yLo > py1) continue;
        cand[kept++] = j;
        spans.insert(spans.end(), {xLo, xHi, yLo, yHi});
    }
    cand.resize(kept);
    upper.assign(tiles.size(), 0.0);
    lower.assign(tiles.size(), 0.0);
    peaks.assign(tiles.size(), 0.0);
    // Tiles are proven inside (above band.hi) only where a band's upper end is finite.
    const bool proveInside = std::isfinite(band.hi);
    // Tile (a, b)'s footprint: its points' cells, tile spacings wide, centred at cx0 + a tile dx.
    const double stepX = tile * dx, stepY = tile * dy;
    const double cx0 = plane.origin.x() + (0.5 + 0.5 * tile) * dx, cy0 = plane.origin.y() + (0.5 + 0.5 * tile) * dy;
    const double halfX = 0.5 * stepX, halfY = 0.5 * stepY, halfDiagonal = std::sqrt(halfX * halfX + halfY * halfY);
    const ExpUpperNodes expNodes = expUpperNodes();
    const auto addTileBounds = hasAvx512Rows() ? addTileBoundsAvx512
                               : hasAvx2Rows() ? addTileBoundsAvx2
                                               : addTileBoundsScalar;
    thread_local std::vector<TileColumnReach> columnReach;
    const LowerTables& lowerTables = LowerTables::instance();
    // Per strut and tile of its reach, its peak times the kernel at the least distance from the
    // footprint, at least the centre's distance less the half diagonal (the kernel taken from a
    // table at or above it: expUpper). (The distance to the footprint itself, segmentBoxDistance,
    // for the tiles this leaves open proved 13 % more of the window outside but cost more than it
    // saved: 16.0 s against 12.8 s of CPU on W10's 4 layers.) The sums made by evaluate() stay
    // within 2.5e-5 of the peaks counted of the exact field's.
    // A strut that reaches no tile's footprint grown by a spacing (its points and its halo) adds
    // nothing to any value planeValues gives: it is left out of evaluate()'s struts.
    const double haloX = halfX + dx, haloY = halfY + dy, haloDiagonal = std::sqrt(haloX * haloX + haloY * haloY);
    kept = 0;
    for (std::size_t n = 0; n < cand.size(); ++n) {
        const std::uint32_t j = cand[n];
        const GaussianSegment& s = mSegments[j];
        const double rc = std::sqrt(mCutoffSqr[j]);
        const double xLo = spans[4 * n], xHi = spans[4 * n + 1], yLo = spans[4 * n + 2], yHi = spans[4 * n + 3];
        const int a0 = int(std::clamp(std::ceil((xLo - haloX - cx0) / stepX), 0.0, double(tiles.nx)));
        const int a1 = int(std::clamp(std::floor((xHi + haloX - cx0) / stepX), -1.0, double(tiles.nx - 1)));
        const int b0 = int(std::clamp(std::ceil((yLo - haloY - cy0) / stepY), 0.0, double(tiles.ny)));
        const int b1 = int(std::clamp(std::floor((yHi + haloY - cy0) / stepY), -1.0, double(tiles.ny - 1)));
        const double inv2s2 = 0.5 / (s.sigma * s.sigma), margin = 1e-9 * rc;
        // A centre at or beyond far has every point of its footprint beyond the cut-off, at or
        // beyond farHalo every point of its footprint grown by a spacing.
        const double far = rc + halfDiagonal + margin, farSqr = far * far * (1.0 + 1e-12);
        const double farHalo = rc + haloDiagonal + margin, farHaloSqr = farHalo * farHalo * (1.0 + 1e-12);
        const double ux = s.u.x(), uy = s.u.y(), uz = s.u.z(), length = s.length;
        const double ez = z - s.a.z();
        // A centre nearer than inner has every point of its footprint within the cut-off (the
        // distance to the segment is 1-Lipschitz; 1e-7 of rc^2 far above the test's rounding):
        // the strut adds at least its lower bound there (tileLower), so a tile may be proven inside.
        const double innerRoot = std::min(rc * (1.0 - 1e-7), 2.5 * s.sigma) - halfDiagonal - margin;
        const double innerSqr = proveInside && innerRoot > 0.0 ? innerRoot * innerRoot * (1.0 - 1e-12) : -1.0;
        // The strut's least contribution over a footprint centred at e from its start (tileLower):
        // wMin times the unit-weight closed form at the line distance plus the half diagonal and at
        // the footprint's h farthest from the middle (I0 falls away from L / 2), as bound() takes it.
        const double spreadH = halfX * std::abs(ux) + halfY * std::abs(uy);
        const double invS2 = 1.0 / (s.sigma * std::numbers::sqrt2);
        auto tileLower = [&](double ex, double ey) {
            const double h = ex * ux + ey * uy + ez * uz;
            // The line's distance is convex (the norm of an affine map of the point): over the
            // footprint it is largest at a corner, so the largest of the four corners' distances
            // bounds it (the centre's plus the half diagonal was up to 1.7x looser across a
            // strut's section, and left half the tiles within W10's sections open). Each distance
            // squared loses up to a few ulps of |e|^2 to cancellation: 1e-12 of it more is above
            // every rounding.
            double rSqrMax = 0.0;
            for (const double sx : {-halfX, halfX})
                for (const double sy : {-halfY, halfY}) {
                    const double cx = ex + sx, cy = ey + sy;
                    const double hc = cx * ux + cy * uy + ez * uz;
                    const double eSqr = cx * cx + cy * cy + ez * ez;
                    rSqrMax = std::max(rSqrMax, std::max(0.0, eSqr - hc * hc) + 1e-12 * eSqr);
                }
            const double rMax = std::sqrt(rSqrMax) + margin;
            const double hLo = h - spreadH, hHi = h + spreadH;
            const double hFar = std::abs(hLo - 0.5 * length) > std::abs(hHi - 0.5 * length) ? hLo : hHi;
            const double i0 = s.sigma * std::sqrt(std::numbers::pi / 2.0) *
                              (lowerTables.erfBelow((length - hFar) * invS2) + lowerTables.erfBelow(hFar * invS2));
            return i0 > 0.0 ? mWMin[j] * i0 * lowerTables.expBelow(rMax * rMax * inv2s2) * (1.0 - 1e-9) : 0.0;
        };
        // The box of tiles whose footprint grown by a spacing the strut reaches: columns
        // reachA0..reachA1, rows reachB0..reachB1.
        int reachA0 = tiles.nx, reachA1 = -1, reachB0 = tiles.ny, reachB1 = -1;
        if (a0 <= a1 && b0 <= b1) {
            // Per tile of the box, the strut's upper bound (TileBounds.h: two or eight tiles at a
            // time, the same doubles), then the reach and the lower bounds of the tiles within.
            const TileColumnStrut strut{cx0,   stepX, s.a.x(),      cy0,    stepY,    s.a.y(),    ux,
                                        uy,    uz,    length,       ez,     farSqr,   farHaloSqr, innerSqr,
                                        halfX, halfY, halfDiagonal, margin, mPeak[j], inv2s2};
            columnReach.resize(std::size_t(a1 - a0 + 1));
            addTileBounds(strut, a0, a1, b0, b1, tiles.ny, expNodes, upper.data(), peaks.data(), columnReach.data());
            for (int a = a0; a <= a1; ++a) {
                const TileColumnReach& met = columnReach[std::size_t(a - a0)];
                if (met.halo) {
                    reachA0 = std::min(reachA0, a);
                    reachA1 = a;
                    reachB0 = std::min(reachB0, std::countr_zero(met.halo));
                    reachB1 = std::max(reachB1, 63 - std::countl_zero(met.halo));
                }
                const double ex = cx0 + a * stepX - s.a.x();
                const std::size_t row = std::size_t(a) * tiles.ny;
                for (std::uint64_t inner = met.inner; inner; inner &= inner - 1) {
                    const int b = std::countr_zero(inner);
                    lower[row + b] += tileLower(ex, cy0 + b * stepY - s.a.y());
                }
            }
        }
        if (reachA1 >= 0) {
            std::copy_n(&spans[4 * n], 4, &spans[4 * kept]);  // kept <= n: spans already read
            cand[kept++] = j;
            reach.insert(reach.end(), {reachA0, reachA1, reachB0, reachB1});
        }
    }
    cand.resize(kept);
    columnTiles.assign(std::size_t(plane.nx), 0);
    openTiles.assign(std::size_t(tiles.nx), 0);
    bool any = false;
    for (int a = 0; a < tiles.nx; ++a) {
        std::uint64_t open = 0;
        for (int b = 0; b < tiles.ny; ++b) {
            const std::size_t t = std::size_t(a) * tiles.ny + b;
            const TileNeed needed = needOf(need, t);
            side[t] =
                static_cast<signed char>(needed != TileNeed::Decide                                              ? 0
                                         : upper[t] * (1.0 + 1e-12) + 2.5e-5 * peaks[t] < band.lo                ? -1
                                         : proveInside && lower[t] * (1.0 - 1e-12) - 2.5e-5 * peaks[t] > band.hi ? 1
                                                                                                                 : 0);
            if (side[t] == 0 && needed != TileNeed::Skip) open |= std::uint64_t(1) << b;
        }
        openTiles[std::size_t(a)] = open;
        // Tile column a's points and their halo: columns a tile .. (a + 1) tile + 1.
        for (int i = a * tile; i <= (a + 1) * tile + 1; ++i) columnTiles[i] |= open;
        any = any || open != 0;
    }
    if (!any) {
        std::fill(out.begin(), out.begin() + plane.size(), 0.0);
        return;
    }
    // A strut that reaches no open tile's footprint grown by a spacing adds nothing to any point
    // evaluate() makes (each lies in an open tile or its one-point halo): it is left out before
    // its rows' ranges are sought (on W10's plate, struts whose reach of the plane lies where
    // every tile is proven outside). Tested on the box of tiles it reaches, a superset.
    kept = 0;
    double sigmaMin = std::numeric_limits<double>::infinity();
    for (std::size_t n = 0; n < cand.size(); ++n) {
        const int* r = &reach[4 * n];
        const std::uint64_t bits =
            (r[3] >= 63 ? ~std::uint64_t(0) : (std::uint64_t(2) << r[3]) - 1) & ~((std::uint64_t(1) << r[2]) - 1);
        bool meets = false;
        for (int a = r[0]; a <= r[1] && !meets; ++a) meets = (openTiles[std::size_t(a)] & bits) != 0;
        if (meets) {
            sigmaMin = std::min(sigmaMin, mSegments[cand[n]].sigma);
            std::copy_n(&spans[4 * n], 4, &spans[4 * kept]);
            cand[kept++] = cand[n];
        }
    }
    cand.resize(kept);
    // Columns between exact ones interpolated along x where the proven bound allows
    // (ColumnStencils.h: below mPlaneTolerance of the peaks near, sigma the least of the struts
    // kept, C8 the largest of the field's struts along x): the nodes take the points their
    // interpolated neighbours need as well.
    thread_local ColumnStencils stencils;
    thread_local std::array<double, 5> stencilKey{};
    const bool interpolated = mPlaneTolerance > 0.0 && kept > 0;
    // The stencils hang on the plane's width, its spacing, the least sigma, the tolerance and C8
    // (fields of different tolerances or struts may run on one thread).
    const double eighthBound = mEighthBoundAxes[0];  // along x, the planes' columns
    const std::array<double, 5> key{double(plane.nx), dx, sigmaMin, mPlaneTolerance, eighthBound};
    if (interpolated && stencilKey != key) {
        stencils = columnStencils(plane.nx, dx, sigmaMin, mPlaneTolerance, eighthBound);
        stencilKey = key;
    }
    if (!interpolated || stencils.stride < 2) {
        evaluate(plane, out, cand, columnTiles.data(), tile, spans.data());
        return;
    }
    thread_local std::vector<std::uint64_t> nodeTiles;
    nodeTiles.assign(std::size_t(plane.nx), 0);
    for (int i = 0; i < plane.nx; ++i) {
        const int f = stencils.first[std::size_t(i)];
        if (f < 0) {
            nodeTiles[std::size_t(i)] |= columnTiles[std::size_t(i)];
            continue;
        }
        for (int l = 0; l < 8; ++l) nodeTiles[std::size_t(f + l * stencils.stride)] |= columnTiles[std::size_t(i)];
    }
    evaluate(plane, out, cand, nodeTiles.data(), tile, spans.data());
    interpolateColumns(stencils, plane.ny, columnTiles.data(), tile, out.data());
}

Interval StrutConvolution::bound(const Box3& box) const
{
    thread_local std::vector<std::uint32_t> cand;
    thread_local std::vector<double> boxDistance;
    // Each strut's distance to the box, the gather's own where its test took one (a strut near
    // the edge of its reach took it twice, a tenth of the wireframe's solve in segmentBoxDistance).
    mIndex.gather(box, cand, &boxDistance);
    double lo = 0.0, hi = 0.0;
    const Vec3d c = box.center();
    const double radius = box.radius();
    for (std::size_t n = 0; n < cand.size(); ++n) {
        const std::uint32_t j = cand[n];
        const GaussianSegment& s = mSegments[j];
        const double sigma = s.sigma;
        const double dMin = boxDistance[n];
        hi += gaussianSegmentUpperBound(dMin, sigma, mPeak[j] / (sigma * kSqrtTwoPi));
        // A positive lower bound only where the whole box lies within the cut-off.
        double h, r2;
        const double dc = std::sqrt(s.distanceSqr(c, h, r2));
        if (dc + radius >= std::sqrt(mCutoffSqr[j])) continue;
        const double rMax = std::sqrt(r2) + radius;
        const double hLo = h - radius, hHi = h + radius;
        // I0(h) is symmetric about L/2 and falls away from it: its minimum over [hLo, hHi] is
        // at the end farther from L/2.
        const double hFar = std::abs(hLo - 0.5 * s.length) > std::abs(hHi - 0.5 * s.length) ? hLo : hHi;
        GaussianSegment unit = s;
        unit.w0 = 1.0;
        unit.slope = 0.0;
        lo += mWMin[j] * unit.value(hFar, rMax * rMax);
    }
    // Rounding: the sums above and the evaluation's sums may differ in the last bits.
    const double slack = 1e-12 * (hi + 1e-300);
    return {std::max(0.0, lo * (1.0 - 1e-12)), hi + slack};
}

}  // namespace voxlat
