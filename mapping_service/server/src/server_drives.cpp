// Drive endpoints: POST /v1/drives (package upload), GET /v1/drives, GET/DELETE /v1/drives/{id}.
#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <ctime>

#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/util/file.hpp"
#include "polmap/util/sha256.hpp"
#include "server_impl.hpp"

namespace polmap::mapping {
namespace {

// A file created for one upload and removed when the request ends, whatever happens.
class TempUpload {
 public:
  explicit TempUpload(const std::filesystem::path& dir) {
    std::string templ = (dir / "polmap-upload-XXXXXX.tar").string();
    fd_ = ::mkstemps(templ.data(), 4);
    if (fd_ < 0)
      throw IoError("cannot create upload file in " + dir.string() + ": " + std::strerror(errno));
    path_ = templ;
  }
  ~TempUpload() {
    if (fd_ >= 0) ::close(fd_);
    std::error_code ec;
    std::filesystem::remove(path_, ec);
  }
  TempUpload(const TempUpload&) = delete;
  TempUpload& operator=(const TempUpload&) = delete;

  /// 0, or the errno of the failed write.
  int write(const char* data, std::size_t n) { return util::write_all(fd_, {data, n}); }
  bool close() {
    const int rc = ::close(fd_);
    fd_ = -1;
    return rc == 0;
  }
  [[nodiscard]] const std::filesystem::path& path() const { return path_; }

