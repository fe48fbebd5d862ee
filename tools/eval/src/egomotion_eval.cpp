#include "polmap/eval/egomotion_eval.hpp"

#include <algorithm>
#include <cmath>
#include <ctime>
#include <fstream>
#include <map>
#include <numbers>

#include "csv_text.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::eval {

namespace {

constexpr double kRadToDeg = 180.0 / std::numbers::pi;

using detail::blank_or_comment;
using detail::split_commas;

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const double pos = q * static_cast<double>(v.size() - 1);
  const auto lo = static_cast<std::size_t>(std::floor(pos));
  const std::size_t hi = std::min(lo + 1, v.size() - 1);
  return v[lo] + (pos - static_cast<double>(lo)) * (v[hi] - v[lo]);
}

}  // namespace

// ------------------------------------------------------------------ truth

MotionTruth::MotionTruth(std::vector<MotionTruthSample> samples, bool have_poses)
    : samples_(std::move(samples)), poses_integrated_(!have_poses) {
  for (std::size_t i = 1; i < samples_.size(); ++i) {
    POLMAP_EXPECT(samples_[i].time_s > samples_[i - 1].time_s);
  }
  if (!have_poses && !samples_.empty()) {
    samples_[0].T_frame_vehicle = Pose2{};
    for (std::size_t i = 1; i < samples_.size(); ++i) {
      const auto& a = samples_[i - 1];
      const double dt = samples_[i].time_s - a.time_s;
      samples_[i].T_frame_vehicle =
          a.T_frame_vehicle * integrate_motion(0.5 * (a.v_mps + samples_[i].v_mps),
                                               0.5 * (a.yaw_rate_rps + samples_[i].yaw_rate_rps),
                                               dt);
    }
  }
}

std::optional<MotionTruthSample> MotionTruth::at(double time_s) const {
  if (samples_.empty() || time_s < samples_.front().time_s || time_s > samples_.back().time_s) {
    return std::nullopt;
  }
  auto it = std::lower_bound(samples_.begin(), samples_.end(), time_s,
                             [](const MotionTruthSample& s, double t) { return s.time_s < t; });
  if (it == samples_.begin()) return *it;
  const MotionTruthSample& b = *it;
  const MotionTruthSample& a = *std::prev(it);
  const double f = (time_s - a.time_s) / (b.time_s - a.time_s);
  MotionTruthSample s;
  s.time_s = time_s;
  s.v_mps = a.v_mps + f * (b.v_mps - a.v_mps);
  s.yaw_rate_rps = a.yaw_rate_rps + f * (b.yaw_rate_rps - a.yaw_rate_rps);
  s.T_frame_vehicle.x_m =
      a.T_frame_vehicle.x_m + f * (b.T_frame_vehicle.x_m - a.T_frame_vehicle.x_m);
  s.T_frame_vehicle.y_m =
      a.T_frame_vehicle.y_m + f * (b.T_frame_vehicle.y_m - a.T_frame_vehicle.y_m);
  s.T_frame_vehicle.yaw_rad =
      wrap_angle_rad(a.T_frame_vehicle.yaw_rad +
                     f * wrap_angle_rad(b.T_frame_vehicle.yaw_rad - a.T_frame_vehicle.yaw_rad));
  return s;
}

MotionTruth truth_from_trajectory(const std::vector<TrajectorySample>& samples,
                                  const tiles::LocalFrame& frame) {
  std::vector<MotionTruthSample> out;
  out.reserve(samples.size());
  for (const TrajectorySample& t : samples) {
    if (!out.empty() && t.time_s <= out.back().time_s) continue;  // duplicates
    MotionTruthSample s;
    s.time_s = t.time_s;
    s.v_mps = t.speed_mps;
    s.yaw_rate_rps = t.yaw_rate_rps;
    const Eigen::Vector2d xy = frame.to_local(t.lat_deg, t.lon_deg);
    s.T_frame_vehicle = {xy.x(), xy.y(), wrap_angle_rad(t.yaw_enu_rad + frame.convergence_rad(xy))};
    out.push_back(s);
  }
  return MotionTruth(std::move(out), true);
}

