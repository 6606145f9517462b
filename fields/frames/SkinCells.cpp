#include "fields/frames/SkinCells.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace voxlat {

namespace {

constexpr double kInside = 1e-9;  // slack on local coordinates for points on a shared face

}  // namespace

SkinCells::SkinCells(std::vector<Vec3d> corners, std::vector<std::array<int, 8>> hexes, std::vector<char> outer,
                     double extension, FieldPtr clip, double clipLevel)
    : mCorners(std::move(corners)),
      mHexes(std::move(hexes)),
      mOuter(std::move(outer)),
      mExtension(extension),
      mClip(std::move(clip)),
      mClipLevel(clipLevel)
{
    if (mOuter.size() != mHexes.size()) throw std::invalid_argument("SkinCells: one outer flag per hex");
    if (mExtension > 0.0 && !mClip) throw std::invalid_argument("SkinCells: an extension needs a clip field");
    mBounds = Box3{Vec3d(1e300), Vec3d(-1e300)};
    double sizeSum = 0.0;
    mBoxes.reserve(mHexes.size());
    for (std::size_t h = 0; h < mHexes.size(); ++h) {
        Box3 b{Vec3d(1e300), Vec3d(-1e300)};
        for (int i : mHexes[h])
            for (int a = 0; a < 3; ++a) {
                b.min[a] = std::min(b.min[a], mCorners[i][a]);
                b.max[a] = std::max(b.max[a], mCorners[i][a]);
            }
        // The extension reaches out to w = -e along the w edges (x is linear in w along them,
        // and trilinear in u, v, so the extended cell stays within the corners pushed out).
        if (mOuter[h] && mExtension > 0.0)
            for (int i = 0; i < 4; ++i) {
                const Vec3d q =
                    mCorners[mHexes[h][i]] - mExtension * (mCorners[mHexes[h][i + 4]] - mCorners[mHexes[h][i]]);
                for (int a = 0; a < 3; ++a) {
                    b.min[a] = std::min(b.min[a], q[a]);
                    b.max[a] = std::max(b.max[a], q[a]);
                }
            }
        const double e = b.extent()[0] + b.extent()[1] + b.extent()[2];
        sizeSum += e / 3.0;
        // A hair of slack so that points on a face are found from both sides.
        b.min -= Vec3d(1e-9 * e);
        b.max += Vec3d(1e-9 * e);
        mBoxes.push_back(b);
        for (int a = 0; a < 3; ++a) {
            mBounds.min[a] = std::min(mBounds.min[a], b.min[a]);
            mBounds.max[a] = std::max(mBounds.max[a], b.max[a]);
        }
    }
    if (mHexes.empty()) {
        mBounds = Box3{};
        mBinStart = {0, 0};
        return;
    }
    mScale = sizeSum / double(mHexes.size());
    // Bins about a cell wide, at most ~4M of them.
    const Vec3d ext = mBounds.extent();
    mBin = std::max(mScale, std::cbrt(ext[0] * ext[1] * ext[2] / 4e6));
    for (int a = 0; a < 3; ++a) mBinDims[a] = std::max(1, int(std::ceil(ext[a] / mBin)));
    const std::size_t bins = std::size_t(mBinDims[0]) * mBinDims[1] * mBinDims[2];
    std::vector<std::uint32_t> count(bins + 1, 0);
    auto each = [&](auto&& fn) {
        for (std::size_t h = 0; h < mHexes.size(); ++h) forBins(mBoxes[h], [&](std::size_t b) { fn(h, b); });
    };
    each([&](std::size_t, std::size_t b) { ++count[b + 1]; });
    for (std::size_t b = 0; b < bins; ++b) count[b + 1] += count[b];
    mBinStart = count;
    mBinHexes.resize(count.back());
    each([&](std::size_t h, std::size_t b) { mBinHexes[count[b]++] = std::uint32_t(h); });
}

template <typename Fn>
void SkinCells::forBins(const Box3& box, Fn&& fn) const
{
    std::array<int, 3> lo, hi;
    for (int a = 0; a < 3; ++a) {
        lo[a] = std::max(0, int(std::floor((box.min[a] - mBounds.min[a]) / mBin)));
        hi[a] = std::min(mBinDims[a] - 1, int(std::floor((box.max[a] - mBounds.min[a]) / mBin)));
        if (lo[a] > hi[a]) return;
    }
    for (int i = lo[0]; i <= hi[0]; ++i)
        for (int j = lo[1]; j <= hi[1]; ++j)
            for (int k = lo[2]; k <= hi[2]; ++k) fn((std::size_t(i) * mBinDims[1] + j) * mBinDims[2] + k);
}

