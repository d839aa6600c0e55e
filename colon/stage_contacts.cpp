// Contacts between touching loops in the pipeline: cut at the end of the segment stage
// (colon/contacts.h), carried to the centerline stage inside lumen.vdb as metadata of the
// lumen_sdf grid (so that the cache, which tracks lumen.vdb, keeps the two together), and
// placed along the path there.
#include "colon/study_run.h"

#include "colon/contacts.h"
#include "colon/segment.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>

using nlohmann::json;

namespace flyover {

namespace {

/// Metadata key of the lumen_sdf grid holding the contacts (a JSON array as a string).
constexpr const char* CONTACTS_META = "flyover_contacts";

std::string mm(double v)
{
    std::ostringstream s;
    s << std::fixed << std::setprecision(1) << v;
    return s.str();
}

std::string pointText(const Vec3d& p)
{
    return "(" + mm(p.x) + ", " + mm(p.y) + ", " + mm(p.z) + ") mm";
}

} // namespace

json cutLumenContacts(StudyRun& run, LumenSegmentation& seg)
{
    const ContactParams& params = run.opt.params.segment.contacts;
    const ContactReport report = cutContacts(*seg.sdf, seg.mask.get(), params);
    json list = json::array();
    for (const ContactInfo& c : report.contacts)
        list.push_back(json{{"position_mm", vec3Json(c.positionMm)},
                            {"width_mm", c.widthMm},
                            {"side_a_mm", vec3Json(c.sideMm[0])},
                            {"side_b_mm", vec3Json(c.sideMm[1])},
                            {"side_radius_mm", json::array({c.sideRadiusMm[0], c.sideRadiusMm[1]})},
                            {"straight_mm", c.straightMm},
                            {"detour_mm", c.detourMm},  // at least; null: no way round
                            {"links", c.links},
                            {"voxels_removed", c.voxelsRemoved},
                            {"cut", c.cut},
                            {"reason", c.reason}});
    seg.sdf->insertMeta(CONTACTS_META, openvdb::StringMetadata(list.dump()));
    if (run.opt.log)
        for (const ContactInfo& c : report.contacts)
            run.opt.log->message(std::string("segment: ") + (c.cut ? "cut a contact" : "warning: kept a contact") +
                                 " at " + pointText(c.positionMm) + ", neck " + mm(c.widthMm) +
                                 " mm wide between lumen of radius " + mm(c.sideRadiusMm[0]) + " and " +
                                 mm(c.sideRadiusMm[1]) + " mm (" + mm(c.straightMm) + " mm apart, " +
                                 mm(c.detourMm) + " mm the way round): " + c.reason);
    return json{{"world_frame", "LPS"},
                {"enabled", params.enabled},
                {"criterion", "a neck whose radius is below contact_neck_ratio x the lumen radius on both "
                              "sides, cut when it closes a cycle whose way round through the lumen deeper "
                              "than the neck is long (a loop, not a polyp or fold within one tube), or when "
                              "it closes none but meets a tube from the side on both hands (two loops kept "
                              "apart along the colon by a collapse); a narrow place across one tube (a "
                              "collapse, stricture or fold) is never cut"},
                {"regions", report.regions},
                {"links", report.links},
                {"cycle_links", report.cycleLinks},
                {"wide_cycles_kept", report.wideCycles},
                {"cut", std::count_if(report.contacts.begin(), report.contacts.end(),
                                      [](const ContactInfo& c) { return c.cut; })},
                {"contacts", list}};
}

json contactsAlongPath(const openvdb::FloatGrid& sdf, const Centerline& centerline)
{
    const auto meta = sdf.getMetadata<openvdb::StringMetadata>(CONTACTS_META);
    if (!meta) return json();
    json list = json::parse(meta->value(), nullptr, false);
    if (!list.is_array()) return json();
    const auto& pts = centerline.points;
    auto nearestArc = [&](const json& p, double& distanceMm) {
        const Vec3d q{p.at(0).get<double>(), p.at(1).get<double>(), p.at(2).get<double>()};
        double best = std::numeric_limits<double>::infinity(), arc = 0;
        for (std::size_t i = 0; i < pts.size(); ++i) {
            const double d = distance(pts[i].positionMm, q);
            if (d < best) {
                best = d;
                arc = double(i) * centerline.stepMm;
            }
        }
        distanceMm = best;
        return arc;
    };
    for (json& c : list) {
        double da = 0, db = 0;
        const double a = nearestArc(c.at("side_a_mm"), da), b = nearestArc(c.at("side_b_mm"), db);
        c["arc_a_mm"] = std::min(a, b);
        c["arc_b_mm"] = std::max(a, b);
        c["side_to_path_mm"] = json::array({da, db});
    }
    return list;
}

} // namespace flyover
