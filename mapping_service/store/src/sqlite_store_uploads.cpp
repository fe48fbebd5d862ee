// SqliteMapStore: resumable upload sessions (rows in upload_sessions, bytes in
// <db>.uploads/<id>). The store keeps the acknowledged offset and the files' lifetime; the
// server appends the bytes (it holds the file lock while it does).
#include <fcntl.h>
#include <sys/random.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <limits>

#include "polmap/util/file.hpp"
#include "polmap/util/text.hpp"
#include "sqlite_store_impl.hpp"

namespace polmap::mapping {
namespace fs = std::filesystem;

namespace {

constexpr const char* kSessionColumns =
    "id, owner, length_bytes, offset_bytes, COALESCE(sha256, ''), created_at, expires_at, "
    "file_path, outcome_status, outcome_location, outcome_body";

UploadSession session_from_row(const fs::path& uploads_dir, Stmt& s) {
  UploadSession u;
  u.id = s.text(0);
  u.owner = s.text(1);
  u.length_bytes = static_cast<std::uint64_t>(s.i64(2));
  u.offset_bytes = static_cast<std::uint64_t>(s.i64(3));
  u.sha256 = s.text(4);
  u.created_at = s.text(5);
  u.expires_at = s.text(6);
  u.file = uploads_dir / s.text(7);
  if (s.i64(8) != 0) u.outcome = UploadOutcome{static_cast<int>(s.i64(8)), s.text(9), s.text(10)};
  return u;
}

}  // namespace

CreateUploadSessionResult SqliteMapStore::create_upload_session(const UploadSessionRequest& r) {
  Impl& I = *impl_;
  validate_upload_request(r);
  const std::string now = iso_utc(r.now);
  const std::string expires = iso_utc(r.now + std::chrono::seconds(r.ttl_s));
  const std::string id = random_session_id();
  const fs::path file = I.uploads_dir / id;

  // The file first, durable with its directory entry, then the row that names it: a crash
  // in between leaves a file without a row, swept on the owner's next open.
  create_session_file(file);
  util::ScopedTempDir guard(file);  // (a file too) removed unless the row commits
  util::sync_directory(I.uploads_dir);

  CreateUploadSessionResult out = I.write([&](Connection& c) {
    CreateUploadSessionResult res;
    auto s = c.stmt(
        "SELECT COUNT(*), COALESCE(SUM(length_bytes), 0) FROM upload_sessions "
        "WHERE owner = ?1 AND expires_at > ?2 AND outcome_status = 0");
    s.bind(1, r.owner).bind(2, now);
    if (s.step()) {
      res.open_sessions = static_cast<std::size_t>(s.i64(0));
      res.open_bytes = static_cast<std::uint64_t>(s.i64(1));
    }
    if (res.open_sessions + 1 > r.max_sessions_per_owner) {
      res.status = CreateUploadSessionResult::Status::TooManySessions;
      return res;
    }
    if (res.open_bytes + r.length_bytes > r.max_bytes_per_owner ||
        res.open_bytes + r.length_bytes < res.open_bytes) {
      res.status = CreateUploadSessionResult::Status::TooManyBytes;
      return res;
    }
    auto ins = c.stmt(
        "INSERT INTO upload_sessions(id, owner, length_bytes, offset_bytes, sha256, created_at, "
        "expires_at, file_path) VALUES (?1, ?2, ?3, 0, ?4, ?5, ?6, ?7)");
    ins.bind(1, id).bind(2, r.owner).bind(3, static_cast<std::int64_t>(r.length_bytes));
    if (r.sha256.empty()) {
      ins.bind_null(4);
    } else {
      ins.bind(4, r.sha256);
    }
    ins.bind(5, now).bind(6, expires).bind(7, id).run();
    res.status = CreateUploadSessionResult::Status::Created;
    res.session = {id, r.owner, r.length_bytes, 0, r.sha256, now, expires, file, std::nullopt};
    return res;
  });
  if (out.status == CreateUploadSessionResult::Status::Created) guard.release();
  return out;
}

std::optional<UploadSession> SqliteMapStore::get_upload_session(std::string_view id) const {
  return impl_->read([&](Connection& c) -> std::optional<UploadSession> {
    auto s =
        c.stmt(std::string("SELECT ") + kSessionColumns + " FROM upload_sessions WHERE id = ?1");
    s.bind(1, id);
    if (!s.step()) return std::nullopt;
    return session_from_row(impl_->uploads_dir, s);
  });
}

bool SqliteMapStore::advance_upload_offset(std::string_view id, std::uint64_t from,
                                           std::uint64_t to) {
  if (to <= from) {
    throw ValidationError("advance_upload_offset: offset must grow (" + std::to_string(from) +
                          " -> " + std::to_string(to) + ")");
  }
  return impl_->write([&](Connection& c) {
    std::int64_t length = 0;
    {
      auto s = c.stmt("SELECT length_bytes FROM upload_sessions WHERE id = ?1");
      s.bind(1, id);
      if (!s.step()) return false;
      length = s.i64(0);
    }
    if (to > static_cast<std::uint64_t>(length)) {
      throw ValidationError("advance_upload_offset: offset " + std::to_string(to) +
                            " beyond the session's length " + std::to_string(length));
    }
    c.stmt(
         "UPDATE upload_sessions SET offset_bytes = ?1 WHERE id = ?2 AND offset_bytes = ?3 AND "
         "outcome_status = 0")
        .bind(1, static_cast<std::int64_t>(to))
        .bind(2, id)
        .bind(3, static_cast<std::int64_t>(from))
        .run();
    return c.changes() == 1;
  });
}

bool SqliteMapStore::delete_upload_session(std::string_view id) {
  std::optional<fs::path> file;
  impl_->write([&](Connection& c) {
    {
      auto s = c.stmt("SELECT file_path FROM upload_sessions WHERE id = ?1");
      s.bind(1, id);
      if (!s.step()) return;
      file = impl_->uploads_dir / s.text(0);
    }
    c.stmt("DELETE FROM upload_sessions WHERE id = ?1").bind(1, id).run();
  });
  if (!file) return false;
  std::error_code ec;
  fs::remove(*file, ec);  // after commit; a failure leaves an orphan swept on open
  return true;
}

bool SqliteMapStore::complete_upload_session(std::string_view id, const UploadOutcome& outcome) {
  validate_upload_outcome(outcome);
  std::optional<fs::path> file;
  impl_->write([&](Connection& c) {
    {
      auto s = c.stmt("SELECT file_path FROM upload_sessions WHERE id = ?1 AND outcome_status = 0");
      s.bind(1, id);
      if (!s.step()) return;
      file = impl_->uploads_dir / s.text(0);
    }
    c.stmt(
         "UPDATE upload_sessions SET outcome_status = ?1, outcome_location = ?2, outcome_body = "
         "?3 WHERE id = ?4")
        .bind(1, static_cast<std::int64_t>(outcome.http_status))
        .bind(2, outcome.location)
        .bind(3, outcome.body)
        .bind(4, id)
        .run();
  });
  if (!file) return false;
  std::error_code ec;
  fs::remove(*file, ec);  // after commit; a failure leaves an orphan swept on open
  return true;
}

std::size_t SqliteMapStore::sweep_expired_upload_sessions(
    std::chrono::system_clock::time_point now) {
  const std::string cutoff = iso_utc(now);
  std::vector<fs::path> files;
  impl_->write([&](Connection& c) {
    {
      auto s = c.stmt("SELECT file_path FROM upload_sessions WHERE expires_at <= ?1");
      s.bind(1, cutoff);
      while (s.step()) files.push_back(impl_->uploads_dir / s.text(0));
    }
    c.stmt("DELETE FROM upload_sessions WHERE expires_at <= ?1").bind(1, cutoff).run();
  });
  std::error_code ec;
  for (const fs::path& f : files) fs::remove(f, ec);
  return files.size();
}

}  // namespace polmap::mapping
