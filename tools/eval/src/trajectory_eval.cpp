#include "polmap/eval/trajectory_eval.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <numbers>
#include <string_view>

#include "csv_text.hpp"
#include "polmap/localization_client/localizer.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/schema/pose2.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::eval {
namespace {

constexpr double kRadToDeg = 180.0 / std::numbers::pi;

std::vector<std::string_view> split_commas(std::string_view line) {
  std::vector<std::string_view> out;
  std::size_t pos = 0;
  while (true) {
    const std::size_t c = line.find(',', pos);
    out.push_back(line.substr(pos, c == std::string_view::npos ? line.npos : c - pos));
    if (c == std::string_view::npos) break;
    pos = c + 1;
  }
  for (auto& f : out) {
    while (!f.empty() && (f.front() == ' ' || f.front() == '\t')) f.remove_prefix(1);
    while (!f.empty() && (f.back() == ' ' || f.back() == '\t' || f.back() == '\r')) {
      f.remove_suffix(1);
    }
  }
  return out;
}

/// Parses a header + rows CSV into named columns; calls row(fields, line_no).
template <class RowFn>
void read_csv(const std::filesystem::path& path, const std::vector<std::string>& required,
              std::map<std::string, int, std::less<>>& col, RowFn&& row) {
  std::ifstream in(path);
  if (!in) throw IoError("cannot open " + path.string());
  std::string line;
  std::uint64_t line_no = 0;
  bool header = false;
  while (std::getline(in, line)) {
    ++line_no;
    std::string_view v(line);
    while (!v.empty() && (v.back() == '\r' || v.back() == ' ')) v.remove_suffix(1);
    if (v.empty() || v.front() == '#') continue;
    const auto f = split_commas(v);
    if (!header) {
      for (std::size_t i = 0; i < f.size(); ++i) col[std::string(f[i])] = static_cast<int>(i);
      for (const auto& r : required) {
        if (!col.contains(r)) {
          throw FormatError(path.string() + ": line " + std::to_string(line_no) +
                            ": header lacks column '" + r + "'");
        }
      }
      header = true;
      continue;
    }
    row(f, line_no);
  }
  if (!header) throw FormatError(path.string() + ": empty file (no header line)");
}

double parse_double(std::string_view s, const std::filesystem::path& path, std::uint64_t line,
                    int column, std::string_view name) {
  const std::optional<double> v = detail::parse_double(s);
  if (!v || !std::isfinite(*v)) {
    throw FormatError(path.string() + ": line " + std::to_string(line) + ", column " +
                      std::to_string(column + 1) + " (" + std::string(name) + "): '" +
                      std::string(s) + "' is not a finite number");
  }
  return *v;
}

}  // namespace

TrajectoryRow to_trajectory_row(const loc::LocalizationOutput& out) {
  POLMAP_EXPECT(out.has_pose);
  TrajectoryRow r;
  r.time_s = out.time_s;
  r.status = std::string(loc::to_string(out.status));
  r.lat_deg = out.pose.position.lat_deg;
  r.lon_deg = out.pose.position.lon_deg;
  r.yaw_enu_rad = out.pose.yaw_enu_rad;
  r.cov_xx_m2 = out.covariance(0, 0);
  r.cov_xy_m2 = out.covariance(0, 1);
  r.cov_yy_m2 = out.covariance(1, 1);
  r.cov_yaw_rad2 = out.covariance(2, 2);
  r.matched_points = out.matched_points;
  r.matched_lines = out.matched_lines;
  r.map_version = out.map_version;
  r.graph_ms = out.graph_updated ? 1e3 * out.graph_update_time_s : 0.0;
  r.pl_lat_m = out.protection_level_lat_m;
  return r;
}

const std::string& trajectory_csv_header() {
  static const std::string h =
      "time_s,status,lat_deg,lon_deg,yaw_enu_rad,cov_xx_m2,cov_xy_m2,cov_yy_m2,cov_yaw_rad2,"
      "matched_points,matched_lines,map_version,graph_ms,pl_lat_m";
  return h;
}

