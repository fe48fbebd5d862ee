// PostgresMapStore: resumable upload sessions (rows in upload_sessions, bytes in
// <package_dir>/uploads/<id>). The quota check and the insert run in one transaction under
// the store's write lock, so concurrent creates (also on other replicas) cannot exceed it.
#include "polmap/util/file.hpp"
#include "postgres_store_impl.hpp"

namespace polmap::mapping {
namespace fs = std::filesystem;

namespace {

constexpr const char* kSessionColumns =
    "id, owner, length_bytes, offset_bytes, COALESCE(sha256, ''), created_at, expires_at, "
    "file_path, outcome_status, outcome_location, outcome_body";

UploadSession session_from_row(const fs::path& uploads_dir, const Result& s, int i) {
  UploadSession u;
  u.id = s.text(i, 0);
  u.owner = s.text(i, 1);
  u.length_bytes = static_cast<std::uint64_t>(s.i64(i, 2));
  u.offset_bytes = static_cast<std::uint64_t>(s.i64(i, 3));
  u.sha256 = s.text(i, 4);
  u.created_at = s.text(i, 5);
  u.expires_at = s.text(i, 6);
  u.file = uploads_dir / s.text(i, 7);
  if (s.i64(i, 8) != 0) {
    u.outcome = UploadOutcome{static_cast<int>(s.i64(i, 8)), s.text(i, 9), s.text(i, 10)};
  }
  return u;
}

}  // namespace

CreateUploadSessionResult PostgresMapStore::create_upload_session(const UploadSessionRequest& r) {
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
    const Result s = c.run(
        "SELECT COUNT(*), COALESCE(SUM(length_bytes), 0)::bigint FROM upload_sessions "
        "WHERE owner = $1 AND expires_at > $2 AND outcome_status = 0",
        r.owner, now);
    res.open_sessions = static_cast<std::size_t>(s.i64(0, 0));
    res.open_bytes = static_cast<std::uint64_t>(s.i64(0, 1));
    if (res.open_sessions + 1 > r.max_sessions_per_owner) {
      res.status = CreateUploadSessionResult::Status::TooManySessions;
      return res;
    }
    if (res.open_bytes + r.length_bytes > r.max_bytes_per_owner ||
        res.open_bytes + r.length_bytes < res.open_bytes) {
      res.status = CreateUploadSessionResult::Status::TooManyBytes;
      return res;
    }
    std::optional<std::string> sha;
    if (!r.sha256.empty()) sha = r.sha256;
    c.run(
        "INSERT INTO upload_sessions(id, owner, length_bytes, offset_bytes, sha256, created_at, "
        "expires_at, file_path) VALUES ($1, $2, $3, 0, $4, $5, $6, $7)",
        id, r.owner, static_cast<std::int64_t>(r.length_bytes), sha, now, expires, id);
    res.status = CreateUploadSessionResult::Status::Created;
    res.session = {id, r.owner, r.length_bytes, 0, r.sha256, now, expires, file, std::nullopt};
    return res;
  });
  if (out.status == CreateUploadSessionResult::Status::Created) guard.release();
  return out;
}

std::optional<UploadSession> PostgresMapStore::get_upload_session(std::string_view id) const {
  return impl_->read([&](Connection& c) -> std::optional<UploadSession> {
    const Result r =
        c.run(std::string("SELECT ") + kSessionColumns + " FROM upload_sessions WHERE id = $1", id);
    if (r.empty()) return std::nullopt;
    return session_from_row(impl_->uploads_dir, r, 0);
  });
}

bool PostgresMapStore::advance_upload_offset(std::string_view id, std::uint64_t from,
                                             std::uint64_t to) {
  if (to <= from) {
    throw ValidationError("advance_upload_offset: offset must grow (" + std::to_string(from) +
                          " -> " + std::to_string(to) + ")");
  }
  return impl_->write([&](Connection& c) {
    const Result r = c.run("SELECT length_bytes FROM upload_sessions WHERE id = $1", id);
    if (r.empty()) return false;
    const std::int64_t length = r.i64(0, 0);
    if (to > static_cast<std::uint64_t>(length)) {
      throw ValidationError("advance_upload_offset: offset " + std::to_string(to) +
                            " beyond the session's length " + std::to_string(length));
    }
    return c.run(
                "UPDATE upload_sessions SET offset_bytes = $1 WHERE id = $2 AND offset_bytes = $3 "
                "AND outcome_status = 0",
                static_cast<std::int64_t>(to), id, static_cast<std::int64_t>(from))
               .affected() == 1;
  });
}

bool PostgresMapStore::delete_upload_session(std::string_view id) {
  std::optional<fs::path> file;
  impl_->write([&](Connection& c) {
    const Result r = c.run("DELETE FROM upload_sessions WHERE id = $1 RETURNING file_path", id);
    if (!r.empty()) file = impl_->uploads_dir / r.text(0, 0);
  });
  if (!file) return false;
  std::error_code ec;
  fs::remove(*file, ec);  // after commit; a failure leaves an orphan swept on open
  return true;
}

bool PostgresMapStore::complete_upload_session(std::string_view id, const UploadOutcome& outcome) {
  validate_upload_outcome(outcome);
  std::optional<fs::path> file;
  impl_->write([&](Connection& c) {
    const Result r = c.run(
        "UPDATE upload_sessions SET outcome_status = $1, outcome_location = $2, outcome_body = $3 "
        "WHERE id = $4 AND outcome_status = 0 RETURNING file_path",
        outcome.http_status, outcome.location, outcome.body, id);
    if (!r.empty()) file = impl_->uploads_dir / r.text(0, 0);
  });
  if (!file) return false;
  std::error_code ec;
  fs::remove(*file, ec);  // after commit; a failure leaves an orphan swept on open
  return true;
}

std::size_t PostgresMapStore::sweep_expired_upload_sessions(
    std::chrono::system_clock::time_point now) {
  const std::string cutoff = iso_utc(now);
  std::vector<fs::path> files;
  impl_->write([&](Connection& c) {
    const Result r =
        c.run("DELETE FROM upload_sessions WHERE expires_at <= $1 RETURNING file_path", cutoff);
    for (int i = 0; i < r.rows(); ++i) files.push_back(impl_->uploads_dir / r.text(i, 0));
  });
  std::error_code ec;
  for (const fs::path& f : files) fs::remove(f, ec);
  return files.size();
}

}  // namespace polmap::mapping
