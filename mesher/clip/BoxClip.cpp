#include "mesher/clip/BoxClip.h"

#include "mesher/checks/MeshCheck.h"
#include "mesher/extract/PhaseProgress.h"

#include <CGAL/Constrained_Delaunay_triangulation_2.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Triangulation_face_base_with_info_2.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <deque>
#include <limits>
#include <map>
#include <numeric>
#include <optional>
#include <vector>

namespace voxlat {

namespace {

using Tri = std::array<std::uint32_t, 3>;

/// Faces are numbered -x, +x, -y, +y, -z, +z: axis face / 2, upper face % 2.
constexpr int kFaces = 6;

double planeOf(const Box3& box, int face)
{
    return face % 2 ? box.max[face / 2] : box.min[face / 2];
}

/// Signed distance of @a p outside face @a face's plane (positive outside the box).
double outside(const Vec3d& p, const Box3& box, int face)
{
    const int axis = face / 2;
    return face % 2 ? p[axis] - box.max[axis] : box.min[axis] - p[axis];
}

/// The mesh being cut: positions in double, the faces each vertex lies on as bits.
struct Work {
    std::vector<Vec3d> points;
    std::vector<std::uint8_t> faces;
    std::vector<Tri> triangles;
    /// Crease points left where the straight edge crosses (by vertex; set for new ones only).
    std::vector<std::uint8_t> leftOnEdge;
};

/// Moves each of @a vertices onto the level set within the faces it lies on (those coordinates
/// are held, and the axes in @a heldAxes, one set of bits per vertex, if given), by Newton steps;
/// a vertex that does not converge within maxMove, or leaves the box through one of the first
/// @a cutFaces faces, keeps its position. Returns the new positions (the old ones where not
/// moved); @a leftAxes (if given) gets per vertex the axes of the cut faces it converged beyond.
std::vector<Vec3d> newtonInFaces(const Work& w, const std::vector<std::uint32_t>& vertices, const FieldNode& field,
                                 const Box3& box, int cutFaces, const BoxClipOptions& o,
                                 std::vector<std::uint8_t>& converged,
                                 const std::vector<std::uint8_t>* heldAxes = nullptr,
                                 std::vector<std::uint8_t>* leftAxes = nullptr)
{
    if (leftAxes) leftAxes->assign(vertices.size(), 0);
    std::vector<Vec3d> out(vertices.size());
    converged.assign(vertices.size(), 0);
    const std::size_t chunks = (vertices.size() + kBatchSize - 1) / kBatchSize;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks, 1), [&](const auto& range) {
        std::vector<Vec3d> x, batch, grad;
        std::vector<double> value;
        std::vector<std::uint32_t> open;
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            const std::size_t begin = c * kBatchSize, count = std::min(kBatchSize, vertices.size() - begin);
            x.resize(count);
            open.clear();
            for (std::size_t k = 0; k < count; ++k) {
                x[k] = w.points[vertices[begin + k]];
                open.push_back(std::uint32_t(k));
            }
            std::vector<std::uint8_t> done(count, 0);
            for (int iteration = 0; iteration <= o.maxIterations && !open.empty(); ++iteration) {
                batch.resize(open.size());
                value.resize(open.size());
                grad.resize(open.size());
                for (std::size_t j = 0; j < open.size(); ++j) batch[j] = x[open[j]];
                field.gradients(batch, value, grad);
                std::size_t kept = 0;
                for (std::size_t j = 0; j < open.size(); ++j) {
                    const std::uint32_t k = open[j];
                    const std::uint8_t held = w.faces[vertices[begin + k]];
                    Vec3d g = grad[j];
                    for (int a = 0; a < 3; ++a)
                        if ((held >> (2 * a) & 3u) || (heldAxes && ((*heldAxes)[begin + k] >> a & 1u))) g[a] = 0.0;
                    const double r = value[j] - o.level, g2 = g.lengthSqr();
                    if (!(g2 > 0.0)) continue;
                    if (std::abs(r) / std::sqrt(g2) <= o.tolerance) {
                        done[k] = 1;
                        continue;
                    }
                    if (iteration == o.maxIterations) continue;
                    x[k] -= (r / g2) * g;
                    if (!((x[k] - w.points[vertices[begin + k]]).length() <= o.maxMove)) continue;
                    open[kept++] = k;
                }
                open.resize(kept);
            }
            for (std::size_t k = 0; k < count; ++k) {
                const Vec3d& start = w.points[vertices[begin + k]];
                bool good = done[k] && (x[k] - start).length() <= o.maxMove;
                // Inside the faces cut already (the later ones cut what passes them).
                for (int f = 0; f < cutFaces && good; ++f)
                    if (!(w.faces[vertices[begin + k]] >> f & 1u) && !(outside(x[k], box, f) <= 0.0)) {
                        good = false;
                        if (leftAxes) (*leftAxes)[begin + k] |= std::uint8_t(1u << (f / 2));
                    }
                out[begin + k] = good ? x[k] : start;
                converged[begin + k] = good;
            }
        }
    });
    return out;
}

