#include "engine/parts/MeshSdf.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <utility>
#include <vector>

namespace voxlat {

namespace {

using Leaf = openvdb::FloatTree::LeafNodeType;

/// A triangle as corner a and edges ab, ac (double, world units), with its plane and the planes
/// through its edges perpendicular to it, for the common case of a point over the face.
struct Triangle {
    openvdb::Vec3d a, ab, ac;
    openvdb::Vec3d normal;     ///< unit normal (zero for a triangle without area)
    double offset;             ///< normal . a
    openvdb::Vec3d inward[3];  ///< per edge, in the plane and pointing into the triangle
    double inwardOffset[3];    ///< inward[e] . (the edge's first corner)

    Triangle(const openvdb::Vec3d& pa, const openvdb::Vec3d& pb, const openvdb::Vec3d& pc)
        : a(pa), ab(pb - pa), ac(pc - pa)
    {
        const openvdb::Vec3d n = ab.cross(ac);
        const double length = n.length();
        normal = length > 0.0 ? n / length : openvdb::Vec3d(0.0);
        offset = normal.dot(a);
        const openvdb::Vec3d corner[3] = {pa, pb, pc};
        for (int e = 0; e < 3; ++e) {
            inward[e] = normal.cross(corner[(e + 1) % 3] - corner[e]);
            // Without area no point is over the face: an offset no zero vector reaches.
            inwardOffset[e] = length > 0.0 ? inward[e].dot(corner[e]) : 1.0;
        }
    }
};

/// Distance from @a p to the triangle's plane: a lower bound of the distance to the triangle.
double planeDistance(const Triangle& t, const openvdb::Vec3d& p)
{
    return std::abs(t.normal.dot(p) - t.offset);
}

/// Squared distance from @a p to the triangle (Ericson, Real-Time Collision Detection, 5.1.5),
/// short cut where @a p lies over the face: the distance to the plane (@a h), squared.
double distanceSq(const Triangle& t, const openvdb::Vec3d& p, double h)
{
    if (t.inward[0].dot(p) >= t.inwardOffset[0] && t.inward[1].dot(p) >= t.inwardOffset[1] &&
        t.inward[2].dot(p) >= t.inwardOffset[2])
        return h * h;
    const openvdb::Vec3d ap = p - t.a;
    const double d1 = t.ab.dot(ap), d2 = t.ac.dot(ap);
    if (d1 <= 0.0 && d2 <= 0.0) return ap.lengthSqr();  // corner a
    const openvdb::Vec3d bp = ap - t.ab;
    const double d3 = t.ab.dot(bp), d4 = t.ac.dot(bp);
    if (d3 >= 0.0 && d4 <= d3) return bp.lengthSqr();  // corner b
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return (ap - t.ab * (d1 / (d1 - d3))).lengthSqr();  // edge ab
    const openvdb::Vec3d cp = ap - t.ac;
    const double d5 = t.ab.dot(cp), d6 = t.ac.dot(cp);
    if (d6 >= 0.0 && d5 <= d6) return cp.lengthSqr();  // corner c
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return (ap - t.ac * (d2 / (d2 - d6))).lengthSqr();  // edge ac
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {  // edge bc
        const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (bp - (t.ac - t.ab) * w).lengthSqr();
    }
    const double denom = 1.0 / (va + vb + vc);  // the face
    return (ap - t.ab * (vb * denom) - t.ac * (vc * denom)).lengthSqr();
}

/// Inside/outside of every sample by the parity of the mesh's crossings along vertical rays,
/// one ray per column (i, j) of samples.
class ColumnParity {
public:
    ColumnParity(const TriangleMesh& mesh, const openvdb::Vec3d& origin, double voxel) : mOrigin(origin), mVoxel(voxel)
    {
        const openvdb::BBoxd b = mesh.bounds();
        mI0 = int(std::floor((b.min()[0] - origin[0]) / voxel)) - 1;
        mJ0 = int(std::floor((b.min()[1] - origin[1]) / voxel)) - 1;
        mNi = int(std::ceil((b.max()[0] - origin[0]) / voxel)) + 2 - mI0;
        mNj = int(std::ceil((b.max()[1] - origin[1]) / voxel)) + 2 - mJ0;
        // Rays a tiny, odd distance off the sample lattice, so that none runs exactly along an
        // edge or through a vertex of a mesh drawn on round numbers.
        mNudge = openvdb::Vec3d(0.7071e-6, 0.5773e-6, 0.0) * voxel;
        std::vector<std::pair<std::uint32_t, double>> hits;
        for (const auto& tri : mesh.triangles) {
            openvdb::Vec2d q[3];
            for (int c = 0; c < 3; ++c) {
                const openvdb::Vec3d p = mesh.points[tri[c]];
                q[c] = openvdb::Vec2d(p[0], p[1]);
            }
            const double area = orient(q[0], q[1], q[2]);
            if (area == 0.0) continue;  // seen edge-on from above: no ray crosses it
            const openvdb::Vec3d a = mesh.points[tri[0]], b = mesh.points[tri[1]], c = mesh.points[tri[2]];
            const openvdb::Vec3d n = (b - a).cross(c - a);
            const double lox = std::min({q[0][0], q[1][0], q[2][0]}), hix = std::max({q[0][0], q[1][0], q[2][0]});
            const double loy = std::min({q[0][1], q[1][1], q[2][1]}), hiy = std::max({q[0][1], q[1][1], q[2][1]});
            const int i0 = int(std::ceil((lox - origin[0] - mNudge[0]) / voxel)),
                      i1 = int(std::floor((hix - origin[0] - mNudge[0]) / voxel));
            const int j0 = int(std::ceil((loy - origin[1] - mNudge[1]) / voxel)),
                      j1 = int(std::floor((hiy - origin[1] - mNudge[1]) / voxel));
            for (int i = i0; i <= i1; ++i)
                for (int j = j0; j <= j1; ++j) {
                    const openvdb::Vec2d p = ray(i, j);
                    bool inside = true;
                    for (int e = 0; e < 3 && inside; ++e) {
                        // The edge's side of p computed from its lower-numbered end, so both
                        // triangles of an edge agree exactly (ties go to one side).
                        const std::uint32_t u = tri[e], v = tri[(e + 1) % 3];
                        const int ku = u < v ? e : (e + 1) % 3, kv = u < v ? (e + 1) % 3 : e;
                        const bool positive = orient(q[ku], q[kv], p) >= 0.0;
                        inside = (positive == (u < v)) == (area > 0.0);
                    }
                    if (!inside) continue;
                    const double z = a[2] - (n[0] * (p[0] - a[0]) + n[1] * (p[1] - a[1])) / n[2];
                    hits.emplace_back(column(i, j), z);
                }
        }
        std::sort(hits.begin(), hits.end());
        mStart.assign(std::size_t(mNi) * mNj + 1, 0);
        for (const auto& h : hits) ++mStart[h.first + 1];
        for (std::size_t c = 1; c < mStart.size(); ++c) mStart[c] += mStart[c - 1];
        mZ.resize(hits.size());
        for (std::size_t n = 0; n < hits.size(); ++n) mZ[n] = hits[n].second;
    }

