#include "fields/shapes/Boolean.h"

#include "fields/core/Scratch.h"

#include <algorithm>
#include <array>
#include <limits>
#include <span>
#include <stdexcept>
#include <vector>

namespace voxlat {

BooleanField::BooleanField(BooleanOp op, std::vector<FieldPtr> operands, double blendRadius)
    : mOp(op), mOperands(std::move(operands)), mBlend(blendRadius)
{
    if (mOperands.empty()) throw std::invalid_argument("a boolean needs at least one operand");
    if (mOp == BooleanOp::Difference && mOperands.size() < 2)
        throw std::invalid_argument("a difference needs at least two operands");
}

void BooleanField::combine(double& a, Vec3d* ga, double b, const Vec3d* gb) const
{
    // Intersection and difference are negated unions: max(a, b) = -min(-a, -b).
    const double sa = mOp == BooleanOp::Union ? 1.0 : -1.0;
    const double sb = mOp == BooleanOp::Intersection ? -1.0 : 1.0;
    const double x = sa * a, y = sb * b;  // minimise x and y
    double m, h;
    if (mBlend > 0.0) {
        h = std::clamp(0.5 + 0.5 * (y - x) / mBlend, 0.0, 1.0);
        m = y + h * (x - y) - mBlend * h * (1.0 - h);
    } else {
        h = x <= y ? 1.0 : 0.0;
        m = x <= y ? x : y;
    }
    a = sa * m;
    if (ga) *ga = sa * (h * sa * (*ga) + (1.0 - h) * sb * (*gb));
}

void BooleanField::values(std::span<const Vec3d> points, std::span<double> out) const
{
    mOperands[0]->values(points, out);
    std::array<double, kBatchSize> buf;
    for (std::size_t o = 1; o < mOperands.size(); ++o)
        forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
            mOperands[o]->values(points.subspan(b, n), std::span<double>(buf.data(), n));
            for (std::size_t i = 0; i < n; ++i) combine(out[b + i], nullptr, buf[i], nullptr);
        });
}

void BooleanField::gradients(std::span<const Vec3d> points, std::span<double> out, std::span<Vec3d> grad) const
{
    mOperands[0]->gradients(points, out, grad);
    std::array<double, kBatchSize> buf;
    std::array<Vec3d, kBatchSize> gbuf;
    for (std::size_t o = 1; o < mOperands.size(); ++o)
        forEachChunk(points.size(), [&](std::size_t b, std::size_t n) {
            mOperands[o]->gradients(points.subspan(b, n), std::span<double>(buf.data(), n),
                                    std::span<Vec3d>(gbuf.data(), n));
            for (std::size_t i = 0; i < n; ++i) combine(out[b + i], &grad[b + i], buf[i], &gbuf[i]);
        });
}

void BooleanField::gridValues(const GridBatch& batch, std::span<double> out) const
{
    // The other operands' values in a per-thread scratch buffer (operands may be booleans too:
    // nested leases take deeper levels). Not a buffer per call: a stack of leaves' 32 KB, freed
    // and allocated again per batch, went back to the system and came back as fresh pages (the
    // 50 mm trimmed frame: two thirds of the run's page faults, the memo's copies at 0.5 GB/s).
    // Batches went point by point until 2026-11 (a strut lattice's std::erf per point and strut
    // in every trimmed or infilled lattice's slices: most of the drained bracket's 521 s).
    const std::size_t n = batch.size();
    ScratchLease scratch(n);
    const std::span<double> buf(scratch.data(), n);
    mOperands[0]->gridValues(batch, out);
    for (std::size_t o = 1; o < mOperands.size(); ++o) {
        mOperands[o]->gridValues(batch, buf);
        fold(out.data(), buf.data(), n);
    }
}

void BooleanField::fold(double* out, const double* b, std::size_t n) const
{
    // combine() without gradients, one loop per case (the same arithmetic, so the same values).
    const double sa = mOp == BooleanOp::Union ? 1.0 : -1.0;
    const double sb = mOp == BooleanOp::Intersection ? -1.0 : 1.0;
    const double k = mBlend;
    if (k > 0.0) {
        for (std::size_t i = 0; i < n; ++i) {
            const double x = sa * out[i], y = sb * b[i];
            const double h = std::clamp(0.5 + 0.5 * (y - x) / k, 0.0, 1.0);
            out[i] = sa * (y + h * (x - y) - k * h * (1.0 - h));
        }
    } else {
        for (std::size_t i = 0; i < n; ++i) {
            const double x = sa * out[i], y = sb * b[i];
            out[i] = sa * (x <= y ? x : y);
        }
    }
}