/// Cuts @a w by face @a face, keeping what lies inside; new vertices where edges cross it.
void cutByFace(Work& w, int face, const FieldNode& field, const Box3& box, const BoxClipOptions& o, BoxClipStats& stats)
{
    const int axis = face / 2;
    const double at = planeOf(box, face);
    const std::uint8_t bit = std::uint8_t(1u << face);
    std::vector<double> s(w.points.size());
    for (std::size_t v = 0; v < w.points.size(); ++v) s[v] = (w.faces[v] & bit) ? 0.0 : outside(w.points[v], box, face);

    std::map<std::pair<std::uint32_t, std::uint32_t>, std::uint32_t> crossing;
    std::vector<std::uint32_t> created;
    auto cut = [&](std::uint32_t a, std::uint32_t b) {
        const auto key = std::minmax(a, b);
        const auto it = crossing.find(key);
        if (it != crossing.end()) return it->second;
        // From the lower index, so both triangles of the edge compute the same point.
        const std::uint32_t p = key.first, q = key.second;
        const double t = s[p] / (s[p] - s[q]);
        Vec3d x = w.points[p] + t * (w.points[q] - w.points[p]);
        x[axis] = at;
        const auto index = std::uint32_t(w.points.size());
        w.points.push_back(x);
        w.faces.push_back(std::uint8_t((w.faces[p] & w.faces[q]) | bit));
        crossing.emplace(key, index);
        created.push_back(index);
        return index;
    };

    std::vector<Tri> kept;
    kept.reserve(w.triangles.size());
    // Triangles made by the cut, with their parent's normal, for the turn-over check below.
    std::vector<std::size_t> pieces;
    for (const Tri& tri : w.triangles) {
        int out = 0;
        for (int i = 0; i < 3; ++i) out += s[tri[i]] > 0.0;
        if (out == 0) {
            kept.push_back(tri);
            continue;
        }
        if (out == 3) continue;
        ++stats.cutTriangles;
        std::array<std::uint32_t, 4> poly;
        int n = 0;
        for (int i = 0; i < 3; ++i) {
            const std::uint32_t a = tri[i], b = tri[(i + 1) % 3];
            if (s[a] <= 0.0) poly[n++] = a;
            if ((s[a] < 0.0 && s[b] > 0.0) || (s[a] > 0.0 && s[b] < 0.0)) poly[n++] = cut(a, b);
        }
        auto emit = [&](std::uint32_t a, std::uint32_t b, std::uint32_t c) {
            if (a == b || b == c || c == a) return;
            pieces.push_back(kept.size());
            kept.push_back({a, b, c});
        };
        if (n == 3) {
            emit(poly[0], poly[1], poly[2]);
        } else if (n == 4) {
            // The shorter diagonal.
            const double d02 = (w.points[poly[0]] - w.points[poly[2]]).lengthSqr();
            const double d13 = (w.points[poly[1]] - w.points[poly[3]]).lengthSqr();
            if (d02 <= d13) {
                emit(poly[0], poly[1], poly[2]);
                emit(poly[0], poly[2], poly[3]);
            } else {
                emit(poly[0], poly[1], poly[3]);
                emit(poly[1], poly[2], poly[3]);
            }
        }
    }
    w.triangles = std::move(kept);
    w.leftOnEdge.resize(w.points.size(), 0);
    if (created.empty()) return;

    // The crease points onto the surface within the face, unless a piece would turn over.
    std::vector<std::uint8_t> accept, left;
    std::vector<Vec3d> moved = newtonInFaces(w, created, field, box, face, o, accept, nullptr, &left);
    {
        // A point whose way onto the surface leaves the box through a face cut before (the
        // surface meets this face just past a box edge, W9 at 0.5 mm) goes again with that axis
        // held too: onto the crease beside the edge, inside (else left on the straight edge,
        // off the surface by up to 0.011 mm there).
        std::vector<std::uint32_t> again;
        std::vector<std::uint8_t> axes;
        std::vector<std::size_t> slot;
        for (std::size_t k = 0; k < created.size(); ++k)
            if (!accept[k] && left[k]) {
                again.push_back(created[k]);
                axes.push_back(left[k]);
                slot.push_back(k);
            }
        if (!again.empty()) {
            std::vector<std::uint8_t> acceptAgain;
            const std::vector<Vec3d> movedAgain = newtonInFaces(w, again, field, box, face, o, acceptAgain, &axes);
            for (std::size_t j = 0; j < again.size(); ++j) {
                moved[slot[j]] = movedAgain[j];
                accept[slot[j]] = acceptAgain[j];
            }
        }
    }
    const std::uint32_t firstNew = created.front();
    auto position = [&](std::uint32_t v) {
        return v >= firstNew && accept[v - firstNew] ? moved[v - firstNew] : w.points[v];
    };
    for (bool changed = true; changed;) {
        changed = false;
        for (std::size_t t : pieces) {
            const Tri& tri = w.triangles[t];
            const Vec3d a0 = w.points[tri[0]], b0 = w.points[tri[1]], c0 = w.points[tri[2]];
            const Vec3d n0 = (b0 - a0).cross(c0 - a0);
            const Vec3d a = position(tri[0]), b = position(tri[1]), c = position(tri[2]);
            const Vec3d n1 = (b - a).cross(c - a);
            if (n1.dot(n0) > 0.0) continue;
            for (int i = 0; i < 3; ++i)
                if (tri[i] >= firstNew && accept[tri[i] - firstNew]) {
                    accept[tri[i] - firstNew] = 0;
                    changed = true;
                }
        }
    }
    for (std::size_t k = 0; k < created.size(); ++k) {
        w.leftOnEdge[created[k]] = !accept[k];
        if (accept[k]) w.points[created[k]] = moved[k];
    }
}

