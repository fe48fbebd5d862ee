// Resumable uploads: POST /v1/uploads opens a session, PATCH /v1/uploads/{id} appends a
// chunk at the acknowledged offset, HEAD/GET tells the offset, DELETE aborts. The last chunk
// hands the whole file to ingest_package, the path of POST /v1/drives (docs/security.md).
#include <fcntl.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <ctime>

#include "polmap/schema/errors.hpp"
#include "polmap/util/file.hpp"
#include "polmap/util/sha256.hpp"
#include "polmap/util/text.hpp"
#include "server_impl.hpp"

namespace polmap::mapping {
namespace {

constexpr const char* kChunkType = "application/offset+octet-stream";

/// Session ids are exactly what the store makes: 32 lower-case hex digits.
bool valid_session_id(std::string_view id) { return id.size() == 32 && util::is_lower_hex(id); }

/// UTC now as ISO 8601 in whole seconds, the format of UploadSession::expires_at.
std::string now_iso_s() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

nlohmann::json session_json(const UploadSession& s, std::uint64_t max_chunk_bytes) {
  nlohmann::json j{{"upload_id", s.id},
                   {"href", "/v1/uploads/" + s.id},
                   {"length_bytes", s.length_bytes},
                   {"offset_bytes", s.offset_bytes},
                   {"created_at", s.created_at},
                   {"expires_at", s.expires_at},
                   {"max_chunk_bytes", max_chunk_bytes}};
  if (!s.sha256.empty()) j["sha256"] = s.sha256;
  j["complete"] = s.outcome.has_value();
  if (s.outcome) {
    // Our own answer, kept as sent: parsed back for the listing, replayed verbatim by PATCH.
    j["outcome"] = {{"status", s.outcome->http_status},
                    {"response", nlohmann::json::parse(s.outcome->body, nullptr, false)}};
    if (!s.outcome->location.empty()) j["outcome"]["location"] = s.outcome->location;
  }
  return j;
}

void set_session_headers(httplib::Response& res, const UploadSession& s) {
  res.set_header("Upload-Offset", std::to_string(s.offset_bytes));
  res.set_header("Upload-Length", std::to_string(s.length_bytes));
  res.set_header("Upload-Expires", s.expires_at);
  if (s.outcome) res.set_header("Upload-Complete", std::to_string(s.outcome->http_status));
}

/// The answer a completed session's last chunk got, again.
void replay_outcome(httplib::Response& res, const UploadSession& s) {
  set_session_headers(res, s);
  if (!s.outcome->location.empty()) res.set_header("Location", s.outcome->location);
  res.status = s.outcome->http_status;
  res.set_content(s.outcome->body, "application/json");
}

/// A session file opened for appending, with an exclusive open-file-description lock: one
/// appender at a time per session, between threads and between processes sharing the
/// directory. Released (and closed) on destruction.
class LockedSessionFile {
 public:
  explicit LockedSessionFile(const std::filesystem::path& path) {
    fd_ = ::open(path.c_str(), O_RDWR | O_CLOEXEC);
    if (fd_ < 0) {
      open_errno_ = errno;
      return;
    }
    struct flock l {};
    l.l_type = F_WRLCK;
    l.l_whence = SEEK_SET;
    if (::fcntl(fd_, F_OFD_SETLK, &l) != 0) {
      lock_errno_ = errno;
      ::close(fd_);
      fd_ = -1;
    }
  }
  ~LockedSessionFile() {
    if (fd_ >= 0) ::close(fd_);
  }
  LockedSessionFile(const LockedSessionFile&) = delete;
  LockedSessionFile& operator=(const LockedSessionFile&) = delete;

  [[nodiscard]] bool ok() const { return fd_ >= 0; }
  /// The file is gone (the session was deleted or swept meanwhile).
  [[nodiscard]] bool missing() const { return open_errno_ == ENOENT; }
  /// Another request holds the lock.
  [[nodiscard]] bool busy() const { return lock_errno_ == EAGAIN || lock_errno_ == EACCES; }
  [[nodiscard]] int error() const { return open_errno_ != 0 ? open_errno_ : lock_errno_; }
  [[nodiscard]] int fd() const { return fd_; }