void BooleanField::planeValues(const GridBatch& plane, int tile, Interval band, std::span<double> out,
                               std::span<signed char> side, std::span<const TileNeed> need) const
{
    const PlaneTiles tiles = PlaneTiles::of(plane, tile);
    const std::size_t count = mOperands.size(), nt = tiles.size(), n = plane.size();
    if (nt == 0) {
        gridValues(plane, out);
        return;
    }
    // The side one operand decides alone: a union is below band.lo where any operand is (the
    // smooth minimum is never above the hard one), an intersection or a difference above band.hi
    // (a difference's later operands negated). The other side needs every operand on it, by the
    // blends' reach more: each fold's smooth minimum is at most r / 4 below the hard one. A slack
    // for the blend's rounding on both ends.
    const signed char decisive = mOp == BooleanOp::Union ? -1 : 1;
    const double slack = mBlend > 0.0 ? 1e-12 * (finiteScale(band) + mBlend + 1.0) : 0.0;
    const double reach = mBlend > 0.0 ? double(count - 1) * 0.25 * mBlend + slack : 0.0;
    const Interval wide =
        decisive < 0 ? Interval{band.lo - slack, band.hi + reach} : Interval{band.lo - reach, band.hi + slack};
    auto negated = [&](std::size_t o) { return mOp == BooleanOp::Difference && o > 0; };
    // Operand 0's values in out, the others' in scratch; the cheap operands first.
    ScratchLease scratch((count - 1) * n);
    auto valuesOf = [&](std::size_t o) { return o == 0 ? out.data() : scratch.data() + (o - 1) * n; };
    std::vector<std::size_t> order;
    for (std::size_t o = 0; o < count; ++o)
        if (planeCheapOf(*mOperands[o])) order.push_back(o);
    for (std::size_t o = 0; o < count; ++o)
        if (!planeCheapOf(*mOperands[o])) order.push_back(o);
    std::vector<signed char> sides(count * nt, 0);  // per operand, oriented as the result
    std::vector<TileNeed> needs(nt);
    std::vector<unsigned char> decided(nt, 0);
    // Tiles every operand before this one proved on the other side (-decisive): only there can
    // this one's proof of that side decide the result. Where there are none, that side is not
    // asked of it (its band's end infinite): proven, it would decide nothing and its values would
    // be asked again below (a strut lattice's tiles proven inside a trimming cylinder, whose
    // sides are never proven, were a second evaluation of its struts). The same sides and values.
    std::vector<unsigned char> otherSide(nt, 1);
    for (const std::size_t o : order) {
        bool useful = false;
        for (std::size_t t = 0; t < nt; ++t) {
            const TileNeed caller = needOf(need, t);
            needs[t] = caller == TileNeed::Decide && decided[t] ? TileNeed::Skip : caller;
            useful = useful || (needs[t] == TileNeed::Decide && otherSide[t]);
        }
        Interval oneSided = wide;
        if (!useful) {
            const double inf = std::numeric_limits<double>::infinity();
            if (decisive < 0)
                oneSided.hi = inf;
            else
                oneSided.lo = -inf;
        }
        const Interval b = negated(o) ? Interval{-oneSided.hi, -oneSided.lo} : oneSided;
        signed char* s = sides.data() + o * nt;
        planeValuesOf(*mOperands[o], plane, tile, b, std::span<double>(valuesOf(o), n), std::span<signed char>(s, nt),
                      needs);
        for (std::size_t t = 0; t < nt; ++t) {
            if (needs[t] == TileNeed::Skip) s[t] = 0;
            if (negated(o)) s[t] = static_cast<signed char>(-s[t]);
            if (s[t] == decisive) decided[t] = 1;
            if (s[t] != -decisive) otherSide[t] = 0;
        }
    }
    // The result's sides; an open tile needs every operand's values there.
    std::vector<std::size_t> again(count, 0);
    for (std::size_t t = 0; t < nt; ++t) {
        side[t] = 0;
        if (needOf(need, t) == TileNeed::Skip) continue;
        if (decided[t]) {
            side[t] = decisive;
            continue;
        }
        bool all = true;
        for (std::size_t o = 0; o < count; ++o) all = all && sides[o * nt + t] == -decisive;
        if (all) {
            side[t] = static_cast<signed char>(-decisive);
            continue;
        }
        for (std::size_t o = 0; o < count; ++o) again[o] += sides[o * nt + t] != 0;
    }
    ScratchLease redone(n);
    std::vector<signed char> ignored(nt);
    for (std::size_t o = 0; o < count; ++o) {
        if (again[o] == 0) continue;
        for (std::size_t t = 0; t < nt; ++t)
            needs[t] = side[t] == 0 && needOf(need, t) != TileNeed::Skip && sides[o * nt + t] != 0 ? TileNeed::Exact
                                                                                                   : TileNeed::Skip;
        const Interval b = negated(o) ? Interval{-wide.hi, -wide.lo} : wide;
        planeValuesOf(*mOperands[o], plane, tile, b, std::span<double>(redone.data(), n), ignored, needs);
        for (std::size_t t = 0; t < nt; ++t)
            if (needs[t] == TileNeed::Exact)
                copyTileWithHalo(plane, tile, int(t / tiles.ny), int(t % tiles.ny), redone.data(), valuesOf(o));
    }
    for (std::size_t o = 1; o < count; ++o) fold(out.data(), valuesOf(o), n);
}

