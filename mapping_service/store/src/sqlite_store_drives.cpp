// SqliteMapStore: drives (idempotent ingest, trajectories, deletion) and candidates.
#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <random>
#include <set>
#include <unordered_map>
#include <unordered_set>

#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/schema/json.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "polmap/tiles/polyline_simplify.hpp"
#include "polmap/util/file.hpp"
#include "polmap/util/text.hpp"
#include "sqlite_store_impl.hpp"

namespace polmap::mapping {
namespace fs = std::filesystem;

// --------------------------------------------------------------------- drives

PutDriveResult SqliteMapStore::put_drive(const DrivePackage& package,
                                         const fs::path& package_location,
                                         const std::string& content_hash) {
  Impl& I = *impl_;
  if (!util::is_lower_hex(content_hash) || content_hash.size() < 16 || content_hash.size() > 128) {
    throw ValidationError("put_drive: content hash must be lower-case hex, got '" + content_hash +
                          "'");
  }
  const DriveManifest& m = package.manifest;
  if (m.drive_id.empty())
    throw ValidationError("put_drive: manifest.json: field 'drive_id' is empty");
  if (auto existing = find_drive_by_hash(content_hash)) {
    return {PutDriveResult::Status::AlreadyPresent, *existing};
  }
  if (auto same_name = get_drive(m.drive_id)) {
    // Stored by another thread or replica between the two reads: the same bytes.
    if (same_name->content_hash == content_hash) {
      return {PutDriveResult::Status::AlreadyPresent, *same_name};
    }
    throw ConflictError("drive '" + m.drive_id + "' is already stored with content hash " +
                        same_name->content_hash + " (upload has " + content_hash + ")");
  }
  std::error_code ec;
  if (package_location.empty() || !fs::exists(package_location, ec)) {
    throw IoError("put_drive: package location '" + package_location.string() + "' does not exist");
  }

  // Geodetic coordinates of everything (drive frame -> WGS84) and the bbox.
  const PackageGeo geo = package_geo(package);
  const GeoBox& bbox = geo.bbox;
  const std::vector<GeoPoint>& point_geo = geo.points;
  const auto& line_geo = geo.lines;

  // 1. Files into a temp dir of the drive store (same file system: rename is atomic).
  // Both guards remove their directory unless released: the staging directory always,
  // the renamed package directory unless the transaction that names it committed.
  const std::string rand_suffix = std::to_string(std::random_device{}());
  util::ScopedTempDir staging(I.drives_dir / (".tmp-" + content_hash + "-" + rand_suffix));
  util::ScopedTempDir placed(fs::path{});
  const fs::path& tmp = staging.path();
  const fs::path final_dir = I.drives_dir / content_hash;
  const std::string rel_path = content_hash;
  try {
    fs::create_directories(tmp);
    stage_package_files(package_location, tmp);  // durable before any row names them
    const std::int64_t bytes = dir_bytes(tmp);
    I.hook("files_copied");

    // 2. Rows, rename, commit: one transaction.
    const auto result = I.write([&](Connection& c) -> std::optional<DriveRecord> {
      // Re-check under the write lock: another thread may have stored it meanwhile.
      if (auto existing = I.drive_where(c, "content_hash = ?1", content_hash)) return existing;
      if (auto same = I.drive_where(c, "drive_id = ?1", m.drive_id)) {
        throw ConflictError("drive '" + m.drive_id + "' is already stored with content hash " +
                            same->content_hash);
      }
      c.stmt(
           "INSERT INTO drives(drive_id, content_hash, vehicle_id, start_time_s, end_time_s, "
           "min_lat_deg, min_lon_deg, max_lat_deg, max_lon_deg, pol_level, distance_m, num_points, "
           "num_lines, manifest_json, package_path, package_bytes, ingested_at) VALUES "
           "(?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17)")
          .bind(1, m.drive_id)
          .bind(2, content_hash)
          .bind(3, m.vehicle_id)
          .bind(4, m.start_time_s)
          .bind(5, m.end_time_s)
          .bind(6, bbox.min_lat_deg)
          .bind(7, bbox.min_lon_deg)
          .bind(8, bbox.max_lat_deg)
          .bind(9, bbox.max_lon_deg)
          .bind(10, to_string(m.pol_level))
          .bind(11, m.distance_m)
          .bind(12, static_cast<std::int64_t>(package.points.size()))
          .bind(13, static_cast<std::int64_t>(package.lines.size()))
          .bind(14, manifest_json(package).dump())
          .bind(15, rel_path)
          .bind(16, bytes)
          .bind(17, now_iso())
          .run();
      const std::int64_t drive_row = c.last_id();
      insert_rtree(c, "drives_rtree", drive_row, bbox.min_lat_deg, bbox.max_lat_deg,
                   bbox.min_lon_deg, bbox.max_lon_deg);
      const std::string ins =
          "INSERT INTO candidates(drive, kind, lat_deg, lon_deg, x_m, y_m, end_lat_deg, "
          "end_lon_deg, end_x_m, end_y_m, strength, power_db, scattering, num_cells) VALUES "
          "(?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14)";
      for (std::size_t i = 0; i < package.points.size(); ++i) {
        const auto& p = package.points[i];
        const auto& g = point_geo[i];
        c.stmt(ins)
            .bind(1, drive_row)
            .bind(2, 0)
            .bind(3, g.lat_deg)
            .bind(4, g.lon_deg)
            .bind(5, p.position_m.x())
            .bind(6, p.position_m.y())
            .bind_null(7)
            .bind_null(8)
            .bind_null(9)
            .bind_null(10)
            .bind(11, p.strength)
            .bind(12, p.power_db)
            .bind(13, static_cast<int>(p.scattering))
            .bind(14, static_cast<std::int64_t>(p.num_cells))
            .run();
        insert_rtree(c, "candidates_rtree", c.last_id(), g.lat_deg, g.lat_deg, g.lon_deg,
                     g.lon_deg);
      }
      for (std::size_t i = 0; i < package.lines.size(); ++i) {
        const auto& l = package.lines[i];
        const auto& [a, b] = line_geo[i];
        c.stmt(ins)
            .bind(1, drive_row)
            .bind(2, 1)
            .bind(3, a.lat_deg)
            .bind(4, a.lon_deg)
            .bind(5, l.start_m.x())
            .bind(6, l.start_m.y())
            .bind(7, b.lat_deg)
            .bind(8, b.lon_deg)
            .bind(9, l.end_m.x())
            .bind(10, l.end_m.y())
            .bind(11, l.strength)
            .bind_null(12)
            .bind_null(13)
            .bind_null(14)
            .run();
        insert_rtree(c, "candidates_rtree", c.last_id(), std::min(a.lat_deg, b.lat_deg),
                     std::max(a.lat_deg, b.lat_deg), std::min(a.lon_deg, b.lon_deg),
                     std::max(a.lon_deg, b.lon_deg));
      }
      c.stmt(
           "INSERT INTO drive_trajectories(drive, min_spacing_m, samples_json, path_blob) "
           "VALUES (?1, ?2, ?3, ?4)")
          .bind(1, drive_row)
          .bind(2, kTrajectorySpacingM)
          .bind(3, decimated_trajectory_json(package.trajectory).dump())
          .bind_blob(4, packed_path(package.trajectory))
          .run();
      I.hook("rows_inserted");
      std::error_code e;
      if (fs::exists(final_dir, e)) fs::remove_all(final_dir, e);  // crash leftover
      fs::rename(tmp, final_dir);
      staging.release();
      util::sync_directory(I.drives_dir);  // the rename too, before the commit
      placed = util::ScopedTempDir(final_dir);
      I.hook("files_renamed");
      return std::nullopt;
    });
    if (result) return {PutDriveResult::Status::AlreadyPresent, *result};  // raced, same bytes
    placed.release();  // committed: the package directory is the store's now
  } catch (const fs::filesystem_error& e) {
    // The guards remove what was copied or renamed; the transaction has rolled back.
    if (no_space(e.code()))
      throw StorageFullError(std::string("the drive store is full: ") + e.what());
    throw;
  }
  auto rec = get_drive(m.drive_id);
  if (!rec) throw IoError("put_drive: drive '" + m.drive_id + "' vanished after insert");
  return {PutDriveResult::Status::Inserted, *rec};
}

std::vector<DriveRecord> SqliteMapStore::list_drives() const {
  return impl_->read([&](Connection& c) {
    std::vector<DriveRecord> out;
    auto s = c.stmt(std::string("SELECT ") + kDriveColumns + " FROM drives ORDER BY id");
    while (s.step()) out.push_back(impl_->drive_from_row(s));
    return out;
  });
}

std::optional<DriveRecord> SqliteMapStore::get_drive(std::string_view drive_id) const {
  return impl_->read(
      [&](Connection& c) { return impl_->drive_where(c, "drive_id = ?1", drive_id); });
}

std::optional<DriveRecord> SqliteMapStore::find_drive_by_hash(std::string_view content_hash) const {
  return impl_->read(
      [&](Connection& c) { return impl_->drive_where(c, "content_hash = ?1", content_hash); });
}

std::vector<GeoPoint> SqliteMapStore::drive_path(std::string_view drive_id) const {
  return impl_->read([&](Connection& c) {
    auto d = impl_->drive_where(c, "drive_id = ?1", drive_id);
    if (!d) throw NotFoundError("drive '" + std::string(drive_id) + "' is not in the store");
    auto s = c.stmt("SELECT path_blob, samples_json FROM drive_trajectories WHERE drive = ?1");
    s.bind(1, d->row);
    if (!s.step()) return std::vector<GeoPoint>{};  // ingested before migration 2
    if (!s.is_null(0)) return unpack_path(s.blob(0));
    // Ingested before migration 5: simplify the decimated samples.
    return path_from_samples_json(nlohmann::json::parse(s.text(1)));
  });
}

std::vector<TrajectorySample> SqliteMapStore::drive_trajectory(std::string_view drive_id) const {
  return impl_->read([&](Connection& c) {
    auto d = impl_->drive_where(c, "drive_id = ?1", drive_id);
    if (!d) throw NotFoundError("drive '" + std::string(drive_id) + "' is not in the store");
    auto s = c.stmt("SELECT samples_json FROM drive_trajectories WHERE drive = ?1");
    s.bind(1, d->row);
    if (!s.step()) return std::vector<TrajectorySample>{};  // ingested before migration 2
    return trajectory_from_json(nlohmann::json::parse(s.text(0)));
  });
}

std::vector<DriveRecord> SqliteMapStore::drives_in(const GeoBox& box) const {
  return impl_->read([&](Connection& c) {
    std::vector<DriveRecord> out;
    std::set<std::int64_t> seen;
    for (const GeoBox& b : split_box(box)) {
      auto s = c.stmt(std::string("SELECT ") + kDriveColumns +
                      " FROM drives WHERE id IN (SELECT id FROM drives_rtree WHERE max_lat >= ?1 "
                      "AND min_lat <= ?2 AND max_lon >= ?3 AND min_lon <= ?4) ORDER BY id");
      s.bind(1, b.min_lat_deg).bind(2, b.max_lat_deg).bind(3, b.min_lon_deg).bind(4, b.max_lon_deg);
      while (s.step()) {
        DriveRecord d = impl_->drive_from_row(s);
        if (seen.insert(d.row).second && box_intersects(box, d.bbox.min_lat_deg, d.bbox.min_lon_deg,
                                                        d.bbox.max_lat_deg, d.bbox.max_lon_deg)) {
          out.push_back(std::move(d));
        }
      }
    }
    std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.row < b.row; });
    return out;
  });
}