    /// Whether sample (i, j, k) is inside (an odd number of crossings below it).
    bool inside(const openvdb::Coord& c) const
    {
        const int i = c.x() - mI0, j = c.y() - mJ0;
        if (i < 0 || j < 0 || i >= mNi || j >= mNj) return false;
        const std::uint32_t col = std::uint32_t(i) * mNj + j;
        const double z = mOrigin[2] + c.z() * mVoxel;
        const auto first = mZ.begin() + mStart[col], last = mZ.begin() + mStart[col + 1];
        return (std::lower_bound(first, last, z) - first) % 2 == 1;
    }

    /// inside() of the @a n samples from @a c up the column, into @a out: one search, then a walk.
    void insideRun(const openvdb::Coord& c, int n, bool* out) const
    {
        const int i = c.x() - mI0, j = c.y() - mJ0;
        if (i < 0 || j < 0 || i >= mNi || j >= mNj) {
            std::fill(out, out + n, false);
            return;
        }
        const std::uint32_t col = std::uint32_t(i) * mNj + j;
        const auto first = mZ.begin() + mStart[col], last = mZ.begin() + mStart[col + 1];
        auto it = std::lower_bound(first, last, mOrigin[2] + c.z() * mVoxel);
        for (int k = 0; k < n; ++k) {
            const double z = mOrigin[2] + (c.z() + k) * mVoxel;
            while (it != last && *it < z) ++it;
            out[k] = (it - first) % 2 == 1;
        }
    }

private:
    static double orient(const openvdb::Vec2d& a, const openvdb::Vec2d& b, const openvdb::Vec2d& p)
    {
        return (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
    }
    openvdb::Vec2d ray(int i, int j) const
    {
        return openvdb::Vec2d(mOrigin[0] + i * mVoxel + mNudge[0], mOrigin[1] + j * mVoxel + mNudge[1]);
    }
    std::uint32_t column(int i, int j) const { return std::uint32_t(i - mI0) * mNj + std::uint32_t(j - mJ0); }

    openvdb::Vec3d mOrigin, mNudge;
    double mVoxel;
    int mI0 = 0, mJ0 = 0, mNi = 0, mNj = 0;
    std::vector<std::uint32_t> mStart;
    std::vector<double> mZ;
};

class Converter {
public:
    Converter(const TriangleMesh& mesh, const openvdb::math::Transform& xform, float exterior, float interior)
        : mVoxel(xform.voxelSize()[0]),
          mOrigin(xform.indexToWorld(openvdb::Vec3d(0.0))),
          mExterior(double(exterior) * mVoxel),
          mInterior(double(interior) * mVoxel),
          mParity(mesh, mOrigin, mVoxel)
    {
        mTriangles.reserve(mesh.triangles.size());
        for (const auto& t : mesh.triangles) {
            const openvdb::Vec3d a = mesh.points[t[0]], b = mesh.points[t[1]], c = mesh.points[t[2]];
            mTriangles.emplace_back(a, b, c);
        }
        mGrid = openvdb::FloatGrid::create(float(mExterior));
        mGrid->setTransform(xform.copy());
        mGrid->setGridClass(openvdb::GRID_LEVEL_SET);
    }

