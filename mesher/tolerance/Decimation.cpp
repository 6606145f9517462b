#include "mesher/tolerance/Decimation.h"

#include "fields/shapes/BoxField.h"
#include "fields/shapes/SurfaceDistance.h"
#include "mesher/checks/MeshCheck.h"
#include "mesher/checks/TriangleCheck.h"
#include "mesher/extract/ExtractProgress.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cfloat>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <mutex>
#include <numeric>
#include <queue>
#include <tuple>
#include <unordered_map>
#include <vector>

namespace voxlat {

namespace {

/// No collapse makes an edge longer than this many voxels (see FieldDecimater::fieldAllows).
constexpr double kMaxEdgeVoxels = 6.0;

/// Signed first-order distance (f - level) / |grad f|; a flat spot away from the level is far.
double signedDistance(double r, const Vec3d& g)
{
    return firstOrderSignedDistance(r, g.length());
}

/// A triangle to check: corners, the signed distances there, and its edge midpoints (indices
/// into FieldDecimater::mMid; edge i runs from corner i to corner i + 1).
struct CheckTriangle {
    std::array<Vec3d, 3> p;
    std::array<double, 3> s;
    std::array<int, 3> mid;
};

/// An edge midpoint of a check and its signed distance (kUnknown until evaluated).
struct Midpoint {
    Vec3d p;
    double distance;
};

/// Marks a distance not evaluated yet (no field reaches it: signedDistance caps at 1e30).
constexpr double kUnknown = std::numeric_limits<double>::max();

/// Garland and Heckbert's plane quadric: the symmetric 4 x 4 matrix of (a, b, c, d) for the plane
/// ax + by + cz + d = 0, kept as its ten distinct entries.
struct Quadric {
    double a2 = 0, ab = 0, ac = 0, ad = 0, b2 = 0, bc = 0, bd = 0, c2 = 0, cd = 0, d2 = 0;
    Quadric() = default;
    Quadric(double a, double b, double c, double d, double weight)
        : a2(weight * a * a),
          ab(weight * a * b),
          ac(weight * a * c),
          ad(weight * a * d),
          b2(weight * b * b),
          bc(weight * b * c),
          bd(weight * b * d),
          c2(weight * c * c),
          cd(weight * c * d),
          d2(weight * d * d)
    {
    }
    Quadric& operator+=(const Quadric& q)
    {
        a2 += q.a2, ab += q.ab, ac += q.ac, ad += q.ad, b2 += q.b2, bc += q.bc, bd += q.bd, c2 += q.c2, cd += q.cd,
            d2 += q.d2;
        return *this;
    }
    /// The weighted sum of squared distances of @a p to the planes.
    double operator()(const Vec3d& p) const
    {
        const double x = p.x(), y = p.y(), z = p.z();
        return x * (a2 * x + 2.0 * (ab * y + ac * z + ad)) + y * (b2 * y + 2.0 * (bc * z + bd)) +
               z * (c2 * z + 2.0 * cd) + d2;
    }
};

/// Halfedge collapses on a block's triangles in flat arrays (corner lists and, per vertex, its
/// triangles in a fixed number of slots), in the order of the quadric error metric (area-weighted
/// plane quadrics), each checked by the link condition (the mesh stays closed, manifold and
/// oriented) and then against the field. The field check, which costs field evaluations, runs only
/// on the collapse about to be made; candidates that cannot pass for reasons known without the
/// field (quadric error, edge length, seams) are never queued.
class FieldDecimater {
public:
    /// Triangles per vertex at most: a collapse that would give a vertex more is not made.
    static constexpr int kSlots = 24;

    /// @a points, @a triangles (indices into points), which vertices stay (@a locked) and the
    /// signed distance at each vertex; vertices whose triangles do not close a single fan are
    /// kept as they are.
    FieldDecimater(std::vector<Vec3d> points, std::vector<std::array<std::uint32_t, 3>> triangles,
                   std::vector<std::uint8_t> locked, std::vector<double> vertexDistance, const FieldNode& field,
                   const DecimationOptions& options)
        : mPoints(std::move(points)),
          mTriangles(std::move(triangles)),
          mLocked(std::move(locked)),
          mField(field),
          mOptions(options),
          mVertexDistance(std::move(vertexDistance))
    {
        if (options.box) mBox.emplace(*options.box);
        // A collapse whose quadric error exceeds the squared tolerance puts the point far off one
        // of the planes merged into it: such candidates are mostly refused by the field check
        // anyway, so they are not tried (the field check still decides the rest).
        mMaxError = options.quadricShare * options.tolerance * options.tolerance;
        mMaxEdgeSqr = (kMaxEdgeVoxels * options.voxel) * (kMaxEdgeVoxels * options.voxel);
        const std::size_t nv = mPoints.size(), nt = mTriangles.size();
        mQuadrics.assign(nv, Quadric());
        mSlots.assign(nv * kSlots, 0);
        mCount.assign(nv, 0);
        mOverflow.assign(nv, 0);
        mAlive.assign(nt, 1);
        mEdgeMid.assign(nt, {kUnknown, kUnknown, kUnknown});
        for (std::uint32_t t = 0; t < nt; ++t) {
            const auto& c = mTriangles[t];
            const Vec3d &p0 = mPoints[c[0]], &p1 = mPoints[c[1]], &p2 = mPoints[c[2]];
            Vec3d n = (p1 - p0).cross(p2 - p0);
            double area = n.length();
            if (area > FLT_MIN) {
                n /= area;
                area *= 0.5;
            }
            const Quadric q(n.x(), n.y(), n.z(), -p0.dot(n), area);
            for (std::uint32_t v : c) {
                mQuadrics[v] += q;
                if (mCount[v] < kSlots)
                    mSlots[std::size_t(v) * kSlots + mCount[v]] = t;
                else
                    mLocked[v] = mOverflow[v] = 1;  // more triangles than slots: kept, and not joined
                mCount[v] = std::uint8_t(std::min(kSlots, mCount[v] + 1));
            }
        }
        mStamp.assign(nv, 0);
        mQueued.assign(nv, 0);
        mDirty.assign(nv, 0);
        mRefused.assign(nv * kSlots, 0);
        mRefusedCount.assign(nv, 0);
    }

