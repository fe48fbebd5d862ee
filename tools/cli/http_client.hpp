#pragma once
/// @file http_client.hpp
/// Client side of the mapping service API shared by the CLI commands that talk to
/// a server (upload, build-map, drives).
///
/// Include this header last: httplib pulls in <resolv.h>, whose `_res` macro
/// breaks Eigen templates.
#include <httplib.h>

#include <memory>
#include <string>

namespace polmap::cli {

/// A client for `url` (http://HOST:PORT or https://HOST:PORT, trailing slashes
/// ignored) with a 10 s connection timeout and `timeout_s` read/write timeouts.
/// Throws ValidationError naming --server for anything else.
std::unique_ptr<httplib::Client> make_client(const std::string& url, int timeout_s);

/// Returns the response of a successful request; otherwise throws a one-line
/// error starting with `what`: IoError for a transport failure (naming `url`),
/// Error for HTTP status >= 400 with the server's JSON error message and field.
const httplib::Response& expect_ok(const httplib::Result& r, const std::string& url,
                                   const std::string& what);

/// RFC 3986 percent-encoding of a path segment (unreserved characters kept).
std::string percent_encode(const std::string& s);

}  // namespace polmap::cli
