/// @file findings_routes.h
/// @brief The viewer's findings API (docs/viewer.md): GET /api/findings, POST
///        /api/findings/review (accept or reject a candidate), /api/findings/edit (size, status,
///        note), /api/findings/hand (a finding at a picked point), DELETE /api/findings?id=.
#pragma once

namespace httplib {
struct Request;
struct Response;
} // namespace httplib

namespace flyover {

class FindingStore;
class ViewStudy;

/// Answers a request whose path starts with /api/findings. @throw http::HttpError (4xx).
void serveFindings(const httplib::Request& req, httplib::Response& res, FindingStore& store, const ViewStudy& study);

} // namespace flyover