    /// Collapses until no candidate is left; @a check (optional) is called every 16 vertices
    /// queued and candidates taken, and may throw to stop.
    void run(DecimationStats& stats, const std::function<void()>& check = {})
    {
        for (std::uint32_t v = 0; v < mPoints.size(); ++v) {
            if (check && (v & 15) == 0) check();
            queueVertex(v);
        }
        for (std::size_t taken = 0; !mHeap.empty(); ++taken) {
            if (check && (taken & 15) == 0) check();
            const Entry top = mHeap.top();
            mHeap.pop();
            const std::uint32_t v = std::get<1>(top), w = std::get<3>(top);
            if (std::get<2>(top) != mStamp[v] || mCount[v] == 0) continue;  // gone
            if (mDirty[v]) {
                // Its one-ring changed since it was queued: its candidate is chosen again now,
                // once, rather than after every collapse next to it.
                queueVertex(v);
                continue;
            }
            Collapse c;
            // The topology test first: it needs no field evaluations.
            if (!collapseLegal(v, w, c)) {
                refuse(v, w);
                queueVertex(v);
                continue;
            }
            if (!fieldAllows(c)) {
                ++stats.refused;
                refuse(v, w);
                queueVertex(v);
                continue;
            }
            collapse(c);
            ++stats.collapses;
        }
    }

    /// The triangles left, as corner lists into the block's points.
    std::vector<std::array<std::uint32_t, 3>> triangles() const
    {
        std::vector<std::array<std::uint32_t, 3>> out;
        for (std::size_t t = 0; t < mTriangles.size(); ++t)
            if (mAlive[t]) out.push_back(mTriangles[t]);
        return out;
    }

private:
    /// (priority, vertex, stamp, target vertex); the smallest priority first, ties by vertex index.
    using Entry = std::tuple<float, std::uint32_t, unsigned, std::uint32_t>;

    /// A collapse of v0 onto v1 across the edge whose triangles are fl (v0 -> v1 in its corner
    /// order, third corner vl) and fr (v1 -> v0, third corner vr).
    struct Collapse {
        std::uint32_t v0, v1, fl, fr, vl, vr;
    };

    const std::uint32_t* slots(std::uint32_t v) const { return &mSlots[std::size_t(v) * kSlots]; }
    std::uint32_t* slots(std::uint32_t v) { return &mSlots[std::size_t(v) * kSlots]; }

    /// The vertices joined to @a v by an edge (in the order of its triangles when they close a
    /// fan); false when they do not (a seam vertex's open part of a fan in this block).
    bool ring(std::uint32_t v, std::vector<std::uint32_t>& out) const
    {
        // In an oriented fan each neighbour follows v in one triangle and precedes it in the
        // next: the ring is the followers, closed when they are distinct and are the precedents.
        out.clear();
        mPrecedents.clear();
        const std::uint32_t* s = slots(v);
        for (int k = 0; k < mCount[v]; ++k) {
            const auto& c = mTriangles[s[k]];
            const int i = c[0] == v ? 0 : c[1] == v ? 1 : 2;
            out.push_back(c[(i + 1) % 3]);
            mPrecedents.push_back(c[(i + 2) % 3]);
        }
        bool closed = true;
        for (std::size_t a = 0; a < out.size() && closed; ++a) {
            closed = std::find(mPrecedents.begin(), mPrecedents.end(), out[a]) != mPrecedents.end();
            for (std::size_t b = a + 1; b < out.size() && closed; ++b) closed = out[a] != out[b];
        }
        if (!closed) {
            // An open fan (a seam vertex's part in this block): its neighbours, each once.
            for (std::uint32_t x : mPrecedents)
                if (std::find(out.begin(), out.end(), x) == out.end()) out.push_back(x);
            std::sort(out.begin(), out.end());
            out.erase(std::unique(out.begin(), out.end()), out.end());
        }
        return closed;
    }

    bool isRefused(std::uint32_t v, std::uint32_t w) const
    {
        const std::uint32_t* r = &mRefused[std::size_t(v) * kSlots];
        return std::find(r, r + mRefusedCount[v], w) != r + mRefusedCount[v];
    }
    void refuse(std::uint32_t v, std::uint32_t w)
    {
        if (mRefusedCount[v] < kSlots) mRefused[std::size_t(v) * kSlots + mRefusedCount[v]++] = w;
    }

    /// Queues @a v with its cheapest collapse onto a neighbour not yet refused whose quadric error
    /// is below the bound, that makes no edge longer than the limit and that a seam allows
    /// (topology and the field are checked when it comes up).
    void queueVertex(std::uint32_t v)
    {
        ++mStamp[v];
        mDirty[v] = 0;
        mQueued[v] = 0;
        // A locked vertex stays, and so does one whose triangles do not close one fan (a
        // collapsed vertex has none: nothing to choose from).
        if (mLocked[v] || !ring(v, mRing)) return;
        double best = mMaxError;
        std::uint32_t bestTarget = 0;
        bool found = false;
        for (std::uint32_t w : mRing) {
            if (isRefused(v, w)) continue;
            Quadric q = mQuadrics[v];
            q += mQuadrics[w];
            const double error = q(mPoints[w]);
            // Ties go to the first neighbour.
            if (!(error < best)) continue;
            if (!shortEnough(w) || !seamAllows(v, w)) continue;
            best = error;
            bestTarget = w;
            found = true;
        }
        if (found) {
            mHeap.emplace(float(best), v, mStamp[v], bestTarget);
            mQueued[v] = 1;
        }
    }