TrajectoryCsvWriter::TrajectoryCsvWriter(const std::filesystem::path& path)
    : path_(path), out_(path, std::ios::trunc) {
  if (!out_) throw IoError("cannot create trajectory CSV " + path.string());
  out_ << trajectory_csv_header() << '\n';
}

void TrajectoryCsvWriter::write(const TrajectoryRow& r) {
  char buf[512];
  // 9 decimals of a degree ≈ 0.1 mm; covariances in full precision.
  std::snprintf(buf, sizeof buf,
                "%.4f,%s,%.9f,%.9f,%.6f,%.6g,%.6g,%.6g,%.6g,%d,%d,%llu,%.3f,%.4f\n", r.time_s,
                r.status.c_str(), r.lat_deg, r.lon_deg, r.yaw_enu_rad, r.cov_xx_m2, r.cov_xy_m2,
                r.cov_yy_m2, r.cov_yaw_rad2, r.matched_points, r.matched_lines,
                static_cast<unsigned long long>(r.map_version), r.graph_ms, r.pl_lat_m);
  out_ << buf;
  if (!out_) throw IoError("cannot write trajectory CSV " + path_.string());
}

void TrajectoryCsvWriter::close() {
  out_.flush();
  if (!out_) throw IoError("cannot write trajectory CSV " + path_.string());
  out_.close();
}

std::vector<TrajectoryRow> read_trajectory_csv(const std::filesystem::path& path) {
  std::vector<TrajectoryRow> rows;
  std::map<std::string, int, std::less<>> col;
  read_csv(path, {"time_s", "status", "lat_deg", "lon_deg", "yaw_enu_rad"}, col,
           [&](const std::vector<std::string_view>& f, std::uint64_t line) {
             auto num = [&](std::string_view name, double dflt) {
               const auto it = col.find(name);
               if (it == col.end()) return dflt;
               if (it->second >= static_cast<int>(f.size())) {
                 throw FormatError(path.string() + ": line " + std::to_string(line) +
                                   ": missing column " + std::to_string(it->second + 1) + " (" +
                                   std::string(name) + ")");
               }
               return parse_double(f[it->second], path, line, it->second, name);
             };
             TrajectoryRow r;
             r.time_s = num("time_s", 0.0);
             const int sc = col.at("status");
             if (sc >= static_cast<int>(f.size())) {
               throw FormatError(path.string() + ": line " + std::to_string(line) +
                                 ": missing column " + std::to_string(sc + 1) + " (status)");
             }
             r.status = std::string(f[sc]);
             r.lat_deg = num("lat_deg", 0.0);
             r.lon_deg = num("lon_deg", 0.0);
             r.yaw_enu_rad = num("yaw_enu_rad", 0.0);
             r.cov_xx_m2 = num("cov_xx_m2", 0.0);
             r.cov_xy_m2 = num("cov_xy_m2", 0.0);
             r.cov_yy_m2 = num("cov_yy_m2", 0.0);
             r.cov_yaw_rad2 = num("cov_yaw_rad2", 0.0);
             r.matched_points = static_cast<int>(num("matched_points", 0.0));
             r.matched_lines = static_cast<int>(num("matched_lines", 0.0));
             r.map_version = static_cast<std::uint64_t>(num("map_version", 0.0));
             r.graph_ms = num("graph_ms", 0.0);
             r.pl_lat_m = num("pl_lat_m", 0.0);
             if (!rows.empty() && r.time_s < rows.back().time_s) {
               throw FormatError(path.string() + ": line " + std::to_string(line) +
                                 ": time_s goes backwards");
             }
             rows.push_back(std::move(r));
           });
  return rows;
}

std::vector<ReferenceSample> reference_from_samples(const std::vector<TrajectorySample>& samples) {
  std::vector<ReferenceSample> out;
  out.reserve(samples.size());
  for (const auto& s : samples) {
    out.push_back({s.time_s, s.lat_deg, s.lon_deg, s.yaw_enu_rad, s.speed_mps,
                   s.solution == GnssSolution::CarrierPhaseFixed});
  }
  return out;
}

