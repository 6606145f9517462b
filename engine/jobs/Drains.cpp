#include "engine/jobs/Drains.h"

#include "engine/checks/Traps.h"
#include "engine/core/Format.h"

#include <algorithm>
#include <cmath>

namespace voxlat {

namespace {

/// Cavities smaller than this many samples are crumbs of the sampling, not traps worth a hole.
constexpr std::uint64_t kCrumbSamples = 8;

nlohmann::json vec(const Vec3d& v)
{
    return {v[0], v[1], v[2]};
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
        const std::vector<Trap> traps = findTraps(*d.node->solid(), box, spacing, context, d.part ? nullptr : &open);
        const FieldNode& part = d.part ? *d.part : *open;
        std::vector<DrainChannel> channels;
        nlohmann::json holes = nlohmann::json::array();
        std::uint64_t crumbs = 0;
        const double limit = box.extent().length();
        for (const Trap& trap : traps) {
            if (trap.samples < kCrumbSamples) {
                ++crumbs;
                continue;
            }
            // The part's lowest face stands on the build plate, which closes a hole there: the
            // channel leaves at the cavity's lowest point straight down only where it comes out
            // above the plate, else sideways (the shortest of +-x, +-y) at the same height, kept a
            // radius and a sample above the plate; where neither way out exists, along the
            // part's outward normal (the thinnest wall).
            const double plate = support->min.z();
            Vec3d p = trap.lowest;
            const double step = 0.25 * spacing;
            struct Way {
                Vec3d dir;
                const char* placed;
            };
            const Way ways[] = {{{0, 0, -1}, "the cavity's lowest point, straight down"},
                                {{-1, 0, 0}, "the cavity's lowest point, sideways (-x)"},
                                {{1, 0, 0}, "the cavity's lowest point, sideways (+x)"},
                                {{0, -1, 0}, "the cavity's lowest point, sideways (-y)"},
                                {{0, 1, 0}, "the cavity's lowest point, sideways (+y)"}};
            const Way* best = nullptr;
            double reach = limit, bestCost = 0.0;
            for (const Way& w : ways) {
                Vec3d from = p;
                if (w.dir.z() == 0.0) from.z() = std::max(p.z(), plate + 0.5 * d.diameter + spacing);
                const double t = exitDistance(part, from, w.dir, step, limit);
                if (t >= limit) continue;  // never leaves the part within its box
                const Vec3d exit = from + t * w.dir;
                if (w.dir.z() < 0.0 && exit.z() - 0.5 * d.diameter < plate + spacing) continue;  // onto the plate
                // Straight down is preferred while it is no longer than a sideways way by a diameter.
                const double cost = t - (w.dir.z() < 0.0 ? d.diameter : 0.0);
                if (!best || cost < bestCost) {
                    best = &w;
                    reach = t;
                    bestCost = cost;
                }
            }
            Vec3d dir;
            const char* placed;
            if (best) {
                dir = best->dir;
                placed = best->placed;
                if (dir.z() == 0.0) p.z() = std::max(p.z(), plate + 0.5 * d.diameter + spacing);
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
            holes.push_back({{"position", vec(c.from)},
                             {"direction", vec(dir)},
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
