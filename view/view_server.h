/// @file view_server.h
/// @brief `flyover view`: an HTTP server on 127.0.0.1 (cpp-httplib) over one ViewStudy, for the
///        page in view/web/. Every request needs the session's random token (query `token=`,
///        header X-Flyover-Token or the HttpOnly cookie flyover_token set when the page is
///        loaded); the Host header must be 127.0.0.1:PORT or localhost:PORT (DNS rebinding);
///        POST and DELETE need the server's own Origin. Assets are served from a map of files
///        read at start (no path ever reaches the file system). API: README "Viewer".
#pragma once

#include "view/bookmarks.h"
#include "view/finding_store.h"
#include "view/live_study.h"
#include "view/view_study.h"

#include <atomic>
#include <map>
#include <memory>
#include <ostream>
#include <string>

namespace httplib {
class Server;
struct Request;
struct Response;
} // namespace httplib

namespace flyover {

struct ViewServerOptions {
    int port = 0;              ///< 0: a free port
    std::string token;         ///< "" = 32 random bytes from /dev/urandom, hex
    std::string assetDir;      ///< "" = defaultAssetDir()
    int threads = 16;          ///< worker threads of the HTTP server (a keep-alive connection holds one)
};

/// The installed page folder: $FLYOVER_VIEW_ASSETS, else <exe>/../share/flyover/web (install
/// tree and build tree alike), else the build tree's copy.
std::string defaultAssetDir();

class ViewServer {
public:
    /// Serves `study` as it is now: the study of its latest revision answers each request.
    ViewServer(LiveStudy& study, const ViewServerOptions& options);
    ~ViewServer();
    ViewServer(const ViewServer&) = delete;
    ViewServer& operator=(const ViewServer&) = delete;

    /// Binds 127.0.0.1:port. @return the port. @throw InputError when it cannot bind.
    int bind();
    /// Serves until stop(); call after bind().
    void listen();
    /// Stops listen() (from any thread; not from a signal handler).
    void stop();
    bool isRunning() const;

    int port() const { return mPort; }
    const std::string& token() const { return mToken; }
    std::string url() const;

    /// A file of the page, held in memory.
    struct Asset {
        std::string body, mime;
    };

private:
    void handle(const httplib::Request& req, httplib::Response& res);
    void route(const httplib::Request& req, httplib::Response& res);
    bool allowed(const httplib::Request& req, httplib::Response& res) const;

    LiveStudy& mLive;
    std::unique_ptr<httplib::Server> mServer;
    std::unique_ptr<BookmarkStore> mBookmarks;
    std::unique_ptr<FindingStore> mFindings;
    std::map<std::string, Asset> mAssets;  ///< "index.html", "app.js", "sub/x.png" -> content
    std::string mAssetDir;
    std::string mToken;
    int mPort = 0;
    int mThreads = 8;
    std::atomic<unsigned> mShotCounter{0};
};

/// The `flyover view` command: loads the study, binds, prints
/// `flyover: view: http://127.0.0.1:PORT/?token=TOKEN` on `out`, serves until SIGINT or SIGTERM.
/// @throw InputError naming what the study lacks (and the run command that makes it).
int runViewCommand(const std::string& studyDir, int port, const std::string& ctPath, std::ostream& out);

} // namespace flyover
