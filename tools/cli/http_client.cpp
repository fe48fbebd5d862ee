// Client side of the mapping service API (see http_client.hpp).
#include "http_client.hpp"

#include <cctype>
#include <nlohmann/json.hpp>

#include "polmap/schema/errors.hpp"

namespace polmap::cli {

std::unique_ptr<httplib::Client> make_client(const std::string& url, int timeout_s) {
  if (url.rfind("http://", 0) != 0 && url.rfind("https://", 0) != 0) {
    throw ValidationError("--server '" + url + "': expected http://HOST:PORT");
  }
  std::string base = url;
  while (base.size() > 8 && base.back() == '/') base.pop_back();
  auto cli = std::make_unique<httplib::Client>(base);
  if (!cli->is_valid()) throw ValidationError("--server '" + url + "': not a usable URL");
  cli->set_connection_timeout(10, 0);
  cli->set_read_timeout(timeout_s, 0);
  cli->set_write_timeout(timeout_s, 0);
  cli->set_keep_alive(false);
  return cli;
}

/// Throws a one-line error for a failed request: transport error or HTTP status >= 400,
/// with the server's JSON error message and field when present.
const httplib::Response& expect_ok(const httplib::Result& r, const std::string& url,
                                   const std::string& what) {
  if (!r) {
    std::string reason = httplib::to_string(r.error());
    if (r.error() == httplib::Error::Connection) reason = "connection refused or host unreachable";
    throw IoError(what + ": cannot reach " + url + " (" + reason + ")");
  }
  if (r->status < 400) return *r;
  std::string message = r->body;
  std::string field;
  try {
    const auto j = nlohmann::json::parse(r->body);
    if (j.is_object() && j.contains("error")) message = j["error"].get<std::string>();
    if (j.is_object() && j.contains("field")) field = j["field"].get<std::string>();
  } catch (const std::exception&) {
  }
  if (message.size() > 500) message = message.substr(0, 500) + "...";
  std::string line = what + ": server answered " + std::to_string(r->status);
  if (r->status == 401) line += " (API key missing or not accepted)";
  line += ": " + message;
  if (!field.empty() && message.find(field) == std::string::npos) line += " [field: " + field + "]";
  throw Error(line);
}

std::string percent_encode(const std::string& s) {
  static constexpr char kHex[] = "0123456789ABCDEF";
  std::string out;
  for (unsigned char c : s) {
    if (std::isalnum(c) || c == '-' || c == '_' || c == '.' || c == '~') {
      out.push_back(static_cast<char>(c));
    } else {
      out.push_back('%');
      out.push_back(kHex[c >> 4]);
      out.push_back(kHex[c & 15]);
    }
  }
  return out;
}

}  // namespace polmap::cli