// The constrained Delaunay triangulation of one face's cap, in the face's two other coordinates.
using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using VertexBase = CGAL::Triangulation_vertex_base_with_info_2<std::uint32_t, Kernel>;
using FaceInfoBase = CGAL::Triangulation_face_base_with_info_2<int, Kernel>;
using FaceBase = CGAL::Constrained_triangulation_face_base_2<Kernel, FaceInfoBase>;
using Tds = CGAL::Triangulation_data_structure_2<VertexBase, FaceBase>;
using Cdt = CGAL::Constrained_Delaunay_triangulation_2<Kernel, Tds, CGAL::No_constraint_intersection_tag>;

/// Nesting depth of every face (CGAL's polygon-with-holes recipe): 0 outside every polygon, one
/// more each time a constraint is crossed; odd depths are inside.
void markDepths(Cdt& cdt)
{
    for (auto f : cdt.all_face_handles()) f->info() = -1;
    std::deque<Cdt::Edge> border;
    auto flood = [&](Cdt::Face_handle start, int depth) {
        if (start->info() != -1) return;
        std::deque<Cdt::Face_handle> queue{start};
        while (!queue.empty()) {
            const Cdt::Face_handle f = queue.front();
            queue.pop_front();
            if (f->info() != -1) continue;
            f->info() = depth;
            for (int i = 0; i < 3; ++i) {
                const Cdt::Face_handle n = f->neighbor(i);
                if (n->info() != -1) continue;
                if (cdt.is_constrained(Cdt::Edge(f, i)))
                    border.push_back(Cdt::Edge(f, i));
                else
                    queue.push_back(n);
            }
        }
    };
    flood(cdt.infinite_face(), 0);
    while (!border.empty()) {
        const Cdt::Edge e = border.front();
        border.pop_front();
        const Cdt::Face_handle n = e.first->neighbor(e.second);
        if (n->info() == -1) flood(n, e.first->info() + 1);
    }
}