 private:
  int fd_ = -1;
  std::filesystem::path path_;
};

/// Throws StorageFullError for ENOSPC/EDQUOT (HTTP 507), IoError otherwise.
[[noreturn]] void throw_file_error(int err, const std::string& what) {
  const std::string msg = what + ": " + std::strerror(err);
  if (err == ENOSPC || err == EDQUOT) throw StorageFullError(msg);
  throw IoError(msg);
}

/// The members of a validated archive as files in a new directory below `parent`, read by
/// the same ustar reader that validated them; a full upload directory is StorageFullError
/// (507, not 500).
util::ScopedTempDir write_members(std::string_view tar_bytes, const std::filesystem::path& parent) {
  std::string templ = (parent / "polmap-upload-members-XXXXXX").string();
  if (::mkdtemp(templ.data()) == nullptr) throw_file_error(errno, "cannot create " + templ);
  util::ScopedTempDir dir{std::filesystem::path(templ)};
  unpack_drive_package(tar_bytes, dir.path());
  return dir;
}

bool acceptable_upload_type(const std::string& content_type) {
  const std::string t = content_type.substr(0, content_type.find(';'));
  return t.empty() || t == "application/x-tar" || t == "application/tar" ||
         t == "application/octet-stream";
}

}  // namespace

void Server::Impl::reply_uploads_busy(httplib::Response& res) const {
  res.set_header("Retry-After", "5");
  reply_error(res, 503,
              "the server is receiving " + std::to_string(cfg.max_concurrent_uploads) +
                  " uploads already; retry later",
              "body");
}

nlohmann::json drive_to_json(const DriveRecord& d, bool with_manifest) {
  nlohmann::json j{{"drive_id", d.drive_id},
                   {"content_hash", d.content_hash},
                   {"vehicle_id", d.vehicle_id},
                   {"start_time_s", d.start_time_s},
                   {"end_time_s", d.end_time_s},
                   {"bbox", geobox_to_json(d.bbox)},
                   {"pol_level", std::string(to_string(d.pol_level))},
                   {"distance_m", d.distance_m},
                   {"num_points", d.num_points},
                   {"num_lines", d.num_lines},
                   {"ingested_at", d.ingested_at},
                   {"href", "/v1/drives/" + d.drive_id}};
  if (with_manifest) j["manifest"] = d.manifest;
  // The validated trajectory's accuracy (store_common.cpp): which drives are consumer-grade.
  if (d.manifest.is_object() && d.manifest.contains("positioning")) {
    j["positioning"] = d.manifest["positioning"];
  }
  return j;
}

std::size_t Server::Impl::apply_retention() {
  if (cfg.drive_retention_days <= 0.0) return 0;
  const auto cutoff = std::chrono::system_clock::now() -
                      std::chrono::duration_cast<std::chrono::system_clock::duration>(
                          std::chrono::duration<double>(cfg.drive_retention_days * 86400.0));
  const std::time_t t = std::chrono::system_clock::to_time_t(cutoff);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char iso[32];
  std::strftime(iso, sizeof iso, "%Y-%m-%dT%H:%M:%SZ", &tm);  // the store's ingested_at format
  std::size_t n = 0;
  try {
    for (const DriveRecord& d : store.list_drives()) {
      if (d.ingested_at < iso && store.delete_drive(d.drive_id)) ++n;
    }
  } catch (const std::exception& e) {
    log("error", std::string("retention: ") + e.what());
  }
  if (n > 0) {
    log("info", "retention: deleted " + std::to_string(n) + " drives ingested before " + iso);
  }
  return n;
}

std::filesystem::path Server::Impl::upload_scratch_dir() const {
  return cfg.upload_dir.empty() ? std::filesystem::temp_directory_path() : cfg.upload_dir;
}

int Server::Impl::ingest_package(const std::string& bytes, const std::string& hash,
                                 const ApiKey& key, const std::filesystem::path& scratch_dir,
                                 httplib::Response& res) {
  const std::uint64_t received = bytes.size();
  auto already_present = [&](const DriveRecord& existing) {
    metrics.upload("already_present", received);
    nlohmann::json j = drive_to_json(existing, false);
    j["status"] = "already_present";
    res.set_header("Location", "/v1/drives/" + existing.drive_id);
    reply_json(res, 200, j);
    return 200;
  };
  if (auto existing = store.find_drive_by_hash(hash)) return already_present(*existing);
  // One parser, one canonical copy: the bytes validated here are unpacked by the same ustar
  // reader into member files, and only those are stored; GDAL never sees the archive.
  auto pkg = try_validate_package_bytes(bytes);
  if (!pkg) {
    const PackageError& e = pkg.error();
    const int status = e.http_status == 422 ? 422 : 400;
    metrics.upload(status == 422 ? "invalid" : "bad_request", received);
    log("info", "upload rejected: " + e.what());
    nlohmann::json extra{{"file", e.file}};
    reply_error(res, status, e.what(), e.field, extra);
    return status;
  }
  if (!key.vehicle_id.empty() && pkg->manifest.vehicle_id != key.vehicle_id) {
    metrics.upload("forbidden", received);
    reply_error(res, 403,
                "this key uploads drives of vehicle '" + key.vehicle_id +
                    "', the package is of vehicle '" + pkg->manifest.vehicle_id + "'",
                "vehicle_id");
    return 403;
  }
  PutDriveResult put;
  try {
    const util::ScopedTempDir members = write_members(bytes, scratch_dir);
    put = store.put_drive(*pkg, members.path(), hash);
  } catch (const ConflictError& e) {
    // Another replica of the same store may have stored these very bytes meanwhile: then
    // the upload is a repeat, not a conflict.
    if (auto existing = store.find_drive_by_hash(hash)) return already_present(*existing);
    metrics.upload("conflict", received);
    reply_error(res, 409, e.what(), "drive_id");
    return 409;
  } catch (const StorageFullError& e) {
    // Nothing is kept: the members directory is removed, the store rolled back.
    metrics.upload("storage_full", received);
    log("warn", "upload: storage full: " + std::string(e.what()));
    reply_error(res, 507, kStorageFullMessage);
    return 507;
  }
  nlohmann::json j = drive_to_json(put.drive, false);
  res.set_header("Location", "/v1/drives/" + put.drive.drive_id);
  if (put.status == PutDriveResult::Status::Inserted) {
    metrics.upload("inserted", received);
    log("info", "drive " + put.drive.drive_id + " ingested (" + std::to_string(received) +
                    " bytes, " + std::to_string(put.drive.num_points) + " points, " +
                    std::to_string(put.drive.num_lines) + " lines)");
    j["status"] = "inserted";
    reply_json(res, 201, j);
    return 201;
  }
  metrics.upload("already_present", received);
  j["status"] = "already_present";
  reply_json(res, 200, j);
  return 200;
}

void Server::Impl::register_drive_routes() {
  http.Post("/v1/drives", [this](const httplib::Request& req, httplib::Response& res,
                                 const httplib::ContentReader& reader) {
    set_route("drives_upload");
    // Rejections before the body is read: drain a small body so the keep-alive
    // connection stays usable, otherwise close the connection after replying. Only a
    // declared length is drained: a chunked body (it wins over a Content-Length) has none
    // and could go on for ever.
    auto reject_unread = [&](const char* outcome) {
      metrics.upload(outcome, 0);
      const auto len = std::strtoull(req.get_header_value("Content-Length").c_str(), nullptr, 10);
      if (!req.has_header("Transfer-Encoding") && req.has_header("Content-Length") &&
          len <= (1u << 20)) {
        reader([](const char*, std::size_t) { return true; });
      } else {
        res.set_header("Connection", "close");
      }
    };
    const auto key = require(req, res, Access::Upload);
    if (!key) return reject_unread("unauthorized");
    if (!acceptable_upload_type(req.get_header_value("Content-Type"))) {
      reply_error(
          res, 415,
          "Content-Type must be application/x-tar (the package as one ustar archive), got '" +
              req.get_header_value("Content-Type") + "'",
          "Content-Type");
      return reject_unread("bad_request");
    }
    if (req.has_header("Content-Length")) {
      const auto len = std::strtoull(req.get_header_value("Content-Length").c_str(), nullptr, 10);
      if (len > cfg.max_upload_bytes) {
        reply_error(res, 413,
                    "package of " + std::to_string(len) + " bytes exceeds the upload limit of " +
                        std::to_string(cfg.max_upload_bytes) + " bytes",
                    "Content-Length", {{"limit_bytes", cfg.max_upload_bytes}});
        return reject_unread("too_large");
      }
    }

    // At most max_concurrent_uploads at once; the slot is held until this request ends.
    const ConcurrencySlot slot(uploads_in_flight, cfg.max_concurrent_uploads);
    if (!slot.acquired()) {
      reply_uploads_busy(res);
      return reject_unread("busy");
    }
    const std::filesystem::path dir = upload_scratch_dir();
    TempUpload upload(dir);
    util::Sha256 sha;
    std::uint64_t received = 0;
    bool too_large = false;
    int write_errno = 0;  // of the failed write to the upload file (0: none failed)
    const bool complete = reader([&](const char* data, std::size_t n) {
      received += n;
      if (received > cfg.max_upload_bytes) {
        too_large = true;
        return false;
      }
      // After a failed write the rest is read and dropped (at most the upload limit), so
      // the client, still sending, gets the answer instead of a reset connection.
      if (write_errno != 0) return true;
      sha.update(std::string_view(data, n));
      write_errno = upload.write(data, n);
      return true;
    });
    if (too_large) {
      metrics.upload("too_large", received);
      res.set_header("Connection", "close");
      return reply_error(
          res, 413,
          "package exceeds the upload limit of " + std::to_string(cfg.max_upload_bytes) + " bytes",
          "body", {{"limit_bytes", cfg.max_upload_bytes}});
    }
    if (!complete) {
      // The client went away or sent a malformed/short chunked body: nothing is kept.
      metrics.upload("interrupted", received);
      res.set_header("Connection", "close");
      return reply_error(res, 400,
                         "upload interrupted after " + std::to_string(received) + " bytes", "body");
    }
    if (write_errno == 0 && !upload.close()) write_errno = errno != 0 ? errno : EIO;
    if (write_errno != 0) {
      const std::string what =
          "cannot write " + upload.path().string() + ": " + std::strerror(write_errno);
      if (write_errno == ENOSPC || write_errno == EDQUOT) {
        metrics.upload("storage_full", received);
        log("warn", "upload: storage full: " + what);
        return reply_error(res, 507, kStorageFullMessage);
      }
      metrics.upload("server_error", received);
      throw IoError("upload: " + what);  // 500, detail in the log
    }
    if (received == 0) {
      metrics.upload("bad_request", 0);
      return reply_error(res, 400, "empty body: send the drive package as one ustar archive",
                         "body");
    }
    // One parser, one canonical copy: ingest_package validates these bytes and stores the
    // members its reader unpacks from them; GDAL never sees the archive.
    (void)ingest_package(util::read_file_bytes(upload.path()), sha.hex(), *key, dir, res);
  });

  http.Get("/v1/drives", [this](const httplib::Request& req, httplib::Response& res) {
    set_route("drives_list");
    if (!require(req, res, Access::ReadDrives)) return;
    nlohmann::json list = nlohmann::json::array();
    for (const DriveRecord& d : store.list_drives()) list.push_back(drive_to_json(d, false));
    reply_json(res, 200, {{"drives", list}, {"count", list.size()}});
  });

  http.Get(R"(/v1/drives/([^/]+))", [this](const httplib::Request& req, httplib::Response& res) {
    set_route("drives_get");
    if (!require(req, res, Access::ReadDrives)) return;
    const std::string id = req.matches[1];
    if (auto d = store.get_drive(id)) return reply_json(res, 200, drive_to_json(*d, true));
    reply_error(res, 404, "drive '" + id + "' does not exist", "drive_id");
  });

  // Erasure on request: every drive of one vehicle (its data subject's right to erasure).
  http.Delete(R"(/v1/vehicles/([^/]+)/drives)",
              [this](const httplib::Request& req, httplib::Response& res) {
                set_route("vehicle_erase");
                if (!require(req, res, Access::Operate)) return;
                const std::string vehicle = req.matches[1];
                nlohmann::json ids = nlohmann::json::array();
                for (const DriveRecord& d : store.list_drives()) {
                  if (d.vehicle_id == vehicle && store.delete_drive(d.drive_id))
                    ids.push_back(d.drive_id);
                }
                // Its localization run reports are its data too.
                std::size_t runs = 0;
                if (!vehicle.empty()) {
                  for (const auto& r : store.list_localization_runs(
                           static_cast<std::size_t>(cfg.max_localization_runs), vehicle)) {
                    if (store.delete_localization_run(r.id)) ++runs;
                  }
                }
                log("info", "vehicle " + vehicle + ": " + std::to_string(ids.size()) +
                                " drives and " + std::to_string(runs) + " runs erased");
                reply_json(res, 200,
                           {{"vehicle_id", vehicle},
                            {"deleted", ids.size()},
                            {"drive_ids", ids},
                            {"runs_deleted", runs}});
              });

  http.Delete(R"(/v1/drives/([^/]+))", [this](const httplib::Request& req, httplib::Response& res) {
    set_route("drives_delete");
    if (!require(req, res, Access::Operate)) return;
    const std::string id = req.matches[1];
    if (!store.delete_drive(id)) {
      return reply_error(res, 404, "drive '" + id + "' does not exist", "drive_id");
    }
    log("info", "drive " + id + " deleted");
    res.status = 204;
  });
}

}  // namespace polmap::mapping
