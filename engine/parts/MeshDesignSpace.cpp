#include "engine/parts/MeshDesignSpace.h"

#include "engine/core/Errors.h"
#include "engine/core/SystemInfo.h"
#include "engine/parts/MeshSdf.h"
#include "mesher/checks/MeshCheck.h"

#include <openvdb/tools/MeshToVolume.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <deque>
#include <map>
#include <sstream>

namespace voxlat {

namespace {

std::string mm(double v)
{
    std::ostringstream s;
    s.precision(v < 10 ? 3 : 4);
    s << v;
    return s.str();
}

std::string sizeText(const Vec3d& e)
{
    return mm(e[0]) + " x " + mm(e[1]) + " x " + mm(e[2]) + " mm";
}

std::uint64_t edgeKey(std::uint32_t a, std::uint32_t b)
{
    return (std::uint64_t(std::min(a, b)) << 32) | std::max(a, b);
}

/// Triangles around each undirected edge, in a fixed (sorted) order.
struct EdgeUse {
    std::uint64_t key;
    std::uint32_t triangle;
    std::uint8_t corner;  ///< the edge runs from corner to corner + 1
    bool operator<(const EdgeUse& o) const { return key != o.key ? key < o.key : triangle < o.triangle; }
};

std::vector<EdgeUse> edgeUses(const TriangleMesh& m)
{
    std::vector<EdgeUse> uses;
    uses.reserve(3 * m.triangles.size());
    for (std::uint32_t t = 0; t < m.triangles.size(); ++t)
        for (std::uint8_t c = 0; c < 3; ++c)
            uses.push_back({edgeKey(m.triangles[t][c], m.triangles[t][(c + 1) % 3]), t, c});
    std::sort(uses.begin(), uses.end());
    return uses;
}

}  // namespace

MeshDesignSpace::MeshDesignSpace(PartMesh part, std::string shown, const MeshSpaceOptions& options)
    : mMesh(std::move(part.mesh)),
      mShown(std::move(shown)),
      mFormat(part.format),
      mVoxel(options.voxel),
      mSampleOrigin(options.sampleOrigin)
{
    mUnitMm = options.unitMm.value_or(part.fileUnitMm.value_or(1.0));
    mUnitsKnown = options.unitMm || part.fileUnitMm;
    if (mUnitMm != 1.0)
        for (auto& p : mMesh.points) p *= float(mUnitMm);

    // Triangles with a repeated corner enclose nothing: drop them.
    const std::size_t before = mMesh.triangles.size();
    std::erase_if(mMesh.triangles,
                  [](const openvdb::Vec3I& t) { return t[0] == t[1] || t[1] == t[2] || t[0] == t[2]; });
    mDegenerateDropped = before - mMesh.triangles.size();
    if (mMesh.triangles.empty()) throw InputError(mShown + ": every triangle is degenerate (no area)");

    const MeshTopology topology = checkTopology(mMesh);
    if (topology.nonManifoldEdges > 0)
        throw InputError(mShown + ": " + std::to_string(topology.nonManifoldEdges) +
                         " edges are shared by more than two triangles (a non-manifold or self-touching mesh), so "
                         "inside and outside are undefined there: merge the touching bodies or fix the mesh in your "
                         "CAD tool");
    orientShells();
    fillHoles(options.repair);

    const openvdb::BBoxd b = mMesh.bounds();
    mBounds = Box3{b.min(), b.max()};
    checkSize(options);
}

void MeshDesignSpace::orientShells()
{
    // Walk each connected shell from its first triangle, turning neighbours so that every shared
    // edge is traversed in opposite directions. A manifold shell either orients or is
    // non-orientable (a Moebius-like surface): then no inside exists.
    const std::vector<EdgeUse> uses = edgeUses(mMesh);
    std::vector<std::array<std::uint32_t, 3>> neighbour(mMesh.triangles.size(), {~0u, ~0u, ~0u});
    for (std::size_t i = 0; i + 1 < uses.size(); ++i)
        if (uses[i].key == uses[i + 1].key) {
            neighbour[uses[i].triangle][uses[i].corner] = uses[i + 1].triangle;
            neighbour[uses[i + 1].triangle][uses[i + 1].corner] = uses[i].triangle;
        }
    mShellOf.assign(mMesh.triangles.size(), ~0u);
    mShells = 0;
    std::vector<char> flip(mMesh.triangles.size(), 0);
    // Whether triangle t, as it will be turned, runs along its edge from a to b.
    auto runs = [&](std::uint32_t t, std::uint32_t a, std::uint32_t b) {
        const auto& tri = mMesh.triangles[t];
        bool forward = false;
        for (int k = 0; k < 3; ++k) forward = forward || (tri[k] == a && tri[(k + 1) % 3] == b);
        return forward != bool(flip[t]);
    };
    std::deque<std::uint32_t> queue;
    for (std::uint32_t seed = 0; seed < mMesh.triangles.size(); ++seed) {
        if (mShellOf[seed] != ~0u) continue;
        mShellOf[seed] = mShells;
        queue.push_back(seed);
        while (!queue.empty()) {
            const std::uint32_t t = queue.front();
            queue.pop_front();
            for (int c = 0; c < 3; ++c) {
                const std::uint32_t n = neighbour[t][c];
                if (n == ~0u) continue;
                const std::uint32_t a = mMesh.triangles[t][c], b = mMesh.triangles[t][(c + 1) % 3];
                const bool tForward = runs(t, a, b);
                if (mShellOf[n] == ~0u) {
                    // Consistent neighbours run a shared edge in opposite directions.
                    mShellOf[n] = mShells;
                    if (runs(n, a, b) == tForward) flip[n] = 1;
                    queue.push_back(n);
                } else if (runs(n, a, b) == tForward) {
                    throw InputError(mShown + ": shell " + std::to_string(mShells + 1) +
                                     " is non-orientable (like a Moebius strip): it has no inside; fix the mesh in "
                                     "your CAD tool");
                }
            }
        }
        ++mShells;
    }
    std::size_t turned = 0;
    for (std::uint32_t t = 0; t < mMesh.triangles.size(); ++t)
        if (flip[t]) {
            std::swap(mMesh.triangles[t][1], mMesh.triangles[t][2]);
            ++turned;
        }
    // Each shell now turns one way; which way (outward or inside out) the grid decides in build().
    mReorientedTriangles += turned;
    if (turned > 0)
        mWarnings.push_back("turned " + std::to_string(turned) +
                            " triangles whose normals disagreed with their neighbours'");
}

void MeshDesignSpace::fillHoles(bool repair)
{
    // Boundary half-edges a -> b (used by one triangle); a hole is a loop of them.
    const std::vector<EdgeUse> uses = edgeUses(mMesh);
    std::map<std::uint32_t, std::uint32_t> next;
    std::size_t boundary = 0;
    for (std::size_t i = 0; i < uses.size(); ++i) {
        const bool single =
            (i == 0 || uses[i - 1].key != uses[i].key) && (i + 1 == uses.size() || uses[i + 1].key != uses[i].key);
        if (!single) continue;
        ++boundary;
        const auto& t = mMesh.triangles[uses[i].triangle];
        const std::uint32_t a = t[uses[i].corner], b = t[(uses[i].corner + 1) % 3];
        if (!next.emplace(a, b).second)
            throw InputError(mShown + ": the mesh is open: " + std::to_string(boundary) +
                             "+ boundary edges (edges with one triangle), and holes meet at vertex " +
                             std::to_string(a) +
                             ", so they cannot be filled automatically: close the mesh in your "
                             "CAD tool");
    }
    if (boundary == 0) return;
    // Walk the loops.
    std::vector<std::vector<std::uint32_t>> loops;
    std::map<std::uint32_t, bool> used;
    for (const auto& [start, to] : next) {
        if (used[start]) continue;
        std::vector<std::uint32_t> loop;
        std::uint32_t v = start;
        while (!used[v]) {
            used[v] = true;
            loop.push_back(v);
            const auto it = next.find(v);
            if (it == next.end()) break;
            v = it->second;
        }
        loops.push_back(std::move(loop));
    }
    if (!repair)
        throw InputError(mShown + ": the mesh is open: " + std::to_string(boundary) +
                         " boundary edges (edges with one triangle) in " + std::to_string(loops.size()) +
                         (loops.size() == 1 ? " hole" : " holes") +
                         ", so inside and outside are undefined: add `repair: true` to the mesh node to fill small "
                         "holes, or close the mesh in your CAD tool");
    const openvdb::BBoxd all = mMesh.bounds();
    const double partSize = all.extents().length();
    for (const auto& loop : loops) {
        openvdb::BBoxd box;
        box.min() = openvdb::Vec3d(std::numeric_limits<double>::max());
        box.max() = openvdb::Vec3d(std::numeric_limits<double>::lowest());
        openvdb::Vec3d centroid(0.0);
        for (std::uint32_t v : loop) {
            const openvdb::Vec3d p = mMesh.points[v];
            box.expand(p);
            centroid += p;
        }
        centroid /= double(loop.size());
        const double across = box.extents().length();
        if (across > 0.2 * partSize)
            throw InputError(mShown + ": the mesh is open and a hole of " + std::to_string(loop.size()) +
                             " edges spans " + mm(across) +
                             " mm, too large for `repair: true` to fill safely "
                             "(at most a fifth of the part, " +
                             mm(0.2 * partSize) + " mm): close the mesh in your CAD tool");
        // A fan around the centroid; each new triangle runs its boundary edge backwards (b -> a),
        // so the patch takes the orientation of the triangles around the hole.
        const auto c = std::uint32_t(mMesh.points.size());
        mMesh.points.emplace_back(float(centroid[0]), float(centroid[1]), float(centroid[2]));
        for (std::size_t i = 0; i < loop.size(); ++i) {
            const std::uint32_t a = loop[i], b = loop[(i + 1) % loop.size()];
            mMesh.triangles.emplace_back(b, a, c);
        }
        mHoleEdges += loop.size();
        ++mHolesFilled;
    }
    // The patches join shells: find shells again (their orientation is already consistent).
    orientShells();
    if (checkTopology(mMesh).boundaryEdges != 0)
        throw InputError(mShown +
                         ": the mesh is open and filling its holes did not close it: close the mesh in your "
                         "CAD tool");
    mWarnings.push_back("filled " + std::to_string(mHolesFilled) + " holes (" + std::to_string(mHoleEdges) +
                        " boundary edges) as asked by `repair: true`");
}

void MeshDesignSpace::checkSize(const MeshSpaceOptions& options)
{
    const Vec3d extent = mBounds.extent();
    const double largest = std::max({extent[0], extent[1], extent[2]});
    if (!mUnitsKnown) {
        // STL, OBJ and PLY carry no unit: millimetres are assumed. Parts drawn in inches come
        // out 25.4 times too small, parts in micrometres 1000 times too large.
        if (largest < 8.0)
            mWarnings.push_back(mShown + " is only " + sizeText(extent) +
                                " across; if it was drawn in inches add `units: in` to the mesh node (it would be " +
                                sizeText(extent * 25.4) + ")");
        else if (largest > 5000.0)
            mWarnings.push_back(mShown + " is " + sizeText(extent) +
                                " across; if it was drawn in micrometres add `units: um` to the mesh node");
    }
    if (largest < 4.0 * mVoxel)
        throw InputError(mShown + ": the part is " + sizeText(extent) + ", only a few voxels of " + mm(mVoxel) +
                         " mm: lower `voxel:` or set the mesh's `units:` (in, cm, m)");
    if (options.domain) {
        const Vec3d d = options.domain->extent();
        const double domainLargest = std::max({d[0], d[1], d[2]});
        if (largest > 10.0 * domainLargest)
            throw InputError(mShown + ": the mesh (" + sizeText(extent) + ") is far larger than the domain (" +
                             sizeText(d) +
                             "): set the mesh's `units:` if it is not in millimetres (um, mm, cm, m, in), "
                             "or fix `domain:` (or leave it out: the part's box is then used)");
    }
}

void MeshDesignSpace::build()
{
    std::call_once(mBuilt, [&] { convert(); });
}

std::shared_ptr<const MeshDistance> MeshDesignSpace::distance()
{
    build();
    return mDistance;
}

void MeshDesignSpace::convert()
{
    // Exact distances to three voxels outside (the mesher and booleans need a voxel or two) and
    // to the deepest any user asked for inside, plus two voxels for interpolation stencils.
    const float exterior = 3.0f;
    const float interior = float(std::max(3.0, std::ceil(mInteriorMm / mVoxel) + 2.0));
    const double area = mMesh.area();
    // About 24 bytes per band voxel while converting (distances, triangle indices, masks).
    const double bandVoxels = area / (mVoxel * mVoxel) * double(exterior + interior) * 1.3;
    const double bytes = 24.0 * bandVoxels;
    if (bytes > 0.7 * double(availableMemoryBytes())) {
        std::ostringstream msg;
        msg << mShown << ": converting this part (" << sizeText(mBounds.extent()) << ", " << mm(area)
            << " mm2 of surface) at voxel " << mVoxel << " mm needs about " << std::llround(bytes / 1048576.0)
            << " MB, more than this machine can give: raise `voxel:` or check the mesh's `units:`";
        throw JobError(msg.str());
    }
    auto xform = openvdb::math::Transform::createLinearTransform(mVoxel);
    xform->postTranslate(mSampleOrigin);
    // Our own conversion (exact distances, ray parity) unless the mesh overlaps itself, where
    // parity would hollow out the overlap: then OpenVDB's, which takes the union.
    openvdb::FloatGrid::Ptr grid = meshToSdf(mMesh, *xform, exterior, interior);
    orientAndMeasure(grid);
    const double meshVol = mMesh.volume();
    if (std::abs(mGridVolume - meshVol) > 0.02 * meshVol + 0.5 * area * mVoxel) {
        const std::vector<openvdb::Vec4I> quads;
        grid = openvdb::tools::meshToSignedDistanceField<openvdb::FloatGrid>(*xform, mMesh.points, mMesh.triangles,
                                                                             quads, exterior, interior);
        grid->setGridClass(openvdb::GRID_LEVEL_SET);
        orientAndMeasure(grid);
        mConverter = "openvdb (the mesh overlaps itself)";
    }
    // Overlapping shells count twice in the divergence theorem but once in the grid.
    if (std::abs(mGridVolume - mMesh.volume()) > 0.02 * mMesh.volume() + 0.5 * area * mVoxel)
        mWarnings.push_back("the mesh's own volume (" + mm(mMesh.volume()) + " mm3) and the volume inside it (" +
                            mm(mGridVolume) +
                            " mm3) differ: the mesh probably intersects itself or has overlapping "
                            "shells (the part is taken as their union)");
}

void MeshDesignSpace::orientAndMeasure(const openvdb::FloatGrid::Ptr& grid)
{
    const Box3 support{mBounds.min - Vec3d(mVoxel), mBounds.max + Vec3d(mVoxel)};
    mDistance = std::make_shared<MeshDistance>(grid, support);
    const std::size_t flippedBefore = mFlippedShells;

    // Orientation: the grid knows inside from outside whatever the normals say. Compare each
    // shell's normals with the distance gradient at its triangles (area weighted, up to 4096
    // triangles per shell) and turn shells that point inward.
    std::vector<double> agree(mShells, 0.0), total(mShells, 0.0);
    std::vector<std::size_t> seen(mShells, 0), shellSize(mShells, 0);
    for (std::uint32_t s : mShellOf) ++shellSize[s];
    std::vector<Vec3d> centres;
    std::vector<std::pair<std::uint32_t, Vec3d>> normals;  // shell, area vector
    for (std::uint32_t t = 0; t < mMesh.triangles.size(); ++t) {
        const std::uint32_t s = mShellOf[t];
        const std::size_t stride = std::max<std::size_t>(1, shellSize[s] / 4096);
        if (seen[s]++ % stride != 0) continue;
        const Vec3d a = mMesh.points[mMesh.triangles[t][0]], b = mMesh.points[mMesh.triangles[t][1]],
                    c = mMesh.points[mMesh.triangles[t][2]];
        centres.push_back((a + b + c) / 3.0);
        normals.emplace_back(s, 0.5 * (b - a).cross(c - a));
    }
    std::vector<double> values(centres.size());
    std::vector<Vec3d> gradients(centres.size());
    mDistance->gradients(centres, values, gradients);
    for (std::size_t i = 0; i < centres.size(); ++i) {
        if (gradients[i].length() < 0.5) continue;  // a thin wall's centre: no clear direction
        const auto& [s, n] = normals[i];
        const double w = n.length();
        total[s] += w;
        if (n.dot(gradients[i]) > 0) agree[s] += w;
    }
    for (std::uint32_t s = 0; s < mShells; ++s) {
        if (total[s] <= 0.0) continue;
        const double share = agree[s] / total[s];
        if (share >= 0.75) continue;
        if (share > 0.25)
            throw InputError(mShown + ": cannot tell which way shell " + std::to_string(s + 1) + " faces: only " +
                             std::to_string(int(std::lround(100 * share))) +
                             " % of its surface has normals pointing out (the mesh intersects itself or has "
                             "internal faces): fix it in your CAD tool");
        for (std::uint32_t t = 0; t < mMesh.triangles.size(); ++t)
            if (mShellOf[t] == s) std::swap(mMesh.triangles[t][1], mMesh.triangles[t][2]);
        ++mFlippedShells;
    }
    if (mFlippedShells > flippedBefore)
        mWarnings.push_back("turned " + std::to_string(mFlippedShells - flippedBefore) + " inside-out shell" +
                            (mFlippedShells - flippedBefore == 1 ? "" : "s") +
                            " (normals pointing inward) the right way");

    // Volume inside the grid: each sample's cell counts by how much of it lies inside, 1/2 - d/voxel
    // clamped to [0, 1] (exact for a face parallel to the cells; a plain count of samples below
    // zero would be half a voxel off wherever a face runs through a plane of samples). Tiles
    // (the inactive inside ones too) count whole. Summed per leaf in parallel, then in leaf order.
    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    grid->tree().getNodes(leaves);
    std::vector<double> perLeaf(leaves.size(), 0.0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size()), [&](const auto& range) {
        for (std::size_t n = range.begin(); n != range.end(); ++n) {
            const float* data = leaves[n]->buffer().data();
            double sum = 0.0;
            for (int i = 0; i < 512; ++i) sum += std::clamp(0.5 - double(data[i]) / mVoxel, 0.0, 1.0);
            perLeaf[n] = sum;
        }
    });
    double covered = 0.0;
    auto tile = grid->tree().cbeginValueAll();
    tile.setMaxDepth(tile.getLeafDepth() - 1);  // tiles only
    for (; tile; ++tile)
        if (!tile.isVoxelValue() && *tile < 0.0f) covered += double(tile.getVoxelCount());
    for (const double sum : perLeaf) covered += sum;
    mGridVolume = covered * mVoxel * mVoxel * mVoxel;
}