/// Triangulates the cap of face @a face bounded by @a segments (vertex pairs); appends its
/// triangles, facing out of the box, to @a out. Empty optional when it fails (constraints that
/// cross, points that coincide in the face).
std::optional<std::string> capFace(const Work& w, int face,
                                   const std::vector<std::pair<std::uint32_t, std::uint32_t>>& segments,
                                   std::vector<Tri>& out)
{
    if (segments.empty()) return std::nullopt;
    const int axis = face / 2, u = (axis + 1) % 3, v = (axis + 2) % 3;
    std::vector<std::uint32_t> ids;
    for (const auto& [a, b] : segments) {
        ids.push_back(a);
        ids.push_back(b);
    }
    std::sort(ids.begin(), ids.end());
    ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
    // Every cap vertex ends an even number of segments, or the polygons are not closed.
    std::vector<int> degree(ids.size(), 0);
    auto slot = [&](std::uint32_t id) {
        return std::size_t(std::lower_bound(ids.begin(), ids.end(), id) - ids.begin());
    };
    for (const auto& [a, b] : segments) {
        ++degree[slot(a)];
        ++degree[slot(b)];
    }
    for (int d : degree)
        if (d % 2) return "a crease polygon on face " + std::to_string(face) + " is not closed";

    std::vector<std::pair<Kernel::Point_2, std::uint32_t>> points;
    points.reserve(ids.size());
    for (std::uint32_t id : ids) points.emplace_back(Kernel::Point_2(w.points[id][u], w.points[id][v]), id);
    Cdt cdt;
    std::vector<Cdt::Vertex_handle> handle(ids.size());
    try {
        cdt.insert(points.begin(), points.end());
        if (cdt.number_of_vertices() != ids.size()) return "two cap points coincide on face " + std::to_string(face);
        for (auto vh : cdt.finite_vertex_handles()) handle[slot(vh->info())] = vh;
        for (const auto& [a, b] : segments) {
            if (a == b) return "a crease segment on face " + std::to_string(face) + " has no length";
            cdt.insert_constraint(handle[slot(a)], handle[slot(b)]);
        }
    } catch (const std::exception&) {
        return "crease polygons cross on face " + std::to_string(face);
    }
    if (cdt.number_of_vertices() != ids.size()) return "crease polygons cross on face " + std::to_string(face);
    markDepths(cdt);
    const double outward = face % 2 ? 1.0 : -1.0;
    for (auto f : cdt.finite_face_handles()) {
        if (f->info() % 2 == 0) continue;
        Tri t{f->vertex(0)->info(), f->vertex(1)->info(), f->vertex(2)->info()};
        const Vec3d n = (w.points[t[1]] - w.points[t[0]]).cross(w.points[t[2]] - w.points[t[0]]);
        if (n[axis] * outward < 0.0) std::swap(t[1], t[2]);
        out.push_back(t);
    }
    return std::nullopt;
}

}  // namespace

std::size_t flipFlatTriangles(TriangleMesh& mesh, std::size_t first)
{
    auto area2 = [&](const openvdb::Vec3I& t) {
        const Vec3d a = toDouble(mesh.points[t[0]]), b = toDouble(mesh.points[t[1]]), c = toDouble(mesh.points[t[2]]);
        return (b - a).cross(c - a);
    };
    auto key = [](std::uint32_t from, std::uint32_t to) { return std::uint64_t(from) << 32 | to; };
    constexpr std::size_t kNone = std::numeric_limits<std::size_t>::max();
    struct Flat {
        std::size_t triangle;
        int longest;                 ///< its longest edge runs from corner `longest` to the next
        std::size_t across = kNone;  ///< the triangle across that edge
    };
    std::size_t flipped = 0;
    for (int round = 0; round < 3; ++round) {
        // Each flat triangle's longest edge, keyed as the neighbour across it runs it.
        std::vector<Flat> flats;
        std::map<std::uint64_t, std::size_t> wanted;  // edge -> index in flats
        for (std::size_t t = first; t < mesh.triangles.size(); ++t) {
            const openvdb::Vec3I& tri = mesh.triangles[t];
            if (tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] || area2(tri).lengthSqr() != 0.0) continue;
            int longest = 0;
            double length = -1.0;
            for (int i = 0; i < 3; ++i) {
                const double l = (toDouble(mesh.points[tri[(i + 1) % 3]]) - toDouble(mesh.points[tri[i]])).lengthSqr();
                if (l > length) {
                    length = l;
                    longest = i;
                }
            }
            if (!(length > 0.0)) continue;  // its corners coincide: no flip helps
            if (wanted.emplace(key(tri[(longest + 1) % 3], tri[longest]), flats.size()).second)
                flats.push_back({t, longest});
        }
        if (flats.empty()) break;
        // The neighbours: only triangles with a corner that starts a wanted edge are looked up.
        std::vector<std::uint8_t> starts(mesh.points.size(), 0);
        for (const auto& [edge, k] : wanted) starts[edge >> 32] = 1;
        for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
            const openvdb::Vec3I& tri = mesh.triangles[t];
            if (!starts[tri[0]] && !starts[tri[1]] && !starts[tri[2]]) continue;
            for (int i = 0; i < 3; ++i)
                if (const auto it = wanted.find(key(tri[i], tri[(i + 1) % 3])); it != wanted.end())
                    flats[it->second].across = t;
        }
        std::vector<std::uint8_t> changed(mesh.triangles.size(), 0);
        std::size_t flips = 0;
        for (const Flat& f : flats) {
            const std::size_t t = f.triangle, n = f.across;
            if (n == kNone || changed[t] || changed[n]) continue;
            const openvdb::Vec3I tri = mesh.triangles[t], other = mesh.triangles[n];
            // The flat triangle (a, b, c) with c on the edge a-b; the neighbour (b, a, d).
            const std::uint32_t a = tri[f.longest], b = tri[(f.longest + 1) % 3], c = tri[(f.longest + 2) % 3];
            std::uint32_t d = other[0];
            for (int i = 0; i < 3; ++i)
                if (other[i] != a && other[i] != b) d = other[i];
            const openvdb::Vec3I first1(a, d, c), second1(d, b, c);
            const Vec3d facing = area2(other);
            if (!(area2(first1).dot(facing) > 0.0) || !(area2(second1).dot(facing) > 0.0)) continue;
            mesh.triangles[t] = first1;
            mesh.triangles[n] = second1;
            changed[t] = changed[n] = 1;
            ++flips;
        }
        flipped += flips;
        if (flips == 0) break;
    }
    return flipped;
}