    /// Whether moving the vertex whose one-ring is mRing onto @a v1 keeps every edge within the
    /// length limit (see fieldAllows).
    bool shortEnough(std::uint32_t v1) const
    {
        const Vec3d& p1 = mPoints[v1];
        for (std::uint32_t w : mRing)
            if ((mPoints[w] - p1).lengthSqr() > mMaxEdgeSqr) return false;
        return true;
    }

    /// Whether @a a and @a b share a triangle.
    bool joined(std::uint32_t a, std::uint32_t b) const { return hasTriangle(a, b, b); }

    /// In a block of a larger mesh, locked vertices are shared with other blocks, which may hold
    /// an edge between two of them or make one at the same time: a collapse onto a locked vertex
    /// may not join it to another locked vertex it is not joined to here already (mRing: v0's).
    bool seamAllows(std::uint32_t v0, std::uint32_t v1) const
    {
        if (!mLocked[v1]) return true;
        for (std::uint32_t w : mRing)
            if (w != v1 && w != v0 && mLocked[w] && !joined(v1, w)) return false;
        return true;
    }

    /// The link condition: v0 and v1 share exactly the two neighbours across their edge and no
    /// triangle with both (so the collapse leaves a manifold; OpenMesh's is_collapse_ok and the
    /// decimater's tetrahedron test), and v1's triangles fit its slots afterwards.
    bool collapseLegal(std::uint32_t v0, std::uint32_t v1, Collapse& c)
    {
        c.v0 = v0;
        c.v1 = v1;
        int shared = 0;
        const std::uint32_t* s = slots(v0);
        for (int k = 0; k < mCount[v0]; ++k) {
            const auto& t = mTriangles[s[k]];
            for (int i = 0; i < 3; ++i)
                if (t[i] == v0) {
                    if (t[(i + 1) % 3] == v1) c.fl = s[k], c.vl = t[(i + 2) % 3], ++shared;
                    if (t[(i + 2) % 3] == v1) c.fr = s[k], c.vr = t[(i + 1) % 3], ++shared;
                }
        }
        if (shared != 2 || c.vl == c.vr) return false;
        if (mCount[v0] + mCount[v1] - 4 > kSlots) return false;
        if (mOverflow[v1] || mOverflow[c.vl] || mOverflow[c.vr] || !ring(v0, mRing)) return false;
        // A seam vertex's fan in this block may be open.
        if (!ring(v1, mRing1) && !mLocked[v1]) return false;
        int common = 0;
        for (std::uint32_t x : mRing)
            if (x != v1 && std::find(mRing1.begin(), mRing1.end(), x) != mRing1.end()) {
                if (x != c.vl && x != c.vr) return false;
                ++common;
            }
        if (common != 2) return false;
        // The edge's link too: triangles v0 vl vr and v1 vl vr both there would fold onto each
        // other; and vl, vr joined with three neighbours each would leave a flat tetrahedron.
        if (hasTriangle(v0, c.vl, c.vr) && hasTriangle(v1, c.vl, c.vr)) return false;
        return !(mCount[c.vl] == 3 && mCount[c.vr] == 3 && joined(c.vl, c.vr));
    }

    /// Whether one of @a a's triangles has corners @a b and @a c too.
    bool hasTriangle(std::uint32_t a, std::uint32_t b, std::uint32_t c) const
    {
        const std::uint32_t* s = slots(a);
        for (int k = 0; k < mCount[a]; ++k) {
            const auto& t = mTriangles[s[k]];
            if ((t[0] == b || t[1] == b || t[2] == b) && (t[0] == c || t[1] == c || t[2] == c)) return true;
        }
        return false;
    }

    /// The triangles around v0 that survive the collapse, with v0 moved onto v1: none may turn
    /// over or vanish, and each must stay within the tolerance.
    bool fieldAllows(const Collapse& c)
    {
        mChecks.clear();
        mMid.clear();
        mSpokes.clear();
        mMidEdge.clear();
        const Vec3d& p1 = mPoints[c.v1];
        // The midpoint of the new edge from v1 to @a w (shared by the two triangles beside it).
        auto spoke = [&](std::uint32_t w) {
            for (const auto& [vertex, index] : mSpokes)
                if (vertex == w) return index;
            const int index = int(mMid.size());
            mMid.push_back({0.5 * (p1 + mPoints[w]), kUnknown});
            mSpokes.emplace_back(w, index);
            return index;
        };
        const std::uint32_t* s = slots(c.v0);
        for (int k = 0; k < mCount[c.v0]; ++k) {
            const std::uint32_t f = s[k];
            if (f == c.fl || f == c.fr) continue;
            const auto& corners = mTriangles[f];
            CheckTriangle t;
            std::array<Vec3d, 3> before;
            for (int i = 0; i < 3; ++i) {
                const std::uint32_t a = corners[i], b = corners[(i + 1) % 3];
                before[i] = mPoints[a];
                t.p[i] = a == c.v0 ? p1 : before[i];
                t.s[i] = mVertexDistance[a == c.v0 ? c.v1 : a];
                if (a == c.v0 || b == c.v0) {
                    t.mid[i] = spoke(a == c.v0 ? b : a);
                } else {
                    // An edge of the one-ring, which the collapse keeps as it is: its midpoint's
                    // distance is kept from one check to the next.
                    t.mid[i] = int(mMid.size());
                    mMid.push_back({0.5 * (before[i] + mPoints[b]), mEdgeMid[f][i]});
                    if (mEdgeMid[f][i] == kUnknown) mMidEdge.emplace_back(t.mid[i], f, i);
                }
            }
            const Vec3d n0 = (before[1] - before[0]).cross(before[2] - before[0]);
            const Vec3d n1 = (t.p[1] - t.p[0]).cross(t.p[2] - t.p[0]);
            if (!(n1.dot(n0) > 0.0) || !(n1.lengthSqr() > 1e-12 * n0.lengthSqr())) return false;
            // A quadratic fits the distance over a few voxels of a surface the grid resolves;
            // longer triangles would have to be checked in many pieces (most of the field
            // evaluations went there, mostly on flat faces where they then passed), so they
            // are not made: a flat region ends up in triangles of a few voxels.
            if ((t.p[1] - t.p[0]).lengthSqr() > mMaxEdgeSqr || (t.p[2] - t.p[1]).lengthSqr() > mMaxEdgeSqr ||
                (t.p[0] - t.p[2]).lengthSqr() > mMaxEdgeSqr)
                return false;
            mChecks.push_back(t);
        }
        return withinTolerance();
    }