bool BooleanField::planeCheap() const
{
    return std::all_of(mOperands.begin(), mOperands.end(), [](const FieldPtr& o) { return planeCheapOf(*o); });
}

double BooleanField::period(int axis) const
{
    double p = kInvariant;
    for (const FieldPtr& operand : mOperands) p = commonPeriod(p, operand->period(axis));
    return p;
}

Interval BooleanField::bound(const Box3& box) const
{
    return foldRanges([&](const FieldNode& operand) { return operand.bound(box); });
}

std::optional<Interval> BooleanField::heldRange(const GridBatch& points) const
{
    std::vector<std::optional<Interval>> held(mOperands.size());
    bool any = false;
    for (std::size_t o = 0; o < mOperands.size(); ++o) any = (held[o] = mOperands[o]->heldRange(points)) || any;
    if (!any) return std::nullopt;
    // The points lie in their box: an operand's bound there holds at each of them.
    const Box3 box = points.bounds();
    std::size_t o = 0;
    return foldRanges([&](const FieldNode& operand) {
        const std::optional<Interval>& h = held[o++];
        return h ? *h : operand.bound(box);
    });
}

template <class Of>
Interval BooleanField::foldRanges(Of of) const
{
    Interval r = of(*mOperands[0]);
    for (std::size_t o = 1; o < mOperands.size(); ++o) {
        const Interval b = of(*mOperands[o]);
        switch (mOp) {
            case BooleanOp::Union:
                r = min(r, b);
                break;
            case BooleanOp::Intersection:
                r = max(r, b);
                break;
            case BooleanOp::Difference:
                r = max(r, -b);
                break;
        }
        // The smooth minimum lies within r/4 below the hard one (above it for max).
        if (mBlend > 0.0)
            r = mOp == BooleanOp::Union ? Interval{r.lo - 0.25 * mBlend, r.hi} : Interval{r.lo, r.hi + 0.25 * mBlend};
    }
    return r;
}

bool BooleanField::meets(const Box3& box, const Interval& band) const
{
    if (mBlend > 0.0) return false;
    // The other operands' bounds must keep the proving operand's extreme point: below band.hi
    // for a max, above band.lo for a min.
    auto othersKeep = [&](std::size_t proving) {
        for (std::size_t o = 0; o < mOperands.size(); ++o) {
            if (o == proving) continue;
            const Interval b = mOperands[o]->bound(box);
            const bool keeps = mOp == BooleanOp::Union          ? b.lo >= band.lo
                               : mOp == BooleanOp::Intersection ? b.hi <= band.hi
                                                                : -b.lo <= band.hi;  // difference: -b
            if (!keeps) return false;
        }
        return true;
    };
    const std::size_t candidates = mOp == BooleanOp::Difference ? 1 : mOperands.size();
    for (std::size_t o = 0; o < candidates; ++o)
        if (mOperands[o]->meets(box, band) && othersKeep(o)) return true;
    return false;
}

std::optional<Box3> BooleanField::support() const
{
    if (mOp == BooleanOp::Difference) return mOperands[0]->support();
    std::optional<Box3> r;
    for (std::size_t o = 0; o < mOperands.size(); ++o) {
        const std::optional<Box3> b = mOperands[o]->support();
        if (mOp == BooleanOp::Union) {
            if (!b) return std::nullopt;  // one unbounded operand makes the union unbounded
            r = o == 0 ? *b
                       : Box3{openvdb::math::minComponent(r->min, b->min), openvdb::math::maxComponent(r->max, b->max)};
        } else if (b) {
            // The smooth maximum is never below the hard one, so any box bounds the result.
            r = !r ? *b
                   : Box3{openvdb::math::maxComponent(r->min, b->min), openvdb::math::minComponent(r->max, b->max)};
        }
    }
    if (r && mOp == BooleanOp::Union && mBlend > 0.0) r = Box3{r->min - Vec3d(mBlend), r->max + Vec3d(mBlend)};
    if (r)
        for (int a = 0; a < 3; ++a) r->max[a] = std::max(r->max[a], r->min[a]);  // disjoint: an empty box
    return r;
}

}  // namespace voxlat
