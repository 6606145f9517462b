#include "engine/jobs/Drains.h"

#include "engine/checks/Traps.h"
#include "engine/core/Format.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

namespace voxlat {

namespace {

/// Cavities smaller than this many samples are crumbs of the sampling, not traps worth a hole.
constexpr std::uint64_t kCrumbSamples = 8;

nlohmann::json xyzJson(const Vec3d& v)
{
    return {v[0] + 0.0, v[1] + 0.0, v[2] + 0.0};  // no -0 (a direction negated)
}

/// "+x" for an axis, else "[x, y, z]".
std::string directionName(const Vec3d& v)
{
    for (int a = 0; a < 3; ++a)
        if (std::abs(std::abs(v[a]) - 1.0) < 1e-12) return std::string(v[a] > 0 ? "+" : "-") + "xyz"[a];
    return "[" + formatNumber(v[0]) + ", " + formatNumber(v[1]) + ", " + formatNumber(v[2]) + "]";
}

/// How far from @a p along @a dir the part is left (its value positive), in steps of @a step up
/// to @a limit; limit when it is not left.
double exitDistance(const FieldNode& part, const Vec3d& p, const Vec3d& dir, double step, double limit)
{
    for (double t = 0.0; t <= limit; t += step)
        if (part.value(p + t * dir) > 0.0) return t;
    return limit;
}

}  // namespace

nlohmann::json planDrains(const std::vector<DrainRequest>& drains, double voxel, const JobContext* context)
{
    nlohmann::json out = nlohmann::json::object();
    for (const DrainRequest& d : drains) {
        const std::optional<Box3> support = d.node->solid()->support();
        if (!support) {
            d.node->setChannels({});
            continue;
        }
        // Finer than the wall and the channel, and never finer than the recipe's voxel.
        const double spacing = std::max(voxel, 0.5 * std::min(d.wall, d.diameter));
        const Box3 box{support->min - Vec3d(2.0 * spacing), support->max + Vec3d(2.0 * spacing)};
        // A part's outside is where its field is positive; a result drained for its slices has
        // no part, and its outside is the void the search reaches from the faces of its box.
        std::shared_ptr<const FieldNode> open;
        double lowestSolid = 0.0;
        const std::vector<Trap> traps =
            findTraps(*d.node->solid(), box, spacing, context, d.part ? nullptr : &open, d.up, &lowestSolid);
        const FieldNode& part = d.part ? *d.part : *open;
        std::vector<DrainChannel> channels;
        nlohmann::json holes = nlohmann::json::array();
        std::uint64_t crumbs = 0;
        const double limit = box.extent().length();
        // The build direction and two directions across it (x and y for +z). The plate is the
        // part's lowest extent along it: along an axis its support box's face, else its lowest
        // solid sample (a box's corner lies below an oblique part's bottom).
        const Vec3d up = d.up;
        Vec3d across = std::abs(up.x()) < 0.9 ? Vec3d(1, 0, 0) : Vec3d(0, 1, 0);
        across = across - across.dot(up) * up;
        across.normalize();
        const Vec3d across2 = up.cross(across);
        const bool alongAxis = std::abs(std::abs(up.x()) + std::abs(up.y()) + std::abs(up.z()) - 1.0) < 1e-12;
        double plate = lowestSolid;
        if (alongAxis) {
            plate = std::numeric_limits<double>::infinity();
            for (int c = 0; c < 8; ++c) {
                const Vec3d corner(c & 1 ? support->max.x() : support->min.x(),
                                   c & 2 ? support->max.y() : support->min.y(),
                                   c & 4 ? support->max.z() : support->min.z());
                plate = std::min(plate, corner.dot(up));
            }
        }
        struct Way {
            Vec3d dir;
            std::string placed;
        };
        const std::vector<Way> ways{{-up, "the cavity's lowest point, straight down"},
                                    {-across, "the cavity's lowest point, sideways (" + directionName(-across) + ")"},
                                    {across, "the cavity's lowest point, sideways (" + directionName(across) + ")"},
                                    {-across2, "the cavity's lowest point, sideways (" + directionName(-across2) + ")"},
                                    {across2, "the cavity's lowest point, sideways (" + directionName(across2) + ")"}};
        for (const Trap& trap : traps) {
            if (trap.samples < kCrumbSamples) {
                ++crumbs;
                continue;
            }
            // The part's lowest face (along the build direction) stands on the build plate,
            // which closes a hole there: the channel leaves at the cavity's lowest point straight
            // down (against the build direction) only where it comes out above the plate, else
            // sideways (the shortest of four directions across the build direction) at the same
            // height, kept a radius and a sample above the plate; where neither way out exists,
            // along the part's outward normal (the thinnest wall).
            Vec3d p = trap.lowest;
            const double step = 0.25 * spacing;
            // A sideways channel's height: a radius and a sample above the plate (along an axis
            // the coordinate is set, so +z gives the bytes it always gave).
            const double height = plate + 0.5 * d.diameter + spacing;
            auto raised = [&](Vec3d q) {
                const double h = q.dot(up);
                if (h >= height) return q;
                if (!alongAxis) return Vec3d(q + (height - h) * up);
                for (int a = 0; a < 3; ++a)
                    if (up[a] != 0.0) q[a] = height * up[a];  // up[a] is +-1
                return q;
            };
            const Way* best = nullptr;
            double reach = limit, bestCost = 0.0;
            for (const Way& w : ways) {
                const bool down = w.dir.dot(up) < -0.5;
                const Vec3d from = down ? p : raised(p);
                const double t = exitDistance(part, from, w.dir, step, limit);
                if (t >= limit) continue;  // never leaves the part within its box
                const Vec3d exit = from + t * w.dir;
                if (down && exit.dot(up) - 0.5 * d.diameter < plate + spacing) continue;  // onto the plate
                // Straight down is preferred while it is no longer than a sideways way by a diameter.
                const double cost = t - (down ? d.diameter : 0.0);
                if (!best || cost < bestCost) {
                    best = &w;
                    reach = t;
                    bestCost = cost;
                }
            }
            Vec3d dir;
            std::string placed;
            if (best) {
                dir = best->dir;
                placed = best->placed;
                if (dir.dot(up) > -0.5) p = raised(p);
            } else {
                Vec3d normal = part.valueAndGradient(p).second;
                const double length = normal.length();
                dir = length > 0.0 ? normal / length : Vec3d(1, 0, 0);
                placed = "the thinnest wall (the part's outward normal)";
                reach = exitDistance(part, p, dir, step, limit);
            }
            // From half a sample inside the cavity to a radius and a sample past the part's surface.
            DrainChannel c{p - 0.5 * spacing * dir, p + (reach + 0.5 * d.diameter + spacing) * dir, d.diameter};
            channels.push_back(c);
            holes.push_back({{"position", xyzJson(c.from)},
                             {"direction", xyzJson(dir)},
                             {"length_mm", (c.to - c.from).length()},
                             {"through_wall_mm", reach},
                             {"placed", placed},
                             {"trap_volume_mm3", trap.volumeMm3}});
        }
        d.node->setChannels(channels);
        // The drained solid, searched again: what is left is told with numbers.
        const std::vector<Trap> left = channels.empty() ? traps : findTraps(*d.node, box, spacing, context);
        std::uint64_t leftTraps = 0;
        double leftVolume = 0.0;
        for (const Trap& t : left)
            if (t.samples >= kCrumbSamples) {
                ++leftTraps;
                leftVolume += t.volumeMm3;
            }
        double found = 0.0;
        for (const Trap& t : traps) found += t.volumeMm3;
        out[d.name] = {{"diameter_mm", d.diameter},
                       {"build_direction", xyzJson(up)},
                       {"search_spacing_mm", spacing},
                       {"traps_found", traps.size() - crumbs},
                       {"trap_volume_mm3", found},
                       {"crumbs_below_samples", kCrumbSamples},
                       {"crumbs", crumbs},
                       {"holes", holes},
                       {"traps_left", leftTraps},
                       {"trap_volume_left_mm3", leftVolume}};
        if (leftTraps > 0 && context)
            context->warn("drain_incomplete",
                          d.where + ": " + std::to_string(leftTraps) + " closed cavit" +
                              (leftTraps == 1 ? "y" : "ies") + " (" + formatNumber(leftVolume) +
                              " mm^3) remain after " + std::to_string(channels.size()) +
                              " drain channel(s): a channel crossed another cavity or a cavity is narrower than " +
                              formatNumber(spacing) + " mm; raise the diameter or add a shell opening",
                          {{"field", d.name}, {"traps_left", leftTraps}, {"volume_mm3", leftVolume}});
    }
    return out;
}

}  // namespace voxlat