    /// Makes the collapse @a c: fl and fr go, v0's other triangles take v1 (their new edges keep
    /// the midpoint distances the check found), v1's quadric takes v0's, and the vertices around
    /// v0 are queued again (their collapses refused before may pass now).
    void collapse(const Collapse& c)
    {
        mSupport.swap(mRing);  // v0's one-ring, as collapseLegal found it
        auto drop = [&](std::uint32_t v, std::uint32_t f) {
            std::uint32_t* s = slots(v);
            std::uint8_t& n = mCount[v];
            const auto at = std::find(s, s + n, f);
            if (at != s + n) {
                std::copy(at + 1, s + n, at);
                --n;
            }
        };
        for (std::uint32_t f : {c.fl, c.fr}) {
            mAlive[f] = 0;
            for (std::uint32_t x : mTriangles[f])
                if (x != c.v0) drop(x, f);
        }
        const std::uint32_t* s = slots(c.v0);
        for (int k = 0; k < mCount[c.v0]; ++k) {
            const std::uint32_t f = s[k];
            if (!mAlive[f]) continue;
            auto& corners = mTriangles[f];
            for (int i = 0; i < 3; ++i)
                if (corners[i] == c.v0) {
                    corners[i] = c.v1;
                    // Edges i (to corner i + 1) and i + 2 (from corner i + 2) now run from v1.
                    for (int e : {i, (i + 2) % 3}) {
                        const std::uint32_t other = corners[e == i ? (i + 1) % 3 : e];
                        double value = kUnknown;
                        for (const auto& [vertex, index] : mSpokes)
                            if (vertex == other) value = mMid[index].distance;
                        mEdgeMid[f][e] = value;
                    }
                }
            slots(c.v1)[mCount[c.v1]++] = f;
        }
        mCount[c.v0] = 0;
        mQuadrics[c.v1] += mQuadrics[c.v0];
        for (std::uint32_t w : mSupport) {
            mRefusedCount[w] = 0;
            if (mQueued[w])
                mDirty[w] = 1;
            else
                queueVertex(w);
        }
    }

    /// Evaluates every triangle's centre and the unknown edge midpoints in a batch and bounds
    /// |distance| over each triangle by its quadratic interpolant plus the centre's miss.
    bool withinTolerance()
    {
        // A tenth of the tolerance is kept back for what the quadratic misses.
        const double tolerance = 0.9 * mOptions.tolerance;
        // The centres first: most refused collapses fail there.
        mEval.clear();
        for (const CheckTriangle& t : mChecks) mEval.push_back((t.p[0] + t.p[1] + t.p[2]) / 3.0);
        evaluate();
        mCentres.resize(mChecks.size());
        for (std::size_t k = 0; k < mChecks.size(); ++k) {
            mCentres[k] = signedDistance(mValues[k] - mOptions.level, mGradients[k]);
            const double centre = mBox ? std::max(mCentres[k], boxDistance(mEval[k])) : mCentres[k];
            if (std::abs(centre) > tolerance) return false;
        }
        mEval.clear();
        for (const Midpoint& m : mMid)
            if (m.distance == kUnknown) mEval.push_back(m.p);
        evaluate();
        std::size_t next = 0;
        for (Midpoint& m : mMid)
            if (m.distance == kUnknown) {
                m.distance = signedDistance(mValues[next] - mOptions.level, mGradients[next]);
                ++next;
            }
        for (const auto& [index, f, e] : mMidEdge) mEdgeMid[f][e] = mMid[index].distance;
        for (std::size_t k = 0; k < mChecks.size(); ++k) {
            const CheckTriangle& t = mChecks[k];
            const std::array<double, 3> m = {mMid[t.mid[0]].distance, mMid[t.mid[1]].distance, mMid[t.mid[2]].distance};
            if (!triangleWithin(t.p, t.s, m, mCentres[k], mOptions.box, tolerance)) return false;
        }
        return true;
    }

    /// Values and gradients of the field at mEval.
    void evaluate()
    {
        mValues.resize(mEval.size());
        mGradients.resize(mEval.size());
        forEachChunk(mEval.size(), [&](std::size_t begin, std::size_t count) {
            mField.gradients(std::span<const Vec3d>(mEval.data() + begin, count),
                             std::span<double>(mValues.data() + begin, count),
                             std::span<Vec3d>(mGradients.data() + begin, count));
        });
    }

    /// The box's exact signed distance (options.box).
    double boxDistance(const Vec3d& p) const { return mBox->eval(p.x(), p.y(), p.z()); }