std::vector<ReferenceSample> reference_from_truth_csv(const std::filesystem::path& path,
                                                      const std::vector<TrajectorySample>& gnss) {
  std::vector<ReferenceSample> out;
  std::map<std::string, int, std::less<>> col;
  read_csv(path, {"time_s", "lat_deg", "lon_deg", "yaw_enu_rad", "v_mps"}, col,
           [&](const std::vector<std::string_view>& f, std::uint64_t line) {
             auto num = [&](std::string_view name) {
               const int c = col.find(name)->second;
               if (c >= static_cast<int>(f.size())) {
                 throw FormatError(path.string() + ": line " + std::to_string(line) +
                                   ": missing column " + std::to_string(c + 1));
               }
               return parse_double(f[c], path, line, c, name);
             };
             out.push_back({num("time_s"), num("lat_deg"), num("lon_deg"), num("yaw_enu_rad"),
                            num("v_mps"), true});
           });
  if (!gnss.empty()) {
    std::size_t j = 0;
    for (auto& r : out) {
      while (j + 1 < gnss.size() &&
             std::abs(gnss[j + 1].time_s - r.time_s) <= std::abs(gnss[j].time_s - r.time_s)) {
        ++j;
      }
      r.carrier_phase = gnss[j].solution == GnssSolution::CarrierPhaseFixed;
    }
  }
  return out;
}

