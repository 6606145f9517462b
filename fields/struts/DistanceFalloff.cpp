#include "fields/struts/DistanceFalloff.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>

namespace voxlat {

namespace {
/// ln(1e12): a Gaussian term below 1e-12 of its weight is dropped.
constexpr double kLogCut = 27.631021115928547;
}  // namespace

DistanceFalloff::DistanceFalloff(std::vector<FalloffSource> sources, Falloff falloff, double sigma)
    : mFalloff(falloff), mSigma(sigma)
{
    if (falloff == Falloff::Gaussian && !(sigma > 0.0))
        throw std::invalid_argument("a Gaussian falloff needs sigma > 0");
    mCutoff = falloff == Falloff::Gaussian ? sigma * std::sqrt(2.0 * kLogCut) : std::numeric_limits<double>::infinity();
    for (std::size_t g = 0; g < sources.size(); ++g) {
        const FalloffSource& s = sources[g];
        if (s.vertices.empty()) throw std::invalid_argument("a falloff source needs at least one vertex");
        if (!std::isfinite(s.weight)) throw std::invalid_argument("a falloff weight must be finite");
        mWeights.push_back(s.weight);
        if (s.vertices.size() == 1) {
            mA.push_back(s.vertices[0]);
            mB.push_back(s.vertices[0]);
            mSource.push_back(std::uint32_t(g));
        }
        for (std::size_t k = 0; k + 1 < s.vertices.size(); ++k) {
            mA.push_back(s.vertices[k]);
            mB.push_back(s.vertices[k + 1]);
            mSource.push_back(std::uint32_t(g));
        }
    }
    mAll.resize(mA.size());
    std::iota(mAll.begin(), mAll.end(), 0u);
    if (falloff == Falloff::Gaussian) mIndex = StrutIndex(mA, mB, std::vector<double>(mA.size(), mCutoff));
}

double DistanceFalloff::kernel(double d) const
{
    switch (mFalloff) {
        case Falloff::Inverse:
            return 1.0 / std::max(d, kMinDistance);
        case Falloff::InverseSquare: {
            const double c = std::max(d, kMinDistance);
            return 1.0 / (c * c);
        }
        case Falloff::Gaussian:
            return d >= mCutoff ? 0.0 : std::exp(-d * d / (2.0 * mSigma * mSigma));
    }
    return 0.0;
}

void DistanceFalloff::candidates(const Box3& box, bool exact, std::vector<std::uint32_t>& out) const
{
    if (mFalloff != Falloff::Gaussian) {
        out = mAll;
        return;
    }
    if (exact)
        mIndex.gather(box, out);
    else
        mIndex.candidates(box, out);
}

double DistanceFalloff::pointValue(const Vec3d& p, const std::vector<std::uint32_t>& cand, Vec3d* grad) const
{
    double sum = 0.0;
    if (grad) *grad = Vec3d(0.0);
    const double cut2 = mCutoff * mCutoff;
    // The nearest point of the current source so far; its term is added when the source ends.
    std::uint32_t source = std::numeric_limits<std::uint32_t>::max();
    double best = 0.0;
    Vec3d nearest(0.0);
    auto flush = [&] {
        if (source == std::numeric_limits<std::uint32_t>::max() || !(best < cut2)) return;
        const double w = mWeights[source];
        const double d = std::sqrt(best);
        double k, dkOverD;  // k(d) and k'(d) / d
        switch (mFalloff) {
            case Falloff::Inverse:
                k = 1.0 / std::max(d, kMinDistance);
                dkOverD = d > kMinDistance ? -k / (d * d) : 0.0;
                break;
            case Falloff::InverseSquare: {
                const double c = std::max(d, kMinDistance);
                k = 1.0 / (c * c);
                dkOverD = d > kMinDistance ? -2.0 * k / (d * d) : 0.0;
                break;
            }
            default:
                k = std::exp(-best / (2.0 * mSigma * mSigma));
                dkOverD = -k / (mSigma * mSigma);
                break;
        }
        sum += w * k;
        if (grad) *grad += (w * dkOverD) * (p - nearest);
    };
    for (const std::uint32_t j : cand) {
        if (mSource[j] != source) {
            flush();
            source = mSource[j];
            best = std::numeric_limits<double>::infinity();
        }
        const Vec3d ab = mB[j] - mA[j], ap = p - mA[j];
        const double l2 = ab.lengthSqr();
        const double t = l2 > 0.0 ? std::clamp(ap.dot(ab) / l2, 0.0, 1.0) : 0.0;
        const Vec3d q = mA[j] + t * ab;
        const double d2 = (p - q).lengthSqr();
        if (d2 < best) {
            best = d2;
            nearest = q;
        }
    }
    flush();
    return sum;
}

void DistanceFalloff::values(std::span<const Vec3d> points, std::span<double> out) const
{
    std::vector<std::uint32_t> cand;
    for (std::size_t n = 0; n < points.size(); ++n) {
        candidates(Box3{points[n], points[n]}, false, cand);
        out[n] = pointValue(points[n], cand, nullptr);
    }
}

void DistanceFalloff::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    std::vector<std::uint32_t> cand;
    for (std::size_t n = 0; n < points.size(); ++n) {
        candidates(Box3{points[n], points[n]}, false, cand);
        out[n] = pointValue(points[n], cand, &grad[n]);
    }
}

void DistanceFalloff::gridValues(const GridBatch& batch, std::span<double> out) const
{
    // Leaf by leaf in a stack (StrutCapsules::gridValues): the same doubles, since any box that
    // holds a point gives its value (values() takes the point's own).
    thread_local std::vector<std::uint32_t> cand;
    pointValuesBySlab(
        batch, out, [&](const Box3& box) { candidates(box, true, cand); },
        [&](const Vec3d& p) { return pointValue(p, cand, nullptr); });
}

Interval DistanceFalloff::bound(const Box3& box) const
{
    thread_local std::vector<std::uint32_t> cand;
    candidates(box, true, cand);
    double lo = 0.0, hi = 0.0, magnitude = 0.0;
    std::size_t j = 0;
    while (j < cand.size()) {
        // One source: its distance over the box lies in [min_s d_lo(s), min_s d_hi(s)].
        const std::uint32_t source = mSource[cand[j]];
        double dLo = std::numeric_limits<double>::infinity(), dHi = dLo;
        for (; j < cand.size() && mSource[cand[j]] == source; ++j) {
            dLo = std::min(dLo, segmentBoxDistance(mA[cand[j]], mB[cand[j]], box));
            dHi = std::min(dHi, segmentBoxMaxDistance(mA[cand[j]], mB[cand[j]], box));
        }
        const double kHi = kernel(dLo), kLo = kernel(dHi);
        const double w = mWeights[source];
        lo += w >= 0.0 ? w * kLo : w * kHi;
        hi += w >= 0.0 ? w * kHi : w * kLo;
        magnitude += std::abs(w) * std::max(kHi, 1.0);
    }
    // Rounding: the sums above and the evaluation's sums may differ in the last bits.
    const double slack = 2e-12 * magnitude + 1e-300;
    return {lo - slack, hi + slack};
}

}  // namespace voxlat