    openvdb::FloatGrid::Ptr run(const openvdb::BBoxd& meshBounds)
    {
        // Cubes of 32^3 samples over the mesh's box and the outside band.
        constexpr int kTop = 32;
        const double margin = mExterior + mVoxel;
        openvdb::Coord lo, hi;
        for (int a = 0; a < 3; ++a) {
            lo[a] = blockFloor(int(std::floor((meshBounds.min()[a] - margin - mOrigin[a]) / mVoxel)), kTop);
            hi[a] = blockFloor(int(std::ceil((meshBounds.max()[a] + margin - mOrigin[a]) / mVoxel)), kTop);
        }
        std::vector<openvdb::Coord> tops;
        for (int x = lo.x(); x <= hi.x(); x += kTop)
            for (int y = lo.y(); y <= hi.y(); y += kTop)
                for (int z = lo.z(); z <= hi.z(); z += kTop) tops.emplace_back(x, y, z);
        // Every triangle, at distance 0 from a point infinitely far: none is skipped at the top.
        std::vector<Candidate> all(mTriangles.size());
        for (std::uint32_t i = 0; i < all.size(); ++i) all[i] = {i, 0.0};

        // Leaves and inside tiles per top cube, put in the tree after the parallel pass.
        std::vector<Output> outputs(tops.size());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, tops.size(), 1), [&](const auto& range) {
            Scratch s;
            for (std::size_t n = range.begin(); n != range.end(); ++n) {
                s.out = &outputs[n];
                descend(tops[n], kTop, all, std::numeric_limits<double>::infinity(), s, 0);
            }
        });
        auto& tree = mGrid->tree();
        for (auto& out : outputs) {
            for (auto& leaf : out.leaves) tree.addLeaf(leaf.release());
            for (const auto& box : out.insideTiles) tree.fill(box, float(-mInterior), false);
        }
        tree.prune();
        return mGrid;
    }

private:
    struct Output {
        std::vector<std::unique_ptr<Leaf>> leaves;
        std::vector<openvdb::CoordBBox> insideTiles;
    };
    /// A triangle that can be nearest to some sample of a cube, and its distance from the cube's centre.
    struct Candidate {
        std::uint32_t triangle;
        double distance;
    };
    struct Scratch {
        Output* out = nullptr;
        std::vector<Candidate> candidates[8];  ///< per depth of the descent
        std::vector<double> distances;
        Leaf* leaf = nullptr;  ///< the leaf being filled
        bool inside[512];      ///< its samples' sides
    };