Vec3d SkinCells::map(std::size_t h, const Vec3d& t, std::array<Vec3d, 3>* jacobian) const
{
    const auto& c = mHexes[h];
    Vec3d x(0.0), du(0.0), dv(0.0), dw(0.0);
    for (int i = 0; i < 8; ++i) {
        const int bu = i & 1, bv = (i >> 1) & 1, bw = (i >> 2) & 1;
        const double fu = bu ? t[0] : 1.0 - t[0], fv = bv ? t[1] : 1.0 - t[1], fw = bw ? t[2] : 1.0 - t[2];
        const double su = bu ? 1.0 : -1.0, sv = bv ? 1.0 : -1.0, sw = bw ? 1.0 : -1.0;
        const Vec3d& p = mCorners[c[i]];
        x += (fu * fv * fw) * p;
        if (jacobian) {
            du += (su * fv * fw) * p;
            dv += (fu * sv * fw) * p;
            dw += (fu * fv * sw) * p;
        }
    }
    if (jacobian) *jacobian = {du, dv, dw};
    return x;
}

bool SkinCells::inverse(std::size_t h, const Vec3d& p, Vec3d& local) const
{
    Vec3d t(0.5);
    const double tol = 1e-10 * mScale;
    for (int it = 0; it < 30; ++it) {
        std::array<Vec3d, 3> J;
        const Vec3d r = map(h, t, &J) - p;
        if (r.length() <= tol) {
            local = t;
            return true;
        }
        const double det = triple(J[0], J[1], J[2]);
        if (!(std::abs(det) > 1e-14 * mScale * mScale * mScale)) return false;
        // Cramer's rule for J d = r.
        const Vec3d d(triple(r, J[1], J[2]) / det, triple(J[0], r, J[2]) / det, triple(J[0], J[1], r) / det);
        t -= d;
        // Keep the iterate near the cell: far outside the map folds and Newton wanders.
        for (int a = 0; a < 3; ++a) t[a] = std::clamp(t[a], -2.0, 3.0);
    }
    return false;
}

int SkinCells::locate(const Vec3d& p, Vec3d& local) const
{
    if (mHexes.empty()) return -1;
    int b[3];
    for (int a = 0; a < 3; ++a) {
        const double f = (p[a] - mBounds.min[a]) / mBin;
        if (!(f >= 0.0) || f >= mBinDims[a]) return -1;
        b[a] = int(f);
    }
    const std::size_t bin = (std::size_t(b[0]) * mBinDims[1] + b[1]) * mBinDims[2] + b[2];
    int extended = -1;
    Vec3d extendedLocal(0.0);
    for (std::uint32_t i = mBinStart[bin]; i < mBinStart[bin + 1]; ++i) {
        const std::uint32_t h = mBinHexes[i];
        const Box3& box = mBoxes[h];
        if (p[0] < box.min[0] || p[1] < box.min[1] || p[2] < box.min[2] || p[0] > box.max[0] || p[1] > box.max[1] ||
            p[2] > box.max[2])
            continue;
        Vec3d t;
        if (!inverse(h, p, t)) continue;
        const bool inUV = t[0] >= -kInside && t[0] <= 1 + kInside && t[1] >= -kInside && t[1] <= 1 + kInside;
        if (inUV && t[2] >= -kInside && t[2] <= 1 + kInside) {
            local = t;
            return int(h);
        }
        if (extended < 0 && inUV && mOuter[h] && t[2] < 0.0 && t[2] >= -mExtension) {
            extended = int(h);
            extendedLocal = t;
        }
    }
    if (extended >= 0 && mClip->value(p) <= mClipLevel) {
        local = extendedLocal;
        return extended;
    }
    return -1;
}

bool SkinCells::touches(const Box3& box) const
{
    bool found = false;
    forBins(box, [&](std::size_t bin) {
        if (found) return;
        for (std::uint32_t i = mBinStart[bin]; i < mBinStart[bin + 1] && !found; ++i) {
            const Box3& c = mBoxes[mBinHexes[i]];
            found = c.min[0] <= box.max[0] && c.max[0] >= box.min[0] && c.min[1] <= box.max[1] &&
                    c.max[1] >= box.min[1] && c.min[2] <= box.max[2] && c.max[2] >= box.min[2];
        }
    });
    return found;
}

}  // namespace voxlat
