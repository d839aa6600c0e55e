// local_mesh_probe: the measurement behind colon/local_first_pair.h (issue 15). Does a mesh
// extracted and smoothed (the mesh stage's extraction, Taubin and orientation guard) from a level
// set clipped to a cube round the first centerline point equal the whole mesh away from the clip?
//
//   local_mesh_probe STUDY/lumen.vdb STUDY/centerline.json HALF_MM STUDY/frames/poses.json
//
// Prints the whole and local meshes' sizes and seconds; per 5 mm band of distance from the clip,
// the local vertices, those found among the whole mesh's extracted vertices, and those whose
// smoothed position is bit for bit the whole mesh's; how far from the point the first pair's
// rays (poses.json's frame 0, 512 x 512 views) meet the whole surface; and how many of the
// pair's pixels the local surface renders differently.
#include "surface/extract_surface.h"
#include "surface/lumen_surface.h"
#include "surface/smooth_mesh.h"
#include "render/ray_scene.h"
#include "render/render_view.h"
#include "render/camera.h"
#include <map>
#include <array>
#include <openvdb/openvdb.h>
#include <openvdb/tools/Clip.h>
#include <nlohmann/json.hpp>
#include <chrono>
#include <cstring>
#include <fstream>
#include <iostream>
#include <unordered_map>
using namespace flyover;
static double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }
struct Key { float x, y, z; bool operator==(const Key& o) const { return std::memcmp(this, &o, sizeof(Key)) == 0; } };
struct KeyHash { size_t operator()(const Key& k) const { uint32_t a[3]; std::memcpy(a, &k, 12); return (size_t(a[0]) * 73856093u) ^ (size_t(a[1]) * 19349663u) ^ (size_t(a[2]) * 83492791u); } };
static TriMesh build(const openvdb::FloatGrid& g, std::vector<TriMesh::Point>& raw, double& secs)
{
    const double t0 = now();
    MeshParams p;
    TriMesh m = extractSurface(g, p, nullptr, nullptr, false);
    raw.resize(m.n_vertices());
    for (auto v : m.vertices()) raw[v.idx()] = m.point(v);
    TaubinParams t;
    smoothMeshTaubin(m, t);
    restoreNonInwardFaces(m, raw, g);
    secs = now() - t0;
    return m;
}
int main(int argc, char** argv)
{
    if (argc != 5) {
        std::cerr << "usage: local_mesh_probe LUMEN.vdb CENTERLINE.json HALF_MM POSES.json\n";
        return 2;
    }
    openvdb::initialize();
    openvdb::io::File f(argv[1]);
    f.open();
    openvdb::FloatGrid::Ptr sdf;
    for (auto it = f.beginName(); it != f.endName(); ++it) {
        auto g = f.readGrid(it.gridName());
        if (g->getGridClass() == openvdb::GRID_LEVEL_SET) sdf = openvdb::gridPtrCast<openvdb::FloatGrid>(g);
    }
    nlohmann::json cl; std::ifstream(argv[2]) >> cl;
    const auto& p0j = cl["position_mm"][0];
    openvdb::Vec3d p0(p0j[0], p0j[1], p0j[2]);
    const double half = std::atof(argv[3]);
    std::vector<TriMesh::Point> rawG, rawL;
    double sg, sl;
    TriMesh G = build(*sdf, rawG, sg);
    const double tc = now();
    openvdb::BBoxd box(p0 - openvdb::Vec3d(half), p0 + openvdb::Vec3d(half));
    auto clipped = openvdb::tools::clip(*sdf, box);
    const double clipSecs = now() - tc;
    TriMesh L = build(*clipped, rawL, sl);
    std::cout << "whole " << G.n_vertices() << " v " << sg << " s; local " << L.n_vertices() << " v " << sl << " s, clip " << clipSecs << " s\n";
    std::unordered_map<Key, int, KeyHash> index;
    for (size_t i = 0; i < rawG.size(); ++i) index[{rawG[i][0], rawG[i][1], rawG[i][2]}] = int(i);
    // by distance of the vertex to the box's boundary (mm): counts of matched and of identical
    std::map<int, std::array<long, 3>> byDist;
    for (auto v : L.vertices()) {
        const auto& r = rawL[v.idx()];
        double d = 1e9;
        for (int a = 0; a < 3; ++a) d = std::min({d, double(r[a]) - box.min()[a], box.max()[a] - double(r[a])});
        auto& c = byDist[int(d / 5) * 5];
        c[0]++;
        auto it = index.find({r[0], r[1], r[2]});
        if (it == index.end()) continue;
        c[1]++;
        if (G.point(TriMesh::VertexHandle(it->second)) == L.point(v)) c[2]++;
    }
    for (auto& [d, c] : byDist) std::cout << "dist " << d << " mm: local " << c[0] << " matched " << c[1] << " identical " << c[2] << "\n";

    // The first pair's rays on the whole scene: how far from p0 do they hit?
    nlohmann::json poses; std::ifstream(argv[4]) >> poses;
    RayScene scene(G);
    RenderOptions ro; ro.widthPx = ro.heightPx = 512; ro.ost = true;
    double maxHit = 0; long hitsN = 0, miss = 0;
    auto vec = [](const nlohmann::json& j) { return Vec3d{j[0], j[1], j[2]}; };
    std::vector<Camera> cams;
    for (const auto& c : poses["frames"][0]["cameras"]) {
        Camera cam; cam.position = vec(c["position_mm"]); cam.forward = vec(c["forward"]); cam.up = vec(c["up"]);
        cam.right = vec(c["right"]); cam.fovDeg = c["fov_deg"]; cam.nearMm = c["near_mm"];
        cams.push_back(cam);
        HitImage hits; renderView(scene, cam, ro, &hits);
        for (int y = 0; y < 512; ++y) for (int x = 0; x < 512; ++x) {
            const size_t i = size_t(y) * 512 + x;
            if (hits.primId[i] == UINT32_MAX) { ++miss; continue; }
            ++hitsN;
            const Vec3d d = pixelDirection(cam, 512, 512, x + 0.5, y + 0.5);
            const Vec3d h = cam.position + d * double(hits.t[i]);
            double m = 0; for (int a = 0; a < 3; ++a) m = std::max(m, std::fabs(h[a] - p0[a]));
            maxHit = std::max(maxHit, m);
        }
    }
    std::cout << "pair rays: hits " << hitsN << " misses " << miss << " max |hit - p0|_inf " << maxHit << " mm\n";
    // Active leaves of the level set in either frustum (beyond the near plane): their bbox.
    openvdb::BBoxd inView;
    long leaves = 0, leavesIn = 0;
    for (auto leaf = sdf->tree().cbeginLeaf(); leaf; ++leaf) {
        ++leaves;
        const openvdb::CoordBBox cb = leaf->getNodeBoundingBox();
        const openvdb::BBoxd wb = sdf->transform().indexToWorld(cb);
        bool any = false;
        for (const Camera& cam : cams) {
            // outside if all 8 corners are beyond one plane
            const double th = std::tan(0.5 * cam.fovDeg * M_PI / 180.0);
            Vec3d c8[8];
            for (int k = 0; k < 8; ++k) c8[k] = Vec3d{(k & 1) ? wb.max()[0] : wb.min()[0], (k & 2) ? wb.max()[1] : wb.min()[1], (k & 4) ? wb.max()[2] : wb.min()[2]};
            bool out = false;
            for (int plane = 0; plane < 5 && !out; ++plane) {
                bool allOut = true;
                for (int k = 0; k < 8 && allOut; ++k) {
                    const Vec3d q = c8[k] - cam.position;
                    const double z = dot(q, cam.forward), x = dot(q, cam.right), y = dot(q, cam.up);
                    double s = 0;
                    if (plane == 0) s = cam.nearMm - z; else if (plane == 1) s = x - z * th; else if (plane == 2) s = -x - z * th; else if (plane == 3) s = y - z * th; else s = -y - z * th;
                    allOut = s > 0;
                }
                out = allOut;
            }
            any = any || !out;
        }
        if (any) { ++leavesIn; inView.expand(wb); }
    }
    std::cout << "leaves " << leaves << " in a frustum " << leavesIn << " bbox " << inView.min() << " " << inView.max() << " p0 " << p0 << "\n";

    {
        RayScene localScene(L);
        std::size_t differ = 0, total = 0;
        for (const Camera& cam : cams) {
            RgbImage a = renderView(scene, cam, ro), b = renderView(localScene, cam, ro);
            differ += differingPixels(a, b); total += size_t(a.width) * a.height;
        }
        std::cout << "local scene (" << L.n_faces() << " faces) vs whole: " << differ << " of " << total << " pixels differ\n";
    }
}