 private:
  int fd_ = -1;
  int open_errno_ = 0;
  int lock_errno_ = 0;
};

}  // namespace

std::string upload_owner(const ApiKey& key) {
  return util::sha256_hex("polmap upload session owner\n" + key.key);
}

bool is_upload_chunk(const httplib::Request& req) {
  return req.method == "PATCH" && req.path.starts_with("/v1/uploads/");
}

std::size_t Server::Impl::sweep_upload_sessions() {
  try {
    const std::size_t n = store.sweep_expired_upload_sessions(std::chrono::system_clock::now());
    if (n > 0) log("info", "removed " + std::to_string(n) + " expired upload sessions");
    return n;
  } catch (const std::exception& e) {
    log("error", std::string("upload session sweep: ") + e.what());
    return 0;
  }
}

void Server::Impl::register_upload_routes() {
  // The session `id` of `key`: nullopt with the reply written when the id is malformed,
  // unknown or another key's (404 alike: ids of other keys are not confirmed), or expired
  // (410, unless allow_expired).
  auto find_session = [this](const std::string& id, const ApiKey& key, httplib::Response& res,
                             bool allow_expired = false) -> std::optional<UploadSession> {
    std::optional<UploadSession> s;
    if (valid_session_id(id)) s = store.get_upload_session(id);
    if (!s || s->owner != upload_owner(key)) {
      reply_error(res, 404, "upload session '" + id + "' does not exist", "upload_id");
      return std::nullopt;
    }
    if (!allow_expired && s->expires_at <= now_iso_s()) {
      reply_error(res, 410, "upload session '" + id + "' expired at " + s->expires_at, "upload_id");
      return std::nullopt;
    }
    return s;
  };

  http.Post("/v1/uploads", [this](const httplib::Request& req, httplib::Response& res) {
    set_route("uploads_create");
    const auto key = require(req, res, Access::Upload);
    if (!key) return;
    const auto length = http::parse_int(req.get_header_value("Upload-Length"));
    if (!length || *length <= 0) {
      return reply_error(res, 400,
                         "Upload-Length must be the package's size in bytes (a positive integer)",
                         "Upload-Length");
    }
    if (static_cast<std::uint64_t>(*length) > cfg.max_upload_bytes) {
      return reply_error(res, 413,
                         "package of " + std::to_string(*length) +
                             " bytes exceeds the upload limit of " +
                             std::to_string(cfg.max_upload_bytes) + " bytes",
                         "Upload-Length", {{"limit_bytes", cfg.max_upload_bytes}});
    }
    std::string sha = req.get_header_value("Upload-Sha256");
    for (char& ch : sha) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
    if (!sha.empty() && (sha.size() != 64 || !util::is_lower_hex(sha))) {
      return reply_error(res, 400, "Upload-Sha256 must be 64 hex digits (SHA-256 of the package)",
                         "Upload-Sha256");
    }
    (void)sweep_upload_sessions();
    UploadSessionRequest r;
    r.owner = upload_owner(*key);
    r.length_bytes = static_cast<std::uint64_t>(*length);
    r.sha256 = sha;
    r.ttl_s = cfg.upload_session_ttl_s;
    r.max_sessions_per_owner =
        static_cast<std::size_t>(std::max(0, cfg.max_upload_sessions_per_key));
    r.max_bytes_per_owner = cfg.max_upload_session_bytes_per_key;
    const CreateUploadSessionResult c = store.create_upload_session(r);
    using S = CreateUploadSessionResult::Status;
    if (c.status == S::TooManySessions) {
      return reply_error(
          res, 429,
          "this key has " + std::to_string(c.open_sessions) +
              " open upload sessions, the limit is " +
              std::to_string(cfg.max_upload_sessions_per_key) +
              " (max_upload_sessions_per_key): finish or DELETE one, or wait "
              "until one expires",
          "max_upload_sessions_per_key",
          {{"limit", cfg.max_upload_sessions_per_key}, {"open_sessions", c.open_sessions}});
    }
    if (c.status == S::TooManyBytes) {
      return reply_error(
          res, 429,
          "this key's open upload sessions declare " + std::to_string(c.open_bytes) + " bytes; " +
              std::to_string(r.length_bytes) + " more would exceed the limit of " +
              std::to_string(cfg.max_upload_session_bytes_per_key) +
              " bytes (max_upload_session_bytes_per_key)",
          "max_upload_session_bytes_per_key",
          {{"limit_bytes", cfg.max_upload_session_bytes_per_key}, {"open_bytes", c.open_bytes}});
    }
    const UploadSession& s = c.session;
    res.set_header("Location", "/v1/uploads/" + s.id);
    set_session_headers(res, s);
    reply_json(res, 201, session_json(s, cfg.max_upload_chunk_bytes));
  });

  // GET and HEAD (cpp-httplib routes HEAD to the GET handlers and sends no body).
  http.Get(R"(/v1/uploads/([^/]+))",
           [this, find_session](const httplib::Request& req, httplib::Response& res) {
             set_route("uploads_status");
             const auto key = require(req, res, Access::Upload);
             if (!key) return;
             const auto s = find_session(req.matches[1], *key, res);
             if (!s) return;
             set_session_headers(res, *s);
             reply_json(res, 200, session_json(*s, cfg.max_upload_chunk_bytes));
           });

  http.Delete(R"(/v1/uploads/([^/]+))", [this, find_session](const httplib::Request& req,
                                                             httplib::Response& res) {
    set_route("uploads_delete");
    const auto key = require(req, res, Access::Upload);
    if (!key) return;
    const auto s = find_session(req.matches[1], *key, res, true);
    if (!s) return;
    if (!store.delete_upload_session(s->id)) {
      return reply_error(res, 404, "upload session '" + s->id + "' does not exist", "upload_id");
    }
    res.status = 204;
  });

  http.Patch(R"(/v1/uploads/([^/]+))", [this, find_session](const httplib::Request& req,
                                                            httplib::Response& res,
                                                            const httplib::ContentReader& reader) {
    set_route("uploads_patch");
    // As POST /v1/drives: a small refused body is drained (the connection stays usable), a
    // large one closes the connection.
    auto reject_unread = [&](const char* outcome) {
      metrics.upload(outcome, 0);
      const auto len = http::parse_int(req.get_header_value("Content-Length"));
      if (!req.has_header("Transfer-Encoding") && len && *len >= 0 && *len <= (1 << 20)) {
        reader([](const char*, std::size_t) { return true; });
      } else {
        res.set_header("Connection", "close");
      }
    };
    const auto key = require(req, res, Access::Upload);
    if (!key) return reject_unread("unauthorized");
    const std::string id = req.matches[1];
    if (req.get_header_value("Content-Type") != kChunkType) {
      reply_error(res, 415,
                  std::string("Content-Type of a chunk must be ") + kChunkType + ", got '" +
                      req.get_header_value("Content-Type") + "'",
                  "Content-Type");
      return reject_unread("bad_request");
    }
    if (req.has_header("Transfer-Encoding")) {
      reply_error(res, 411, "send a chunk with a Content-Length (not chunked)",
                  "Transfer-Encoding");
      return reject_unread("bad_request");
    }
    const auto offset = http::parse_int(req.get_header_value("Upload-Offset"));
    if (!offset || *offset < 0) {
      reply_error(res, 400, "Upload-Offset must be the session's offset (a non-negative integer)",
                  "Upload-Offset");
      return reject_unread("bad_request");
    }
    const auto length = http::parse_int(req.get_header_value("Content-Length"));
    if (!length || *length < 0) {
      reply_error(res, 411, "a chunk needs its Content-Length", "Content-Length");
      return reject_unread("bad_request");
    }
    const auto chunk = static_cast<std::uint64_t>(*length);
    if (chunk > cfg.max_upload_chunk_bytes) {
      reply_error(res, 413,
                  "chunk of " + std::to_string(chunk) + " bytes exceeds the chunk limit of " +
                      std::to_string(cfg.max_upload_chunk_bytes) + " bytes",
                  "Content-Length", {{"limit_bytes", cfg.max_upload_chunk_bytes}});
      return reject_unread("too_large");
    }
    auto session = find_session(id, *key, res);
    if (!session) return reject_unread("not_found");
    const auto from = static_cast<std::uint64_t>(*offset);
    auto conflict = [&](const UploadSession& s) {
      set_session_headers(res, s);
      reply_error(res, 409,
                  "Upload-Offset " + std::to_string(from) + " is not the session's offset " +
                      std::to_string(s.offset_bytes) + ": continue from there (HEAD tells it)",
                  "Upload-Offset", {{"offset_bytes", s.offset_bytes}});
      reject_unread("conflict");
    };
    // A completed session answers an empty PATCH at its end with the answer its last chunk
    // got (a client whose connection dropped before that answer arrived asks again), and
    // refuses more bytes.
    auto completed = [&](const UploadSession& s) {
      if (from == s.length_bytes && chunk == 0) {
        metrics.upload("replayed", 0);
        return replay_outcome(res, s);
      }
      set_session_headers(res, s);
      reply_error(res, 409,
                  "upload session '" + id + "' is complete (answered " +
                      std::to_string(s.outcome->http_status) + "): an empty PATCH at offset " +
                      std::to_string(s.length_bytes) + " repeats that answer",
                  "Upload-Offset", {{"offset_bytes", s.offset_bytes}});
      reject_unread("conflict");
    };
    if (session->outcome) return completed(*session);
    if (from != session->offset_bytes) return conflict(*session);
    if (from + chunk > session->length_bytes) {
      set_session_headers(res, *session);
      reply_error(res, 413,
                  "chunk would end at byte " + std::to_string(from + chunk) +
                      ", beyond the session's Upload-Length " +
                      std::to_string(session->length_bytes),
                  "Content-Length");
      return reject_unread("too_large");
    }
    const ConcurrencySlot slot(uploads_in_flight, cfg.max_concurrent_uploads);
    if (!slot.acquired()) {
      reply_uploads_busy(res);
      return reject_unread("busy");
    }
    const LockedSessionFile file(session->file);
    if (!file.ok()) {
      if (file.busy()) {
        res.set_header("Retry-After", "1");
        reply_error(res, 409, "another request is appending to upload session '" + id + "'",
                    "upload_id");
        return reject_unread("conflict");
      }
      if (file.missing()) {
        // Completed meanwhile (its file goes with the completion), or deleted.
        session = store.get_upload_session(id);
        if (session && session->outcome) return completed(*session);
        reply_error(res, 404, "upload session '" + id + "' does not exist", "upload_id");
        return reject_unread("not_found");
      }
      throw IoError("cannot open upload session file " + session->file.string() + ": " +
                    std::strerror(file.error()));
    }
    // Under the lock the store's offset is the truth: bytes beyond it (a chunk cut off
    // before its offset was committed) are dropped.
    session = store.get_upload_session(id);
    if (!session) {
      reply_error(res, 404, "upload session '" + id + "' does not exist", "upload_id");
      return reject_unread("not_found");
    }
    if (session->outcome) return completed(*session);
    if (from != session->offset_bytes) return conflict(*session);
    if (::ftruncate(file.fd(), static_cast<off_t>(from)) != 0 ||
        ::lseek(file.fd(), static_cast<off_t>(from), SEEK_SET) < 0) {
      throw IoError("cannot truncate upload session file " + session->file.string() + ": " +
                    std::strerror(errno));
    }
    std::uint64_t received = 0;
    int write_errno = 0;
    const bool complete = reader([&](const char* data, std::size_t n) {
      received += n;
      if (write_errno == 0) write_errno = util::write_all(file.fd(), {data, n});
      return true;  // after a failed write the rest is drained: the client gets the answer
    });
    if (write_errno == 0 && received > 0 && ::fsync(file.fd()) != 0) write_errno = errno;
    if (write_errno != 0) {
      (void)::ftruncate(file.fd(), static_cast<off_t>(from));
      const std::string what = "cannot write upload session file " + session->file.string() + ": " +
                               std::strerror(write_errno);
      set_session_headers(res, *session);
      if (write_errno == ENOSPC || write_errno == EDQUOT) {
        metrics.upload("storage_full", received);
        log("warn", "upload: storage full: " + what);
        return reply_error(res, 507, kStorageFullMessage);
      }
      metrics.upload("server_error", received);
      throw IoError(what);  // 500, detail in the log
    }
    // The bytes are durable: acknowledge them. A cut connection keeps what arrived whole.
    if (received > 0 && !store.advance_upload_offset(id, from, from + received)) {
      reply_error(res, 404, "upload session '" + id + "' does not exist", "upload_id");
      return;
    }
    session->offset_bytes = from + received;
    set_session_headers(res, *session);
    if (!complete) {
      metrics.upload("interrupted", received);
      res.set_header("Connection", "close");
      return reply_error(res, 400,
                         "chunk interrupted after " + std::to_string(received) + " of " +
                             std::to_string(chunk) + " bytes; the session's offset is now " +
                             std::to_string(session->offset_bytes),
                         "body");
    }
    if (session->offset_bytes < session->length_bytes) {
      res.status = 204;
      return;
    }

    // The last byte is in: the whole file, validated like POST /v1/drives, and only then
    // stored. Still under the lock, so a second completion cannot run beside this one.
    const std::string bytes = util::read_file_bytes(session->file);
    if (bytes.size() != session->length_bytes) {
      throw IoError("upload session file " + session->file.string() + " holds " +
                    std::to_string(bytes.size()) + " bytes, its offset says " +
                    std::to_string(session->length_bytes));
    }
    const std::string hash = util::sha256_hex(bytes);
    int status = 0;
    if (!session->sha256.empty() && hash != session->sha256) {
      metrics.upload("invalid", bytes.size());
      reply_error(res, 422,
                  "the uploaded package's SHA-256 is " + hash + ", the session declared " +
                      session->sha256 + "; nothing was stored",
                  "Upload-Sha256");
      status = 422;
    } else {
      status = ingest_package(bytes, hash, *key, upload_scratch_dir(), res);
    }
    // Stored, already present or refused for good: the upload is over, and the session keeps
    // that answer until it expires. A full disk or an internal error keeps the bytes, so an
    // empty PATCH at the full offset retries the ingest.
    if (status < 500) {
      try {
        (void)store.complete_upload_session(
            id,
            {status, res.has_header("Location") ? res.get_header_value("Location") : "", res.body});
        res.set_header("Upload-Complete", std::to_string(status));
      } catch (const std::exception& e) {
        // The answer stands; the session keeps its bytes, and asking again ingests them again
        // (answered "already present" when they were stored).
        log("warn", "upload session " + id + ": cannot record its outcome: " + e.what());
      }
    }
  });
}

}  // namespace polmap::mapping