    std::vector<Vec3d> mPoints;
    std::vector<std::array<std::uint32_t, 3>> mTriangles;
    std::vector<std::uint8_t> mLocked;
    const FieldNode& mField;
    std::optional<BoxField> mBox;
    DecimationOptions mOptions;
    std::vector<double> mVertexDistance;
    double mMaxEdgeSqr = 0.36;
    double mMaxError = 0.0;
    std::vector<Quadric> mQuadrics;
    /// Each vertex's triangles (kSlots per vertex, mCount used), each triangle's liveness and
    /// the known midpoint distances of its edges (edge i from corner i to corner i + 1).
    std::vector<std::uint32_t> mSlots;
    std::vector<std::uint8_t> mCount, mAlive;
    /// Vertices with more triangles than slots (their lists are incomplete): nothing collapses
    /// onto them or next to them.
    std::vector<std::uint8_t> mOverflow;
    std::vector<std::array<double, 3>> mEdgeMid;
    std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> mHeap;
    /// Per vertex the neighbours its collapse onto was refused (until its one-ring changes).
    std::vector<std::uint32_t> mRefused;
    std::vector<std::uint8_t> mRefusedCount;
    std::vector<unsigned> mStamp;
    /// Whether a vertex has an entry in the heap, and whether its one-ring changed since.
    std::vector<std::uint8_t> mQueued, mDirty;
    std::vector<std::uint32_t> mRing, mRing1, mSupport;
    mutable std::vector<std::uint32_t> mPrecedents;
    std::vector<CheckTriangle> mChecks;
    std::vector<Midpoint> mMid;
    /// The check's new edges from v1 (by the vertex at their other end) and one-ring edges whose
    /// midpoint it evaluates (index into mMid, triangle, edge).
    std::vector<std::pair<std::uint32_t, int>> mSpokes;
    std::vector<std::tuple<int, std::uint32_t, int>> mMidEdge;
    std::vector<double> mCentres;
    std::vector<Vec3d> mEval, mGradients;
    std::vector<double> mValues;
};

}  // namespace

namespace {

/// Counts collapses and reports progress from the blocks (serialised).
struct BlockProgress {
    explicit BlockProgress(const ProgressFn& f) : fn(f) {}
    const ProgressFn& fn;
    std::size_t total = 1, done = 0;
    int percent = -1;
    std::mutex mutex;
    /// Reports the current percent again (so a cancel can stop a block in its middle).
    void check()
    {
        if (!fn) return;
        std::lock_guard<std::mutex> lock(mutex);
        fn(0.01 * std::max(percent, 0));
    }
    void add(std::size_t units)
    {
        if (!fn) return;
        std::lock_guard<std::mutex> lock(mutex);
        done += units;
        const int now = int(std::min<std::size_t>(99, 100 * done / std::max<std::size_t>(1, total)));
        if (now > percent) {
            percent = now;
            fn(0.01 * now);
        }
    }
};

/// What one block gave: its triangles (global vertex indices) and counts.
struct BlockResult {
    std::vector<openvdb::Vec3I> triangles;
    std::size_t collapses = 0, refused = 0;
    bool decimated = true;
};

/// Decimates the triangles @a ids of @a mesh (one block) with the vertices flagged in @a locked
/// kept; returns what is left.
BlockResult decimateBlock(const TriangleMesh& mesh, const std::vector<std::uint32_t>& ids,
                          const std::vector<std::uint8_t>& locked, const std::vector<double>& vertexDistance,
                          const FieldNode& field, const DecimationOptions& options, const std::function<void()>& check)
{
    BlockResult result;
    std::vector<std::uint32_t> vertices;
    vertices.reserve(3 * ids.size());
    for (std::uint32_t t : ids)
        for (int k = 0; k < 3; ++k) vertices.push_back(mesh.triangles[t][k]);
    std::sort(vertices.begin(), vertices.end());
    vertices.erase(std::unique(vertices.begin(), vertices.end()), vertices.end());
    // Global to local indices through a table of the whole mesh's size, kept per thread: only
    // this block's entries are written before they are read, so it is never cleared.
    thread_local std::vector<std::uint32_t> localOf;
    if (localOf.size() < mesh.points.size()) localOf.resize(mesh.points.size());
    for (std::size_t i = 0; i < vertices.size(); ++i) localOf[vertices[i]] = std::uint32_t(i);
    auto local = [&](std::uint32_t v) { return localOf[v]; };
    std::vector<Vec3d> points(vertices.size());
    std::vector<double> distance(vertices.size());
    std::vector<std::uint8_t> keep(vertices.size());
    for (std::size_t i = 0; i < vertices.size(); ++i) {
        points[i] = toDouble(mesh.points[vertices[i]]);
        distance[i] = vertexDistance[vertices[i]];
        keep[i] = locked[vertices[i]];
    }
    std::vector<std::array<std::uint32_t, 3>> triangles(ids.size());
    for (std::size_t k = 0; k < ids.size(); ++k) {
        const openvdb::Vec3I& tri = mesh.triangles[ids[k]];
        triangles[k] = {local(tri[0]), local(tri[1]), local(tri[2])};
        if (triangles[k][0] == triangles[k][1] || triangles[k][1] == triangles[k][2] ||
            triangles[k][2] == triangles[k][0]) {
            // Not a mesh of proper triangles: left as it is.
            result.decimated = false;
            for (std::uint32_t u : ids) result.triangles.push_back(mesh.triangles[u]);
            return result;
        }
    }
    DecimationStats stats;
    FieldDecimater decimater(std::move(points), std::move(triangles), std::move(keep), std::move(distance), field,
                             options);
    decimater.run(stats, check);
    result.collapses = stats.collapses;
    result.refused = stats.refused;
    for (const auto& t : decimater.triangles())
        result.triangles.emplace_back(vertices[t[0]], vertices[t[1]], vertices[t[2]]);
    return result;
}

/// A pass's block results and the locks they were made with (see decimatePass).
struct PassCache {
    std::vector<std::uint8_t> locked;
    std::vector<BlockResult> results;
};

/// One pass over blocks of edge @a size whose corners sit at @a origin + k size: each triangle
/// goes to the block of its centroid, vertices used by triangles of two blocks are kept, the
/// blocks are decimated in parallel and put together in block order (vertices renumbered in
/// their old order), so the result does not depend on the thread count.
bool decimatePass(TriangleMesh& mesh, std::vector<double>& vertexDistance, std::vector<std::uint8_t>& kept,
                  const FieldNode& field, const DecimationOptions& options, const Vec3d& origin, double size,
                  DecimationStats& stats, BlockProgress& progress, PassCache* cache = nullptr)
{
    const std::size_t numTriangles = mesh.triangles.size();
    // (block key, triangle), sorted: blocks in key order, their triangles in index order (a
    // total order, so the parallel sort gives the same for any thread count).
    std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed(numTriangles);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numTriangles), [&](const auto& range) {
        for (std::size_t t = range.begin(); t != range.end(); ++t) {
            const openvdb::Vec3I& tri = mesh.triangles[t];
            const Vec3d c =
                (toDouble(mesh.points[tri[0]]) + toDouble(mesh.points[tri[1]]) + toDouble(mesh.points[tri[2]])) / 3.0;
            std::uint64_t key = 0;
            for (int a = 0; a < 3; ++a)
                key = (key << 21) | std::uint64_t(std::clamp<std::int64_t>(
                                        std::int64_t(std::floor((c[a] - origin[a]) / size)), 0, (1 << 21) - 1));
            keyed[t] = {key, std::uint32_t(t)};
        }
    });
    tbb::parallel_sort(keyed.begin(), keyed.end());
    std::vector<std::vector<std::uint32_t>> blocks;
    for (std::size_t i = 0; i < numTriangles; ++i) {
        if (i == 0 || keyed[i].first != keyed[i - 1].first) blocks.emplace_back();
        blocks.back().push_back(keyed[i].second);
    }
    keyed = {};
    std::vector<std::uint8_t> locked = kept;
    {
        std::vector<std::int64_t> owner(mesh.points.size(), -1);
        for (std::size_t b = 0; b < blocks.size(); ++b)
            for (std::uint32_t t : blocks[b])
                for (int k = 0; k < 3; ++k) {
                    const std::uint32_t v = mesh.triangles[t][k];
                    if (owner[v] < 0)
                        owner[v] = std::int64_t(b);
                    else if (owner[v] != std::int64_t(b))
                        locked[v] = 1;
                }
    }
    std::vector<BlockResult> results(blocks.size());
    // A block's result depends on its triangles and which of their vertices are locked alone: a
    // block of the same mesh whose locks are those of a cached pass is taken from the cache.
    const bool reuse = cache && cache->locked.size() == locked.size() && cache->results.size() == blocks.size();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks.size(), 1), [&](const auto& range) {
        for (std::size_t b = range.begin(); b != range.end(); ++b) {
            const bool same = reuse && std::all_of(blocks[b].begin(), blocks[b].end(), [&](std::uint32_t t) {
                                  const openvdb::Vec3I& tri = mesh.triangles[t];
                                  return locked[tri[0]] == cache->locked[tri[0]] &&
                                         locked[tri[1]] == cache->locked[tri[1]] &&
                                         locked[tri[2]] == cache->locked[tri[2]];
                              });
            results[b] = same ? cache->results[b]
                              : decimateBlock(mesh, blocks[b], locked, vertexDistance, field, options,
                                              [&] { progress.check(); });
            progress.add(blocks[b].size());
        }
    });

    bool all = true;
    TriangleMesh out;
    std::vector<std::uint32_t> newIndex(mesh.points.size(), std::numeric_limits<std::uint32_t>::max());
    for (const BlockResult& r : results) {
        all = all && r.decimated;
        stats.collapses += r.collapses;
        stats.refused += r.refused;
        for (const openvdb::Vec3I& t : r.triangles)
            for (int k = 0; k < 3; ++k) newIndex[t[k]] = 0;
    }
    std::vector<double> distance;
    std::vector<std::uint8_t> keptOut;
    for (std::size_t v = 0; v < mesh.points.size(); ++v) {
        if (newIndex[v] != 0) continue;
        newIndex[v] = std::uint32_t(out.points.size());
        out.points.push_back(mesh.points[v]);
        distance.push_back(vertexDistance[v]);
        keptOut.push_back(kept[v]);
    }
    for (const BlockResult& r : results)
        for (const openvdb::Vec3I& t : r.triangles)
            out.triangles.emplace_back(newIndex[t[0]], newIndex[t[1]], newIndex[t[2]]);
    mesh = std::move(out);
    vertexDistance = std::move(distance);
    kept = std::move(keptOut);
    if (cache && !reuse) *cache = {std::move(locked), std::move(results)};
    return all;
}

