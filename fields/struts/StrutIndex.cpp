#include "fields/struts/StrutIndex.h"

#include <algorithm>
#include <cmath>

namespace voxlat {

double pointSegmentDistanceSqr(const Vec3d& p, const Vec3d& a, const Vec3d& b)
{
    // In scalars, in Vec3's order of operations (the same doubles): no vector temporaries and no
    // clamp through references, which the sanitizers' build kept on the stack, each poisoned and
    // unpoisoned per call (57 % of a capsule job's time under ASan).
    const double abx = b[0] - a[0], aby = b[1] - a[1], abz = b[2] - a[2];
    const double apx = p[0] - a[0], apy = p[1] - a[1], apz = p[2] - a[2];
    const double l2 = abx * abx + aby * aby + abz * abz;
    double s = 0.0;
    if (l2 > 0.0) {
        const double t = (apx * abx + apy * aby + apz * abz) / l2;
        s = t < 0.0 ? 0.0 : (1.0 < t ? 1.0 : t);  // std::clamp(t, 0, 1)
    }
    const double dx = apx - s * abx, dy = apy - s * aby, dz = apz - s * abz;
    return dx * dx + dy * dy + dz * dz;
}

namespace {
/// The squared distance from @a p to @a box.
double pointBoxDistanceSqr(const Vec3d& p, const Box3& box)
{
    double s = 0.0;
    for (int a = 0; a < 3; ++a) {
        const double d = std::max({box.min[a] - p[a], 0.0, p[a] - box.max[a]});
        s += d * d;
    }
    return s;
}
}  // namespace

double segmentBoxDistance(const Vec3d& a, const Vec3d& b, const Box3& box)
{
    // The squared distance from a + t (b - a) to the box is a sum over axes of squared excesses
    // beyond the box's slab, each zero or quadratic in t between the points where the segment
    // crosses a slab face. Between consecutive crossings it is one convex quadratic: its minimum
    // is at an end or where its derivative vanishes. Those few candidates give the minimum.
    const Vec3d ab = b - a;
    double ts[8];
    int n = 0;
    ts[n++] = 0.0;
    ts[n++] = 1.0;
    for (int k = 0; k < 3; ++k) {
        if (ab[k] == 0.0) continue;
        for (const double face : {box.min[k], box.max[k]}) {
            const double t = (face - a[k]) / ab[k];
            if (t > 0.0 && t < 1.0) ts[n++] = t;
        }
    }
    for (int i = 1; i < n; ++i)  // insertion sort: at most eight values
        for (int j = i; j > 0 && ts[j] < ts[j - 1]; --j) std::swap(ts[j], ts[j - 1]);
    // The candidates' squared distances, and one square root of their least: sqrt is monotone and
    // correctly rounded, so sqrt(min) is the min of the square roots bit for bit (one root per
    // call instead of one per candidate: the solve's cull takes one call per strut and leaf).
    double best = std::min(pointBoxDistanceSqr(a, box), pointBoxDistanceSqr(b, box));
    for (int i = 0; i + 1 < n && best > 0.0; ++i) {
        const double t0 = ts[i], t1 = ts[i + 1];
        if (!(t1 > t0)) continue;
        // The axes outside their slab in the interval's middle, and the face each is beyond.
        const Vec3d mid = a + (0.5 * (t0 + t1)) * ab;
        double A = 0.0, B = 0.0;
        for (int k = 0; k < 3; ++k) {
            const double face = mid[k] < box.min[k] ? box.min[k] : mid[k] > box.max[k] ? box.max[k] : mid[k];
            if (face == mid[k]) continue;
            // (a_k - face + t ab_k)^2: A t^2 + B t + const.
            A += ab[k] * ab[k];
            B += 2.0 * (a[k] - face) * ab[k];
        }
        best = std::min(best, pointBoxDistanceSqr(a + t1 * ab, box));
        if (A > 0.0) {
            const double t = std::clamp(-B / (2.0 * A), t0, t1);
            best = std::min(best, pointBoxDistanceSqr(a + t * ab, box));
        }
    }
    // Rounding in the candidates' positions: a hair below, so the result stays a lower bound.
    return std::max(0.0, std::sqrt(best) - 1e-12 * (ab.length() + box.radius() + 1.0));
}

double segmentBoxMaxDistance(const Vec3d& a, const Vec3d& b, const Box3& box)
{
    return std::sqrt(pointSegmentDistanceSqr(box.center(), a, b)) + box.radius();
}

StrutIndex::StrutIndex(const std::vector<Vec3d>& a, const std::vector<Vec3d>& b, const std::vector<double>& reach)
    : mA(a), mB(b), mReach(reach)
{
    if (a.empty()) return;
    mBounds = {Vec3d(std::numeric_limits<double>::max()), Vec3d(-std::numeric_limits<double>::max())};
    double meanExtent = 0.0;
    for (std::size_t j = 0; j < a.size(); ++j) {
        for (int k = 0; k < 3; ++k) {
            mBounds.min[k] = std::min(mBounds.min[k], std::min(a[j][k], b[j][k]) - reach[j]);
            mBounds.max[k] = std::max(mBounds.max[k], std::max(a[j][k], b[j][k]) + reach[j]);
        }
        meanExtent += ((b[j] - a[j]).length() + 2.0 * reach[j]) / double(a.size());
    }
    // Bins about a quarter of a capsule across: each capsule touches about a hundred bins, a leaf a
    // few. (Half a capsule: a leaf's gather took twice the candidates, a 50 mm wireframe's cull
    // and rows 8 % longer; an eighth: the index and the large boxes' gathers cost more.)
    const Vec3d ext = mBounds.extent();
    mBin = std::max(0.25 * meanExtent, std::cbrt(ext[0] * ext[1] * ext[2] / 4.0e6));
    for (int k = 0; k < 3; ++k) mDims[k] = std::max(1, int(std::ceil(ext[k] / mBin)));
    const std::size_t bins = std::size_t(mDims[0]) * mDims[1] * mDims[2];
    auto binRange = [&](std::size_t j, int lo[3], int hi[3]) {
        for (int k = 0; k < 3; ++k) {
            const double l = std::min(a[j][k], b[j][k]) - reach[j], h = std::max(a[j][k], b[j][k]) + reach[j];
            lo[k] = std::clamp(int(std::floor((l - mBounds.min[k]) / mBin)), 0, mDims[k] - 1);
            hi[k] = std::clamp(int(std::floor((h - mBounds.min[k]) / mBin)), 0, mDims[k] - 1);
        }
    };
    // Two passes (count, fill) keep the item lists in ascending segment order.
    mStart.assign(bins + 1, 0);
    for (int pass = 0; pass < 2; ++pass) {
        std::vector<std::uint32_t> fill;
        if (pass == 1) {
            for (std::size_t n = 0; n < bins; ++n) mStart[n + 1] += mStart[n];
            mItems.resize(mStart[bins]);
            fill.assign(mStart.begin(), mStart.end() - 1);
        }
        for (std::size_t j = 0; j < a.size(); ++j) {
            int lo[3], hi[3];
            binRange(j, lo, hi);
            for (int x = lo[0]; x <= hi[0]; ++x)
                for (int y = lo[1]; y <= hi[1]; ++y)
                    for (int z = lo[2]; z <= hi[2]; ++z) {
                        const std::size_t n = (std::size_t(x) * mDims[1] + y) * mDims[2] + z;
                        if (pass == 0)
                            ++mStart[n + 1];
                        else
                            mItems[fill[n]++] = std::uint32_t(j);
                    }
        }
    }
}

void StrutIndex::candidates(const Box3& box, std::vector<std::uint32_t>& out) const
{
    out.clear();
    if (mA.empty()) return;
    int lo[3], hi[3];
    for (int k = 0; k < 3; ++k) {
        if (box.max[k] < mBounds.min[k] || box.min[k] > mBounds.max[k]) return;
        lo[k] = std::clamp(int(std::floor((box.min[k] - mBounds.min[k]) / mBin)), 0, mDims[k] - 1);
        hi[k] = std::clamp(int(std::floor((box.max[k] - mBounds.min[k]) / mBin)), 0, mDims[k] - 1);
    }
    // One bin: its list, ascending without repeats. Several: each strut taken once as it is
    // first met (a stamp per strut and call), then sorted into the same ascending list. (A strut
    // lies in dozens of bins a quarter of its capsule across: sorting the concatenation with its
    // repeats took a coarse grid's gathers, the report's preview of a wireframe, twice as long,
    // and merging bin by bin copied the growing list once per bin.) The stamps are shared by
    // every index a thread gathers from: each call's stamp is above all earlier ones, so a
    // stamp left by an earlier call never matches.
    if (lo[0] == hi[0] && lo[1] == hi[1] && lo[2] == hi[2]) {
        const std::size_t n = (std::size_t(lo[0]) * mDims[1] + lo[1]) * mDims[2] + lo[2];
        out.assign(mItems.begin() + mStart[n], mItems.begin() + mStart[n + 1]);
        return;
    }
    thread_local std::vector<std::uint32_t> stamp;
    thread_local std::uint32_t call = 0;
    if (++call == 0) {
        std::fill(stamp.begin(), stamp.end(), 0u);
        call = 1;
    }
    if (stamp.size() < mA.size()) stamp.resize(mA.size(), 0u);
    for (int x = lo[0]; x <= hi[0]; ++x)
        for (int y = lo[1]; y <= hi[1]; ++y)
            for (int z = lo[2]; z <= hi[2]; ++z) {
                const std::size_t n = (std::size_t(x) * mDims[1] + y) * mDims[2] + z;
                for (std::uint32_t m = mStart[n]; m < mStart[n + 1]; ++m) {
                    const std::uint32_t j = mItems[m];
                    if (stamp[j] == call) continue;
                    stamp[j] = call;
                    out.push_back(j);
                }
            }
    std::sort(out.begin(), out.end());
}

void StrutIndex::gather(const Box3& box, std::vector<std::uint32_t>& out, std::vector<double>* boxDistance) const
{
    candidates(box, out);
    if (boxDistance) boxDistance->clear();
    const Vec3d c = box.center();
    const double radius = box.radius();
    std::size_t kept = 0;
    for (const std::uint32_t j : out) {
        const double reach = mReach[j];
        // Cheap accept / reject by the centre distance first; the exact test only near the edge.
        const double dc = std::sqrt(pointSegmentDistanceSqr(c, mA[j], mB[j]));
        if (dc - radius > reach) continue;
        double d = -1.0;  // the box distance, once taken
        if (dc > reach) {
            d = segmentBoxDistance(mA[j], mB[j], box);
            if (d > reach) continue;
        }
        if (boxDistance) boxDistance->push_back(d >= 0.0 ? d : segmentBoxDistance(mA[j], mB[j], box));
        out[kept++] = j;
    }
    out.resize(kept);
}

}  // namespace voxlat