    static int blockFloor(int i, int size) { return i >= 0 ? i / size * size : -((-i + size - 1) / size) * size; }

    openvdb::Vec3d world(const openvdb::Coord& c) const
    {
        return mOrigin + openvdb::Vec3d(c.x(), c.y(), c.z()) * mVoxel;
    }

    /// Keeps the triangles of @a in that can be nearest to some point within @a r of @a c (those
    /// within the nearest one's distance plus 2 r); returns the distance from @a c to the nearest.
    /// The distances in @a in are from a point @a shift away from @a c (the parent cube's centre):
    /// a triangle whose distance from there, less the shift, exceeds the nearest one's so far plus
    /// 2 r cannot be kept, so its distance from @a c is never computed.
    double filter(const std::vector<Candidate>& in, double shift, const openvdb::Vec3d& c, double r,
                  std::vector<Candidate>& out, Scratch& s) const
    {
        // A little slack for rounding: a kept triangle too many costs nothing but time.
        const double slack = 1e-6 * mVoxel;
        const double skipped = std::numeric_limits<double>::infinity();
        s.distances.resize(in.size());
        // The first candidate is the one nearest the parent's centre: it makes the nearest so far
        // small early.
        const std::size_t first = 0;
        double nearest = std::numeric_limits<double>::infinity();
        if (!in.empty()) {
            const Triangle& t = mTriangles[in[first].triangle];
            nearest = s.distances[first] = std::sqrt(distanceSq(t, c, planeDistance(t, c)));
        }
        for (std::size_t i = 0; i < in.size(); ++i) {
            if (i == first) continue;
            // Two lower bounds: from the parent's centre, and the distance to the plane.
            const Triangle& t = mTriangles[in[i].triangle];
            const double h = in[i].distance - shift > nearest + 2.0 * r + slack ? skipped : planeDistance(t, c);
            if (h > nearest + 2.0 * r + slack) {
                s.distances[i] = skipped;
                continue;
            }
            s.distances[i] = std::sqrt(distanceSq(t, c, h));
            nearest = std::min(nearest, s.distances[i]);
        }
        const double keep = nearest + 2.0 * r + slack;
        out.clear();
        for (std::size_t i = 0; i < in.size(); ++i)
            if (s.distances[i] <= keep) out.push_back({in[i].triangle, s.distances[i]});
        // The nearest first, for the children and the samples.
        const auto best = std::min_element(
            out.begin(), out.end(), [](const Candidate& a, const Candidate& b) { return a.distance < b.distance; });
        if (best != out.end()) std::iter_swap(out.begin(), best);
        return nearest;
    }

