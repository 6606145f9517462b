#include "engine/InteriorDistance.h"

#include <openvdb/tools/ChangeBackground.h>
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

/// A triangle as corner a and edges ab, ac (double, world units).
struct Triangle {
    openvdb::Vec3d a, ab, ac;
};

/// Squared distance from @a p to the triangle (Ericson, Real-Time Collision Detection, 5.1.5).
double distanceSq(const Triangle& t, const openvdb::Vec3d& p)
{
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

class Deepener {
public:
    Deepener(openvdb::FloatGrid& grid, const TriangleMesh& mesh, float interiorVoxels) : mGrid(grid)
    {
        mVoxel = grid.transform().voxelSize()[0];
        mOrigin = grid.transform().indexToWorld(openvdb::Vec3d(0.0));
        mDepth = double(interiorVoxels) * mVoxel;
        mTriangles.reserve(mesh.triangles.size());
        for (const auto& t : mesh.triangles) {
            const openvdb::Vec3d a = mesh.points[t[0]], b = mesh.points[t[1]], c = mesh.points[t[2]];
            mTriangles.push_back({a, b - a, c - a});
        }
    }

    void run(const openvdb::BBoxd& meshBounds)
    {
        // Blocks of 32^3 voxels over the mesh's box (only inside samples change).
        constexpr int kTop = 32;
        openvdb::Coord lo, hi;
        for (int a = 0; a < 3; ++a) {
            lo[a] = blockFloor(int(std::floor((meshBounds.min()[a] - mOrigin[a]) / mVoxel)) - 1, kTop);
            hi[a] = blockFloor(int(std::ceil((meshBounds.max()[a] - mOrigin[a]) / mVoxel)) + 1, kTop);
        }
        std::vector<openvdb::Coord> tops;
        for (int x = lo.x(); x <= hi.x(); x += kTop)
            for (int y = lo.y(); y <= hi.y(); y += kTop)
                for (int z = lo.z(); z <= hi.z(); z += kTop) tops.emplace_back(x, y, z);
        std::vector<std::uint32_t> all(mTriangles.size());
        for (std::uint32_t i = 0; i < all.size(); ++i) all[i] = i;

        // Leaves made from inside tiles, per top block; inserted after the parallel pass (the tree's
        // structure must not change while other threads read it).
        std::vector<std::vector<std::unique_ptr<Leaf>>> created(tops.size());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, tops.size(), 1), [&](const auto& range) {
            Scratch s;
            s.acc =
                std::make_unique<openvdb::tree::ValueAccessor<const openvdb::FloatTree>>(std::as_const(mGrid.tree()));
            for (std::size_t n = range.begin(); n != range.end(); ++n) {
                s.created = &created[n];
                descend(tops[n], kTop, all, s, 0);
            }
        });
        for (auto& block : created)
            for (auto& leaf : block) mGrid.tree().addLeaf(leaf.release());
        openvdb::tools::changeAsymmetricLevelSetBackground(mGrid.tree(), mGrid.background(), float(-mDepth));
    }