void dropTrianglesOutside(TriangleMesh& mesh, const Box3& box, double margin)
{
    std::vector<std::uint8_t> far(mesh.points.size(), 0);
    for (std::size_t v = 0; v < mesh.points.size(); ++v)
        for (int f = 0; f < kFaces; ++f) far[v] |= outside(toDouble(mesh.points[v]), box, f) > margin;
    std::erase_if(mesh.triangles, [&](const openvdb::Vec3I& t) { return far[t[0]] || far[t[1]] || far[t[2]]; });
    std::vector<std::int64_t> index(mesh.points.size(), -1);
    for (const openvdb::Vec3I& t : mesh.triangles)
        for (int i = 0; i < 3; ++i) index[t[i]] = 0;
    std::size_t n = 0;
    for (std::size_t v = 0; v < mesh.points.size(); ++v)
        if (index[v] == 0) {
            index[v] = std::int64_t(n);
            mesh.points[n++] = mesh.points[v];
        }
    mesh.points.resize(n);
    for (openvdb::Vec3I& t : mesh.triangles)
        for (int i = 0; i < 3; ++i) t[i] = std::uint32_t(index[t[i]]);
}

BoxClipStats clipToBox(TriangleMesh& mesh, const FieldNode& field, const Box3& box, const BoxClipOptions& options,
                       const ProgressFn& progress)
{
    BoxClipStats stats;
    PhaseProgress phases(progress);
    phases.begin(0.0);
    const std::size_t original = mesh.points.size(), numTriangles = mesh.triangles.size();
    // A point within snap of a face is put onto it (in double), the faces it lies on kept as bits.
    auto snapped = [&](std::size_t i, std::uint8_t& faces) {
        Vec3d p = toDouble(mesh.points[i]);
        faces = 0;
        for (int f = 0; f < kFaces; ++f)
            if (std::abs(outside(p, box, f)) <= options.snap) {
                p[f / 2] = planeOf(box, f);
                faces |= std::uint8_t(1u << f);
            }
        return p;
    };
    // Triangles with every corner strictly inside the box (deep: on no face either) are neither
    // cut nor part of a cut's edge: set aside, put back first, unchanged with their corners.
    // Only the others (a band along the faces) and their corners are worked on.
    std::vector<std::uint8_t> deep(original);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, original, 1 << 14), [&](const auto& range) {
        for (std::size_t i = range.begin(); i != range.end(); ++i) {
            std::uint8_t faces;
            const Vec3d p = snapped(i, faces);
            bool inside = faces == 0;
            for (int f = 0; f < kFaces; ++f) inside = inside && outside(p, box, f) < 0.0;
            deep[i] = inside;
        }
        phases.check();
    });
    // Per fixed block of triangles: how many are inner and the others' indices; the points the
    // inner ones use are flagged (the same flag from any thread).
    constexpr std::size_t kBlock = 1 << 14;
    const std::size_t numBlocks = (numTriangles + kBlock - 1) / kBlock;
    std::vector<std::size_t> innerBefore(numBlocks + 1, 0);
    std::vector<std::vector<std::uint32_t>> outer(numBlocks);
    std::vector<std::uint8_t> keep(original, 0);
    auto isInner = [&](const openvdb::Vec3I& t) { return deep[t[0]] && deep[t[1]] && deep[t[2]]; };
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numBlocks, 1), [&](const auto& range) {
        for (std::size_t b = range.begin(); b != range.end(); ++b)
            for (std::size_t t = b * kBlock; t < std::min(numTriangles, (b + 1) * kBlock); ++t) {
                const openvdb::Vec3I& tri = mesh.triangles[t];
                if (!isInner(tri)) {
                    outer[b].push_back(std::uint32_t(t));
                    continue;
                }
                ++innerBefore[b + 1];
                for (int k = 0; k < 3; ++k)
                    std::atomic_ref<std::uint8_t>(keep[tri[k]]).store(1, std::memory_order_relaxed);
            }
        phases.check();
    });
    std::partial_sum(innerBefore.begin(), innerBefore.end(), innerBefore.begin());

    // The band's points in ascending order, numbered from 0 (local indices keep the order of the
    // mesh's, so every choice by index below comes out as on the whole mesh).
    std::vector<std::uint8_t> inBand(original, 0);
    for (const auto& list : outer)
        for (std::uint32_t t : list)
            for (int k = 0; k < 3; ++k) inBand[mesh.triangles[t][k]] = 1;
    std::vector<std::vector<std::uint32_t>> bandBlocks((original + kBlock - 1) / kBlock);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, bandBlocks.size(), 1), [&](const auto& range) {
        for (std::size_t b = range.begin(); b != range.end(); ++b)
            for (std::size_t v = b * kBlock; v < std::min(original, (b + 1) * kBlock); ++v)
                if (inBand[v]) bandBlocks[b].push_back(std::uint32_t(v));
    });
    std::vector<std::uint32_t> band;
    for (const auto& list : bandBlocks) band.insert(band.end(), list.begin(), list.end());
    auto local = [&](std::uint32_t v) {
        return std::uint32_t(std::lower_bound(band.begin(), band.end(), v) - band.begin());
    };
    Work w;
    w.points.resize(band.size());
    w.faces.resize(band.size());
    for (std::size_t i = 0; i < band.size(); ++i) w.points[i] = snapped(band[i], w.faces[i]);
    for (const auto& list : outer)
        for (std::uint32_t t : list) {
            const openvdb::Vec3I& tri = mesh.triangles[t];
            w.triangles.push_back({local(tri[0]), local(tri[1]), local(tri[2])});
        }
    w.leftOnEdge.assign(band.size(), 0);
    const std::size_t bandPoints = band.size();
    phases.begin(0.2);
    for (int f = 0; f < kFaces; ++f) {
        cutByFace(w, f, field, box, options, stats);
        phases.begin(0.2 + 0.1 * (f + 1));
    }
    const std::size_t cutPoints = w.points.size();

    // A triangle lying in a face (all its corners on it) is the cap's: dropped.
    std::erase_if(w.triangles, [&](const Tri& t) { return (w.faces[t[0]] & w.faces[t[1]] & w.faces[t[2]]) != 0; });

    // The cut's edges: used by one triangle, both ends on the face they lie in (an edge elsewhere
    // used once is an open edge the closing check below finds).
    std::vector<std::pair<std::uint32_t, std::uint32_t>> undirected;
    for (const Tri& t : w.triangles)
        for (int i = 0; i < 3; ++i) {
            const std::uint32_t a = t[i], b = t[(i + 1) % 3];
            if (w.faces[a] & w.faces[b]) undirected.push_back(std::minmax(a, b));
        }
    std::sort(undirected.begin(), undirected.end());
    std::array<std::vector<std::pair<std::uint32_t, std::uint32_t>>, kFaces> segments;
    for (std::size_t i = 0; i < undirected.size();) {
        std::size_t j = i;
        while (j < undirected.size() && undirected[j] == undirected[i]) ++j;
        if (j - i > 2) {
            stats.failure = "an edge is shared by more than two triangles";
            return stats;
        }
        if (j - i == 1) {
            const auto [a, b] = undirected[i];
            const std::uint8_t common = w.faces[a] & w.faces[b];
            if (common == 0 || (common & (common - 1)) != 0) {
                stats.failure = "a cut edge does not lie in exactly one face of the box";
                return stats;
            }
            segments[std::size_t(std::countr_zero(unsigned(common)))].push_back(undirected[i]);
        }
        i = j;
    }

    // The box's edges: between consecutive crease points on each (and its corners), the pieces
    // whose middle lies inside the solid belong to both faces' caps.
    std::array<std::int64_t, 8> cornerIndex;
    cornerIndex.fill(-1);
    std::vector<std::uint8_t> used(w.points.size(), 0);
    for (const Tri& t : w.triangles)
        for (std::uint32_t v : t) used[v] = 1;
    constexpr std::uint32_t kCornerIds = 0xfffffff8u;  // ids of the eight corners along an edge
    for (int a = 0; a < 3; ++a) {
        const int b = (a + 1) % 3, c = (a + 2) % 3;  // the edge runs along a; sides on b and c
        for (int sb = 0; sb < 2; ++sb)
            for (int sc = 0; sc < 2; ++sc) {
                const std::uint8_t fb = std::uint8_t(1u << (2 * b + sb)), fc = std::uint8_t(1u << (2 * c + sc));
                std::vector<std::pair<double, std::uint32_t>> along;
                for (std::size_t v = 0; v < used.size(); ++v)  // the corners added below have their own ids
                    if (used[v] && (w.faces[v] & fb) && (w.faces[v] & fc))
                        along.emplace_back(w.points[v][a], std::uint32_t(v));
                for (int sa = 0; sa < 2; ++sa) {
                    const int corner = (sa << a) | (sb << b) | (sc << c);
                    Vec3d x;
                    x[a] = sa ? box.max[a] : box.min[a];
                    x[b] = sb ? box.max[b] : box.min[b];
                    x[c] = sc ? box.max[c] : box.min[c];
                    along.emplace_back(x[a], 0xffffffffu - std::uint32_t(corner));
                }
                std::sort(along.begin(), along.end());
                for (std::size_t k = 0; k + 1 < along.size(); ++k) {
                    auto pointOf = [&](std::uint32_t id) {
                        if (id < kCornerIds) return w.points[id];
                        const int corner = int(0xffffffffu - id);
                        Vec3d x;
                        for (int ax = 0; ax < 3; ++ax) x[ax] = (corner >> ax & 1) ? box.max[ax] : box.min[ax];
                        return x;
                    };
                    const Vec3d mid = 0.5 * (pointOf(along[k].second) + pointOf(along[k + 1].second));
                    std::array<double, 1> value;
                    field.values(std::span<const Vec3d>(&mid, 1), value);
                    if (!(value[0] < options.level)) continue;
                    std::array<std::uint32_t, 2> ends;
                    for (int e = 0; e < 2; ++e) {
                        const std::uint32_t id = along[k + e].second;
                        if (id < kCornerIds) {
                            ends[e] = id;
                            continue;
                        }
                        const int corner = int(0xffffffffu - id);
                        if (cornerIndex[std::size_t(corner)] < 0) {
                            cornerIndex[std::size_t(corner)] = std::int64_t(w.points.size());
                            w.points.push_back(pointOf(id));
                            std::uint8_t bits = 0;
                            for (int ax = 0; ax < 3; ++ax) bits |= std::uint8_t(1u << (2 * ax + (corner >> ax & 1)));
                            w.faces.push_back(bits);
                            ++stats.corners;
                        }
                        ends[e] = std::uint32_t(cornerIndex[std::size_t(corner)]);
                    }
                    segments[std::size_t(2 * b + sb)].emplace_back(ends[0], ends[1]);
                    segments[std::size_t(2 * c + sc)].emplace_back(ends[0], ends[1]);
                }
            }
    }

    phases.begin(0.8);
    // The six caps are independent: triangulated in parallel, joined (and the first failure
    // taken) in face order.
    std::array<std::vector<Tri>, kFaces> caps;
    std::array<std::optional<std::string>, kFaces> failures;
    tbb::parallel_for(0, kFaces, [&](int f) {
        failures[std::size_t(f)] = capFace(w, f, segments[std::size_t(f)], caps[std::size_t(f)]);
    });
    for (int f = 0; f < kFaces; ++f)
        if (failures[std::size_t(f)]) {
            stats.failure = *failures[std::size_t(f)];
            return stats;
        }
    for (const std::vector<Tri>& cap : caps) {
        stats.capTriangles += cap.size();
        w.triangles.insert(w.triangles.end(), cap.begin(), cap.end());
    }

    // Only the vertices the triangles use, in their order (the new ones after the mesh's own):
    // the mesh's points the inner triangles use as they were, the band's as cut, then the new ones.
    TriangleMesh result;
    std::vector<std::int64_t> bandIndex(w.points.size(), -1);
    for (const Tri& t : w.triangles)
        for (std::uint32_t v : t) bandIndex[v] = 0;
    for (std::size_t v = 0; v < bandPoints; ++v)
        if (bandIndex[v] == 0) keep[band[v]] = 1;
    for (std::size_t v = bandPoints; v < cutPoints; ++v)
        if (bandIndex[v] == 0) {
            ++stats.creaseVertices;
            stats.leftOnEdge += w.leftOnEdge[v];
        }
    // Fixed blocks of points: their used counts, then each block's new indices from its offset.
    const std::size_t numPointBlocks = (original + kBlock - 1) / kBlock;
    std::vector<std::size_t> usedBefore(numPointBlocks + 1, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numPointBlocks, 1), [&](const auto& range) {
        for (std::size_t b = range.begin(); b != range.end(); ++b)
            for (std::size_t v = b * kBlock; v < std::min(original, (b + 1) * kBlock); ++v)
                usedBefore[b + 1] += keep[v];
    });
    std::partial_sum(usedBefore.begin(), usedBefore.end(), usedBefore.begin());
    std::size_t numNew = 0;
    for (std::size_t v = bandPoints; v < w.points.size(); ++v) numNew += bandIndex[v] == 0;
    result.points.resize(usedBefore.back() + numNew);
    std::vector<std::uint32_t> index(original);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numPointBlocks, 1), [&](const auto& range) {
        for (std::size_t b = range.begin(); b != range.end(); ++b) {
            std::size_t n = usedBefore[b];
            for (std::size_t v = b * kBlock; v < std::min(original, (b + 1) * kBlock); ++v)
                if (keep[v]) {
                    index[v] = std::uint32_t(n);
                    result.points[n++] = mesh.points[v];
                }
        }
    });
    // The band's points as snapped (the deep ones among them the same), the new ones after all.
    std::size_t n = usedBefore.back();
    for (std::size_t v = 0; v < w.points.size(); ++v) {
        if (bandIndex[v] != 0) continue;
        if (v < bandPoints) {
            bandIndex[v] = index[band[v]];
            result.points[std::size_t(bandIndex[v])] = toFloat(w.points[v]);
        } else {
            bandIndex[v] = std::int64_t(n);
            result.points[n++] = toFloat(w.points[v]);
        }
    }
    const std::size_t numInner = innerBefore.back();
    result.triangles.resize(numInner + w.triangles.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numBlocks, 1), [&](const auto& range) {
        for (std::size_t b = range.begin(); b != range.end(); ++b) {
            std::size_t k = innerBefore[b];
            for (std::size_t t = b * kBlock; t < std::min(numTriangles, (b + 1) * kBlock); ++t) {
                const openvdb::Vec3I& tri = mesh.triangles[t];
                if (isInner(tri)) result.triangles[k++] = openvdb::Vec3I(index[tri[0]], index[tri[1]], index[tri[2]]);
            }
        }
    });
    for (std::size_t t = 0; t < w.triangles.size(); ++t) {
        const Tri& tri = w.triangles[t];
        result.triangles[numInner + t] = openvdb::Vec3I(
            std::uint32_t(bandIndex[tri[0]]), std::uint32_t(bandIndex[tri[1]]), std::uint32_t(bandIndex[tri[2]]));
    }
    phases.begin(0.9);
    flipFlatTriangles(result, numInner);
    if (!options.checkTopology) {
        mesh = std::move(result);
        stats.ok = true;
        return stats;
    }
    const MeshTopology topology = checkTopology(result, nullptr, progressPart(progress, 0.9, 1.0));
    if (!topology.closedManifold()) {
        stats.failure = "the capped mesh is not closed and manifold (" + std::to_string(topology.boundaryEdges) +
                        " open edges, " + std::to_string(topology.nonManifoldEdges) + " shared by more than two, " +
                        std::to_string(topology.nonManifoldVertices) + " vertices joining separate fans, " +
                        std::to_string(topology.inconsistentlyOrientedEdges) + " edges oriented against their " +
                        "neighbour, " + std::to_string(topology.degenerateTriangles) + " triangles repeating a corner)";
        return stats;
    }
    phases.begin(1.0);
    mesh = std::move(result);
    stats.topology = topology;
    stats.ok = true;
    return stats;
}

}  // namespace voxlat