TrajectoryMetrics evaluate_trajectory(const std::vector<TrajectoryRow>& rows,
                                      const std::vector<ReferenceSample>& reference,
                                      const TrajectoryEvalOptions& options) {
  TrajectoryMetrics m;
  m.rows = static_cast<int>(rows.size());
  if (rows.empty()) return m;
  std::map<std::string, int> status_rows;
  for (const auto& r : rows) ++status_rows[r.status];
  auto share = [&](const char* s) {
    const auto it = status_rows.find(s);
    return it == status_rows.end() ? 0.0 : static_cast<double>(it->second) / m.rows;
  };
  m.share_tracking = share("tracking");
  m.share_degraded = share("degraded");
  m.share_lost = share("lost");
  m.share_initializing = share("initializing");
  for (const auto& r : rows) {
    if (r.status == "tracking") {
      m.time_to_tracking_s = r.time_s - rows.front().time_s;
      break;
    }
  }
  if (reference.size() < 2) return m;

  const tiles::LocalFrame frame(GeoPoint{reference.front().lat_deg, reference.front().lon_deg, 0});
  std::vector<Eigen::Vector2d> ref_xy;
  ref_xy.reserve(reference.size());
  for (const auto& s : reference) ref_xy.push_back(frame.to_local(s.lat_deg, s.lon_deg));

  double se_long = 0, se_lat = 0, se_rot = 0, nees_sum = 0, pl_sum = 0;
  int nees_within = 0, pl_bounded = 0;
  int moving = 0, moving_reliable = 0;
  std::size_t j = 0;
  for (const auto& r : rows) {
    if (r.time_s < reference.front().time_s || r.time_s > reference.back().time_s) continue;
    ++m.rows_in_reference;
    while (j + 2 < reference.size() && reference[j + 1].time_s <= r.time_s) ++j;
    const ReferenceSample& a = reference[j];
    const ReferenceSample& b = reference[j + 1];
    const double span = b.time_s - a.time_s;
    const double u = span > 0 ? std::clamp((r.time_s - a.time_s) / span, 0.0, 1.0) : 0.0;
    const Eigen::Vector2d t_gt = (1.0 - u) * ref_xy[j] + u * ref_xy[j + 1];
    const double speed = (1.0 - u) * a.speed_mps + u * b.speed_mps;
    // Yaws in the frame: ENU yaw + meridian convergence at the point.
    const double yaw_gt =
        wrap_angle_rad(a.yaw_enu_rad + u * wrap_angle_rad(b.yaw_enu_rad - a.yaw_enu_rad)) +
        frame.convergence_rad(t_gt);
    const bool reliable = u < 0.5 ? a.carrier_phase : b.carrier_phase;
    const bool is_moving = speed > options.min_speed_mps;
    if (is_moving) {
      ++moving;
      if (reliable) ++moving_reliable;
    }
    if (!is_moving) {
      ++m.excluded_speed;
      continue;
    }
    if (options.require_carrier_phase && !reliable) {
      ++m.excluded_not_carrier_phase;
      continue;
    }
    if (std::find(options.statuses.begin(), options.statuses.end(), r.status) ==
        options.statuses.end()) {
      ++m.excluded_status;
      continue;
    }
    const Eigen::Vector2d t_est = frame.to_local(r.lat_deg, r.lon_deg);
    const double yaw_est = r.yaw_enu_rad + frame.convergence_rad(t_est);
    const Eigen::Vector2d e = Pose2{0.0, 0.0, yaw_gt}.rotation().transpose() * (t_est - t_gt);
    // arccos(½ tr(R_gtᵀ R̂)) for planar rotations is |Δyaw| wrapped to [0, π].
    const double dyaw = wrap_angle_rad(yaw_est - yaw_gt);
    const double rot = std::abs(dyaw);
    TrajectoryError te{r.time_s, e.x(), e.y(), rot, speed, r.status};
    // The covariance across and along the reference heading, and the NEES.
    const Eigen::Matrix2d R = Pose2{0.0, 0.0, yaw_gt}.rotation();
    Eigen::Matrix2d c_xy;
    c_xy << r.cov_xx_m2, r.cov_xy_m2, r.cov_xy_m2, r.cov_yy_m2;
    const Eigen::Matrix2d c_ref = R.transpose() * c_xy * R;
    te.sigma_lat_m = std::sqrt(std::max(c_ref(1, 1), 0.0));
    const double det = c_ref.determinant();
    if (det > 0.0 && c_ref(0, 0) > 0.0 && r.cov_yaw_rad2 > 0.0) {
      te.nees = e.dot(c_ref.inverse() * e) + dyaw * dyaw / r.cov_yaw_rad2;
      ++m.nees_samples;
      nees_sum += te.nees;
      if (te.nees <= kChi2Dof3Q95) ++nees_within;
    }
    te.pl_lat_m = r.pl_lat_m;
    if (r.pl_lat_m > 0.0) {
      ++m.pl_samples;
      pl_sum += r.pl_lat_m;
      if (std::abs(e.y()) <= r.pl_lat_m) ++pl_bounded;
    }
    m.errors.push_back(std::move(te));
    se_long += e.x() * e.x();
    se_lat += e.y() * e.y();
    se_rot += rot * rot;
    m.long_max_m = std::max(m.long_max_m, std::abs(e.x()));
    m.lat_max_m = std::max(m.lat_max_m, std::abs(e.y()));
    m.rot_max_deg = std::max(m.rot_max_deg, rot * kRadToDeg);
  }
  m.evaluated = static_cast<int>(m.errors.size());
  if (m.nees_samples > 0) {
    m.nees_mean = nees_sum / m.nees_samples;
    m.nees_within_q95_share = static_cast<double>(nees_within) / m.nees_samples;
  }
  if (m.pl_samples > 0) {
    m.pl_mean_m = pl_sum / m.pl_samples;
    m.pl_bounded_share = static_cast<double>(pl_bounded) / m.pl_samples;
  }
  m.reliable_gt_share = moving > 0 ? static_cast<double>(moving_reliable) / moving : 0.0;
  if (m.evaluated > 0) {
    m.long_rmse_m = std::sqrt(se_long / m.evaluated);
    m.lat_rmse_m = std::sqrt(se_lat / m.evaluated);
    m.rot_rmse_deg = std::sqrt(se_rot / m.evaluated) * kRadToDeg;
  }
  return m;
}

}  // namespace polmap::eval
