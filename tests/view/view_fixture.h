// The viewer tests' study: a small phantom (seed 1) run once per test process through every
// stage with small frames and cut-down coverage, shared read-only by the tests; tests that
// write (bookmarks, screenshots) copy it first. A server is started in-process on port 0.
#pragma once

#include "colon/phantom.h"
#include "pipeline/artifact_io.h"
#include "colon/phantom_io.h"
#include "colon/colon_study.h"
#include "view/view_server.h"

#include <gtest/gtest.h>
#include <httplib.h>
#include <openvdb/openvdb.h>
#include <png.h>

#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <unistd.h>

namespace flyover::test {

inline constexpr int STUDY_PX = 128;

/// The shared study folder (built on first use) and its phantom's truth.
struct SharedStudy {
    std::filesystem::path root;
    std::string study;
    std::string truthPath;
    std::string ctPath;
    PhantomTruth truth;
    RunOptions options;  ///< of the run that made the study
};

inline const SharedStudy& sharedStudy()
{
    static SharedStudy* s = [] {
        openvdb::initialize();
        auto* st = new SharedStudy;
        st->root = std::filesystem::temp_directory_path() / ("flyover-view-" + std::to_string(::getpid()));
        std::filesystem::remove_all(st->root);
        std::filesystem::create_directories(st->root);
        PhantomParams pp;
        pp.size = PhantomSize::Small;
        pp.seed = 1;
        const Phantom ph = makePhantom(pp);
        st->ctPath = (st->root / "ct.nii.gz").string();
        st->truthPath = (st->root / "truth.json").string();
        writePhantom(ph, pp, st->ctPath, st->truthPath, "");
        st->truth = ph.truth;
        RunOptions o;
        o.ctPath = st->ctPath;
        o.studyDir = st->study = (st->root / "study").string();
        o.params.render.widthPx = o.params.render.heightPx = STUDY_PX;
        o.params.render.frameStepMm = 100;
        o.params.render.overviewPx = 160;
        o.params.render.coveragePx = 32;
        o.params.render.coverageStepMm = 20;
        o.params.render.video = false;
        o.params.render.flythroughFrames = false;
        runPipeline(o);
        st->options = o;
        std::atexit([] { std::filesystem::remove_all(s->root); });
        return st;
    }();
    return *s;
}

/// Copies the shared study (for tests that write into it).
inline std::string copyStudy(const std::string& name)
{
    const auto& s = sharedStudy();
    const std::filesystem::path dst = s.root / name;
    std::filesystem::remove_all(dst);
    std::filesystem::create_directories(dst);
    for (const char* f : {"centerline.json", "surface.ply", "ct.vdb", "manifest.json"})
        std::filesystem::copy_file(std::filesystem::path(s.study) / f, dst / f);
    std::filesystem::create_directories(dst / "coverage");
    std::filesystem::copy_file(std::filesystem::path(s.study) / "coverage" / "coverage.json", dst / "coverage" / "coverage.json");
    return dst.string();
}

/// A server on 127.0.0.1:0 over a study, listening in a thread until destroyed.
class RunningServer {
public:
    explicit RunningServer(const std::string& studyDir, const std::string& assetDir = "",
                           LiveStudy::Options liveOptions = {})
        : live(studyDir, "", liveOptions)
    {
        live.start();
        if (live.waitFirstLoad()) held = live.current();
        ViewServerOptions o;
        o.assetDir = assetDir;
        o.threads = 8;
        server = std::make_unique<ViewServer>(live, o);
        port = server->bind();
        thread = std::thread([this] { server->listen(); });
        for (int i = 0; i < 500 && !server->isRunning(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    ~RunningServer()
    {
        server->stop();
        thread.join();
    }

    /// A client with the token header and keep-alive.
    std::unique_ptr<httplib::Client> client(bool withToken = true) const
    {
        auto c = std::make_unique<httplib::Client>("127.0.0.1", port);
        c->set_read_timeout(60, 0);
        if (withToken) c->set_default_headers({{"X-Flyover-Token", server->token()}});
        return c;
    }
    std::string origin() const { return "http://127.0.0.1:" + std::to_string(port); }

    /// The study served at start (a study being computed: none).
    const ViewStudy& study() const { return *held; }

    LiveStudy live;
    std::shared_ptr<const ViewStudy> held;
    std::unique_ptr<ViewServer> server;
    int port = 0;
    std::thread thread;
};

/// Decodes a PNG body (RGB or gray, as RGB) with libpng's simplified API.
inline RgbImage decodePng(const std::string& body)
{
    png_image img{};
    img.version = PNG_IMAGE_VERSION;
    RgbImage out;
    if (!png_image_begin_read_from_memory(&img, body.data(), body.size())) return out;
    img.format = PNG_FORMAT_RGB;
    out.width = int(img.width);
    out.height = int(img.height);
    out.rgb.resize(PNG_IMAGE_SIZE(img));
    if (!png_image_finish_read(&img, nullptr, out.rgb.data(), 0, nullptr)) return RgbImage{};
    return out;
}

} // namespace flyover::test