MotionTruth read_truth_csv(const std::filesystem::path& path, std::optional<GeoPoint> origin) {
  std::ifstream in(path);
  if (!in) throw IoError("cannot open truth CSV " + path.string());
  const std::string src = path.string();
  std::string line;
  std::uint64_t line_no = 0;
  std::map<std::string, int, std::less<>> col;
  while (std::getline(in, line)) {
    ++line_no;
    if (blank_or_comment(line)) continue;
    const auto f = split_commas(line);
    for (std::size_t i = 0; i < f.size(); ++i) col[std::string(f[i])] = static_cast<int>(i);
    break;
  }
  auto has = [&](const char* name) { return col.contains(name); };
  for (const char* req : {"time_s", "v_mps", "yaw_rate_rps"}) {
    if (!has(req)) {
      throw FormatError(src + ": line " + std::to_string(std::max<std::uint64_t>(line_no, 1)) +
                        ": header lacks column '" + req +
                        "' (expected time_s,v_mps,yaw_rate_rps or "
                        "time_s,lat_deg,lon_deg,yaw_enu_rad,v_mps,yaw_rate_rps)");
    }
  }
  const bool geo = has("lat_deg") && has("lon_deg") && has("yaw_enu_rad");
  std::size_t min_fields = 0;
  for (const auto& [k, v] : col) min_fields = std::max(min_fields, static_cast<std::size_t>(v + 1));
  struct Raw {
    double t, v, w, lat, lon, yaw;
  };
  std::vector<Raw> raw;
  while (std::getline(in, line)) {
    ++line_no;
    if (blank_or_comment(line)) continue;
    const auto f = split_commas(line);
    if (f.size() < min_fields) {
      throw FormatError(src + ": line " + std::to_string(line_no) + ", column " +
                        std::to_string(f.size() + 1) + ": row has " + std::to_string(f.size()) +
                        " fields, header needs " + std::to_string(min_fields));
    }
    auto num = [&](const char* name) {
      const int c = col.at(name);
      const std::string_view s = f[c];
      const std::optional<double> v = detail::parse_double(s);
      if (!v || !std::isfinite(*v)) {
        throw FormatError(src + ": line " + std::to_string(line_no) + ", column " +
                          std::to_string(c + 1) + " (" + name + "): '" + std::string(s) +
                          "' is not a finite number");
      }
      return *v;
    };
    Raw r{num("time_s"), num("v_mps"), num("yaw_rate_rps"), 0, 0, 0};
    if (geo) {
      r.lat = num("lat_deg");
      r.lon = num("lon_deg");
      r.yaw = num("yaw_enu_rad");
    }
    if (!raw.empty() && r.t < raw.back().t) {
      throw FormatError(src + ": line " + std::to_string(line_no) + ", column " +
                        std::to_string(col.at("time_s") + 1) +
                        " (time_s): rows are not in time order");
    }
    if (!raw.empty() && r.t == raw.back().t) continue;  // duplicate time: keep the first
    raw.push_back(r);
  }
  if (raw.empty()) throw FormatError(src + ": no data rows");
  std::vector<MotionTruthSample> samples;
  samples.reserve(raw.size());
  if (geo) {
    const tiles::LocalFrame frame(origin ? *origin : GeoPoint{raw.front().lat, raw.front().lon, 0});
    for (const Raw& r : raw) {
      const Eigen::Vector2d xy = frame.to_local(r.lat, r.lon);
      samples.push_back({r.t, r.v, r.w,
                         Pose2{xy.x(), xy.y(), wrap_angle_rad(r.yaw + frame.convergence_rad(xy))}});
    }
  } else {
    for (const Raw& r : raw) samples.push_back({r.t, r.v, r.w, Pose2{}});
  }
  return MotionTruth(std::move(samples), geo);
}

// ------------------------------------------------------------------ runner

EgoMotionRunner::EgoMotionRunner(std::vector<SensorMount> mounts, radar::EgoMotionConfig cfg,
                                 radar::OdometryConfig odo_cfg,
                                 std::optional<radar::MountCalibrationConfig> calib_cfg)
    : estimator_(mounts, cfg), odometry_(odo_cfg) {
  if (calib_cfg) calibrator_.emplace(std::move(mounts), *calib_cfg);
}