void SqliteMapStore::Impl::migrate_archived_packages() {
  struct Archived {
    std::int64_t row;
    std::string drive_id, hash, rel_path;
  };
  const auto archived = read([](Connection& c) {
    std::vector<Archived> out;
    auto s = c.stmt(
        "SELECT id, drive_id, content_hash, package_path FROM drives "
        "WHERE package_path != content_hash");
    while (s.step()) out.push_back({s.i64(0), s.text(1), s.text(2), s.text(3)});
    return out;
  });
  for (const auto& a : archived) {
    const fs::path final_dir = drives_dir / a.hash;
    const fs::path archive = drives_dir / a.rel_path;
    const bool clash = archive.filename() == kManifestFileName ||
                       archive.filename() == "gridmap.tif" ||
                       archive.filename() == "candidates.gpkg";
    std::error_code ec;
    util::ScopedTempDir staging(drives_dir / (".tmp-migrate-" + a.hash));
    fs::remove_all(staging.path(), ec);  // a crashed earlier attempt
    std::string why;
    if (!util::is_lower_hex(a.hash) || archive.parent_path() != final_dir || clash) {
      why = "package path '" + a.rel_path + "' is not <hash>/<archive>";
    } else if (fs::is_regular_file(archive, ec)) {
      try {
        unpack_drive_package(util::read_file_bytes(archive), staging.path());
        (void)read_and_validate_package(staging.path());
      } catch (const Error& e) {
        why = e.what();
      }
    } else if (fs::is_regular_file(final_dir / kManifestFileName, ec)) {
      // A crash after the members were placed: they are the package now.
      try {
        (void)read_and_validate_package(final_dir);
      } catch (const Error& e) {
        why = e.what();
      }
    } else {
      why = "archive " + archive.string() + " is missing";
    }
    if (why.empty()) {
      // Members go next to the archive (atomic renames on one file system; a crash in
      // between is redone on the next open), then the row is repointed, then the archive
      // goes. Until the commit the row names the archive, which stays intact.
      if (fs::exists(staging.path(), ec)) {
        util::sync_tree(staging.path());
        for (const auto& e : fs::directory_iterator(staging.path())) {
          fs::rename(e.path(), final_dir / e.path().filename());
        }
        util::sync_directory(final_dir);
      }
      write([&](Connection& c) {
        c.stmt("UPDATE drives SET package_path = ?1 WHERE id = ?2")
            .bind(1, a.hash)
            .bind(2, a.row)
            .run();
      });
      fs::remove(archive, ec);
      ++archive_report.migrated;
      continue;
    }
    // No longer valid: out of the store, the archive kept for inspection.
    const fs::path quarantine = drives_dir / "quarantine";
    fs::create_directories(quarantine, ec);
    if (fs::is_regular_file(archive, ec)) fs::rename(archive, quarantine / (a.hash + ".tar"), ec);
    write([&](Connection& c) { c.stmt("DELETE FROM drives WHERE id = ?1").bind(1, a.row).run(); });
    fs::remove_all(final_dir, ec);
    archive_report.quarantined.push_back(a.drive_id + ": " + why);
  }
}