/// One decimation of @a mesh (whose vertices' signed distances are @a vertexDistance) with the
/// vertices flagged in @a kept staying: one block, or blocks in two shifted passes (the first
/// pass's blocks cached in, or taken from, @a firstPass when given).
bool decimateOnce(TriangleMesh& mesh, std::vector<double> vertexDistance, std::vector<std::uint8_t> kept,
                  const FieldNode& field, const DecimationOptions& options, DecimationStats& stats,
                  const ProgressFn& progress, PassCache* firstPass)
{
    const openvdb::BBoxd box = mesh.bounds();
    const double extent = std::max({box.extents().x(), box.extents().y(), box.extents().z()});
    const double size = std::max(options.blockVoxels * options.voxel, extent / 16.0);
    BlockProgress report(progress);
    if (mesh.triangles.size() < options.blockedFrom || extent <= size) {
        // One block: the whole mesh at once, serial.
        report.total = mesh.triangles.size();
        return decimatePass(mesh, vertexDistance, kept, field, options, box.min() - Vec3d(1.0), 2.0 * extent + 4.0,
                            stats, report);
    }
    // Blocks in parallel; then blocks shifted by half their size, so the first pass's seams
    // (kept) lie inside the second pass's blocks.
    report.total = 2 * mesh.triangles.size();
    const Vec3d origin = box.min() - Vec3d(1e-3 * size);
    const bool first = decimatePass(mesh, vertexDistance, kept, field, options, origin, size, stats, report, firstPass);
    report.total = report.done + mesh.triangles.size();
    return decimatePass(mesh, vertexDistance, kept, field, options, origin - Vec3d(0.5 * size), size, stats, report) &&
           first;
}

