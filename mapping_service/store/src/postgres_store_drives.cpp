// PostgresMapStore: drives (idempotent ingest, trajectories, deletion) and candidates.
#include <algorithm>
#include <random>
#include <set>
#include <unordered_set>

#include "polmap/util/file.hpp"
#include "polmap/util/text.hpp"
#include "postgres_store_impl.hpp"

namespace polmap::mapping {
namespace fs = std::filesystem;

namespace {

/// Inserts the candidates of a drive (ids first_id, first_id + 1, ...: points, then lines,
/// as SQLite numbers them) in one statement over arrays.
void insert_candidates(Connection& c, std::int64_t drive_row, std::int64_t first_id,
                       const DrivePackage& package, const PackageGeo& geo) {
  const std::size_t n = package.points.size() + package.lines.size();
  if (n == 0) return;
  std::vector<std::int64_t> id(n);
  std::vector<int> kind(n);
  std::vector<double> lat(n), lon(n), x(n), y(n), strength(n);
  std::vector<std::optional<double>> end_lat(n), end_lon(n), end_x(n), end_y(n), power(n);
  std::vector<std::optional<std::int64_t>> scattering(n), cells(n);
  std::vector<std::string> wkb(n);
  std::size_t i = 0;
  for (std::size_t k = 0; k < package.points.size(); ++k, ++i) {
    const auto& p = package.points[k];
    const auto& g = geo.points[k];
    id[i] = first_id + static_cast<std::int64_t>(i);
    kind[i] = 0;
    lat[i] = g.lat_deg;
    lon[i] = g.lon_deg;
    x[i] = p.position_m.x();
    y[i] = p.position_m.y();
    strength[i] = p.strength;
    power[i] = p.power_db;
    scattering[i] = static_cast<std::int64_t>(p.scattering);
    cells[i] = static_cast<std::int64_t>(p.num_cells);
    wkb[i] = wkb_point(g.lat_deg, g.lon_deg);
  }
  for (std::size_t k = 0; k < package.lines.size(); ++k, ++i) {
    const auto& l = package.lines[k];
    const auto& [a, b] = geo.lines[k];
    id[i] = first_id + static_cast<std::int64_t>(i);
    kind[i] = 1;
    lat[i] = a.lat_deg;
    lon[i] = a.lon_deg;
    x[i] = l.start_m.x();
    y[i] = l.start_m.y();
    end_lat[i] = b.lat_deg;
    end_lon[i] = b.lon_deg;
    end_x[i] = l.end_m.x();
    end_y[i] = l.end_m.y();
    strength[i] = l.strength;
    wkb[i] = wkb_line({a, b});
  }
  Params p;
  p.add(drive_row)
      .add_array(id)
      .add_array(kind)
      .add_array(lat)
      .add_array(lon)
      .add_array(x)
      .add_array(y)
      .add_array(end_lat)
      .add_array(end_lon)
      .add_array(end_x)
      .add_array(end_y)
      .add_array(strength)
      .add_array(power)
      .add_array(scattering)
      .add_array(cells)
      .add_bytea_array(wkb);
  c.query(
      "INSERT INTO candidates(id, drive, kind, lat_deg, lon_deg, x_m, y_m, end_lat_deg, "
      "end_lon_deg, end_x_m, end_y_m, strength, power_db, scattering, num_cells, geom) "
      "SELECT u.id, $1, u.kind, u.lat, u.lon, u.x, u.y, u.elat, u.elon, u.ex, u.ey, u.s, u.p, "
      "u.sc, u.nc, ST_GeomFromWKB(u.g, 4326) FROM unnest($2::bigint[], $3::int[], "
      "$4::float8[], $5::float8[], $6::float8[], $7::float8[], $8::float8[], $9::float8[], "
      "$10::float8[], $11::float8[], $12::float8[], $13::float8[], $14::bigint[], $15::bigint[], "
      "$16::bytea[]) AS u(id, kind, lat, lon, x, y, elat, elon, ex, ey, s, p, sc, nc, g)",
      p);
}

}  // namespace

PutDriveResult PostgresMapStore::put_drive(const DrivePackage& package,
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
  const PackageGeo geo = package_geo(package);
  const GeoBox& bbox = geo.bbox;

  // 1. Files into a temp dir of the package directory (same file system: rename is atomic).
  const std::string rand_suffix = std::to_string(std::random_device{}());
  util::ScopedTempDir staging(I.package_dir / (".tmp-" + content_hash + "-" + rand_suffix));
  util::ScopedTempDir placed(fs::path{});
  const fs::path& tmp = staging.path();
  const fs::path final_dir = I.package_dir / content_hash;
  try {
    fs::create_directories(tmp);
    stage_package_files(package_location, tmp);  // durable before any row names them
    const std::int64_t bytes = dir_bytes(tmp);
    I.hook("files_copied");

    // 2. Rows, rename, commit: one transaction under the store's write lock.
    const auto result = I.write([&](Connection& c) -> std::optional<DriveRecord> {
      // Re-check under the lock: another thread or replica may have stored it meanwhile.
      if (auto existing = I.drive_where(c, "content_hash = $1", content_hash)) return existing;
      if (auto same = I.drive_where(c, "drive_id = $1", m.drive_id)) {
        throw ConflictError("drive '" + m.drive_id + "' is already stored with content hash " +
                            same->content_hash);
      }
      const std::int64_t drive_row = Impl::next_id(c, "drives", "id");
      Params p;
      p.add(drive_row)
          .add(m.drive_id)
          .add(content_hash)
          .add(m.vehicle_id)
          .add(m.start_time_s)
          .add(m.end_time_s)
          .add(bbox.min_lat_deg)
          .add(bbox.min_lon_deg)
          .add(bbox.max_lat_deg)
          .add(bbox.max_lon_deg)
          .add(std::string(to_string(m.pol_level)))
          .add(m.distance_m)
          .add(static_cast<std::int64_t>(package.points.size()))
          .add(static_cast<std::int64_t>(package.lines.size()))
          .add(manifest_json(package).dump())
          .add(content_hash)
          .add(bytes)
          .add(now_iso());
      const Result ins = c.query(
          "INSERT INTO drives(id, drive_id, content_hash, vehicle_id, start_time_s, end_time_s, "
          "min_lat_deg, min_lon_deg, max_lat_deg, max_lon_deg, bbox, pol_level, distance_m, "
          "num_points, num_lines, manifest_json, package_path, package_bytes, ingested_at) "
          "VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, ST_MakeEnvelope($8, $7, $10, $9, "
          "4326), $11, $12, $13, $14, $15::jsonb, $16, $17, $18) "
          "ON CONFLICT (content_hash) DO NOTHING RETURNING id",
          p);
      if (ins.empty()) return I.drive_where(c, "content_hash = $1", content_hash);
      const std::int64_t first_candidate = Impl::next_id(c, "candidates", "id");
      insert_candidates(c, drive_row, first_candidate, package, geo);
      c.run(
          "INSERT INTO drive_trajectories(drive, min_spacing_m, samples_json, path_blob) "
          "VALUES ($1, $2, $3::jsonb, $4)",
          drive_row, kTrajectorySpacingM, decimated_trajectory_json(package.trajectory).dump(),
          Bytea{packed_path(package.trajectory)});
      I.hook("rows_inserted");
      std::error_code e;
      if (fs::exists(final_dir, e)) fs::remove_all(final_dir, e);  // crash leftover
      fs::rename(tmp, final_dir);
      staging.release();
      util::sync_directory(I.package_dir);  // the rename too, before the commit
      placed = util::ScopedTempDir(final_dir);
      I.hook("files_renamed");
      return std::nullopt;
    });
    if (result) return {PutDriveResult::Status::AlreadyPresent, *result};  // raced, same bytes
    placed.release();  // committed: the package directory is the store's now
  } catch (const fs::filesystem_error& e) {
    if (no_space(e.code()))
      throw StorageFullError(std::string("the drive store is full: ") + e.what());
    throw;
  }
  auto rec = get_drive(m.drive_id);
  if (!rec) throw IoError("put_drive: drive '" + m.drive_id + "' vanished after insert");
  return {PutDriveResult::Status::Inserted, *rec};
}

std::vector<DriveRecord> PostgresMapStore::list_drives() const {
  return impl_->read([&](Connection& c) {
    std::vector<DriveRecord> out;
    const Result r = c.run(std::string("SELECT ") + kDriveColumns + " FROM drives ORDER BY id");
    for (int i = 0; i < r.rows(); ++i) out.push_back(impl_->drive_from_row(r, i));
    return out;
  });
}

std::optional<DriveRecord> PostgresMapStore::get_drive(std::string_view drive_id) const {
  return impl_->read(
      [&](Connection& c) { return impl_->drive_where(c, "drive_id = $1", drive_id); });
}

std::optional<DriveRecord> PostgresMapStore::find_drive_by_hash(
    std::string_view content_hash) const {
  return impl_->read(
      [&](Connection& c) { return impl_->drive_where(c, "content_hash = $1", content_hash); });
}

std::vector<GeoPoint> PostgresMapStore::drive_path(std::string_view drive_id) const {
  return impl_->read([&](Connection& c) {
    auto d = impl_->drive_where(c, "drive_id = $1", drive_id);
    if (!d) throw NotFoundError("drive '" + std::string(drive_id) + "' is not in the store");
    const Result r =
        c.run("SELECT path_blob, samples_json FROM drive_trajectories WHERE drive = $1", d->row);
    if (r.empty()) return std::vector<GeoPoint>{};
    if (!r.is_null(0, 0)) return unpack_path(r.bytes(0, 0));
    return path_from_samples_json(nlohmann::json::parse(r.text(0, 1)));
  });
}

std::vector<TrajectorySample> PostgresMapStore::drive_trajectory(std::string_view drive_id) const {
  return impl_->read([&](Connection& c) {
    auto d = impl_->drive_where(c, "drive_id = $1", drive_id);
    if (!d) throw NotFoundError("drive '" + std::string(drive_id) + "' is not in the store");
    const Result r = c.run("SELECT samples_json FROM drive_trajectories WHERE drive = $1", d->row);
    if (r.empty()) return std::vector<TrajectorySample>{};
    return trajectory_from_json(nlohmann::json::parse(r.text(0, 0)));
  });
}

std::vector<DriveRecord> PostgresMapStore::drives_in(const GeoBox& box) const {
  return impl_->read([&](Connection& c) {
    std::vector<DriveRecord> out;
    std::set<std::int64_t> seen;
    for (const GeoBox& b : split_box(box)) {
      // The GiST index gives a superset (single-precision boxes rounded outward); the exact
      // test on the double precision bounds is SQLite's.
      const Result r = c.run(std::string("SELECT ") + kDriveColumns +
                                 " FROM drives WHERE bbox && ST_MakeEnvelope($1, $2, $3, $4, "
                                 "4326) ORDER BY id",
                             b.min_lon_deg, b.min_lat_deg, b.max_lon_deg, b.max_lat_deg);
      for (int i = 0; i < r.rows(); ++i) {
        DriveRecord d = impl_->drive_from_row(r, i);
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

bool PostgresMapStore::delete_drive(std::string_view drive_id) {
  std::optional<fs::path> files;
  impl_->write([&](Connection& c) {
    auto d = impl_->drive_where(c, "drive_id = $1", drive_id);
    if (!d) return;
    c.run("DELETE FROM drives WHERE id = $1", d->row);
    files = impl_->package_dir / d->content_hash;
  });
  if (!files) return false;
  std::error_code ec;
  fs::remove_all(*files, ec);  // after commit; a failure leaves an orphan swept on open
  return true;
}

// --------------------------------------------------------------------- candidates

CandidateSet PostgresMapStore::candidates_in(const std::optional<GeoBox>& region,
                                             std::span<const std::string> excluded) const {
  return impl_->read([&](Connection& c) {
    std::unordered_set<std::int64_t> excluded_rows;
    for (const auto& name : excluded) {
      auto d = impl_->drive_where(c, "drive_id = $1", name);
      if (!d) throw NotFoundError("excluded drive '" + name + "' is not in the store");
      excluded_rows.insert(d->row);
    }
    CandidateSet out;
    const std::string cols =
        "SELECT c.id, c.drive, c.kind, c.lat_deg, c.lon_deg, c.x_m, c.y_m, c.end_lat_deg, "
        "c.end_lon_deg, c.end_x_m, c.end_y_m, c.strength, c.power_db, c.scattering, c.num_cells "
        "FROM candidates c";
    auto take = [&](const Result& s, int i) {
      if (excluded_rows.contains(s.i64(i, 1))) return;
      const double lat = s.f64(i, 3), lon = s.f64(i, 4);
      if (s.i64(i, 2) == 0) {
        if (region && !box_contains(*region, lat, lon)) return;
        StoredPointCandidate p;
        p.id = s.i64(i, 0);
        p.drive = s.i64(i, 1);
        p.position = {lat, lon, 0.0};
        p.candidate.position_m = {s.f64(i, 5), s.f64(i, 6)};
        p.candidate.strength = s.f64(i, 11);
        p.candidate.power_db = s.f64(i, 12);
        p.candidate.scattering = static_cast<ScatteringClass>(s.i64(i, 13) & 3);
        p.candidate.num_cells = static_cast<std::uint32_t>(s.i64(i, 14));
        out.points.push_back(p);
      } else {
        const double lat1 = s.f64(i, 7), lon1 = s.f64(i, 8);
        if (region && !box_intersects(*region, std::min(lat, lat1), std::min(lon, lon1),
                                      std::max(lat, lat1), std::max(lon, lon1))) {
          return;
        }
        StoredLineCandidate l;
        l.id = s.i64(i, 0);
        l.drive = s.i64(i, 1);
        l.start = {lat, lon, 0.0};
        l.end = {lat1, lon1, 0.0};
        l.candidate.start_m = {s.f64(i, 5), s.f64(i, 6)};
        l.candidate.end_m = {s.f64(i, 9), s.f64(i, 10)};
        l.candidate.strength = s.f64(i, 11);
        out.lines.push_back(l);
      }
    };
    if (!region) {
      const Result r = c.run(cols + " ORDER BY c.id");
      for (int i = 0; i < r.rows(); ++i) take(r, i);
    } else {
      for (const GeoBox& b : split_box(*region)) {
        const Result r =
            c.run(cols + " WHERE c.geom && ST_MakeEnvelope($1, $2, $3, $4, 4326) ORDER BY c.id",
                  b.min_lon_deg, b.min_lat_deg, b.max_lon_deg, b.max_lat_deg);
        for (int i = 0; i < r.rows(); ++i) take(r, i);
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