nlohmann::json MeshDesignSpace::report() const
{
    nlohmann::json r{{"file", mShown},
                     {"format", mFormat},
                     {"unit_mm", mUnitMm},
                     {"triangles", mMesh.triangles.size()},
                     {"vertices", mMesh.points.size()},
                     {"shells", mShells},
                     {"bounds_min", {mBounds.min[0], mBounds.min[1], mBounds.min[2]}},
                     {"bounds_max", {mBounds.max[0], mBounds.max[1], mBounds.max[2]}},
                     {"mesh_volume_mm3", mMesh.volume()},
                     {"area_mm2", mMesh.area()},
                     {"interior_band_mm", mInteriorMm},
                     {"converter", mConverter},
                     {"degenerate_triangles_dropped", mDegenerateDropped},
                     {"triangles_reoriented", mReorientedTriangles},
                     {"shells_turned", mFlippedShells},
                     {"holes_filled", mHolesFilled},
                     {"warnings", mWarnings}};
    if (mDistance) {
        r["grid_volume_mm3"] = mGridVolume;
        r["grid_leaves"] = mDistance->grid().tree().leafCount();
    }
    return r;
}

std::optional<Box3> PartField::support() const
{
    const Box3 b = mSpace->bounds();
    const double v = 1.5 * mSpace->voxel();
    return Box3{b.min - Vec3d(v), b.max + Vec3d(v)};
}

}  // namespace voxlat