/// Flags the vertices of @a original that lie in the bounds of a triangle of a crossing pair of
/// @a mesh grown by @a grow times its longest edge plus @a voxel: the region whose collapses
/// made the pair.
std::size_t keepAroundCrossings(const TriangleMesh& original, const TriangleMesh& mesh,
                                const std::vector<std::pair<std::uint32_t, std::uint32_t>>& pairs, double grow,
                                double voxel, std::vector<std::uint8_t>& kept)
{
    std::vector<openvdb::BBoxd> boxes;
    for (const auto& [a, b] : pairs)
        for (std::uint32_t t : {a, b}) {
            openvdb::BBoxd bounds;
            double longest = 0.0;
            for (int i = 0; i < 3; ++i) {
                const Vec3d p = toDouble(mesh.points[mesh.triangles[t][i]]);
                bounds.expand(p);
                longest = std::max(longest, (p - toDouble(mesh.points[mesh.triangles[t][(i + 1) % 3]])).length());
            }
            bounds.expand(grow * longest + voxel);
            boxes.push_back(bounds);
        }
    // The boxes binned in cells as large as the largest box (each box in at most 2 x 2 x 2), so
    // a vertex is tested against the few in its cell.
    openvdb::BBoxd all;
    double cell = 0.0;
    for (const openvdb::BBoxd& b : boxes) {
        all.expand(b);
        cell = std::max(cell, b.extents()[b.maxExtent()]);
    }
    auto cellOf = [&](const Vec3d& p) {
        std::uint64_t key = 0;
        for (int a = 0; a < 3; ++a)
            key = (key << 21) | std::uint64_t(std::clamp<std::int64_t>(
                                    std::int64_t(std::floor((p[a] - all.min()[a]) / cell)), 0, (1 << 21) - 1));
        return key;
    };
    std::unordered_map<std::uint64_t, std::vector<std::uint32_t>> bins;
    for (std::uint32_t i = 0; i < boxes.size(); ++i)
        for (int corner = 0; corner < 8; ++corner) {
            Vec3d p;
            for (int a = 0; a < 3; ++a) p[a] = (corner >> a & 1) ? boxes[i].max()[a] : boxes[i].min()[a];
            std::vector<std::uint32_t>& bin = bins[cellOf(p)];
            if (bin.empty() || bin.back() != i) bin.push_back(i);
        }
    std::atomic<std::size_t> flagged{0};
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, original.points.size()), [&](const auto& range) {
        std::size_t count = 0;
        for (std::size_t v = range.begin(); v != range.end(); ++v) {
            const Vec3d p = toDouble(original.points[v]);
            if (kept[v] || !all.isInside(p)) continue;
            const auto bin = bins.find(cellOf(p));
            if (bin == bins.end()) continue;
            for (std::uint32_t i : bin->second)
                if (boxes[i].isInside(p)) {
                    kept[v] = 1;
                    ++count;
                    break;
                }
        }
        flagged += count;
    });
    return flagged;
}

}  // namespace

double quadraticBound(const std::array<double, 3>& s, const std::array<double, 3>& m)
{
    // q's Bernstein coefficients are the corner values and 2 m - (s_i + s_j) / 2 on the edges;
    // q lies within their range (the convex hull property).
    double bound = std::max({std::abs(s[0]), std::abs(s[1]), std::abs(s[2])});
    for (int i = 0; i < 3; ++i) bound = std::max(bound, std::abs(2.0 * m[i] - 0.5 * (s[i] + s[(i + 1) % 3])));
    return bound;
}

