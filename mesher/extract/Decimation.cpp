#include "mesher/extract/Decimation.h"

#include "fields/BoxField.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <OpenMesh/Tools/Decimater/CollapseInfoT.hh>
// QuadricT.hh needs the vector traits the mesh headers bring.
#include <OpenMesh/Core/Geometry/QuadricT.hh>

#include <algorithm>
#include <array>
#include <cfloat>
#include <cmath>
#include <cstdint>
#include <limits>
#include <mutex>
#include <numeric>
#include <queue>
#include <tuple>
#include <vector>

namespace voxlat {

namespace {

/// No collapse makes an edge longer than this many voxels (see FieldDecimater::fieldAllows).
constexpr double kMaxEdgeVoxels = 6.0;

struct Traits : OpenMesh::DefaultTraits {
    VertexAttributes(OpenMesh::Attributes::Status);
    EdgeAttributes(OpenMesh::Attributes::Status);
    FaceAttributes(OpenMesh::Attributes::Status);
    HalfedgeAttributes(OpenMesh::Attributes::PrevHalfedge);
};
using Mesh = OpenMesh::TriMesh_ArrayKernelT<Traits>;

Vec3d toDouble(const Mesh::Point& p)
{
    return {p[0], p[1], p[2]};
}
using voxlat::toDouble;  // the mesh-point overload (TriangleMesh.h) next to OpenMesh's

/// Signed first-order distance (f - level) / |grad f|; a flat spot away from the level is far.
double signedDistance(double r, const Vec3d& g)
{
    const double length = g.length();
    if (length > 0.0) return r / length;
    return r == 0.0 ? 0.0 : std::copysign(1e30, r);
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

/// Halfedge collapses on an OpenMesh mesh in the order of the quadric error metric (Garland and
/// Heckbert's area-weighted plane quadrics, as OpenMesh's ModQuadricT), with OpenMesh's topology
/// test (as its BaseDecimaterT::is_collapse_legal). The field check, which costs field
/// evaluations, runs only on the collapse about to be made; candidates that cannot pass for
/// reasons known without the field (quadric error, edge length, seams) are never queued.
class FieldDecimater {
public:
    using CollapseInfo = OpenMesh::Decimater::CollapseInfoT<Mesh>;
    using Quadric = OpenMesh::Geometry::Quadricd;

    FieldDecimater(Mesh& mesh, const FieldNode& field, const DecimationOptions& options,
                   std::vector<double> vertexDistance)
        : mMesh(mesh), mField(field), mOptions(options), mVertexDistance(std::move(vertexDistance))
    {
        if (options.box) mBox.emplace(*options.box);
        // A collapse whose quadric error (the area-weighted sum of squared distances to the planes
        // of the triangles merged into it) exceeds the squared tolerance puts the point far off
        // one of them: such candidates are mostly refused by the field check anyway, so they are
        // not tried (the field check still decides the rest).
        mMaxError = options.quadricShare * options.tolerance * options.tolerance;
        mQuadrics.assign(mesh.n_vertices(), Quadric());
        for (Mesh::FaceHandle f : mesh.faces()) {
            std::array<Mesh::VertexHandle, 3> v;
            int i = 0;
            for (Mesh::VertexHandle w : mesh.fv_range(f)) v[i++] = w;
            const OpenMesh::Vec3d p0 = OpenMesh::vector_cast<OpenMesh::Vec3d>(mesh.point(v[0]));
            const OpenMesh::Vec3d p1 = OpenMesh::vector_cast<OpenMesh::Vec3d>(mesh.point(v[1]));
            const OpenMesh::Vec3d p2 = OpenMesh::vector_cast<OpenMesh::Vec3d>(mesh.point(v[2]));
            OpenMesh::Vec3d n = (p1 - p0) % (p2 - p0);
            double area = n.norm();
            if (area > FLT_MIN) {
                n /= area;
                area *= 0.5;
            }
            Quadric q(n[0], n[1], n[2], -(p0 | n));
            q *= area;
            for (Mesh::VertexHandle w : v) mQuadrics[w.idx()] += q;
        }
        mRefused.assign(mesh.n_halfedges(), 0);
        mStamp.assign(mesh.n_vertices(), 0);
        mDirty.assign(mesh.n_vertices(), 0);
        mEdgeMid.assign(mesh.n_edges(), kUnknown);
        mQueued.assign(mesh.n_vertices(), 0);
        mMaxEdgeSqr = (kMaxEdgeVoxels * options.voxel) * (kMaxEdgeVoxels * options.voxel);
    }

    void run(DecimationStats& stats, const ProgressFn& progress)
    {
        for (Mesh::VertexHandle v : mMesh.vertices()) queueVertex(v);
        const std::size_t expected = std::max<std::size_t>(1, mMesh.n_vertices());
        int percent = -1;
        while (!mHeap.empty()) {
            const Entry top = mHeap.top();
            mHeap.pop();
            const Mesh::VertexHandle v(int(std::get<1>(top)));
            if (std::get<2>(top) != mStamp[v.idx()] || mMesh.status(v).deleted()) continue;
            if (mDirty[v.idx()]) {
                // Its one-ring changed since it was queued: its candidate is chosen again now,
                // once, rather than after every collapse next to it.
                queueVertex(v);
                continue;
            }
            const Mesh::HalfedgeHandle h(int(std::get<3>(top)));
            CollapseInfo ci(mMesh, h);
            // OpenMesh's topology test is the costly part of a candidate (it tags the one-rings),
            // so it too runs only on the collapse about to be made.
            if (!collapseLegal(ci)) {
                mRefused[h.idx()] = 1;
                queueVertex(v);
                continue;
            }
            if (!fieldAllows(ci)) {
                ++stats.refused;
                mRefused[h.idx()] = 1;
                queueVertex(v);
                continue;
            }
            mSupport.clear();
            for (Mesh::VertexHandle w : mMesh.vv_range(ci.v0)) mSupport.push_back(w);
            mMesh.collapse(h);
            ++stats.collapses;
            mQuadrics[ci.v1.idx()] += mQuadrics[ci.v0.idx()];
            keepSpokes(ci.v1);
            for (Mesh::VertexHandle w : mSupport) {
                // Their neighbourhoods changed: collapses refused before may pass now.
                for (Mesh::HalfedgeHandle out : mMesh.voh_range(w)) mRefused[out.idx()] = 0;
                if (mQueued[w.idx()])
                    mDirty[w.idx()] = 1;
                else
                    queueVertex(w);
            }
            if (progress) {
                const int now = int(std::min<std::size_t>(99, 100 * stats.collapses / expected));
                if (now > percent) {
                    percent = now;
                    progress(0.01 * now);
                }
            }
        }
    }

private:
    /// (priority, vertex, stamp, halfedge); the smallest priority first, ties by vertex index.
    using Entry = std::tuple<float, unsigned, unsigned, unsigned>;

    /// Queues @a v with its cheapest outgoing collapse not yet refused whose quadric error is
    /// below the bound, that makes no edge longer than the limit and that a seam allows
    /// (topology and the field are checked when it comes up).
    void queueVertex(Mesh::VertexHandle v)
    {
        ++mStamp[v.idx()];
        mDirty[v.idx()] = 0;
        mQueued[v.idx()] = 0;
        // A locked vertex stays.
        if (mMesh.status(v).locked()) return;
        mRing.clear();
        for (Mesh::VertexHandle w : mMesh.vv_range(v)) mRing.push_back(w);
        double best = mMaxError;
        Mesh::HalfedgeHandle bestHalfedge;
        for (Mesh::HalfedgeHandle h : mMesh.voh_range(v)) {
            if (mRefused[h.idx()]) continue;
            const Mesh::VertexHandle v1 = mMesh.to_vertex_handle(h);
            const Mesh::Point& p1 = mMesh.point(v1);
            Quadric q = mQuadrics[v.idx()];
            q += mQuadrics[v1.idx()];
            const double error = q(OpenMesh::vector_cast<OpenMesh::Vec3d>(p1));
            // Ties go to the first halfedge around v, as OpenMesh's decimater did.
            if (!(error < best)) continue;
            if (!shortEnough(v1) || !seamAllows(v, v1)) continue;
            best = error;
            bestHalfedge = h;
        }
        if (bestHalfedge.is_valid()) {
            mHeap.emplace(float(best), unsigned(v.idx()), mStamp[v.idx()], unsigned(bestHalfedge.idx()));
            mQueued[v.idx()] = 1;
        }
    }

    /// Whether moving the vertex whose one-ring is mRing onto @a v1 keeps every edge within the
    /// length limit (see fieldAllows).
    bool shortEnough(Mesh::VertexHandle v1) const
    {
        const Mesh::Point& p1 = mMesh.point(v1);
        for (Mesh::VertexHandle w : mRing)
            if ((mMesh.point(w) - p1).sqrnorm() > mMaxEdgeSqr) return false;
        return true;
    }

    /// OpenMesh's BaseDecimaterT::is_collapse_legal without the feature test (no features here).
    bool collapseLegal(const CollapseInfo& ci)
    {
        if (mMesh.status(ci.v0).locked() || !mMesh.is_collapse_ok(ci.v0v1)) return false;
        if (ci.vl.is_valid() && ci.vr.is_valid() && mMesh.find_halfedge(ci.vl, ci.vr).is_valid() &&
            mMesh.valence(ci.vl) == 3 && mMesh.valence(ci.vr) == 3)
            return false;
        if (mMesh.is_boundary(ci.v0)) {
            if (!mMesh.is_boundary(ci.v1)) return false;
            if (ci.vl.is_valid() && ci.vr.is_valid()) return false;
        }
        // At least two faces at v0.
        return mMesh.cw_rotated_halfedge_handle(mMesh.cw_rotated_halfedge_handle(ci.v0v1)) != ci.v0v1;
    }

    /// In a block of a larger mesh, locked vertices are shared with other blocks, which may hold
    /// an edge between two of them or make one at the same time: a collapse onto a locked vertex
    /// may not join it to another locked vertex it is not joined to here already.
    bool seamAllows(Mesh::VertexHandle v0, Mesh::VertexHandle v1)
    {
        if (!mMesh.status(v1).locked()) return true;
        for (Mesh::VertexHandle w : mMesh.vv_range(v0))
            if (w != v1 && mMesh.status(w).locked() && !mMesh.find_halfedge(v1, w).is_valid()) return false;
        return true;
    }

    /// The triangles around ci.v0 that survive the collapse, with v0 moved onto v1: none may turn
    /// over or vanish, and each must stay within the tolerance.
    bool fieldAllows(const CollapseInfo& ci)
    {
        mTriangles.clear();
        mMid.clear();
        mSpokes.clear();
        mMidEdge.clear();
        const Vec3d p1 = toDouble(ci.p1);
        // The midpoint of the new edge from v1 to @a w (shared by the two triangles beside it).
        auto spoke = [&](Mesh::VertexHandle w) {
            for (const auto& [vertex, index] : mSpokes)
                if (vertex == w) return index;
            const int index = int(mMid.size());
            mMid.push_back({0.5 * (p1 + toDouble(mMesh.point(w))), kUnknown});
            mSpokes.emplace_back(w, index);
            return index;
        };
        for (Mesh::FaceHandle f : mMesh.vf_range(ci.v0)) {
            if (f == ci.fl || f == ci.fr) continue;
            CheckTriangle t;
            std::array<Vec3d, 3> before;
            int i = 0;
            for (Mesh::HalfedgeHandle h : mMesh.fh_range(f)) {
                const Mesh::VertexHandle a = mMesh.from_vertex_handle(h), b = mMesh.to_vertex_handle(h);
                before[i] = toDouble(mMesh.point(a));
                t.p[i] = a == ci.v0 ? p1 : before[i];
                t.s[i] = mVertexDistance[(a == ci.v0 ? ci.v1 : a).idx()];
                if (a == ci.v0 || b == ci.v0) {
                    t.mid[i] = spoke(a == ci.v0 ? b : a);
                } else {
                    // An edge of the one-ring, which the collapse keeps as it is: its midpoint's
                    // distance is kept from one check to the next.
                    const int e = mMesh.edge_handle(h).idx();
                    t.mid[i] = int(mMid.size());
                    mMid.push_back({0.5 * (before[i] + toDouble(mMesh.point(b))), mEdgeMid[e]});
                    if (mEdgeMid[e] == kUnknown) mMidEdge.emplace_back(t.mid[i], e);
                }
                ++i;
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
            mTriangles.push_back(t);
        }
        return withinTolerance();
    }

    /// After the collapse of v0 onto @a v1 the spokes checked are @a v1's edges: their midpoints'
    /// distances are kept; an edge that was v0's now runs from v1, so none of v1's may keep an old
    /// value.
    void keepSpokes(Mesh::VertexHandle v1)
    {
        for (Mesh::HalfedgeHandle h : mMesh.voh_range(v1)) {
            double value = kUnknown;
            const Mesh::VertexHandle w = mMesh.to_vertex_handle(h);
            for (const auto& [vertex, index] : mSpokes)
                if (vertex == w) value = mMid[index].distance;
            mEdgeMid[mMesh.edge_handle(h).idx()] = value;
        }
    }

    /// Evaluates every triangle's centre and the unknown edge midpoints in a batch and bounds
    /// |distance| over each triangle by its quadratic interpolant plus the centre's miss.
    bool withinTolerance()
    {
        // A tenth of the tolerance is kept back for what the quadratic misses.
        const double tolerance = 0.9 * mOptions.tolerance;
        // The centres first: most refused collapses fail there.
        mPoints.clear();
        for (const CheckTriangle& t : mTriangles) mPoints.push_back((t.p[0] + t.p[1] + t.p[2]) / 3.0);
        evaluate();
        mCentres.resize(mTriangles.size());
        for (std::size_t k = 0; k < mTriangles.size(); ++k) {
            mCentres[k] = signedDistance(mValues[k] - mOptions.level, mGradients[k]);
            const double centre = mBox ? std::max(mCentres[k], boxDistance(mPoints[k])) : mCentres[k];
            if (std::abs(centre) > tolerance) return false;
        }
        mPoints.clear();
        for (const Midpoint& m : mMid)
            if (m.distance == kUnknown) mPoints.push_back(m.p);
        evaluate();
        std::size_t next = 0;
        for (Midpoint& m : mMid)
            if (m.distance == kUnknown) {
                m.distance = signedDistance(mValues[next] - mOptions.level, mGradients[next]);
                ++next;
            }
        for (const auto& [index, e] : mMidEdge) mEdgeMid[e] = mMid[index].distance;
        for (std::size_t k = 0; k < mTriangles.size(); ++k) {
            const CheckTriangle& t = mTriangles[k];
            const std::array<double, 3>& s = t.s;
            const std::array<double, 3> m = {mMid[t.mid[0]].distance, mMid[t.mid[1]].distance, mMid[t.mid[2]].distance};
            const double centre = mCentres[k];
            // Quadratic through corners s_i and midpoints m_i (m_0 between corners 0 and 1).
            auto quadratic = [&](double l0, double l1, double l2) {
                return s[0] * l0 * (2 * l0 - 1) + s[1] * l1 * (2 * l1 - 1) + s[2] * l2 * (2 * l2 - 1) +
                       4 * (m[0] * l0 * l1 + m[1] * l1 * l2 + m[2] * l2 * l0);
            };
            const double margin = std::abs(centre - quadratic(1.0 / 3, 1.0 / 3, 1.0 / 3));
            if (margin > tolerance) return false;
            constexpr int kSteps = 6;
            double largest = 0.0;
            // The box's distance is convex: over the triangle it is largest at a corner. Where
            // that is below -tolerance, max(quadratic, box) passes or fails as the quadratic does.
            bool nearBox = false;
            if (mBox)
                for (int c = 0; c < 3 && !nearBox; ++c) nearBox = boxDistance(t.p[c]) > -tolerance;
            for (int i = 0; i <= kSteps; ++i)
                for (int j = 0; i + j <= kSteps; ++j) {
                    const double l0 = double(i) / kSteps, l1 = double(j) / kSteps, l2 = 1.0 - l0 - l1;
                    double d = quadratic(l0, l1, l2);
                    // The box's side of a crease exactly: the larger of the two is the solid's.
                    if (nearBox) d = std::max(d, boxDistance(l0 * t.p[0] + l1 * t.p[1] + l2 * t.p[2]));
                    largest = std::max(largest, std::abs(d));
                }
            if (largest + margin > tolerance) return false;
        }
        return true;
    }

    /// Values and gradients of the field at mPoints.
    void evaluate()
    {
        mValues.resize(mPoints.size());
        mGradients.resize(mPoints.size());
        forEachChunk(mPoints.size(), [&](std::size_t begin, std::size_t count) {
            mField.gradients(std::span<const Vec3d>(mPoints.data() + begin, count),
                             std::span<double>(mValues.data() + begin, count),
                             std::span<Vec3d>(mGradients.data() + begin, count));
        });
    }

    Mesh& mMesh;
    /// The box's exact signed distance (options.box).
    double boxDistance(const Vec3d& p) const { return mBox->eval(p.x(), p.y(), p.z()); }

    const FieldNode& mField;
    std::optional<BoxField> mBox;
    std::vector<double> mCentres;
    DecimationOptions mOptions;
    std::vector<double> mVertexDistance;
    double mMaxEdgeSqr = 0.36;
    double mMaxError = 0.0;
    std::vector<Quadric> mQuadrics;
    std::vector<Mesh::VertexHandle> mRing;
    std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> mHeap;
    std::vector<std::uint8_t> mRefused;
    std::vector<unsigned> mStamp;
    /// Whether a vertex has an entry in the heap, and whether its one-ring changed since.
    std::vector<std::uint8_t> mQueued, mDirty;
    std::vector<Mesh::VertexHandle> mSupport;
    std::vector<CheckTriangle> mTriangles;
    std::vector<Midpoint> mMid;
    /// The check's new edges from v1 (by the vertex at their other end) and one-ring edges whose
    /// midpoint it evaluates (index into mMid, edge), and every edge's midpoint distance if known.
    std::vector<std::pair<Mesh::VertexHandle, int>> mSpokes;
    std::vector<std::pair<int, int>> mMidEdge;
    std::vector<double> mEdgeMid;
    std::vector<Vec3d> mPoints, mGradients;
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
                          const FieldNode& field, const DecimationOptions& options, const ProgressFn& progress)
{
    BlockResult result;
    std::vector<std::uint32_t> vertices;
    vertices.reserve(3 * ids.size());
    for (std::uint32_t t : ids)
        for (int k = 0; k < 3; ++k) vertices.push_back(mesh.triangles[t][k]);
    std::sort(vertices.begin(), vertices.end());
    vertices.erase(std::unique(vertices.begin(), vertices.end()), vertices.end());
    auto local = [&](std::uint32_t v) {
        return int(std::lower_bound(vertices.begin(), vertices.end(), v) - vertices.begin());
    };
    Mesh om;
    om.reserve(vertices.size(), 3 * ids.size() / 2 + 3, ids.size());
    std::vector<double> distance(vertices.size());
    for (std::size_t i = 0; i < vertices.size(); ++i) {
        const openvdb::Vec3f& p = mesh.points[vertices[i]];
        om.add_vertex(Mesh::Point(p.x(), p.y(), p.z()));
        distance[i] = vertexDistance[vertices[i]];
    }
    for (std::uint32_t t : ids) {
        const openvdb::Vec3I& tri = mesh.triangles[t];
        const Mesh::FaceHandle f = om.add_face(Mesh::VertexHandle(local(tri[0])), Mesh::VertexHandle(local(tri[1])),
                                               Mesh::VertexHandle(local(tri[2])));
        if (!f.is_valid()) {
            // Not a manifold piece OpenMesh can hold: left as it is.
            result.decimated = false;
            for (std::uint32_t u : ids) result.triangles.push_back(mesh.triangles[u]);
            return result;
        }
    }
    for (Mesh::VertexHandle v : om.vertices())
        if (locked[vertices[v.idx()]] || om.is_isolated(v)) om.status(v).set_locked(true);
    DecimationStats stats;
    FieldDecimater decimater(om, field, options, std::move(distance));
    decimater.run(stats, progress);
    result.collapses = stats.collapses;
    result.refused = stats.refused;
    for (Mesh::FaceHandle f : om.all_faces()) {
        if (om.status(f).deleted()) continue;
        openvdb::Vec3I t;
        int i = 0;
        for (Mesh::VertexHandle v : om.fv_range(f)) t[i++] = vertices[v.idx()];
        result.triangles.push_back(t);
    }
    return result;
}

/// One pass over blocks of edge @a size whose corners sit at @a origin + k size: each triangle
/// goes to the block of its centroid, vertices used by triangles of two blocks are kept, the
/// blocks are decimated in parallel and put together in block order (vertices renumbered in
/// their old order), so the result does not depend on the thread count.
bool decimatePass(TriangleMesh& mesh, std::vector<double>& vertexDistance, const FieldNode& field,
                  const DecimationOptions& options, const Vec3d& origin, double size, DecimationStats& stats,
                  BlockProgress& progress)
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
    std::vector<std::uint8_t> locked(mesh.points.size(), 0);
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
    const ProgressFn perBlock = {};
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks.size(), 1), [&](const auto& range) {
        for (std::size_t b = range.begin(); b != range.end(); ++b) {
            results[b] = decimateBlock(mesh, blocks[b], locked, vertexDistance, field, options, perBlock);
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
    for (std::size_t v = 0; v < mesh.points.size(); ++v) {
        if (newIndex[v] != 0) continue;
        newIndex[v] = std::uint32_t(out.points.size());
        out.points.push_back(mesh.points[v]);
        distance.push_back(vertexDistance[v]);
    }
    for (const BlockResult& r : results)
        for (const openvdb::Vec3I& t : r.triangles)
            out.triangles.emplace_back(newIndex[t[0]], newIndex[t[1]], newIndex[t[2]]);
    mesh = std::move(out);
    vertexDistance = std::move(distance);
    return all;
}

}  // namespace

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

    const openvdb::BBoxd box = mesh.bounds();
    const double extent = std::max({box.extents().x(), box.extents().y(), box.extents().z()});
    const double size = std::max(options.blockVoxels * options.voxel, extent / 16.0);
    BlockProgress report(progress);
    if (mesh.triangles.size() < options.blockedFrom || extent <= size) {
        // One block: the whole mesh at once, serial.
        report.total = mesh.triangles.size();
        stats.decimated = decimatePass(mesh, vertexDistance, field, options, box.min() - Vec3d(1.0), 2.0 * extent + 4.0,
                                       stats, report);
    } else {
        // Blocks in parallel; then blocks shifted by half their size, so the first pass's seams
        // (kept) lie inside the second pass's blocks.
        report.total = 2 * mesh.triangles.size();
        const Vec3d origin = box.min() - Vec3d(1e-3 * size);
        stats.decimated = decimatePass(mesh, vertexDistance, field, options, origin, size, stats, report);
        report.total = report.done + mesh.triangles.size();
        stats.decimated =
            decimatePass(mesh, vertexDistance, field, options, origin - Vec3d(0.5 * size), size, stats, report) &&
            stats.decimated;
    }
    stats.trianglesAfter = mesh.triangles.size();
    stats.verticesAfter = mesh.points.size();
    if (progress) progress(1.0);
    return stats;
}

MeshDeviation measureDeviation(const TriangleMesh& mesh, const FieldNode& field, double level, double spacing)
{
    struct Partial {
        double max = 0.0, sum = 0.0, weight = 0.0;
        std::size_t samples = 0;
    };
    constexpr std::size_t kBlock = 4096;
    const std::size_t blocks = (mesh.triangles.size() + kBlock - 1) / kBlock;
    std::vector<Partial> partial(blocks);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 1), [&](const auto& range) {
        std::vector<Vec3d> points, gradients;
        std::vector<double> values, weights;
        for (std::size_t b = range.begin(); b != range.end(); ++b) {
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