private:
    struct Scratch {
        std::unique_ptr<openvdb::tree::ValueAccessor<const openvdb::FloatTree>> acc;
        std::vector<std::unique_ptr<Leaf>>* created = nullptr;
        std::vector<std::uint32_t> candidates[8];  ///< per depth of the descent
        std::vector<double> distances;
        Leaf* leaf = nullptr;       ///< the leaf being filled (made on its first distance)
        openvdb::Coord leafOrigin;  ///< where that leaf starts
        float tileValue = 0.0f;     ///< the inside tile a new leaf replaces
        bool wanted[512];           ///< the leaf's samples that take a distance
    };

    static int blockFloor(int i, int size) { return i >= 0 ? i / size * size : -((-i + size - 1) / size) * size; }

    openvdb::Vec3d world(const openvdb::Coord& c) const
    {
        return mOrigin + openvdb::Vec3d(c.x(), c.y(), c.z()) * mVoxel;
    }

    /// Keeps the triangles of @a in that can be nearest to some point within @a r of @a c (those
    /// within the nearest one's distance plus 2 r); returns the distance from @a c to the nearest.
    double filter(const std::vector<std::uint32_t>& in, const openvdb::Vec3d& c, double r,
                  std::vector<std::uint32_t>& out, Scratch& s) const
    {
        s.distances.resize(in.size());
        double nearest = std::numeric_limits<double>::infinity();
        for (std::size_t i = 0; i < in.size(); ++i) {
            s.distances[i] = std::sqrt(distanceSq(mTriangles[in[i]], c));
            nearest = std::min(nearest, s.distances[i]);
        }
        // A little slack for rounding: a kept triangle too many costs nothing but time.
        const double keep = nearest + 2.0 * r + 1e-6 * mVoxel;
        out.clear();
        for (std::size_t i = 0; i < in.size(); ++i)
            if (s.distances[i] <= keep) out.push_back(in[i]);
        return nearest;
    }

    /// The cube of @a size samples from @a origin (a power of two), with the candidate triangles of
    /// its parent.
    void descend(const openvdb::Coord& origin, int size, const std::vector<std::uint32_t>& parent, Scratch& s,
                 int depth) const
    {
        if (size == 8 && !enterLeaf(origin, s)) return;
        const double r = 0.5 * std::sqrt(3.0) * (size - 1) * mVoxel;
        const openvdb::Vec3d centre = world(origin) + openvdb::Vec3d(0.5 * (size - 1) * mVoxel);
        std::vector<std::uint32_t>& mine = s.candidates[depth];
        const double nearest = filter(parent, centre, r, mine, s);
        if (nearest - r >= mDepth) {  // every sample is deeper than the band (or far outside)
            return;
        }
        if (size == 2) {
            for (int i = 0; i < 2; ++i)
                for (int j = 0; j < 2; ++j)
                    for (int k = 0; k < 2; ++k) sampleAt(origin.offsetBy(i, j, k), mine, s);
            return;
        }
        const int half = size / 2;
        for (int i = 0; i < 2; ++i)
            for (int j = 0; j < 2; ++j)
                for (int k = 0; k < 2; ++k)
                    descend(origin.offsetBy(i * half, j * half, k * half), half, mine, s, depth + 1);
    }

    /// Whether the leaf at @a origin has inside samples past the grid's band; sets up s.leaf.
    bool enterLeaf(const openvdb::Coord& origin, Scratch& s) const
    {
        bool* wanted = s.wanted;
        const Leaf* existing = s.acc->probeConstLeaf(origin);
        bool any = false;
        if (existing) {
            for (int i = 0; i < 512; ++i) {
                wanted[i] = !existing->isValueOn(i) && existing->getValue(i) < 0.0f;
                any = any || wanted[i];
            }
            s.leaf = const_cast<Leaf*>(existing);  // only this task writes this leaf
        } else {
            if (!(s.acc->getValue(origin) < 0.0f)) return false;
            std::fill(wanted, wanted + 512, true);
            any = true;
            s.leaf = nullptr;  // made when a sample takes a distance
        }
        s.tileValue = existing ? 0.0f : s.acc->getValue(origin);
        s.leafOrigin = origin;
        return any;
    }

    void sampleAt(const openvdb::Coord& c, const std::vector<std::uint32_t>& candidates, Scratch& s) const
    {
        const int offset = Leaf::coordToOffset(c);
        if (!s.wanted[offset]) return;
        const openvdb::Vec3d p = world(c);
        double best = std::numeric_limits<double>::infinity();
        for (std::uint32_t t : candidates) best = std::min(best, distanceSq(mTriangles[t], p));
        const double d = std::sqrt(best);
        if (d >= mDepth) return;
        if (!s.leaf) {
            s.created->push_back(std::make_unique<Leaf>(s.leafOrigin, s.tileValue, false));
            s.leaf = s.created->back().get();
        }
        s.leaf->setValueOn(offset, float(-d));
    }

    openvdb::FloatGrid& mGrid;
    double mVoxel = 1.0, mDepth = 0.0;
    openvdb::Vec3d mOrigin;
    std::vector<Triangle> mTriangles;
};

}  // namespace

void deepenInteriorBand(openvdb::FloatGrid& grid, const TriangleMesh& mesh, float interiorVoxels)
{
    Deepener deepener(grid, mesh, interiorVoxels);
    deepener.run(mesh.bounds());
}

}  // namespace voxlat