const EgoMotionRecord& EgoMotionRunner::process(const SensorFrame& frame) {
  EgoMotionRecord r;
  r.sensor_id = frame.sensor_id;
  // CPU time of this thread, not wall time: the figure must not depend on what
  // else runs on a shared machine.
  auto cpu_s = [] {
    timespec ts{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
  };
  const double t0 = cpu_s();
  r.estimate = estimator_.process(frame);
  if (calibrator_) {
    calibrator_->add_frame(frame);
    if (calibrator_->add_estimate(r.estimate)) {
      const radar::MountCalibrationResult c = calibrator_->result();
      if (!converged_at_s_ && c.status == radar::MountCalibrationResult::Status::Converged) {
        converged_at_s_ = r.estimate.time_s;
      }
      if (calibrator_->config().calibrate_mounts) radar::apply_mount_calibration(estimator_, c);
      if (history_.empty() || r.estimate.time_s >= history_.back().first + snapshot_interval_s) {
        history_.emplace_back(r.estimate.time_s, c);
      }
    }
  }
  r.compute_s = cpu_s() - t0;
  odometry_.add(r.estimate);
  r.T_odom_vehicle = odometry_.try_T_odom_vehicle(r.estimate.time_s);
  records_.push_back(r);
  return records_.back();
}

// ------------------------------------------------------------------ metrics

EgoMotionMetrics evaluate_egomotion(const std::vector<EgoMotionRecord>& records,
                                    const MotionTruth& truth, const EgoMotionEvalConfig& cfg) {
  using Status = radar::MotionEstimate::Status;
  EgoMotionMetrics m;
  m.frames = static_cast<int>(records.size());
  std::vector<double> ev, ew, compute;
  double sv = 0, sw = 0;
  // Odometry and truth poses at the Ok estimate times (for drift).
  std::vector<Pose2> odo, tru;
  for (const EgoMotionRecord& r : records) {
    compute.push_back(r.compute_s * 1e3);
    switch (r.estimate.status) {
      case Status::Ok:
        ++m.estimates_ok;
        break;
      case Status::Rejected:
        ++m.estimates_rejected;
        continue;
      case Status::TooFewDetections:
        ++m.estimates_too_few;
        continue;
    }
    const auto t = truth.at(r.estimate.time_s);
    if (!t) continue;
    ++m.compared;
    const double e_v = r.estimate.v_mps - t->v_mps;
    const double e_w = (r.estimate.yaw_rate_rps - t->yaw_rate_rps) * kRadToDeg;
    ev.push_back(std::abs(e_v));
    ew.push_back(std::abs(e_w));
    sv += e_v;
    sw += e_w;
    m.v_rmse_mps += e_v * e_v;
    m.yaw_rate_rmse_dps += e_w * e_w;
    if (r.T_odom_vehicle) {
      odo.push_back(*r.T_odom_vehicle);
      tru.push_back(t->T_frame_vehicle);
    }
  }
  if (m.compared > 0) {
    const double n = m.compared;
    m.v_rmse_mps = std::sqrt(m.v_rmse_mps / n);
    m.yaw_rate_rmse_dps = std::sqrt(m.yaw_rate_rmse_dps / n);
    m.v_bias_mps = sv / n;
    m.yaw_rate_bias_dps = sw / n;
    m.v_max_err_mps = *std::max_element(ev.begin(), ev.end());
    m.yaw_rate_max_err_dps = *std::max_element(ew.begin(), ew.end());
    m.v_median_err_mps = percentile(ev, 0.5);
    m.yaw_rate_median_err_dps = percentile(ew, 0.5);
  }
  if (!compute.empty()) {
    double s = 0;
    for (double c : compute) s += c;
    m.compute_mean_ms = s / static_cast<double>(compute.size());
    m.compute_p95_ms = percentile(compute, 0.95);
    m.compute_max_ms = *std::max_element(compute.begin(), compute.end());
  }

  // Drift. Cumulative true path length at each pose.
  if (odo.size() >= 2) {
    std::vector<double> dist(tru.size(), 0.0);
    for (std::size_t k = 1; k < tru.size(); ++k) {
      dist[k] = dist[k - 1] + (tru[k].translation() - tru[k - 1].translation()).norm();
    }
    for (std::size_t k = 1; k < odo.size(); ++k) {
      m.odometry_distance_m += (odo[k].translation() - odo[k - 1].translation()).norm();
    }
    m.distance_m = dist.back();
    // Relative error of the sub-path i -> j, displacement in the start's vehicle frame.
    auto rel_error = [&](std::size_t i, std::size_t j, double& heading_err) {
      const Pose2 d_odo = odo[i].inverse() * odo[j];
      const Pose2 d_tru = tru[i].inverse() * tru[j];
      heading_err = std::abs(wrap_angle_rad(d_odo.yaw_rad - d_tru.yaw_rad));
      return (d_odo.translation() - d_tru.translation()).norm();
    };
    if (m.distance_m > 0) {
      double h = 0;
      m.drift_endpoint_pct = 100.0 * rel_error(0, odo.size() - 1, h) / m.distance_m;
    }
    double sum = 0, sum_h = 0;
    std::size_t j = 0;
    for (double start = 0.0; start + cfg.segment_length_m <= m.distance_m;
         start += cfg.segment_step_m) {
      const std::size_t i = static_cast<std::size_t>(
          std::lower_bound(dist.begin(), dist.end(), start) - dist.begin());
      j = std::max(j, i);
      while (j < dist.size() && dist[j] - dist[i] < cfg.segment_length_m) ++j;
      if (j >= dist.size()) break;
      double h = 0;
      sum += rel_error(i, j, h) / (dist[j] - dist[i]);
      sum_h += h * kRadToDeg * (100.0 / (dist[j] - dist[i]));
      ++m.drift_segments;
    }
    if (m.drift_segments > 0) {
      m.drift_segment_pct = 100.0 * sum / m.drift_segments;
      m.heading_drift_deg_per_100m = sum_h / m.drift_segments;
    }
    m.drift_pct = m.drift_segment_pct ? m.drift_segment_pct : m.drift_endpoint_pct;
  }
  return m;
}

nlohmann::json to_json(const EgoMotionMetrics& m) {
  auto opt = [](const std::optional<double>& v) {
    return v ? nlohmann::json(*v) : nlohmann::json();
  };
  return nlohmann::json{
      {"frames", m.frames},
      {"estimates_ok", m.estimates_ok},
      {"estimates_rejected", m.estimates_rejected},
      {"estimates_too_few", m.estimates_too_few},
      {"compared", m.compared},
      {"v_rmse_mps", m.v_rmse_mps},
      {"v_max_err_mps", m.v_max_err_mps},
      {"v_median_err_mps", m.v_median_err_mps},
      {"v_bias_mps", m.v_bias_mps},
      {"yaw_rate_rmse_dps", m.yaw_rate_rmse_dps},
      {"yaw_rate_max_err_dps", m.yaw_rate_max_err_dps},
      {"yaw_rate_median_err_dps", m.yaw_rate_median_err_dps},
      {"yaw_rate_bias_dps", m.yaw_rate_bias_dps},
      {"distance_m", m.distance_m},
      {"odometry_distance_m", m.odometry_distance_m},
      {"drift_pct", opt(m.drift_pct)},
      {"drift_segment_pct", opt(m.drift_segment_pct)},
      {"drift_endpoint_pct", opt(m.drift_endpoint_pct)},
      {"drift_segments", m.drift_segments},
      {"heading_drift_deg_per_100m", opt(m.heading_drift_deg_per_100m)},
      {"compute_mean_ms", m.compute_mean_ms},
      {"compute_p95_ms", m.compute_p95_ms},
      {"compute_max_ms", m.compute_max_ms},
  };
}

void write_egomotion_csv(const std::filesystem::path& path,
                         const std::vector<EgoMotionRecord>& records, const MotionTruth& truth) {
  std::ofstream f(path);
  if (!f) throw IoError("cannot write " + path.string());
  f << "time_s,sensor_id,status,v_mps,yaw_rate_rps,v_std_mps,yaw_rate_std_rps,num_inliers,"
       "num_detections,num_frames,odom_x_m,odom_y_m,odom_yaw_rad,truth_v_mps,truth_yaw_rate_rps,"
       "compute_ms\n";
  char buf[512];
  for (const EgoMotionRecord& r : records) {
    const auto& e = r.estimate;
    const bool ok = e.status == radar::MotionEstimate::Status::Ok;
    std::string line;
    std::snprintf(buf, sizeof buf, "%.6f,%d,%s,", e.time_s, static_cast<int>(r.sensor_id),
                  radar::to_string(e.status));
    line += buf;
    if (ok) {
      std::snprintf(buf, sizeof buf, "%.6f,%.8f,%.6f,%.8f,", e.v_mps, e.yaw_rate_rps,
                    std::sqrt(e.covariance(0, 0)), std::sqrt(e.covariance(1, 1)));
      line += buf;
    } else {
      line += ",,,,";
    }
    std::snprintf(buf, sizeof buf, "%d,%d,%d,", e.num_inliers, e.num_detections, e.num_frames);
    line += buf;
    if (r.T_odom_vehicle) {
      std::snprintf(buf, sizeof buf, "%.4f,%.4f,%.6f,", r.T_odom_vehicle->x_m,
                    r.T_odom_vehicle->y_m, r.T_odom_vehicle->yaw_rad);
      line += buf;
    } else {
      line += ",,,";
    }
    if (const auto t = truth.at(e.time_s)) {
      std::snprintf(buf, sizeof buf, "%.6f,%.8f,", t->v_mps, t->yaw_rate_rps);
      line += buf;
    } else {
      line += ",,";
    }
    std::snprintf(buf, sizeof buf, "%.4f\n", r.compute_s * 1e3);
    line += buf;
    f << line;
  }
  if (!f) throw IoError("write failed: " + path.string());
}

}  // namespace polmap::eval