DecimationStats decimateToTolerance(TriangleMesh& mesh, const FieldNode& field, const DecimationOptions& options,
                                    const ProgressFn& progress)
{
    DecimationStats stats;
    stats.trianglesBefore = stats.trianglesAfter = mesh.triangles.size();
    stats.verticesBefore = stats.verticesAfter = mesh.points.size();
    if (mesh.triangles.empty()) return stats;

    // Signed distances at the original vertices, which halfedge collapses never move.
    std::vector<double> vertexDistance(mesh.points.size());
    const std::size_t chunks = (mesh.points.size() + kBatchSize - 1) / kBatchSize;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks, 1), [&](const auto& range) {
        std::array<Vec3d, kBatchSize> p, g;
        std::array<double, kBatchSize> v;
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            const std::size_t begin = c * kBatchSize, count = std::min(kBatchSize, mesh.points.size() - begin);
            for (std::size_t k = 0; k < count; ++k) p[k] = toDouble(mesh.points[begin + k]);
            field.gradients(std::span<const Vec3d>(p.data(), count), std::span<double>(v.data(), count),
                            std::span<Vec3d>(g.data(), count));
            for (std::size_t k = 0; k < count; ++k)
                vertexDistance[begin + k] = signedDistance(v[k] - options.level, g[k]);
        }
    });

    // Each new triangle is checked against the field, not against the rest of the mesh: where
    // two sheets of the surface come within about twice the tolerance of each other, or along a
    // seam where each block's triangles were checked without the other block's, two may cross. The mesh is checked
    // after decimation; around each crossing pair the original vertices are kept and the whole is decimated again from
    // the original, a wider region each round.
    const TriangleMesh original = options.repairCrossings ? mesh : TriangleMesh();
    std::vector<std::uint8_t> kept(mesh.points.size(), 0);
    // The first pass's blocks away from the kept vertices come out as before: kept for the rounds.
    PassCache firstPass;
    PassCache* cache = options.repairCrossings ? &firstPass : nullptr;
    stats.decimated = decimateOnce(mesh, vertexDistance, kept, field, options, stats, progress, cache);
    if (options.repairCrossings) {
        auto pairs = selfIntersections(mesh);
        stats.crossingPairsFound = pairs.size();
        for (int round = 1; round <= options.repairRounds && !pairs.empty(); ++round) {
            stats.verticesKeptForCrossings +=
                keepAroundCrossings(original, mesh, pairs, 0.5 * round, options.voxel, kept);
            ++stats.repairRounds;
            mesh = original;
            stats.collapses = stats.refused = 0;
            stats.decimated = decimateOnce(mesh, vertexDistance, kept, field, options, stats, {}, cache);
            pairs = selfIntersections(mesh);
        }
        stats.crossingPairs = pairs.size();
    }
    stats.trianglesAfter = mesh.triangles.size();
    stats.verticesAfter = mesh.points.size();
    if (progress) progress(1.0);
    return stats;
}

MeshDeviation measureDeviation(const TriangleMesh& mesh, const FieldNode& field, double level, double spacing,
                               const ProgressFn& progress)
{
    struct Partial {
        double max = 0.0, sum = 0.0, weight = 0.0;
        std::size_t samples = 0;
    };
    constexpr std::size_t kBlock = 4096;
    const std::size_t blocks = (mesh.triangles.size() + kBlock - 1) / kBlock;
    std::vector<Partial> partial(blocks);
    ExtractProgress done(progress, blocks);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 1), [&](const auto& range) {
        std::vector<Vec3d> points, gradients;
        std::vector<double> values, weights;
        for (std::size_t b = range.begin(); b != range.end(); ++b, done.advance()) {
            points.clear();
            weights.clear();
            const std::size_t end = std::min(mesh.triangles.size(), (b + 1) * kBlock);
            for (std::size_t n = b * kBlock; n < end; ++n) {
                // Rows parallel to the longest edge, at most spacing apart, each sampled at most
                // spacing apart: a long sliver (a cap where a box cut the mesh) takes samples in
                // proportion to its length, not to its length squared.
                const openvdb::Vec3I& t = mesh.triangles[n];
                std::array<Vec3d, 3> c = {toDouble(mesh.points[t[0]]), toDouble(mesh.points[t[1]]),
                                          toDouble(mesh.points[t[2]])};
                int far = 0;  // the corner opposite the longest edge
                double longest = -1.0;
                for (int k = 0; k < 3; ++k) {
                    const double length = (c[(k + 2) % 3] - c[(k + 1) % 3]).length();
                    if (length > longest) {
                        longest = length;
                        far = k;
                    }
                }
                const Vec3d apex = c[far], p0 = c[(far + 1) % 3], p1 = c[(far + 2) % 3];
                const double area = 0.5 * (p0 - apex).cross(p1 - apex).length();
                const double height = longest > 0.0 ? 2.0 * area / longest : 0.0;
                const int rows = std::max(1, int(std::ceil(height / spacing)));
                const std::size_t before = points.size();
                for (int r = 0; r <= rows; ++r) {
                    const double f = double(r) / rows;  // 0 on the longest edge, 1 at the apex
                    const Vec3d q0 = p0 + f * (apex - p0), q1 = p1 + f * (apex - p1);
                    const int steps = r == rows ? 0 : std::max(1, int(std::ceil((q1 - q0).length() / spacing)));
                    for (int i = 0; i <= steps; ++i)
                        points.push_back(steps ? q0 + (double(i) / steps) * (q1 - q0) : q0);
                }
                weights.resize(points.size(), area / double(points.size() - before));
            }
            values.resize(points.size());
            gradients.resize(points.size());
            forEachChunk(points.size(), [&](std::size_t begin, std::size_t count) {
                field.gradients(std::span<const Vec3d>(points.data() + begin, count),
                                std::span<double>(values.data() + begin, count),
                                std::span<Vec3d>(gradients.data() + begin, count));
            });
            Partial& p = partial[b];
            for (std::size_t k = 0; k < points.size(); ++k) {
                const double d = std::abs(signedDistance(values[k] - level, gradients[k]));
                p.max = std::max(p.max, d);
                p.sum += weights[k] * d * d;
                p.weight += weights[k];
            }
            p.samples = points.size();
        }
    });
    done.finish();
    MeshDeviation result;
    double sum = 0.0, weight = 0.0;
    for (const Partial& p : partial) {
        result.max = std::max(result.max, p.max);
        sum += p.sum;
        weight += p.weight;
        result.samples += p.samples;
    }
    result.rms = weight > 0.0 ? std::sqrt(sum / weight) : 0.0;
    return result;
}

}  // namespace voxlat
