// `polmap upload --server URL --package PKG --api-key KEY [--chunk-mb 8] [--retries 10] [--json]`:
// uploads one drive package (a package directory, packed on the fly into the canonical ustar
// archive, or a .tar file) to the mapping service. Up to --chunk-mb in one POST /v1/drives;
// larger packages resumably: POST /v1/uploads, then PATCH chunks at the acknowledged offset;
// after a dropped connection it waits (backoff), asks HEAD for the offset and continues from
// there, so no byte the server acknowledged is sent again; when the answer to the last chunk
// is what got lost, HEAD shows the session complete and an empty PATCH at its end gets that
// answer again. A server without /v1/uploads (404) gets the single POST. The session is
// remembered in a state file (--state, default PACKAGE.upload-session) until the upload
// ends, so a run that gave up or was killed is continued by the next run of the same
// command: it asks HEAD where the session stands and sends only the rest.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <charconv>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <thread>

#include "command.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/util/file.hpp"
#include "polmap/util/sha256.hpp"
#include "progress.hpp"

// Last: httplib pulls in <resolv.h>, whose `_res` macro breaks Eigen templates.
#include "http_client.hpp"

namespace polmap::cli {
namespace {

struct UploadOptions {
  std::string server;
  std::string package;
  std::string api_key;
  int timeout_s = 600;
  /// Packages above this go resumably, in chunks of this size (MiB; fractions allowed).
  double chunk_mb = 8.0;
  /// Dropped connections or busy answers in a row before the upload gives up.
  int retries = 10;
  /// First wait after a failure; doubled per failure in a row, at most 30 s.
  double backoff_s = 0.5;
  /// Where the resumable session is remembered until the upload ends (empty: nowhere).
  std::string state;
  bool no_state = false;
  bool json = false;
};

/// The resumable session a run left behind (the state file): it is continued when the
/// same package goes to the same server again.
struct SessionState {
  std::string server;
  std::string location;  ///< /v1/uploads/ID
  std::uint64_t length = 0;
  std::string sha256;
};

constexpr std::uintmax_t kMaxStateBytes = 4096;

/// The state file, if it holds a session of this package on this server. A file that is
/// not one (foreign, damaged, too large) is ignored with a note and later overwritten.
std::optional<SessionState> read_state(const std::filesystem::path& file, const std::string& server,
                                       std::uint64_t length, const std::string& sha256) {
  std::error_code ec;
  if (file.empty() || !std::filesystem::is_regular_file(file, ec)) return std::nullopt;
  const auto size = std::filesystem::file_size(file, ec);
  if (ec || size > kMaxStateBytes) {
    std::fprintf(stderr, "upload: ignoring %s (not an upload session state)\n", file.c_str());
    return std::nullopt;
  }
  try {
    const nlohmann::json j = nlohmann::json::parse(util::read_file_bytes(file));
    SessionState st{j.at("server").get<std::string>(), j.at("location").get<std::string>(),
                    j.at("length").get<std::uint64_t>(), j.at("sha256").get<std::string>()};
    const bool id_ok = st.location.size() > 12 && st.location.size() <= 140 &&
                       st.location.starts_with("/v1/uploads/") &&
                       std::all_of(st.location.begin() + 12, st.location.end(), [](char c) {
                         return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') ||
                                (c >= '0' && c <= '9') || c == '-' || c == '_';
                       });
    if (j.value("version", 0) != 1 || !id_ok) throw std::runtime_error("bad fields");
    if (st.server != server || st.length != length || st.sha256 != sha256) return std::nullopt;
    return st;
  } catch (const std::exception&) {
    std::fprintf(stderr, "upload: ignoring %s (not an upload session state)\n", file.c_str());
    return std::nullopt;
  }
}

/// Remembers the session (written beside, then renamed: a crash leaves the old file or the
/// new one). A state that cannot be written only costs the resumption: noted, not fatal.
void write_state(const std::filesystem::path& file, const SessionState& st) {
  if (file.empty()) return;
  const nlohmann::json j{{"version", 1},
                         {"server", st.server},
                         {"location", st.location},
                         {"length", st.length},
                         {"sha256", st.sha256}};
  try {
    const std::filesystem::path tmp = file.string() + ".tmp";
    util::write_file_bytes(tmp, j.dump() + "\n");
    std::filesystem::rename(tmp, file);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "upload: cannot remember the session in %s (%s)\n", file.c_str(),
                 e.what());
  }
}

void remove_state(const std::filesystem::path& file) {
  std::error_code ec;
  if (!file.empty()) std::filesystem::remove(file, ec);
}

std::string read_file(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  if (!in) throw IoError("cannot read " + p.string());
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::optional<std::uint64_t> parse_offset(const std::string& s) {
  std::uint64_t v = 0;
  const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc{} || p != s.data() + s.size() || s.empty()) return std::nullopt;
  return v;
}

/// What the resumable upload did.
struct ResumableOutcome {
  httplib::Response response;    ///< the server's answer to the last chunk (201/200)
  int reconnects = 0;            ///< failed requests retried
  std::uint64_t sent_bytes = 0;  ///< chunk bytes handed to the connection, all attempts
  /// The answer came from an empty PATCH at the end: the session repeated the answer its
  /// last chunk got, which the dropped connection had lost.
  bool answer_repeated = false;
  /// A session an earlier run left (the state file) was continued from this offset.
  std::optional<std::uint64_t> resumed_from;
};

/// The resumable protocol (schema/openapi.yaml, /v1/uploads). nullopt: the server has no
/// /v1/uploads (an older server), nothing was sent.
std::optional<ResumableOutcome> upload_resumable(const UploadOptions& o, const std::string& body,
                                                 std::size_t chunk_bytes) {
  auto cli = make_client(o.server, o.timeout_s);
  const httplib::Headers auth{{"Authorization", "Bearer " + o.api_key}};
  ResumableOutcome out;
  const std::filesystem::path state_file =
      o.no_state ? std::filesystem::path() : std::filesystem::path(o.state);
  int failures = 0;
  // A failed request: wait, or give up after --retries in a row.
  auto fail = [&](const std::string& why) {
    if (++failures > o.retries) {
      throw IoError("upload of " + o.package + ": giving up after " + std::to_string(o.retries) +
                    " retries (" + why + ")" +
                    (!state_file.empty() && std::filesystem::exists(state_file)
                         ? "; the session is kept in " + state_file.string() +
                               ": run the same command again to continue it"
                         : std::string()));
    }
    ++out.reconnects;
    const double wait =
        std::min(30.0, o.backoff_s * static_cast<double>(1 << std::min(failures - 1, 10)));
    std::fprintf(stderr, "upload: %s; retrying in %.1f s\n", why.c_str(), wait);
    std::this_thread::sleep_for(std::chrono::duration<double>(wait));
  };
  auto transient = [](const httplib::Result& r) {
    return !r || r->status == 503 || r->status == 502 || r->status == 504 ||
           (r->status == 409 && r->has_header("Retry-After"));
  };
  auto why = [](const httplib::Result& r) {
    return r ? "server answered " + std::to_string(r->status)
             : "connection failed: " + httplib::to_string(r.error());
  };

  const std::string sha256 = util::sha256_hex(body);
  std::string location;
  std::uint64_t offset = 0;
  // A session an earlier run of this upload left: where does it stand?
  if (const auto st = read_state(state_file, o.server, body.size(), sha256)) {
    for (;;) {
      const auto s = cli->Head(st->location, auth);
      if (s && s->status == 200) {
        const auto at = parse_offset(s->get_header_value("Upload-Offset"));
        if (at && *at <= body.size()) {
          location = st->location;
          offset = *at;
          out.resumed_from = offset;
        }
        break;
      }
      if (transient(s)) {
        fail(why(s));
        continue;
      }
      break;  // expired, deleted, another key's: a new session
    }
    failures = 0;
  }
  httplib::Headers create = auth;
  create.emplace("Upload-Length", std::to_string(body.size()));
  create.emplace("Upload-Sha256", sha256);
  while (location.empty()) {
    const auto r = cli->Post("/v1/uploads", create, "", "application/json");
    if (r && (r->status == 404 || r->status == 405)) return std::nullopt;
    if (transient(r)) {
      fail(why(r));
      continue;
    }
    location = expect_ok(r, o.server, "upload of " + o.package).get_header_value("Location");
    if (!location.starts_with("/v1/uploads/")) {
      throw Error("upload of " + o.package + ": the server's Location '" + location +
                  "' is not an upload session");
    }
    write_state(state_file, {o.server, location, body.size(), sha256});
  }
  failures = 0;

  Progress progress("upload " + std::filesystem::path(o.package).filename().string(),
                    static_cast<double>(body.size()));
  for (;;) {
    const std::size_t n = std::min<std::size_t>(chunk_bytes, body.size() - offset);
    httplib::Headers h = auth;
    h.emplace("Upload-Offset", std::to_string(offset));
    const std::uint64_t base = offset;
    const auto r = cli->Patch(
        location, h, n,
        [&](std::size_t at, std::size_t length, httplib::DataSink& sink) {
          const std::size_t piece = std::min<std::size_t>(length, 64u << 10);
          if (!sink.write(body.data() + base + at, piece)) return false;
          out.sent_bytes += piece;
          progress.update(static_cast<double>(base + at + piece));
          return true;
        },
        "application/offset+octet-stream");
    if (r && (r->status == 201 || r->status == 200)) {
      out.response = *r;
      out.answer_repeated = n == 0 && r->has_header("Upload-Complete") &&
                            (out.reconnects > 0 || out.resumed_from.has_value());
      remove_state(state_file);
      return out;
    }
    if (r && r->status == 204) {
      const auto next = parse_offset(r->get_header_value("Upload-Offset"));
      if (!next || *next <= offset || *next > body.size()) {
        throw Error("upload of " + o.package + ": the server acknowledged offset '" +
                    r->get_header_value("Upload-Offset") + "' after " + std::to_string(offset));
      }
      offset = *next;
      failures = 0;
      continue;
    }
    if (r && r->status == 409 && !r->has_header("Retry-After")) {
      // Not the server's offset (an earlier chunk arrived after all): continue from its.
      const auto next = parse_offset(r->get_header_value("Upload-Offset"));
      if (!next || *next > body.size()) expect_ok(r, o.server, "upload of " + o.package);
      offset = *next;
      fail("the server's offset is " + std::to_string(offset));
      continue;
    }
    if (!transient(r)) expect_ok(r, o.server, "upload of " + o.package);  // throws
    fail(why(r));
    // Where did the server stop? Its offset is the truth; continue from there.
    for (;;) {
      const auto s = cli->Head(location, auth);
      if (s && s->status == 200) {
        const auto at = parse_offset(s->get_header_value("Upload-Offset"));
        if (!at || *at > body.size()) {
          throw Error("upload of " + o.package + ": the server's Upload-Offset '" +
                      s->get_header_value("Upload-Offset") + "' is not an offset");
        }
        offset = *at;
        break;
      }
      if (s && (s->status == 404 || s->status == 410) && base + n == body.size()) {
        // A completed session repeats its answer until it expires (HEAD gives its end as the
        // offset, and an empty PATCH there the answer); this one is gone already.
        throw Error("upload of " + o.package +
                    ": the answer to the last chunk was lost and the session has expired or "
                    "was deleted since, so the package was most likely stored; upload it "
                    "again to check (a stored package is answered 'already present')");
      }
      if (!transient(s)) expect_ok(s, o.server, "upload of " + o.package);  // throws
      fail(why(s));
    }
  }
}

void run(const UploadOptions& o) {
  if (!(o.chunk_mb > 0.0) || o.chunk_mb > 1024.0) {
    throw ValidationError("--chunk-mb must be in (0, 1024], got " + std::to_string(o.chunk_mb));
  }
  const std::filesystem::path pkg(o.package);
  std::string body;
  if (std::filesystem::is_directory(pkg)) {
    body = mapping::pack_drive_package(pkg);
  } else if (std::filesystem::is_regular_file(pkg)) {
    body = read_file(pkg);
  } else {
    throw IoError("--package " + o.package + ": no such directory or file");
  }
  const auto chunk_bytes =
      std::max<std::size_t>(1, static_cast<std::size_t>(o.chunk_mb * 1024.0 * 1024.0));
  std::optional<ResumableOutcome> resumable;
  if (body.size() > chunk_bytes) resumable = upload_resumable(o, body, chunk_bytes);
  httplib::Response res;
  if (resumable) {
    res = resumable->response;
  } else {
    auto cli = make_client(o.server, o.timeout_s);
    httplib::Headers headers{{"Authorization", "Bearer " + o.api_key}};
    const auto r = cli->Post("/v1/drives", headers, body, "application/x-tar");
    res = expect_ok(r, o.server, "upload of " + o.package);
  }
  if (o.json) {
    std::printf("%s\n", res.body.c_str());
    return;
  }
  std::string id = "?";
  try {
    id = nlohmann::json::parse(res.body).value("drive_id", "?");
  } catch (const std::exception&) {
  }
  std::string how;
  if (resumable) {
    how = ", resumable: " + std::to_string(resumable->sent_bytes) + " bytes sent, " +
          std::to_string(resumable->reconnects) + " retries";
    if (resumable->resumed_from) {
      how += ", continued the session of an earlier run from byte " +
             std::to_string(*resumable->resumed_from);
    }
    if (resumable->answer_repeated) how += ", the lost answer asked for again";
  }
  std::printf("drive %s %s (%zu bytes%s)\n", id.c_str(),
              res.status == 201 ? "uploaded" : "already present, not changed", body.size(),
              how.c_str());
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<UploadOptions>();
  CLI::App* cmd = app.add_subcommand("upload", "Upload a drive package to the mapping service");
  cmd->add_option("--server", opts->server, "Service URL, e.g. http://127.0.0.1:8080")->required();
  cmd->add_option("--package", opts->package, "Package directory or .tar archive")->required();
  cmd->add_option("--api-key", opts->api_key, "API key (Bearer token) for writes")
      ->required()
      ->envname("POLMAP_API_KEY");
  cmd->add_option("--timeout-s", opts->timeout_s, "Read/write timeout")->capture_default_str();
  cmd->add_option("--chunk-mb", opts->chunk_mb,
                  "Packages larger than this go resumably, in chunks of this many MiB")
      ->capture_default_str();
  cmd->add_option("--retries", opts->retries,
                  "Failed requests in a row (dropped connection, busy server) before giving up")
      ->capture_default_str();
  cmd->add_option("--backoff-s", opts->backoff_s,
                  "First wait after a failure (doubled per failure in a row, at most 30 s)")
      ->capture_default_str();
  cmd->add_option("--state", opts->state,
                  "Where a resumable upload's session is remembered until it ends, so that the "
                  "next run of the same upload continues it (default: PACKAGE.upload-session)");
  cmd->add_flag("--no-state", opts->no_state, "Do not remember the session (each run starts anew)");
  cmd->add_flag("--json", opts->json, "Print the server's JSON answer");
  cmd->callback([opts] {
    if (opts->state.empty()) {
      // Beside the package (a directory's trailing slash dropped).
      std::string p = opts->package;
      while (p.size() > 1 && p.back() == '/') p.pop_back();
      opts->state = p + ".upload-session";
    }
    run(*opts);
  });
}

}  // namespace
POLMAP_REGISTER_COMMAND(upload, setup);
}  // namespace polmap::cli
