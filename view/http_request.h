/// @file http_request.h
/// @brief What the viewer's route handlers share: an HTTP error with its status, strict query
///        parameters and JSON bodies (unknown names refused, numbers finite and in range, bodies
///        at most 64 KiB), and JSON answers.
#pragma once

#include <httplib.h>
#include <nlohmann/json.hpp>

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>

namespace flyover {
namespace http {

using nlohmann::json;

constexpr std::size_t MAX_BODY_BYTES = 64 * 1024;

/// An HTTP error with its status; the message becomes {"error": message}.
struct HttpError : std::runtime_error {
    HttpError(int s, const std::string& m) : std::runtime_error(m), status(s) {}
    int status;
};

/// Strict query parameters: only the names an endpoint knows (plus token and a cache-busting
/// "_"), each at most once, numbers finite and in range.
class Query {
public:
    Query(const httplib::Request& req, std::set<std::string> known) : mReq(req)
    {
        known.insert("token");
        known.insert("_");
        for (const auto& kv : req.params) {
            if (!known.count(kv.first))
                throw HttpError(400, "unknown parameter '" + kv.first.substr(0, 40) + "'");
            if (req.params.count(kv.first) > 1) throw HttpError(400, kv.first + ": given more than once");
        }
    }
    bool has(const std::string& name) const { return mReq.has_param(name.c_str()); }
    std::string text(const std::string& name) const { return mReq.get_param_value(name.c_str()); }

    double number(const std::string& name) const
    {
        if (!has(name)) throw HttpError(400, name + ": missing");
        return parseNumber(name, text(name));
    }
    double number(const std::string& name, double fallback) const { return has(name) ? number(name) : fallback; }
    double number(const std::string& name, double fallback, double lo, double hi) const
    {
        const double v = number(name, fallback);
        if (v < lo || v > hi)
            throw HttpError(422, name + ": " + shortNumber(v) + " is outside [" + shortNumber(lo) + ", " + shortNumber(hi) + "]");
        return v;
    }
    int integer(const std::string& name, int fallback, int lo, int hi) const
    {
        const double v = number(name, fallback);
        if (v != std::floor(v)) throw HttpError(400, name + ": must be an integer");
        if (v < lo || v > hi)
            throw HttpError(422, name + ": " + shortNumber(v) + " is outside [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
        return int(v);
    }
    std::string choice(const std::string& name, const std::string& fallback, const std::set<std::string>& options) const
    {
        if (!has(name)) return fallback;
        const std::string v = text(name);
        if (!options.count(v)) {
            std::string list;
            for (const auto& o : options) list += (list.empty() ? "" : "|") + o;
            throw HttpError(400, name + ": must be " + list);
        }
        return v;
    }

    static double parseNumber(const std::string& name, const std::string& s)
    {
        if (s.empty() || s.size() > 64) throw HttpError(400, name + ": not a number");
        char* end = nullptr;
        errno = 0;
        const double v = std::strtod(s.c_str(), &end);
        if (end != s.c_str() + s.size() || errno == ERANGE || !std::isfinite(v))
            throw HttpError(400, name + ": '" + s.substr(0, 24) + "' is not a finite number");
        return v;
    }
    static std::string shortNumber(double v)
    {
        std::ostringstream o;
        o << v;
        return o.str();
    }

private:
    const httplib::Request& mReq;
};

inline double jsonNumber(const json& body, const std::string& name, double fallback, double lo, double hi)
{
    if (!body.contains(name) || body[name].is_null()) return fallback;
    if (!body[name].is_number()) throw HttpError(400, name + ": must be a number");
    const double v = body[name].get<double>();
    if (!std::isfinite(v)) throw HttpError(400, name + ": must be finite");
    if (v < lo || v > hi)
        throw HttpError(422, name + ": " + Query::shortNumber(v) + " is outside [" + Query::shortNumber(lo) + ", " +
                                 Query::shortNumber(hi) + "]");
    return v;
}

inline std::string jsonChoice(const json& body, const std::string& name, const std::string& fallback,
                       const std::set<std::string>& options)
{
    if (!body.contains(name) || body[name].is_null()) return fallback;
    if (!body[name].is_string() || !options.count(body[name].get<std::string>())) {
        std::string list;
        for (const auto& o : options) list += (list.empty() ? "" : "|") + o;
        throw HttpError(400, name + ": must be " + list);
    }
    return body[name].get<std::string>();
}

inline json parseBody(const httplib::Request& req)
{
    if (req.body.size() > MAX_BODY_BYTES) throw HttpError(413, "request body larger than 64 KiB");
    json body = json::parse(req.body, nullptr, false);
    if (body.is_discarded() || !body.is_object()) throw HttpError(400, "body: must be a JSON object");
    return body;
}

inline void sendJson(httplib::Response& res, const json& j, int status = 200)
{
    res.status = status;
    // Request text echoed in a message may be any bytes: replace invalid UTF-8, never throw.
    res.set_content(j.dump(-1, ' ', false, json::error_handler_t::replace), "application/json");
}

inline std::string oneLine(std::string s)
{
    for (char& c : s)
        if (c == '\n' || c == '\r') c = ' ';
    return s.substr(0, 400);
}


/// The body's fields must all be among `known`. @throw HttpError 400 naming the first other.
inline void onlyFields(const json& body, const std::set<std::string>& known)
{
    for (auto it = body.begin(); it != body.end(); ++it)
        if (!known.count(it.key())) throw HttpError(400, "body: unknown field '" + it.key().substr(0, 40) + "'");
}

} // namespace http
} // namespace flyover
