#include "colon/anatomy_segments.h"
#include "volume/vec3.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <stdexcept>

namespace flyover {

namespace {

struct Extent {
    double lo = 1e300, hi = -1e300;
    double mid() const { return 0.5 * (lo + hi); }
    double half() const { return 0.5 * (hi - lo); }
};

Extent extentAlong(const std::vector<Vec3d>& positions, const Vec3d& axis)
{
    Extent e;
    for (const Vec3d& p : positions) {
        const double v = dot(p, axis);
        e.lo = std::min(e.lo, v);
        e.hi = std::max(e.hi, v);
    }
    return e;
}

std::size_t pointsInArc(double arcMm, double stepMm)
{
    return std::size_t(std::max(0L, std::lround(arcMm / std::max(stepMm, 1e-9))));
}

CenterlineLandmark landmark(const char* name, const std::vector<Vec3d>& positions, std::size_t index, double stepMm)
{
    CenterlineLandmark l;
    l.name = name;
    l.index = index;
    l.arcMm = double(index) * stepMm;
    l.positionMm = positions[index];
    return l;
}

} // namespace

const std::vector<std::string>& anatomySegmentNames()
{
    static const std::vector<std::string> names{"rectum",     "sigmoid",         "descending", "splenic_flexure",
                                                "transverse", "hepatic_flexure", "ascending",  "cecum"};
    return names;
}

BodyAxes bodyAxesFromPatientFrame() { return BodyAxes{}; }

bool pathRunsLeftBeforeRight(const std::vector<Vec3d>& positions, const BodyAxes& axes)
{
    if (positions.size() < 3) return true;
    const Extent lateral = extentAlong(positions, axes.left);
    const Extent height = extentAlong(positions, axes.superior);
    const double upper = height.hi - (height.hi - height.lo) / 3.0;
    double leftSum = 0, rightSum = 0;
    std::size_t leftCount = 0, rightCount = 0;
    for (std::size_t i = 0; i < positions.size(); ++i) {
        if (dot(positions[i], axes.superior) < upper) continue;
        if (dot(positions[i], axes.left) >= lateral.mid()) {
            leftSum += double(i);
            ++leftCount;
        } else {
            rightSum += double(i);
            ++rightCount;
        }
    }
    if (leftCount == 0 || rightCount == 0) return true;  // nothing to tell the sides apart by
    return leftSum / double(leftCount) <= rightSum / double(rightCount);
}

BodyAxes bodyAxesFromPath(const std::vector<Vec3d>& positions)
{
    BodyAxes axes;
    if (positions.size() < 2) return axes;
    const std::array<Vec3d, 3> world{Vec3d{1, 0, 0}, Vec3d{0, 1, 0}, Vec3d{0, 0, 1}};
    std::array<Extent, 3> ext;
    for (int a = 0; a < 3; ++a) ext[a] = extentAlong(positions, world[a]);
    // Superior: the axis along which the anal end lies farthest (mm) from the middle of the
    // path's extent (the colon is tall, and the anal end is its bottom).
    int up = 2;
    double best = -1;
    for (int a = 0; a < 3; ++a) {
        const double off = std::abs(dot(positions.front(), world[a]) - ext[a].mid());
        if (off > best + 1e-9) {
            best = off;
            up = a;
        }
    }
    const double upSign = dot(positions.front(), world[up]) <= ext[up].mid() ? 1.0 : -1.0;
    axes.superior = world[up] * upSign;
    // Left: the wider of the other two, signed by the order of the high points.
    const int a1 = (up + 1) % 3, a2 = (up + 2) % 3;
    const int side = ext[a1].half() >= ext[a2].half() ? a1 : a2;
    axes.left = world[side];
    if (!pathRunsLeftBeforeRight(positions, axes)) axes.left = axes.left * -1.0;
    axes.posterior = cross(axes.superior, axes.left);
    return axes;
}

Flexures findFlexures(const std::vector<Vec3d>& positions, const BodyAxes& axes, const AnatomySegmentParams& params)
{
    Flexures f;
    const std::size_t n = positions.size();
    if (n < 3) return f;
    const Extent lateral = extentAlong(positions, axes.left);
    const double margin = params.flexureLateralFraction * lateral.half();
    // Splenic: the highest point on the left.
    double bestLeft = -1e300;
    bool haveLeft = false;
    for (std::size_t i = 0; i < n; ++i) {
        if (dot(positions[i], axes.left) < lateral.mid() + margin) continue;
        const double s = dot(positions[i], axes.superior);
        if (s > bestLeft) {
            bestLeft = s;
            f.splenic = i;
            haveLeft = true;
        }
    }
    if (!haveLeft || f.splenic + 2 >= n) return f;
    // Hepatic: the top of the right limb, climbed from the lowest point of the path's final
    // stretch (the cecum) until the path falls or swings medially.
    const std::size_t tail = std::max<std::size_t>(std::min<std::size_t>(n - f.splenic - 1, 100), n / 10);
    std::size_t start = n - 1;
    for (std::size_t i = n > tail ? n - tail : 0; i < n; ++i)
        if (i > f.splenic && dot(positions[i], axes.superior) < dot(positions[start], axes.superior)) start = i;
    std::size_t top = start;
    double topS = dot(positions[start], axes.superior);
    for (std::size_t i = start; i-- > f.splenic + 1;) {
        const double s = dot(positions[i], axes.superior);
        if (s > topS) {
            topS = s;
            top = i;
            continue;
        }
        const double medial = dot(positions[i], axes.left) - dot(positions[top], axes.left);
        if (topS - s > params.limbTurnStopMm || medial > params.limbMedialStopMm) break;
    }
    if (dot(positions[top], axes.left) <= lateral.mid() - margin) {
        f.hepatic = top;
        f.found = true;
        return f;
    }
    // The right limb's top is not on the right (no ascending colon there): the highest point
    // on the right after the splenic flexure.
    double bestRight = -1e300;
    for (std::size_t i = f.splenic + 1; i < n; ++i) {
        if (dot(positions[i], axes.left) > lateral.mid() - margin) continue;
        const double s = dot(positions[i], axes.superior);
        if (s > bestRight) {
            bestRight = s;
            f.hepatic = i;
            f.found = true;
        }
    }
    return f;
}

std::size_t findDescendingSigmoidJunction(const std::vector<Vec3d>& positions, const BodyAxes& axes,
                                          std::size_t splenic, const AnatomySegmentParams& params)
{
    std::size_t lowest = splenic;
    double lowS = dot(positions[splenic], axes.superior);
    for (std::size_t i = splenic; i-- > 0;) {
        const double s = dot(positions[i], axes.superior);
        if (s < lowS) {
            lowS = s;
            lowest = i;
            continue;
        }
        const double rise = s - lowS;
        const double medial = dot(positions[lowest], axes.left) - dot(positions[i], axes.left);
        if (rise > params.limbTurnStopMm || medial > params.limbMedialStopMm) break;
    }
    return lowest;
}

std::size_t findRectosigmoidJunction(const std::vector<Vec3d>& positions, const BodyAxes& axes, double stepMm,
                                     std::size_t limit, const AnatomySegmentParams& params)
{
    if (positions.empty()) return 0;
    const std::size_t guard = pointsInArc(10.0, stepMm);
    std::size_t cap = std::min(positions.size() - 1, pointsInArc(params.rectumMaxMm, stepMm));
    if (limit < positions.size()) cap = std::min(cap, limit > guard ? limit - guard : 0);
    const std::size_t chord = std::max<std::size_t>(1, pointsInArc(params.rectumChordMm, stepMm));
    const double minSin = std::sin(params.rectumMinElevationDeg * PI / 180.0);
    for (std::size_t i = pointsInArc(params.rectumMinMm, stepMm); i <= cap && i + chord < positions.size(); ++i) {
        const Vec3d d = positions[i + chord] - positions[i];
        const double len = length(d);
        if (len > 0 && dot(d, axes.superior) < minSin * len) return i;
    }
    return std::min(cap, pointsInArc(params.rectumDefaultMm, stepMm));
}

std::size_t findCecumStart(std::size_t pointCount, double stepMm, std::size_t hepatic,
                           const AnatomySegmentParams& params)
{
    if (pointCount == 0) return 0;
    const std::size_t last = pointCount - 1;
    const std::size_t byArc = pointsInArc(params.cecumMm, stepMm);
    const std::size_t third = hepatic < last ? (last - hepatic) / 3 : 0;
    return last - std::min(byArc, third);
}

AnatomySegments labelAnatomySegments(const Centerline& centerline, PatientFrame frame,
                                     const AnatomySegmentParams& params)
{
    AnatomySegments out;
    std::vector<Vec3d> pos;
    pos.reserve(centerline.points.size());
    for (const CenterlinePoint& p : centerline.points) pos.push_back(p.positionMm);
    const std::size_t n = pos.size();
    const double step = centerline.stepMm > 0 ? centerline.stepMm : 1.0;

    // 1. Body axes.
    if (frame == PatientFrame::Unknown) {
        out.frame = "path only";
        out.frameReason = "the scan states no patient orientation";
        out.axes = bodyAxesFromPath(pos);
    } else if (!pathRunsLeftBeforeRight(pos, bodyAxesFromPatientFrame())) {
        out.frame = "path only";
        out.frameReason = "the path reaches the top of the patient's right side before the left (the ascending "
                          "colon before the descending): the scan's left and right are likely mirrored";
        out.axes = bodyAxesFromPath(pos);
    } else {
        out.frame = "patient";
        out.axes = bodyAxesFromPatientFrame();
    }
    out.segment.assign(n, "rectum");
    if (n < 3) return out;

    // 2-5. Landmarks.
    const Flexures flex = findFlexures(pos, out.axes, params);
    if (!flex.found) {
        // Not a whole colon frame: only the rectum and the sigmoid can be told.
        const std::size_t rs = findRectosigmoidJunction(pos, out.axes, step, n, params);
        for (std::size_t i = rs; i < n; ++i) out.segment[i] = "sigmoid";
        out.landmarks.push_back(landmark("rectosigmoid_junction", pos, rs, step));
        return out;
    }
    const std::size_t ds = findDescendingSigmoidJunction(pos, out.axes, flex.splenic, params);
    const std::size_t rs = findRectosigmoidJunction(pos, out.axes, step, ds, params);
    const std::size_t cecum = std::max(findCecumStart(n, step, flex.hepatic, params), flex.hepatic + 1);

    // 6. Segments: the flexure windows clipped to their neighbours' landmarks and to the
    //    middle of the transverse colon.
    const std::size_t half = pointsInArc(params.flexureHalfMm, step);
    const std::size_t midTransverse = (flex.splenic + flex.hepatic) / 2;
    const std::size_t splenicFrom = std::max(ds, flex.splenic > half ? flex.splenic - half : 0);
    const std::size_t splenicTo = std::min(midTransverse, flex.splenic + half);
    const std::size_t hepaticFrom = std::max(midTransverse + 1, flex.hepatic > half ? flex.hepatic - half : 0);
    const std::size_t hepaticTo = std::min(cecum - 1, flex.hepatic + half);
    for (std::size_t i = 0; i < n; ++i) {
        const char* s = "rectum";
        if (i >= cecum) s = "cecum";
        else if (i > hepaticTo) s = "ascending";
        else if (i >= hepaticFrom) s = "hepatic_flexure";
        else if (i > splenicTo) s = "transverse";
        else if (i >= splenicFrom) s = "splenic_flexure";
        else if (i >= ds) s = "descending";
        else if (i >= rs) s = "sigmoid";
        out.segment[i] = s;
    }
    out.landmarks.push_back(landmark("rectosigmoid_junction", pos, rs, step));
    out.landmarks.push_back(landmark("descending_sigmoid_junction", pos, ds, step));
    out.landmarks.push_back(landmark("splenic_flexure", pos, flex.splenic, step));
    out.landmarks.push_back(landmark("hepatic_flexure", pos, flex.hepatic, step));
    out.landmarks.push_back(landmark("cecum", pos, cecum, step));
    return out;
}

void addAnatomySegments(Centerline& centerline, PatientFrame frame, const AnatomySegmentParams& params)
{
    AnatomySegments a = labelAnatomySegments(centerline, frame, params);
    centerline.segment = std::move(a.segment);
    centerline.landmarks = std::move(a.landmarks);
    centerline.segmentsFrame = std::move(a.frame);
    centerline.segmentsFrameReason = std::move(a.frameReason);
}

std::vector<SegmentSeenShare> segmentSeenShares(const std::vector<uint8_t>& seenPerTriangle,
                                                const std::vector<double>& triangleAreaMm2,
                                                const std::vector<std::size_t>& nearestCenterlineIndexPerTriangle,
                                                const std::vector<std::string>& segmentPerPoint)
{
    const std::size_t t = seenPerTriangle.size();
    if (triangleAreaMm2.size() != t || nearestCenterlineIndexPerTriangle.size() != t)
        throw std::invalid_argument("segmentSeenShares: the per-triangle arrays differ in length");
    std::map<std::string, std::size_t> slot;
    std::vector<SegmentSeenShare> out;
    // Path order: the canonical names first, in their order, then any other name as it comes.
    std::vector<std::string> order;
    for (const std::string& name : anatomySegmentNames())
        if (std::find(segmentPerPoint.begin(), segmentPerPoint.end(), name) != segmentPerPoint.end())
            order.push_back(name);
    for (const std::string& name : segmentPerPoint)
        if (std::find(order.begin(), order.end(), name) == order.end()) order.push_back(name);
    for (const std::string& name : order) {
        slot[name] = out.size();
        out.push_back(SegmentSeenShare{name, 0, 0, 0});
    }
    std::vector<std::size_t> pointSlot(segmentPerPoint.size());
    for (std::size_t i = 0; i < segmentPerPoint.size(); ++i) pointSlot[i] = slot[segmentPerPoint[i]];
    for (std::size_t k = 0; k < t; ++k) {
        const std::size_t i = nearestCenterlineIndexPerTriangle[k];
        if (i == NOT_ON_PATH) continue;
        if (i >= segmentPerPoint.size())
            throw std::invalid_argument("segmentSeenShares: triangle " + std::to_string(k) + " names centerline point " +
                                        std::to_string(i) + " of " + std::to_string(segmentPerPoint.size()));
        SegmentSeenShare& s = out[pointSlot[i]];
        s.areaMm2 += triangleAreaMm2[k];
        if (seenPerTriangle[k]) s.seenAreaMm2 += triangleAreaMm2[k];
    }
    for (SegmentSeenShare& s : out) s.fraction = s.areaMm2 > 0 ? s.seenAreaMm2 / s.areaMm2 : 0.0;
    return out;
}

} // namespace flyover