    /// The cube of @a size samples from @a origin (a power of two), with its parent's candidates.
    void descend(const openvdb::Coord& origin, int size, const std::vector<Candidate>& parent, double shift, Scratch& s,
                 int depth) const
    {
        const double r = 0.5 * std::sqrt(3.0) * (size - 1) * mVoxel;
        const openvdb::Vec3d centre = world(origin) + openvdb::Vec3d(0.5 * (size - 1) * mVoxel);
        std::vector<Candidate>& mine = s.candidates[depth];
        const double nearest = filter(parent, shift, centre, r, mine, s);
        if (nearest - r > 0.0) {
            // No surface in the cube: one side throughout. Past the band on that side it keeps
            // the band's constant (a tile inside, the background outside, the leaf's default).
            const bool inside = size >= 8 ? mParity.inside(origin) : s.inside[Leaf::coordToOffset(origin)];
            if (nearest - r >= (inside ? mInterior : mExterior)) {
                if (inside && size >= 8) s.out->insideTiles.emplace_back(origin, origin.offsetBy(size - 1));
                return;
            }
        }
        if (size == 8) {
            enterLeaf(origin, s);
        }
        if (size == 2) {
            for (int i = 0; i < 2; ++i)
                for (int j = 0; j < 2; ++j)
                    for (int k = 0; k < 2; ++k) sampleAt(origin.offsetBy(i, j, k), mine, s);
            return;
        }
        // A child's centre lies a quarter of this cube's diagonal from this one's.
        const int half = size / 2;
        const double childShift = 0.5 * std::sqrt(3.0) * half * mVoxel;
        for (int i = 0; i < 2; ++i)
            for (int j = 0; j < 2; ++j)
                for (int k = 0; k < 2; ++k)
                    descend(origin.offsetBy(i * half, j * half, k * half), half, mine, childShift, s, depth + 1);
        if (size == 8) leaveLeaf(origin, s);
    }

    /// A new leaf with every sample's side, holding the band's constants until distances come.
    void enterLeaf(const openvdb::Coord& origin, Scratch& s) const
    {
        s.out->leaves.push_back(std::make_unique<Leaf>(origin, float(mExterior), false));
        s.leaf = s.out->leaves.back().get();
        for (int i = 0; i < 8; ++i)
            for (int j = 0; j < 8; ++j) {
                const int row = (i << 6) | (j << 3);
                mParity.insideRun(origin.offsetBy(i, j, 0), 8, s.inside + row);
                for (int k = 0; k < 8; ++k)
                    if (s.inside[row + k]) s.leaf->setValueOnly(row + k, float(-mInterior));
            }
    }

    /// A leaf that took no distance is a constant: a tile inside, nothing outside.
    void leaveLeaf(const openvdb::Coord& origin, Scratch& s) const
    {
        if (!s.leaf->isEmpty()) return;
        const bool allInside = std::all_of(s.inside, s.inside + 512, [](bool b) { return b; });
        const bool allOutside = std::none_of(s.inside, s.inside + 512, [](bool b) { return b; });
        if (!allInside && !allOutside) return;
        s.out->leaves.pop_back();
        if (allInside) s.out->insideTiles.emplace_back(origin, origin.offsetBy(7));
    }

    /// The distance at a corner @a c of a cube of 2^3 samples: a candidate whose plane is no
    /// nearer than the nearest triangle so far cannot be nearer (the face beside the nearest one
    /// on a flat side, say), so its distance is never computed.
    void sampleAt(const openvdb::Coord& c, const std::vector<Candidate>& candidates, Scratch& s) const
    {
        const openvdb::Vec3d p = world(c);
        double best = std::numeric_limits<double>::infinity();
        for (const Candidate& candidate : candidates) {
            const Triangle& t = mTriangles[candidate.triangle];
            const double h = planeDistance(t, p);
            if (h * h >= best) continue;
            best = std::min(best, distanceSq(t, p, h));
        }
        const double d = std::sqrt(best);
        const int offset = Leaf::coordToOffset(c);
        const bool inside = s.inside[offset];
        if (d < (inside ? mInterior : mExterior)) s.leaf->setValueOn(offset, float(inside ? -d : d));
    }

    double mVoxel;
    openvdb::Vec3d mOrigin;
    double mExterior, mInterior;
    ColumnParity mParity;
    std::vector<Triangle> mTriangles;
    openvdb::FloatGrid::Ptr mGrid;
};

}  // namespace

openvdb::FloatGrid::Ptr meshToSdf(const TriangleMesh& mesh, const openvdb::math::Transform& xform, float exteriorVoxels,
                                  float interiorVoxels)
{
    Converter converter(mesh, xform, exteriorVoxels, interiorVoxels);
    return converter.run(mesh.bounds());
}

}  // namespace voxlat
