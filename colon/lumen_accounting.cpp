#include "colon/lumen_accounting.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <iomanip>
#include <sstream>
#include <unordered_map>

namespace flyover {

using namespace lumen_index;

namespace {

struct CoordHash {
    std::size_t operator()(const Coord& c) const
    {
        return std::hash<std::int64_t>()((std::int64_t(c[0]) * 73856093) ^ (std::int64_t(c[1]) * 19349663) ^
                                         (std::int64_t(c[2]) * 83492791));
    }
};

/// Multi-source breadth-first flood from the path's voxels: owner (path index, -1 unreached) and
/// steps (26-neighbour steps from it) per slot.
void floodFromPath(const LumenIndex& index, const openvdb::math::Transform& xf, const Centerline& cl,
                   std::vector<std::int32_t>& owner, std::vector<std::int32_t>& steps)
{
    owner.assign(index.slotCount(), -1);
    steps.assign(index.slotCount(), -1);
    std::unordered_map<Coord, std::size_t, CoordHash> blockOf;
    blockOf.reserve(index.blockOrigin.size() * 2);
    for (std::size_t b = 0; b < index.blockOrigin.size(); ++b) blockOf.emplace(index.blockOrigin[b], b);
    SlotBits reached = holeBits(index);
    std::vector<Slot> queue;
    for (std::size_t i = 0; i < cl.points.size(); ++i) {
        if (cl.points[i].bridged) continue;
        const Vec3d& p = cl.points[i].positionMm;
        const openvdb::Vec3d ijk = xf.worldToIndex(openvdb::Vec3d(p.x, p.y, p.z));
        const Coord c(int(std::lround(ijk[0])), int(std::lround(ijk[1])), int(std::lround(ijk[2])));
        const Coord origin(c[0] & ~(LEAF_DIM - 1), c[1] & ~(LEAF_DIM - 1), c[2] & ~(LEAF_DIM - 1));
        const auto it = blockOf.find(origin);
        if (it == blockOf.end()) continue;
        const Coord o = c - origin;
        const Slot s = static_cast<Slot>(it->second * LEAF_VOXELS) +
                       static_cast<Slot>((o[0] << (2 * LEAF_LOG2)) | (o[1] << LEAF_LOG2) | o[2]);
        if (!index.isLumen(s) || reached.testAndSet(s)) continue;
        owner[s] = static_cast<std::int32_t>(i);
        steps[s] = 0;
        queue.push_back(s);
    }
    for (std::size_t head = 0; head < queue.size(); ++head) {
        const Slot s = queue[head];
        forEachClearNeighbour(index, reached, s, [&](Slot t) {
            reached.set(t);
            owner[t] = owner[s];
            steps[t] = steps[s] + 1;
            queue.push_back(t);
        });
    }
}

/// Distance (mm) from p to the polyline through `line`.
double distanceToPolyline(const Vec3d& p, const std::vector<Vec3d>& line)
{
    double best = line.empty() ? 0.0 : distance(p, line.front());
    for (std::size_t i = 1; i < line.size(); ++i) best = std::min(best, distanceToSegment(p, line[i - 1], line[i]));
    return best;
}

} // namespace

std::vector<LeftOutLumen> leftOutLumen(const LumenIndex& index, const openvdb::math::Transform& xf,
                                       const Centerline& cl, double minMl)
{
    std::vector<LeftOutLumen> out;
    if (cl.points.empty() || index.slotCount() == 0) return out;
    const double voxelMm = xf.voxelSize()[0];
    const double voxelMl = voxelMm * voxelMm * voxelMm / 1000.0;
    std::vector<std::int32_t> owner, steps;
    floodFromPath(index, xf, cl, owner, steps);
    // Bits set wherever a region may not grow: holes and the voxels within the path's reach.
    SlotBits done = bitsWhere(index, [&](Slot s) {
        if (!index.isLumen(s)) return true;
        if (owner[s] < 0) return false;
        const double reachMm = 2.0 * cl.points[std::size_t(owner[s])].radiusMm + 2.0 * voxelMm;
        return double(steps[s]) * voxelMm <= reachMm;
    });
    // The far tube the path leaves out (centerline_far_end.h) is reported on its own.
    const double branchReachMm = 3.0 * cl.leftOutBranchRadiusMm + 2.0 * voxelMm;
    std::vector<Slot> queue;
    for (Slot seed = 0; seed < index.slotCount(); ++seed) {
        if (done.test(seed)) continue;
        queue.assign(1, seed);
        done.set(seed);
        std::size_t count = 0;
        Vec3d sum{0, 0, 0};
        std::int32_t minSteps = -1, maxSteps = -1, mouthOwner = -1;
        std::size_t inBranch = 0;
        for (std::size_t head = 0; head < queue.size(); ++head) {
            const Slot s = queue[head];
            ++count;
            const openvdb::Vec3d w = xf.indexToWorld(index.coord(s));
            sum += Vec3d{w[0], w[1], w[2]};
            if (!cl.leftOutBranchMm.empty() &&
                distanceToPolyline(Vec3d{w[0], w[1], w[2]}, cl.leftOutBranchMm) <= branchReachMm)
                ++inBranch;
            if (owner[s] >= 0) {
                if (minSteps < 0 || steps[s] < minSteps) {
                    minSteps = steps[s];
                    mouthOwner = owner[s];
                }
                maxSteps = std::max(maxSteps, steps[s]);
            }
            forEachClearNeighbour(index, done, s, [&](Slot t) {
                done.set(t);
                queue.push_back(t);
            });
        }
        const double ml = double(count) * voxelMl;
        if (ml < minMl) continue;
        LeftOutLumen r;
        r.volumeMl = ml;
        r.centroidMm = sum / double(count);
        std::ostringstream why;
        why << std::fixed << std::setprecision(1) << r.volumeMl << " mL of lumen at (" << r.centroidMm.x << ", "
            << r.centroidMm.y << ", " << r.centroidMm.z << ") LPS mm ";
        if (2 * inBranch >= count) {
            r.kind = "far branch";
            r.arcMm = double(cl.points.size() - 1) * cl.stepMm;
            why << "is the narrow tube at the far end that the path leaves out (the terminal ileum or the "
                   "appendix; far_branch_left_out)";
        } else if (mouthOwner < 0) {
            r.kind = "separate piece";
            why << "is a separate piece that the path does not join (too small beside the largest, or no "
                   "plausible place in the chain)";
        } else {
            r.arcMm = double(mouthOwner) * cl.stepMm;
            const double reachMm = 2.0 * cl.points[std::size_t(mouthOwner)].radiusMm + 2.0 * voxelMm;
            r.extentMm = double(maxSteps) * voxelMm - reachMm;
            r.kind = r.extentMm < DEAD_END_MAX_MM ? "dead end" : "not entered";
            why << std::setprecision(0) << "off the path at arc " << r.arcMm << " mm, reaching " << r.extentMm
                << " mm beyond it: "
                << (r.kind == "dead end" ? "a dead end (a diverticulum, a haustral pouch or the appendix)"
                                         : "a stretch the path does not enter (a loop cut off at a contact, or "
                                           "skipped by the chain)");
        }
        r.reason = why.str();
        out.push_back(std::move(r));
    }
    std::sort(out.begin(), out.end(), [](const LeftOutLumen& a, const LeftOutLumen& b) { return a.volumeMl > b.volumeMl; });
    return out;
}

} // namespace flyover