bool SqliteMapStore::delete_drive(std::string_view drive_id) {
  std::optional<fs::path> files;
  impl_->write([&](Connection& c) {
    auto d = impl_->drive_where(c, "drive_id = ?1", drive_id);
    if (!d) return;
    c.stmt("DELETE FROM drives WHERE id = ?1").bind(1, d->row).run();
    files = impl_->drives_dir / d->content_hash;
  });
  if (!files) return false;
  std::error_code ec;
  fs::remove_all(*files, ec);  // after commit; a failure leaves an orphan swept on open
  return true;
}

// --------------------------------------------------------------------- candidates

CandidateSet SqliteMapStore::candidates_in(const std::optional<GeoBox>& region,
                                           std::span<const std::string> excluded) const {
  return impl_->read([&](Connection& c) {
    std::unordered_set<std::int64_t> excluded_rows;
    for (const auto& name : excluded) {
      auto d = impl_->drive_where(c, "drive_id = ?1", name);
      if (!d) throw NotFoundError("excluded drive '" + name + "' is not in the store");
      excluded_rows.insert(d->row);
    }
    CandidateSet out;
    const std::string cols =
        "SELECT c.id, c.drive, c.kind, c.lat_deg, c.lon_deg, c.x_m, c.y_m, c.end_lat_deg, "
        "c.end_lon_deg, c.end_x_m, c.end_y_m, c.strength, c.power_db, c.scattering, c.num_cells "
        "FROM candidates c";
    auto take = [&](Stmt& s) {
      if (excluded_rows.contains(s.i64(1))) return;
      const double lat = s.f64(3), lon = s.f64(4);
      if (s.i64(2) == 0) {
        if (region && !box_contains(*region, lat, lon)) return;
        StoredPointCandidate p;
        p.id = s.i64(0);
        p.drive = s.i64(1);
        p.position = {lat, lon, 0.0};
        p.candidate.position_m = {s.f64(5), s.f64(6)};
        p.candidate.strength = s.f64(11);
        p.candidate.power_db = s.f64(12);
        p.candidate.scattering = static_cast<ScatteringClass>(s.i64(13) & 3);
        p.candidate.num_cells = static_cast<std::uint32_t>(s.i64(14));
        out.points.push_back(p);
      } else {
        const double lat1 = s.f64(7), lon1 = s.f64(8);
        if (region && !box_intersects(*region, std::min(lat, lat1), std::min(lon, lon1),
                                      std::max(lat, lat1), std::max(lon, lon1))) {
          return;
        }
        StoredLineCandidate l;
        l.id = s.i64(0);
        l.drive = s.i64(1);
        l.start = {lat, lon, 0.0};
        l.end = {lat1, lon1, 0.0};
        l.candidate.start_m = {s.f64(5), s.f64(6)};
        l.candidate.end_m = {s.f64(9), s.f64(10)};
        l.candidate.strength = s.f64(11);
        out.lines.push_back(l);
      }
    };
    if (!region) {
      auto s = c.stmt(cols + " ORDER BY c.id");
      while (s.step()) take(s);
    } else {
      for (const GeoBox& b : split_box(*region)) {
        auto s = c.stmt(cols +
                        " JOIN candidates_rtree r ON r.id = c.id WHERE r.max_lat >= ?1 AND "
                        "r.min_lat <= ?2 AND r.max_lon >= ?3 AND r.min_lon <= ?4 ORDER BY c.id");
        s.bind(1, b.min_lat_deg)
            .bind(2, b.max_lat_deg)
            .bind(3, b.min_lon_deg)
            .bind(4, b.max_lon_deg);
        while (s.step()) take(s);
      }
      if (region->crosses_antimeridian()) {
        auto by_id = [](const auto& a, const auto& b) { return a.id < b.id; };
        auto same = [](const auto& a, const auto& b) { return a.id == b.id; };
        std::sort(out.points.begin(), out.points.end(), by_id);
        out.points.erase(std::unique(out.points.begin(), out.points.end(), same), out.points.end());
        std::sort(out.lines.begin(), out.lines.end(), by_id);
        out.lines.erase(std::unique(out.lines.begin(), out.lines.end(), same), out.lines.end());
      }
    }
    return out;
  });
}

}  // namespace polmap::mapping
