// Helpers shared by the store backends (store_common.hpp), and the interface's free
// functions of store.hpp (content_etag, to_string, parse_landmark_change_kind).
#include "store_common.hpp"

#include <fcntl.h>
#include <sys/random.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <ctime>
#include <limits>

#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/trajectory_odometry.hpp"
#include "polmap/schema/json.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "polmap/tiles/polyline_simplify.hpp"
#include "polmap/util/file.hpp"
#include "polmap/util/sha256.hpp"
#include "polmap/util/text.hpp"

namespace polmap::mapping {
namespace fs = std::filesystem;

std::string_view to_string(MapVersionStatus s) {
  switch (s) {
    case MapVersionStatus::Published:
      return "published";
    case MapVersionStatus::Failed:
      return "failed";
    default:
      return "building";
  }
}

std::string content_etag(std::string_view payload) { return util::sha256_hex(payload); }

bool is_valid_hdmap_comparison_name(std::string_view name) {
  if (name.empty() || name.size() > 64 || name.front() == '.') return false;
  return std::all_of(name.begin(), name.end(), [](char ch) {
    return (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') ||
           ch == '.' || ch == '_' || ch == '-';
  });
}

std::string_view to_string(LandmarkChangeKind k) {
  switch (k) {
    case LandmarkChangeKind::Moved:
      return "moved";
    case LandmarkChangeKind::Retired:
      return "retired";
    default:
      return "added";
  }
}

std::optional<LandmarkChangeKind> parse_landmark_change_kind(std::string_view s) {
  if (s == "added") return LandmarkChangeKind::Added;
  if (s == "moved") return LandmarkChangeKind::Moved;
  if (s == "retired") return LandmarkChangeKind::Retired;
  return std::nullopt;
}

namespace store_detail {

std::string now_iso() { return iso_utc(std::chrono::system_clock::now()); }

std::string iso_utc(std::chrono::system_clock::time_point tp) {
  const std::time_t t =
      std::chrono::system_clock::to_time_t(std::chrono::time_point_cast<std::chrono::seconds>(tp));
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

std::vector<GeoBox> split_box(const GeoBox& b) {
  if (!b.crosses_antimeridian()) return {b};
  GeoBox east = b, west = b;
  east.max_lon_deg = 180.0;
  west.min_lon_deg = -180.0;
  return {east, west};
}

bool box_contains(const GeoBox& b, double lat, double lon) {
  for (const GeoBox& p : split_box(b)) {
    if (lat >= p.min_lat_deg && lat <= p.max_lat_deg && lon >= p.min_lon_deg &&
        lon <= p.max_lon_deg) {
      return true;
    }
  }
  return false;
}

bool box_intersects(const GeoBox& b, double lat0, double lon0, double lat1, double lon1) {
  for (const GeoBox& p : split_box(b)) {
    if (lat1 >= p.min_lat_deg && lat0 <= p.max_lat_deg && lon1 >= p.min_lon_deg &&
        lon0 <= p.max_lon_deg) {
      return true;
    }
  }
  return false;
}

nlohmann::json manifest_json(const DrivePackage& package) {
  const DriveManifest& m = package.manifest;
  nlohmann::json j;
  j["format_version"] = m.format_version;
  j["drive_id"] = m.drive_id;
  j["vehicle_id"] = m.vehicle_id;
  j["start_time_s"] = m.start_time_s;
  j["end_time_s"] = m.end_time_s;
  j["origin"] = m.origin;
  j["crs_proj"] = m.crs_proj;
  j["sensors"] = m.sensors;
  j["pol_level"] = std::string(to_string(m.pol_level));
  j["cell_size_m"] = m.cell_size_m;
  j["distance_m"] = m.distance_m;
  j["producer"] = m.producer;
  if (!package.trajectory.empty()) {
    std::vector<double> pos, yaw;
    std::array<std::size_t, 3> solutions{};
    for (const TrajectorySample& s : package.trajectory) {
      pos.push_back(std::max(s.std_east_m, s.std_north_m));
      yaw.push_back(s.std_yaw_rad);
      const auto k = static_cast<std::size_t>(s.solution);
      if (k < solutions.size()) ++solutions[k];
    }
    auto median = [](std::vector<double>& v) {
      const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
      std::nth_element(v.begin(), mid, v.end());
      return *mid;
    };
    const auto top = static_cast<std::size_t>(std::max_element(solutions.begin(), solutions.end()) -
                                              solutions.begin());
    j["positioning"] = {{"median_std_m", median(pos)},
                        {"median_std_yaw_rad", median(yaw)},
                        {"solution", std::string(to_string(static_cast<GnssSolution>(top)))}};
  }
  return j;
}

std::int64_t dir_bytes(const fs::path& p) {
  std::error_code ec;
  if (fs::is_regular_file(p, ec)) return static_cast<std::int64_t>(fs::file_size(p, ec));
  std::int64_t n = 0;
  for (auto it = fs::recursive_directory_iterator(p, ec); !ec && it != fs::end(it);
       it.increment(ec)) {
    if (it->is_regular_file(ec)) n += static_cast<std::int64_t>(it->file_size(ec));
  }
  return n;
}

const char* tile_table(TileLayer layer) {
  switch (layer) {
    case TileLayer::Localization:
      return "tiles";
    case TileLayer::GridmapMechanism:
      return "gridmap_mechanism_tiles";
    default:
      return "gridmap_tiles";
  }
}

MapVersionStatus parse_status(const std::string& s) {
  if (s == "published") return MapVersionStatus::Published;
  if (s == "failed") return MapVersionStatus::Failed;
  return MapVersionStatus::Building;
}

PackageGeo package_geo(const DrivePackage& package) {
  const DriveManifest& m = package.manifest;
  const tiles::LocalFrame frame(m.origin);
  PackageGeo g;
  GeoBox& bbox = g.bbox;
  bbox = {90.0, 180.0, -90.0, -180.0};
  auto grow = [&](double lat, double lon) {
    bbox.min_lat_deg = std::min(bbox.min_lat_deg, lat);
    bbox.max_lat_deg = std::max(bbox.max_lat_deg, lat);
    bbox.min_lon_deg = std::min(bbox.min_lon_deg, lon);
    bbox.max_lon_deg = std::max(bbox.max_lon_deg, lon);
  };
  g.points.reserve(package.points.size());
  for (const auto& p : package.points) {
    g.points.push_back(frame.to_geo(p.position_m));
    grow(g.points.back().lat_deg, g.points.back().lon_deg);
  }
  g.lines.reserve(package.lines.size());
  for (const auto& l : package.lines) {
    g.lines.emplace_back(frame.to_geo(l.start_m), frame.to_geo(l.end_m));
    grow(g.lines.back().first.lat_deg, g.lines.back().first.lon_deg);
    grow(g.lines.back().second.lat_deg, g.lines.back().second.lon_deg);
  }
  for (const auto& t : package.trajectory) grow(t.lat_deg, t.lon_deg);
  if (bbox.min_lat_deg > bbox.max_lat_deg)
    bbox = {m.origin.lat_deg, m.origin.lon_deg, m.origin.lat_deg, m.origin.lon_deg};
  return g;
}

std::vector<GeoPoint> simplify_path(const std::vector<GeoPoint>& pl) {
  return tiles::simplify_polyline(pl, kDrivePathToleranceM, 1024);
}

std::string packed_path(const std::vector<TrajectorySample>& trajectory) {
  std::vector<GeoPoint> pl;
  pl.reserve(trajectory.size());
  for (const auto& t : trajectory) pl.push_back({t.lat_deg, t.lon_deg, 0.0});
  pl = simplify_path(pl);
  static_assert(std::endian::native == std::endian::little, "path_blob is little-endian");
  std::string out(pl.size() * 16, '\0');
  for (std::size_t i = 0; i < pl.size(); ++i) {
    std::memcpy(out.data() + 16 * i, &pl[i].lat_deg, 8);
    std::memcpy(out.data() + 16 * i + 8, &pl[i].lon_deg, 8);
  }
  return out;
}

std::vector<GeoPoint> unpack_path(std::string_view blob) {
  std::vector<GeoPoint> pl(blob.size() / 16);
  for (std::size_t i = 0; i < pl.size(); ++i) {
    std::memcpy(&pl[i].lat_deg, blob.data() + 16 * i, 8);
    std::memcpy(&pl[i].lon_deg, blob.data() + 16 * i + 8, 8);
  }
  return pl;
}

nlohmann::json decimated_trajectory_json(const std::vector<TrajectorySample>& trajectory) {
  nlohmann::json samples = nlohmann::json::array();
  const auto push = [&](const TrajectorySample& t) {
    samples.push_back({t.time_s, t.lat_deg, t.lon_deg, t.yaw_enu_rad, t.speed_mps, t.yaw_rate_rps});
  };
  // The kept samples must reproduce the full-rate odometry: map builds align consumer-grade
  // drives with it (drive_alignment.hpp).
  const TrajectoryOdometry odometry(trajectory);
  std::size_t last = 0;
  for (std::size_t i = 0; i < trajectory.size(); ++i) {
    const auto& t = trajectory[i];
    if (i == 0) {
      push(t);
      continue;
    }
    // Keep the previous sample when skipping it would lose odometry.
    if (i - 1 > last && !odometry.kept_by(last, i, kTrajectoryMaxYawIntegralErrorRad,
                                          kTrajectoryMaxDistanceErrorM)) {
      push(trajectory[i - 1]);
      last = i - 1;
    }
    const auto& l = trajectory[last];
    bool keep = i + 1 == trajectory.size() || t.time_s - l.time_s >= kTrajectoryMaxGapS;
    if (!keep) {
      const double dn = (t.lat_deg - l.lat_deg) * 111320.0;
      const double de =
          (t.lon_deg - l.lon_deg) * 111320.0 * std::cos(t.lat_deg * 3.14159265358979 / 180.0);
      keep = dn * dn + de * de >= kTrajectorySpacingM * kTrajectorySpacingM;
    }
    if (!keep) continue;
    push(t);
    last = i;
  }
  return samples;
}

std::vector<TrajectorySample> trajectory_from_json(const nlohmann::json& samples) {
  std::vector<TrajectorySample> out;
  for (const auto& v : samples) {
    TrajectorySample t;
    t.time_s = v.at(0).get<double>();
    t.lat_deg = v.at(1).get<double>();
    t.lon_deg = v.at(2).get<double>();
    t.yaw_enu_rad = v.at(3).get<double>();
    t.speed_mps = v.at(4).get<double>();
    // Drives stored before the yaw rate was kept (2026-12-05): unknown.
    t.yaw_rate_rps =
        v.size() > 5 ? v.at(5).get<double>() : std::numeric_limits<double>::quiet_NaN();
    out.push_back(t);
  }
  return out;
}

std::vector<GeoPoint> path_from_samples_json(const nlohmann::json& samples) {
  std::vector<GeoPoint> pl;
  for (const auto& v : samples) pl.push_back({v.at(1).get<double>(), v.at(2).get<double>(), 0.0});
  return simplify_path(pl);
}

bool no_space(const std::error_code& ec) {
  return ec == std::errc::no_space_on_device ||
         ((ec.category() == std::generic_category() || ec.category() == std::system_category()) &&
          ec.value() == EDQUOT);
}

namespace {

[[noreturn]] void throw_copy_error(int err, const fs::path& from, const fs::path& to) {
  const std::string msg =
      "cannot copy " + from.string() + " to " + to.string() + ": " + std::strerror(err);
  if (err == ENOSPC || err == EDQUOT) throw StorageFullError("the drive store is full: " + msg);
  throw IoError("put_drive: " + msg);
}

/// Copies one file with read(2)/write(2). Not std::filesystem::copy_file: libstdc++ reports
/// a sendfile that stops short on a full disk as EIO, and a full disk must be told (507).
void copy_file_checked(const fs::path& from, const fs::path& to) {
  const int in = ::open(from.c_str(), O_RDONLY | O_CLOEXEC);
  if (in < 0) throw_copy_error(errno, from, to);
  const int out = ::open(to.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (out < 0) {
    const int err = errno;
    ::close(in);
    throw_copy_error(err, from, to);
  }
  std::vector<char> buf(1u << 20);
  int err = 0;
  for (;;) {
    const ssize_t r = ::read(in, buf.data(), buf.size());
    if (r < 0 && errno == EINTR) continue;
    if (r <= 0) {
      if (r < 0) err = errno;
      break;
    }
    err = util::write_all(out, {buf.data(), static_cast<std::size_t>(r)});
    if (err != 0) break;
  }
  ::close(in);
  if (::close(out) != 0 && err == 0) err = errno;
  if (err != 0) throw_copy_error(err, from, to);
}

/// Copies the regular files below `from` into `to` (existing), keeping relative paths.
void copy_tree_checked(const fs::path& from, const fs::path& to) {
  for (const auto& e : fs::recursive_directory_iterator(from)) {
    const fs::path target = to / fs::relative(e.path(), from);
    if (e.is_directory()) {
      fs::create_directories(target);
    } else if (e.is_regular_file()) {
      copy_file_checked(e.path(), target);
    }
  }
}

}  // namespace

void stage_package_files(const fs::path& package_location, const fs::path& dir) {
  if (fs::is_directory(package_location)) {
    copy_tree_checked(package_location, dir);
  } else {
    // An archive: its members, as our ustar reader sees them (the validator's reader).
    unpack_drive_package(util::read_file_bytes(package_location), dir);
  }
  util::sync_tree(dir);  // the files are durable before any row names them
}

nlohmann::json geometry_json(const std::vector<GeoPoint>& g) {
  nlohmann::json a = nlohmann::json::array();
  for (const auto& p : g) a.push_back({p.lat_deg, p.lon_deg});
  return a;
}

std::vector<GeoPoint> geometry_from_json(const nlohmann::json& j) {
  std::vector<GeoPoint> out;
  if (!j.is_array()) return out;
  for (const auto& p : j) {
    if (p.is_array() && p.size() == 2 && p[0].is_number() && p[1].is_number()) {
      out.push_back({p[0].get<double>(), p[1].get<double>(), 0.0});
    }
  }
  return out;
}

std::string random_session_id() {
  unsigned char bytes[16];
  std::size_t got = 0;
  while (got < sizeof bytes) {
    const ssize_t n = ::getrandom(bytes + got, sizeof bytes - got, 0);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) throw IoError(std::string("getrandom: ") + std::strerror(errno));
    got += static_cast<std::size_t>(n);
  }
  static constexpr char kHex[] = "0123456789abcdef";
  std::string id;
  for (const unsigned char b : bytes) {
    id.push_back(kHex[b >> 4]);
    id.push_back(kHex[b & 15]);
  }
  return id;
}

void create_session_file(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
  if (fd < 0) {
    const int err = errno;
    const std::string msg =
        "cannot create upload session file " + path.string() + ": " + std::strerror(err);
    if (err == ENOSPC || err == EDQUOT) throw StorageFullError(msg);
    throw IoError(msg);
  }
  ::close(fd);
}

void check_localization_run(const LocalizationRunRecord& record,
                            std::span<const LocalizationRunCell> cells, std::size_t keep_newest) {
  const auto& b = record.bounds;
  const bool finite = std::isfinite(b.min_lat_deg) && std::isfinite(b.max_lat_deg) &&
                      std::isfinite(b.min_lon_deg) && std::isfinite(b.max_lon_deg);
  if (!finite || b.min_lat_deg > b.max_lat_deg || b.min_lon_deg > b.max_lon_deg) {
    throw ValidationError("put_localization_run: bounds must be finite and ordered");
  }
  if (record.samples < 0 || record.map_version < 0) {
    throw ValidationError("put_localization_run: samples and map_version must be >= 0");
  }
  if (keep_newest == 0) throw ValidationError("put_localization_run: keep_newest must be >= 1");
  for (const LocalizationRunCell& c : cells) {
    if (c.z < 0 || c.z > 24 || c.x < 0 || c.y < 0 || c.x >= (1 << c.z) || c.y >= (1 << c.z)) {
      throw ValidationError("put_localization_run: cell outside its zoom's tile range");
    }
  }
}

void validate_upload_request(const UploadSessionRequest& r) {
  if (r.owner.empty()) throw ValidationError("create_upload_session: owner is empty");
  if (r.length_bytes == 0 ||
      r.length_bytes > static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max())) {
    throw ValidationError("create_upload_session: length_bytes must be positive, got " +
                          std::to_string(r.length_bytes));
  }
  if (!r.sha256.empty() && (r.sha256.size() != 64 || !util::is_lower_hex(r.sha256))) {
    throw ValidationError("create_upload_session: sha256 must be 64 lower-case hex digits");
  }
  if (r.ttl_s <= 0) throw ValidationError("create_upload_session: ttl_s must be positive");
}

void validate_upload_outcome(const UploadOutcome& o) {
  if (o.http_status < 200 || o.http_status > 499) {
    throw ValidationError("complete_upload_session: http_status must be 200-499, got " +
                          std::to_string(o.http_status));
  }
}

}  // namespace store_detail
}  // namespace polmap::mapping

namespace polmap::mapping {

std::string_view to_string(BuildJobState s) {
  switch (s) {
    case BuildJobState::Running:
      return "running";
    case BuildJobState::Done:
      return "done";
    case BuildJobState::Failed:
      return "failed";
    default:
      return "pending";
  }
}

}  // namespace polmap::mapping

namespace polmap::mapping::store_detail {

BuildJobState parse_build_job_state(std::string_view s) {
  if (s == "running") return BuildJobState::Running;
  if (s == "done") return BuildJobState::Done;
  if (s == "failed") return BuildJobState::Failed;
  return BuildJobState::Pending;
}

void check_build_job_specs(std::span<const BuildJobSpec> jobs) {
  for (const auto& j : jobs) {
    if (j.kind != "region" && j.kind != "gridmap" && j.kind != "publish") {
      throw ValidationError("enqueue_build_jobs: unknown job kind '" + j.kind +
                            "' (known: region, gridmap, publish)");
    }
    if (!tiles::is_valid(j.region)) {
      throw ValidationError("enqueue_build_jobs: invalid region tile " +
                            tiles::to_string(j.region));
    }
  }
}

double epoch_seconds_now() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

std::vector<LandmarkHistoryEntry> walk_landmark_history(
    std::int64_t key, std::int64_t version, bool is_line,
    const std::function<std::optional<LandmarkHistoryEntry>(std::int64_t, std::int64_t)>& latest,
    const std::function<std::optional<std::pair<std::int64_t, std::string>>(
        std::int64_t, std::int64_t)>& first_version) {
  std::vector<LandmarkHistoryEntry> out;
  std::int64_t k = key;
  std::int64_t upto = version;
  // Each step goes at least one version back, so versions bound the walk.
  while (upto > 0) {
    auto e = latest(k, upto);
    if (!e) break;
    upto = e->version - 1;
    if (e->change.change == LandmarkChangeKind::Moved && e->change.previous_key != 0) {
      k = e->change.previous_key;
    }
    out.push_back(std::move(*e));
  }
  if (upto > 0) {
    if (const auto first = first_version(k, upto)) {
      LandmarkHistoryEntry e;
      e.version = first->first;
      e.published_at = first->second;
      e.change.change = LandmarkChangeKind::Added;
      e.change.is_line = is_line;
      e.change.key = k;
      e.inferred = true;
      out.push_back(std::move(e));
    }
  }
  return out;
}

}  // namespace polmap::mapping::store_detail
