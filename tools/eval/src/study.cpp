#include "polmap/eval/study.hpp"

#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <memory>
#include <numbers>
#include <random>
#include <sstream>
#include <thread>

#include "polmap/eval/map_geometry.hpp"
#include "polmap/eval/stage_budget.hpp"
#include "polmap/eval/store_tile_source.hpp"
#include "polmap/eval/svg_plot.hpp"
#include "polmap/eval/trajectory_eval.hpp"
#include "polmap/localization_client/tile_fetcher.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/map_builder.hpp"
#include "polmap/mapping_service/server.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/radar/drive_processor.hpp"
#include "polmap/radar/egomotion.hpp"
#include "polmap/radar/odometry.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/truth.hpp"
#include "polmap/sim/world.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "polmap/util/cpu_time.hpp"

namespace polmap::eval {
namespace {

using Clock = std::chrono::steady_clock;
constexpr double kDeg = std::numbers::pi / 180.0;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

/// CPU time of the calling thread: the localizer is single-threaded (Ceres runs
/// with one thread), so this is its cost independent of other load on the machine.
using util::thread_cpu_s;

std::string level_dir_name(PolLevel l) { return std::string(to_string(l)); }

// ------------------------------------------------------------------ processing

/// A simulated drive, processed in mapping mode and written as a package.
struct ProcessedDrive {
  std::string drive_id;
  std::filesystem::path package_dir;
  std::int64_t points = 0;
  std::int64_t lines = 0;
};

ProcessedDrive process_to_package(RecordSource& source, const StudyConfig& cfg, PolLevel level,
                                  const std::filesystem::path& dir,
                                  const std::function<void(double)>& progress) {
  radar::DriveProcessingConfig pcfg;
  pcfg.gridmap = cfg.mapping_gridmap;
  pcfg.gridmap.level = level;
  pcfg.gridmap.window_s = 0.0;
  pcfg.points = cfg.points;
  pcfg.lines = cfg.lines;
  mapping::PackageWriteOptions wo;
  wo.overwrite = true;
  wo.format_version = cfg.package_format;
  wo.landmarks_only = cfg.landmarks_only;
  const radar::DriveProcessingResult r =
      mapping::process_drive_for_package(source, pcfg, wo, progress);
  mapping::write_drive_package(r, dir, wo);
  return {r.header.drive_id, dir, static_cast<std::int64_t>(r.points.size()),
          static_cast<std::int64_t>(r.lines.size())};
}

// ------------------------------------------------------------------ truth

/// GNSS solution flags of the drive's trajectory samples (step function).
class FixFlags {
 public:
  void add(double t, bool fixed) {
    if (!t_.empty() && t <= t_.back()) return;
    t_.push_back(t);
    fixed_.push_back(fixed);
  }
  [[nodiscard]] bool fixed_at(double t) const {
    if (t_.empty()) return false;
    auto it = std::upper_bound(t_.begin(), t_.end(), t);
    const std::size_t i = it == t_.begin() ? 0 : static_cast<std::size_t>(it - t_.begin()) - 1;
    return fixed_[i];
  }
  [[nodiscard]] double fixed_share() const {
    if (fixed_.empty()) return 0.0;
    return static_cast<double>(std::count(fixed_.begin(), fixed_.end(), true)) /
           static_cast<double>(fixed_.size());
  }

 private:
  std::vector<double> t_;
  std::vector<bool> fixed_;
};

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const double idx = p * static_cast<double>(v.size() - 1);
  const auto i = static_cast<std::size_t>(std::floor(idx));
  const std::size_t j = std::min(v.size() - 1, i + 1);
  return v[i] + (idx - static_cast<double>(i)) * (v[j] - v[i]);
}

double mean(const std::vector<double>& v) {
  if (v.empty()) return 0.0;
  double s = 0.0;
  for (double x : v) s += x;
  return s / static_cast<double>(v.size());
}

// ------------------------------------------------------------------ localization

/// Seeded initial-pose error: magnitude initial_error_m in a uniform random
/// direction, yaw error ±initial_error_yaw_deg (random sign).
GeoPose perturbed_initial_pose(const TrajectorySample& s, const tiles::LocalFrame& frame,
                               const StudyConfig& cfg, std::uint64_t seed, int drive) {
  std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ULL + static_cast<std::uint64_t>(drive) * 7919 + 17);
  std::uniform_real_distribution<double> u(0.0, 2.0 * std::numbers::pi);
  const double dir = u(rng);
  const double sign = (rng() & 1U) != 0U ? 1.0 : -1.0;
  const Eigen::Vector2d xy = frame.to_local(s.lat_deg, s.lon_deg) +
                             cfg.initial_error_m * Eigen::Vector2d(std::cos(dir), std::sin(dir));
  GeoPose g;
  g.position = frame.to_geo(xy);
  g.yaw_enu_rad = wrap_angle_rad(s.yaw_enu_rad + sign * cfg.initial_error_yaw_deg * kDeg);
  return g;
}

/// The calibration's estimates against the simulator's true mounts and time offsets.
StudyDriveResult::Calibration calibration_against_truth(const radar::MountCalibrationResult& cal,
                                                        const std::vector<SensorMount>& nominal,
                                                        const std::vector<SensorMount>& truth,
                                                        const std::vector<double>& time_offsets_s,
                                                        bool common_yaw_enabled) {
  POLMAP_EXPECT(nominal.size() == truth.size() && cal.sensors.size() == nominal.size());
  const std::size_t n = nominal.size();
  std::vector<double> dyaw(n), dt(n, 0.0);
  double mean_yaw = 0.0, mean_t = 0.0, mean_est = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    dyaw[i] =
        wrap_angle_rad(truth[i].T_vehicle_sensor.yaw_rad - nominal[i].T_vehicle_sensor.yaw_rad);
    if (i < time_offsets_s.size()) dt[i] = time_offsets_s[i];
    mean_yaw += dyaw[i] / static_cast<double>(n);
    mean_t += dt[i] / static_cast<double>(n);
    mean_est += cal.sensors[i].yaw_offset_rad / static_cast<double>(n);
  }
  StudyDriveResult::Calibration c;
  c.common_yaw_deg = cal.common_yaw_rad / kDeg;
  c.common_yaw_sigma_deg = cal.common_yaw_sigma_rad / kDeg;
  c.common_yaw_true_deg = mean_yaw / kDeg;
  // The reported offsets carry the common yaw exactly when it was applied.
  c.common_yaw_applied = common_yaw_enabled && cal.common_yaw_applied;
  for (std::size_t i = 0; i < n; ++i) {
    const auto& e = cal.sensors[i];
    const double rel_yaw_err = (e.yaw_offset_rad - mean_est) - (dyaw[i] - mean_yaw);
    const double rel_t_err = e.time_offset_s - (dt[i] - mean_t);
    c.relative_yaw_max_error_deg =
        std::max(c.relative_yaw_max_error_deg, std::abs(rel_yaw_err) / kDeg);
    c.relative_time_max_error_ms =
        std::max(c.relative_time_max_error_ms, 1e3 * std::abs(rel_t_err));
  }
  return c;
}

ErrorSummary error_summary(const TrajectoryMetrics& m) {
  ErrorSummary e;
  e.samples = m.evaluated;
  e.long_rmse_m = m.long_rmse_m;
  e.long_max_m = m.long_max_m;
  e.lat_rmse_m = m.lat_rmse_m;
  e.lat_max_m = m.lat_max_m;
  e.rot_rmse_deg = m.rot_rmse_deg;
  e.rot_max_deg = m.rot_max_deg;
  e.nees_samples = m.nees_samples;
  e.nees_mean = m.nees_mean;
  e.nees_within_q95_share = m.nees_within_q95_share;
  e.pl_samples = m.pl_samples;
  e.pl_bounded_share = m.pl_bounded_share;
  e.pl_mean_m = m.pl_mean_m;
  return e;
}

}  // namespace

StudyDriveResult localize_simulated_drive(const std::shared_ptr<const sim::World>& world,
                                          const sim::SimConfig& sim_cfg, int drive, PolLevel level,
                                          const StudyConfig& cfg, loc::TileSource& tiles,
                                          const LocalizeOptions& opt) {
  StudyDriveResult r;
  r.seed = sim_cfg.seed;
  r.level = level;
  r.drive = drive;
  sim::DriveSimulator simulator(world, sim_cfg, drive);
  r.drive_id = simulator.header().drive_id;
  r.duration_s = simulator.duration_s();
  r.distance_m = simulator.plan().distance_m();

  loc::LocalizerConfig lcfg = cfg.localizer;
  lcfg.gridmap.level = level;
  loc::Localizer localizer(lcfg, simulator.header().sensors, tiles);

  std::unique_ptr<TrajectoryCsvWriter> csv;
  if (!opt.csv_path.empty()) csv = std::make_unique<TrajectoryCsvWriter>(opt.csv_path);

  FixFlags fix;
  bool initialized = false;
  std::vector<SensorFrame> early;  // frames before the first GNSS sample
  std::vector<TrajectoryRow> rows;
  std::vector<double> frame_ms, frame_wall_ms, graph_ms, extract_ms, match_ms;
  double first_frame_t = std::numeric_limits<double>::quiet_NaN();
  double last_t = 0.0;
  std::int64_t matched_sum = 0;
  double calibration_converged_s = -1.0;
  const double fetcher_cpu0_s = opt.fetcher != nullptr ? opt.fetcher->stats().worker_cpu_s : 0.0;

  auto handle = [&](const SensorFrame& f) {
    if (opt.before_frame) opt.before_frame(f.time_s);
    const auto t0 = Clock::now();
    const double c0 = thread_cpu_s();
    const loc::LocalizationOutput out = localizer.process(f);
    const double cpu = thread_cpu_s() - c0;
    r.stage_cpu += out.cpu;
    const double wall = seconds_since(t0);
    r.localizer_cpu_s += cpu;
    r.localizer_wall_s += wall;
    frame_ms.push_back(1e3 * cpu);
    frame_wall_ms.push_back(1e3 * wall);
    ++r.frames;
    if (std::isnan(first_frame_t)) first_frame_t = f.time_s;
    last_t = f.time_s;
    if (out.graph_updated) {
      graph_ms.push_back(1e3 * out.graph_update_time_s);
      matched_sum += out.matched_points;
    }
    if (out.extracted) {
      extract_ms.push_back(1e3 * out.extraction_time_s);
      match_ms.push_back(1e3 * out.matching_time_s);
    }
    if (calibration_converged_s < 0.0 && out.extracted) {
      const auto cal = localizer.mount_calibration();
      if (cal && cal->status == radar::MountCalibrationResult::Status::Converged) {
        calibration_converged_s = f.time_s - first_frame_t;
      }
    }
    if (!out.has_pose) return;
    const TrajectoryRow row = to_trajectory_row(out);
    if (csv) csv->write(row);
    rows.push_back(std::move(row));
  };

  while (auto rec = simulator.next()) {
    if (const auto* s = std::get_if<TrajectorySample>(&*rec)) {
      // GNSS samples only give the start pose and the evaluation's
      // carrier-phase flags; the localizer never sees them.
      fix.add(s->time_s, s->solution == GnssSolution::CarrierPhaseFixed);
      if (!initialized) {
        // The one coarse pose the localizer gets (see study.hpp).
        const tiles::LocalFrame df(simulator.header().origin);
        const GeoPose g = perturbed_initial_pose(*s, df, cfg, sim_cfg.seed, drive);
        localizer.set_initial_pose(g, std::max(0.5, cfg.initial_error_m),
                                   std::max(0.5, cfg.initial_error_yaw_deg) * kDeg);
        initialized = true;
        if (opt.fetcher != nullptr) {
          const auto keys = loc::tiles_around(g.position, lcfg.map_radius_m + cfg.initial_error_m);
          opt.fetcher->wait_for(keys, 20.0);
        }
        for (const auto& f : early) handle(f);
        early.clear();
      }
      if (opt.progress) opt.progress(s->time_s / std::max(1e-9, simulator.duration_s()));
    } else {
      auto& f = std::get<SensorFrame>(*rec);
      if (!initialized) {
        early.push_back(std::move(f));
      } else {
        handle(f);
      }
    }
  }
  if (csv) csv->close();
  if (const auto cal = localizer.mount_calibration()) {
    r.calibration = calibration_against_truth(*cal, simulator.header().sensors,
                                              simulator.true_mounts(), simulator.time_offsets_s(),
                                              lcfg.mount_calibration.estimate_common_yaw);
    r.calibration->converged_after_s = calibration_converged_s;
  }

  // Reference: the simulator's exact poses, carrier-phase flags of the drive's GNSS; in the
  // map's frame (see LocalizeOptions) when asked, globally or around each pose.
  const std::vector<sim::ExactState> exact = simulator.exact_trajectory();
  using Rigid = std::pair<Eigen::Matrix2d, Eigen::Vector2d>;
  auto reference = [&](const std::function<std::optional<Rigid>(const Eigen::Vector2d&)>& frame) {
    std::vector<ReferenceSample> out;
    out.reserve(exact.size());
    for (sim::ExactState e : exact) {
      if (const std::optional<Rigid> Rt = frame(Eigen::Vector2d(e.x_m, e.y_m))) {
        const auto& [R, t] = *Rt;
        const Eigen::Vector2d p = R.transpose() * (Eigen::Vector2d(e.x_m, e.y_m) - t);
        e.x_m = p.x();
        e.y_m = p.y();
        e.yaw_rad -= std::atan2(R(1, 0), R(0, 0));
      }
      const sim::GeoTruth g = sim::to_geo_truth(e, world->frame);
      out.push_back(
          {e.time_s, g.lat_deg, g.lon_deg, g.yaw_enu_rad, e.v_mps, fix.fixed_at(e.time_s)});
    }
    return out;
  };
  const auto global_frame = [&](const Eigen::Vector2d&) { return opt.truth_to_map; };
  const std::vector<ReferenceSample> ref = reference(global_frame);
  TrajectoryEvalOptions eo;
  eo.min_speed_mps = cfg.min_speed_mps;
  eo.require_carrier_phase = cfg.require_carrier_phase;
  const TrajectoryMetrics m = evaluate_trajectory(rows, ref, eo);
  r.errors = error_summary(m);
  r.reliable_gnss_share = m.reliable_gt_share;
  if (opt.truth_to_local_map) {
    r.errors_local_frame =
        error_summary(evaluate_trajectory(rows, reference([&](const Eigen::Vector2d& p) {
                                            std::optional<Rigid> local = opt.truth_to_local_map(p);
                                            return local ? local : opt.truth_to_map;
                                          }),
                                          eo));
  }
  for (const TrajectoryError& e : m.errors) {
    r.sample_time_s.push_back(e.time_s);
    r.abs_long_m.push_back(std::abs(e.long_m));
    r.abs_lat_m.push_back(std::abs(e.lat_m));
    r.rot_deg.push_back(std::abs(e.rot_rad) / kDeg);
    r.nees.push_back(e.nees);
    r.pl_lat_m.push_back(e.pl_lat_m);
  }
  r.converged = m.time_to_tracking_s >= 0.0;
  r.converge_time_s = r.converged ? m.time_to_tracking_s : 0.0;

  // Health over every output after convergence (no speed or GNSS filter):
  // divergence, lost events, status shares.
  TrajectoryEvalOptions all;
  all.min_speed_mps = -1.0;
  all.require_carrier_phase = false;
  const TrajectoryMetrics h = evaluate_trajectory(rows, ref, all);
  for (const TrajectoryError& e : h.errors) {
    if (std::hypot(e.long_m, e.lat_m) > cfg.divergence_threshold_m) r.diverged = true;
  }
  if (!r.converged) r.diverged = true;
  std::int64_t after = 0, n_track = 0, n_degr = 0, n_lost = 0;
  bool conv = false;
  std::string prev;
  for (const auto& row : rows) {
    conv = conv || row.status == "tracking";
    if (conv) {
      ++after;
      n_track += row.status == "tracking" ? 1 : 0;
      n_degr += row.status == "degraded" ? 1 : 0;
      n_lost += row.status == "lost" ? 1 : 0;
      if (row.status == "lost" && prev != "lost") ++r.lost_events;
    }
    prev = row.status;
  }
  if (after > 0) {
    r.tracking_share = static_cast<double>(n_track) / static_cast<double>(after);
    r.degraded_share = static_cast<double>(n_degr) / static_cast<double>(after);
    r.lost_share = static_cast<double>(n_lost) / static_cast<double>(after);
  }
  if (opt.errors_csv_path.has_value() && !opt.errors_csv_path->empty()) {
    std::ofstream f(*opt.errors_csv_path);
    if (!f) throw IoError("cannot write " + opt.errors_csv_path->string());
    f << "time_s,status,speed_mps,e_long_m,e_lat_m,e_rot_deg,included\n";
    std::size_t j = 0;
    for (const TrajectoryError& e : h.errors) {
      while (j < m.errors.size() && m.errors[j].time_s < e.time_s) ++j;
      const bool inc = j < m.errors.size() && m.errors[j].time_s == e.time_s;
      char buf[200];
      std::snprintf(buf, sizeof buf, "%.4f,%s,%.3f,%.4f,%.4f,%.4f,%d\n", e.time_s, e.status.c_str(),
                    e.speed_mps, e.long_m, e.lat_m, std::abs(e.rot_rad) / kDeg, inc ? 1 : 0);
      f << buf;
    }
  }

  r.graph_updates = static_cast<std::int64_t>(graph_ms.size());
  r.mean_matched_points =
      graph_ms.empty() ? 0.0
                       : static_cast<double>(matched_sum) / static_cast<double>(graph_ms.size());
  r.frame_mean_ms = mean(frame_ms);
  r.frame_p95_ms = percentile(frame_ms, 0.95);
  r.frame_p99_ms = percentile(frame_ms, 0.99);
  r.frame_max_ms = frame_ms.empty() ? 0.0 : *std::max_element(frame_ms.begin(), frame_ms.end());
  r.extraction_mean_ms = mean(extract_ms);
  r.matching_mean_ms = mean(match_ms);
  r.graph_update_mean_ms = mean(graph_ms);
  r.graph_update_p95_ms = percentile(graph_ms, 0.95);
  r.graph_update_max_ms =
      graph_ms.empty() ? 0.0 : *std::max_element(graph_ms.begin(), graph_ms.end());
  const double span = last_t - first_frame_t;
  if (opt.fetcher != nullptr) {
    // The fetcher's worker thread works for this localizer (one drive at a time).
    r.helper_threads_cpu_s = opt.fetcher->stats().worker_cpu_s - fetcher_cpu0_s;
    r.localizer_cpu_s += r.helper_threads_cpu_s;
  }
  r.realtime_factor = r.localizer_cpu_s > 0 ? span / r.localizer_cpu_s : 0.0;
  r.realtime_factor_wall = r.localizer_wall_s > 0 ? span / r.localizer_wall_s : 0.0;
  return r;
}

namespace {

/// Exact trajectory (world frame) with linear interpolation.
class ExactPoses {
 public:
  explicit ExactPoses(std::vector<sim::ExactState> s) : s_(std::move(s)) {}
  [[nodiscard]] std::optional<sim::ExactState> at(double t) const {
    if (s_.empty() || t < s_.front().time_s || t > s_.back().time_s) return std::nullopt;
    auto it = std::lower_bound(s_.begin(), s_.end(), t,
                               [](const sim::ExactState& e, double x) { return e.time_s < x; });
    if (it == s_.begin()) return *it;
    const auto& b = *it;
    const auto& a = *(it - 1);
    const double w = (t - a.time_s) / std::max(1e-12, b.time_s - a.time_s);
    sim::ExactState r = a;
    r.time_s = t;
    r.x_m = a.x_m + w * (b.x_m - a.x_m);
    r.y_m = a.y_m + w * (b.y_m - a.y_m);
    r.yaw_rad = wrap_angle_rad(a.yaw_rad + w * wrap_angle_rad(b.yaw_rad - a.yaw_rad));
    r.v_mps = a.v_mps + w * (b.v_mps - a.v_mps);
    return r;
  }
  [[nodiscard]] std::optional<Pose2> pose(double t) const {
    const auto e = at(t);
    if (!e) return std::nullopt;
    return Pose2{e->x_m, e->y_m, e->yaw_rad};
  }

 private:
  std::vector<sim::ExactState> s_;
};

double point_segment_distance(const Eigen::Vector2d& p, const Eigen::Vector2d& a,
                              const Eigen::Vector2d& b) {
  const Eigen::Vector2d ab = b - a;
  const double l2 = ab.squaredNorm();
  const double u = l2 > 0 ? std::clamp((p - a).dot(ab) / l2, 0.0, 1.0) : 0.0;
  return (a + u * ab - p).norm();
}

}  // namespace

DriveDiagnosis diagnose_drive(const std::shared_ptr<const sim::World>& world,
                              const sim::SimConfig& sim_cfg, int drive, PolLevel level,
                              const StudyConfig& cfg, const mapping::MapStore& store,
                              std::int64_t version, const DiagnosisConfig& dcfg,
                              const std::filesystem::path& csv_path) {
  DriveDiagnosis d;
  sim::DriveSimulator simulator(world, sim_cfg, drive);
  const ExactPoses truth(simulator.exact_trajectory());
  const tiles::LocalFrame& wf = world->frame;

  // Map landmarks in the world frame.
  const mapping::LandmarkSet lms = store.landmarks_in(version, std::nullopt, false);
  std::vector<Eigen::Vector2d> map_pts;
  for (const auto& p : lms.points) map_pts.push_back(wf.to_local(p.position));
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> map_segs;
  for (const auto& l : lms.lines) {
    for (std::size_t i = 0; i + 1 < l.polyline.size(); ++i) {
      map_segs.emplace_back(wf.to_local(l.polyline[i]), wf.to_local(l.polyline[i + 1]));
    }
  }
  d.map_points = static_cast<std::int64_t>(lms.points.size());
  d.map_lines = static_cast<std::int64_t>(lms.lines.size());

  loc::LocalizerConfig lcfg = cfg.localizer;
  lcfg.gridmap.level = level;
  const auto& mounts = simulator.header().sensors;
  std::map<std::uint8_t, SensorMount> mount_by_id;
  for (const auto& m : mounts) mount_by_id[m.sensor_id] = m;
  const auto last = std::max_element(
      mounts.begin(), mounts.end(),
      [](const auto& a, const auto& b) { return a.trigger_offset_s < b.trigger_offset_s; });
  const std::uint8_t last_sensor = last->sensor_id;

  radar::EgoMotionEstimator ego(mounts, lcfg.egomotion);
  radar::Odometry odo(lcfg.odometry);
  radar::CovarianceGridmap grid(lcfg.gridmap);
  struct OdoSample {
    double t;
    Pose2 odo, truth;
  };
  std::vector<OdoSample> odo_samples;

  std::unique_ptr<std::ofstream> csv;
  if (!csv_path.empty()) {
    csv = std::make_unique<std::ofstream>(csv_path);
    if (!*csv) throw IoError("cannot write " + csv_path.string());
    *csv << "time_s,speed_mps,candidates,pairs,offset_long_m,offset_lat_m,offset_rms_m,"
            "line_candidates,lines_matched\n";
  }

  double sum_long = 0, sum_lat = 0, sum_sq = 0;
  std::int64_t n_cand = 0, n_pairs = 0, n_sparse = 0, n_line_cand = 0, n_line_match = 0;
  double line_sq = 0;
  std::uint64_t extraction_no = 0;
  while (auto rec = simulator.next()) {
    const auto* fp = std::get_if<SensorFrame>(&*rec);
    if (fp == nullptr) continue;
    const SensorFrame& f = *fp;
    const radar::MotionEstimate m = ego.process(f);
    ++d.egomotion_frames;
    d.egomotion_ok += m.status == radar::MotionEstimate::Status::Ok ? 1 : 0;
    odo.add(m);
    const auto T_true = truth.pose(f.time_s);
    if (!T_true) continue;
    if (const auto T_odo = odo.try_T_odom_vehicle(f.time_s)) {
      odo_samples.push_back({f.time_s, *T_odo, *T_true});
    }
    const auto mit = mount_by_id.find(f.sensor_id);
    if (mit == mount_by_id.end() || f.spectrum.azimuth_bins_rad.size() < 2) continue;
    grid.add(f.spectrum, *T_true * mit->second.T_vehicle_sensor, f.time_s);
    if (f.sensor_id != last_sensor ||
        f.cycle_index % static_cast<std::uint32_t>(std::max(1, lcfg.extract_every_n_cycles)) != 0) {
      continue;
    }
    ++extraction_no;
    ++d.extractions;
    const auto pts = radar::extract_points(grid, lcfg.points);
    const Eigen::Matrix2d R_vw = T_true->rotation().transpose();
    double el = 0, ea = 0, sq = 0;
    int pairs = 0;
    for (const auto& c : pts) {
      double best = std::numeric_limits<double>::infinity();
      Eigen::Vector2d best_lm = Eigen::Vector2d::Zero();
      for (const auto& lm : map_pts) {
        const double dist = (lm - c.position_m).squaredNorm();
        if (dist < best) {
          best = dist;
          best_lm = lm;
        }
      }
      if (std::sqrt(best) <= dcfg.assoc_radius_m) {
        const Eigen::Vector2d off = R_vw * (c.position_m - best_lm);
        el += off.x();
        ea += off.y();
        sq += off.squaredNorm();
        ++pairs;
      }
    }
    n_cand += static_cast<std::int64_t>(pts.size());
    n_pairs += pairs;
    sum_long += el;
    sum_lat += ea;
    sum_sq += sq;
    n_sparse += pairs < 3 ? 1 : 0;
    int line_cands = 0, line_matched = 0;
    if (lcfg.lines_every_n_extractions > 0 &&
        extraction_no % static_cast<std::uint64_t>(lcfg.lines_every_n_extractions) == 0) {
      const auto lines = radar::extract_lines(grid, lcfg.lines);
      for (const auto& l : lines) {
        const Eigen::Vector2d mid = 0.5 * (l.start_m + l.end_m);
        double best = std::numeric_limits<double>::infinity();
        for (const auto& [a, b] : map_segs)
          best = std::min(best, point_segment_distance(mid, a, b));
        ++line_cands;
        if (best <= dcfg.assoc_radius_m) {
          ++line_matched;
          line_sq += best * best;
        }
      }
      n_line_cand += line_cands;
      n_line_match += line_matched;
    }
    if (csv) {
      const auto e = truth.at(f.time_s);
      char buf[256];
      std::snprintf(buf, sizeof buf, "%.3f,%.2f,%zu,%d,%.4f,%.4f,%.4f,%d,%d\n", f.time_s,
                    e ? e->v_mps : 0.0, pts.size(), pairs, pairs ? el / pairs : 0.0,
                    pairs ? ea / pairs : 0.0, pairs ? std::sqrt(sq / pairs) : 0.0, line_cands,
                    line_matched);
      *csv << buf;
    }
  }
  if (d.extractions > 0) {
    const double ne = static_cast<double>(d.extractions);
    d.candidates_per_extraction = static_cast<double>(n_cand) / ne;
    d.pairs_per_extraction = static_cast<double>(n_pairs) / ne;
    d.sparse_extraction_share = static_cast<double>(n_sparse) / ne;
    const double nl = static_cast<double>(d.extractions) /
                      static_cast<double>(std::max(1, lcfg.lines_every_n_extractions));
    d.line_candidates_per_extraction = nl > 0 ? static_cast<double>(n_line_cand) / nl : 0.0;
  }
  if (n_cand > 0) d.matched_share = static_cast<double>(n_pairs) / static_cast<double>(n_cand);
  if (n_pairs > 0) {
    const double np = static_cast<double>(n_pairs);
    d.offset_long_mean_m = sum_long / np;
    d.offset_lat_mean_m = sum_lat / np;
    d.offset_rms_m = std::sqrt(sum_sq / np);
  }
  if (n_line_cand > 0) {
    d.line_matched_share = static_cast<double>(n_line_match) / static_cast<double>(n_line_cand);
  }
  if (n_line_match > 0)
    d.line_offset_rms_m = std::sqrt(line_sq / static_cast<double>(n_line_match));

  // Odometry over windows of window_s (starts every 1 s).
  double pos_sq = 0, lat_sq = 0, yaw_sq = 0;
  std::int64_t nw = 0;
  std::size_t j = 0;
  double next_start = odo_samples.empty() ? 0.0 : odo_samples.front().t;
  for (std::size_t i = 0; i < odo_samples.size(); ++i) {
    const auto& a = odo_samples[i];
    if (a.t < next_start) continue;
    next_start = a.t + 1.0;
    j = std::max(j, i);
    while (j + 1 < odo_samples.size() && odo_samples[j].t < a.t + dcfg.window_s) ++j;
    const auto& b = odo_samples[j];
    if (b.t - a.t < 0.9 * dcfg.window_s) break;
    const Pose2 rel_odo = a.odo.inverse() * b.odo;
    const Pose2 rel_true = a.truth.inverse() * b.truth;
    const Eigen::Vector2d dp = rel_odo.translation() - rel_true.translation();
    const double dyaw = std::abs(wrap_angle_rad(rel_odo.yaw_rad - rel_true.yaw_rad)) / kDeg;
    pos_sq += dp.squaredNorm();
    lat_sq += dp.y() * dp.y();
    yaw_sq += dyaw * dyaw;
    d.odo_window_pos_max_m = std::max(d.odo_window_pos_max_m, dp.norm());
    d.odo_window_yaw_max_deg = std::max(d.odo_window_yaw_max_deg, dyaw);
    ++nw;
  }
  if (nw > 0) {
    d.odo_window_pos_rms_m = std::sqrt(pos_sq / static_cast<double>(nw));
    d.odo_window_lat_rms_m = std::sqrt(lat_sq / static_cast<double>(nw));
    d.odo_window_yaw_rms_deg = std::sqrt(yaw_sq / static_cast<double>(nw));
  }
  return d;
}

nlohmann::json to_json(const DriveDiagnosis& d) {
  return {{"egomotion_ok", d.egomotion_ok},
          {"egomotion_frames", d.egomotion_frames},
          {"odo_window_pos_rms_m", d.odo_window_pos_rms_m},
          {"odo_window_pos_max_m", d.odo_window_pos_max_m},
          {"odo_window_lat_rms_m", d.odo_window_lat_rms_m},
          {"odo_window_yaw_rms_deg", d.odo_window_yaw_rms_deg},
          {"odo_window_yaw_max_deg", d.odo_window_yaw_max_deg},
          {"extractions", d.extractions},
          {"candidates_per_extraction", d.candidates_per_extraction},
          {"matched_share", d.matched_share},
          {"pairs_per_extraction", d.pairs_per_extraction},
          {"sparse_extraction_share", d.sparse_extraction_share},
          {"offset_long_mean_m", d.offset_long_mean_m},
          {"offset_lat_mean_m", d.offset_lat_mean_m},
          {"offset_rms_m", d.offset_rms_m},
          {"line_candidates_per_extraction", d.line_candidates_per_extraction},
          {"line_matched_share", d.line_matched_share},
          {"line_offset_rms_m", d.line_offset_rms_m},
          {"map_points", d.map_points},
          {"map_lines", d.map_lines}};
}

StudyPackage simulate_and_package(const std::shared_ptr<const sim::World>& world,
                                  const sim::SimConfig& sim_cfg, int drive, PolLevel level,
                                  const StudyConfig& cfg, const std::filesystem::path& package_dir,
                                  const std::function<void(double fraction)>& progress) {
  const auto t0 = Clock::now();
  sim::DriveSimulator simulator(world, sim_cfg, drive);
  const double dur = std::max(1e-9, simulator.duration_s());
  const ProcessedDrive pd = process_to_package(simulator, cfg, level, package_dir, [&](double t) {
    if (progress) progress(t / dur);
  });
  return {pd.drive_id, pd.package_dir, pd.points, pd.lines, seconds_since(t0)};
}

namespace {

/// A real mapping server on loopback over the study's store (HTTP mode).
class LoopbackServer {
 public:
  explicit LoopbackServer(mapping::MapStore& store) {
    mapping::ServerConfig sc;
    sc.log_requests = false;
    sc.threads = 4;
    server_ = std::make_unique<mapping::Server>(store, sc);
    thread_ = std::thread([this] { server_->listen("127.0.0.1", 0); });
    if (!server_->wait_until_listening(std::chrono::seconds(10))) {
      stop();
      throw IoError("study: the loopback server did not start");
    }
  }
  ~LoopbackServer() { stop(); }
  LoopbackServer(const LoopbackServer&) = delete;
  LoopbackServer& operator=(const LoopbackServer&) = delete;
  [[nodiscard]] std::string url() const {
    return "http://127.0.0.1:" + std::to_string(server_->bound_port());
  }

 private:
  void stop() {
    if (server_) server_->stop();
    if (thread_.joinable()) thread_.join();
  }
  std::unique_ptr<mapping::Server> server_;
  std::thread thread_;
};

std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

}  // namespace

// ------------------------------------------------------------------ summaries

ErrorSummary pool_error_summaries(const std::vector<ErrorSummary>& parts) {
  ErrorSummary s;
  double sl = 0, sa = 0, sr = 0, nees = 0, nees_in = 0, pl = 0, pl_in = 0;
  for (const ErrorSummary& e : parts) {
    const auto n = static_cast<double>(e.samples);
    s.samples += e.samples;
    sl += n * e.long_rmse_m * e.long_rmse_m;
    sa += n * e.lat_rmse_m * e.lat_rmse_m;
    sr += n * e.rot_rmse_deg * e.rot_rmse_deg;
    s.long_max_m = std::max(s.long_max_m, e.long_max_m);
    s.lat_max_m = std::max(s.lat_max_m, e.lat_max_m);
    s.rot_max_deg = std::max(s.rot_max_deg, e.rot_max_deg);
    s.nees_samples += e.nees_samples;
    nees += static_cast<double>(e.nees_samples) * e.nees_mean;
    nees_in += static_cast<double>(e.nees_samples) * e.nees_within_q95_share;
    s.pl_samples += e.pl_samples;
    pl += static_cast<double>(e.pl_samples) * e.pl_mean_m;
    pl_in += static_cast<double>(e.pl_samples) * e.pl_bounded_share;
  }
  if (s.samples > 0) {
    const auto n = static_cast<double>(s.samples);
    s.long_rmse_m = std::sqrt(sl / n);
    s.lat_rmse_m = std::sqrt(sa / n);
    s.rot_rmse_deg = std::sqrt(sr / n);
  }
  if (s.nees_samples > 0) {
    s.nees_mean = nees / static_cast<double>(s.nees_samples);
    s.nees_within_q95_share = nees_in / static_cast<double>(s.nees_samples);
  }
  if (s.pl_samples > 0) {
    s.pl_mean_m = pl / static_cast<double>(s.pl_samples);
    s.pl_bounded_share = pl_in / static_cast<double>(s.pl_samples);
  }
  return s;
}

ErrorSummary summarize_errors(const std::vector<const StudyDriveResult*>& drives) {
  ErrorSummary s;
  double sl = 0, sa = 0, sr = 0, nees = 0, pl = 0;
  std::int64_t nees_in = 0, pl_in = 0;
  for (const auto* d : drives) {
    for (std::size_t i = 0; i < d->abs_long_m.size(); ++i) {
      sl += d->abs_long_m[i] * d->abs_long_m[i];
      sa += d->abs_lat_m[i] * d->abs_lat_m[i];
      sr += d->rot_deg[i] * d->rot_deg[i];
    }
    for (std::size_t i = 0; i < d->nees.size(); ++i) {
      if (d->nees[i] >= 0.0) {
        ++s.nees_samples;
        nees += d->nees[i];
        nees_in += d->nees[i] <= kChi2Dof3Q95 ? 1 : 0;
      }
      if (d->pl_lat_m[i] > 0.0) {
        ++s.pl_samples;
        pl += d->pl_lat_m[i];
        pl_in += d->abs_lat_m[i] <= d->pl_lat_m[i] ? 1 : 0;
      }
    }
    s.samples += static_cast<std::int64_t>(d->abs_long_m.size());
    s.long_max_m = std::max(s.long_max_m, d->errors.long_max_m);
    s.lat_max_m = std::max(s.lat_max_m, d->errors.lat_max_m);
    s.rot_max_deg = std::max(s.rot_max_deg, d->errors.rot_max_deg);
  }
  if (s.samples > 0) {
    const double n = static_cast<double>(s.samples);
    s.long_rmse_m = std::sqrt(sl / n);
    s.lat_rmse_m = std::sqrt(sa / n);
    s.rot_rmse_deg = std::sqrt(sr / n);
  }
  if (s.nees_samples > 0) {
    s.nees_mean = nees / static_cast<double>(s.nees_samples);
    s.nees_within_q95_share = static_cast<double>(nees_in) / static_cast<double>(s.nees_samples);
  }
  if (s.pl_samples > 0) {
    s.pl_mean_m = pl / static_cast<double>(s.pl_samples);
    s.pl_bounded_share = static_cast<double>(pl_in) / static_cast<double>(s.pl_samples);
  }
  return s;
}

StudyResult run_study(const StudyConfig& cfg,
                      const std::function<void(const StudyProgress&)>& progress) {
  if (cfg.drives < 3) {
    throw ValidationError(
        "study: --drives must be at least 3 (the left-out drive plus N_p = 2 "
        "drives for the consensus), got " +
        std::to_string(cfg.drives));
  }
  if (cfg.seeds.empty()) throw ValidationError("study: no seeds given");
  if (cfg.levels.empty()) throw ValidationError("study: no polarimetric levels given");
  if (cfg.out_dir.empty()) throw ValidationError("study: no output directory given");
  if (!(cfg.length_m > 0)) throw ValidationError("study: --length-m must be > 0");
  std::error_code ec;
  std::filesystem::create_directories(cfg.out_dir, ec);
  if (ec) throw IoError("study: cannot create " + cfg.out_dir.string() + ": " + ec.message());

  const auto t_start = Clock::now();
  StudyResult result;
  result.world = cfg.world;
  {
    const auto& rc = cfg.sim.realism;
    const std::vector<std::pair<const char*, bool>> on{{"noise", rc.radar_noise.enabled},
                                                       {"mounts", rc.mounts.enabled},
                                                       {"timing", rc.timing.enabled},
                                                       {"slip", rc.slip.enabled},
                                                       {"multipath", rc.multipath.enabled},
                                                       {"elevation", rc.elevation.enabled},
                                                       {"ins", rc.ins.enabled}};
    std::string kept;
    bool all = true;
    for (const auto& [name, enabled] : on) {
      all = all && enabled;
      if (enabled) kept += (kept.empty() ? "" : ",") + std::string(name);
    }
    result.realism = kept.empty() ? "ideal" : all ? "realistic" : "realistic (" + kept + ")";
  }
  result.length_m = cfg.length_m;
  if (cfg.held_out_drives < 0 || cfg.held_out_drives > cfg.drives) {
    throw ValidationError("study: --held-out must be between 0 and --drives (" +
                          std::to_string(cfg.drives) + "), got " +
                          std::to_string(cfg.held_out_drives));
  }
  const int first_held_out = cfg.held_out_drives > 0 ? cfg.drives - cfg.held_out_drives : 0;
  result.drives = cfg.drives;
  result.seeds = cfg.seeds;
  result.http = cfg.http;

  // Progress in work units: simulate+process 1 per drive, build 0.2 and localize 1 per
  // left-out drive.
  const double per_set = cfg.drives + 1.2 * (cfg.drives - first_held_out);
  const double total_units = per_set * static_cast<double>(cfg.seeds.size() * cfg.levels.size());
  double done_units = 0.0;
  auto report = [&](const char* stage, std::uint64_t seed, PolLevel level, int drive, double frac,
                    double weight) {
    if (!progress) return;
    StudyProgress p;
    p.stage = stage;
    p.seed = seed;
    p.level = level;
    p.drive = drive;
    p.fraction = std::clamp((done_units + weight * frac) / total_units, 0.0, 1.0);
    progress(p);
  };

  for (const std::uint64_t seed : cfg.seeds) {
    sim::SimConfig sim_cfg = cfg.sim;
    sim_cfg.seed = seed;
    std::shared_ptr<const sim::World> world =
        sim::load_world(cfg.world, cfg.length_m, seed, sim_cfg);
    // Consumer-grade studies: the first rtk_drives drives are survey-grade.
    auto drive_sim_cfg = [&](int k) {
      sim::SimConfig c = sim_cfg;
      if (k < cfg.rtk_drives) c.gnss.grade = sim::GnssGrade::Rtk;
      return c;
    };
    const bool consumer = sim_cfg.gnss.grade == sim::GnssGrade::Consumer;
    const std::vector<Eigen::Vector2d> truth_points = truth_point_objects(*world);
    for (const PolLevel level : cfg.levels) {
      const auto dir = cfg.out_dir / ("seed_" + std::to_string(seed)) / level_dir_name(level);
      std::filesystem::remove_all(dir, ec);
      std::filesystem::create_directories(dir / "packages", ec);
      if (ec) throw IoError("study: cannot create " + dir.string() + ": " + ec.message());
      mapping::SqliteMapStore store(dir / "map.sqlite");

      // 1-2. simulate + process + package + ingest every drive.
      std::vector<StudyPackage> processed;
      for (int k = 0; k < cfg.drives; ++k) {
        const auto pkg_dir = dir / "packages" / ("drive_" + std::to_string(k));
        StudyPackage sp = simulate_and_package(
            world, drive_sim_cfg(k), k, level, cfg, pkg_dir,
            [&](double f) { report("simulate+process", seed, level, k, f, 1.0); });
        const mapping::DrivePackage pkg = mapping::read_and_validate_package(pkg_dir);
        store.put_drive(pkg, pkg_dir, pkg.content_sha256);
        if (!cfg.keep_packages) std::filesystem::remove_all(pkg_dir, ec);
        processed.push_back(std::move(sp));
        done_units += 1.0;
      }

      std::unique_ptr<LoopbackServer> server;
      if (cfg.http) server = std::make_unique<LoopbackServer>(store);

      // 3-4. leave one out: build without drive k, localize drive k.
      for (int k = first_held_out; k < cfg.drives; ++k) {
        const std::string drive_id = processed[k].drive_id;
        report("build", seed, level, k, 0.0, 0.2);
        mapping::MapBuildRequest req;
        req.excluded_drive_ids = {drive_id};
        req.make_current = false;
        req.build_gridmap = false;  // localization needs landmarks only
        req.notes = "leave-one-out: without " + drive_id;
        const auto tb = Clock::now();
        const mapping::MapBuildResult br = mapping::MapBuilder{}.build(store, req);
        const double build_s = seconds_since(tb);
        if (br.status != mapping::MapBuildResult::Status::Published) {
          throw Error("study: map build without " + drive_id + " failed: " + br.error);
        }
        done_units += 0.2;

        std::unique_ptr<StoreTileSource> store_tiles;
        std::unique_ptr<loc::TileFetcher> fetcher;
        loc::TileSource* source = nullptr;
        if (server) {
          loc::TileFetcherConfig fc;
          fc.server_url = server->url();
          fc.cache_dir = dir / "tile-cache" / drive_id;
          std::filesystem::remove_all(fc.cache_dir, ec);
          fc.query = "version=" + std::to_string(br.version);
          fetcher = std::make_unique<loc::TileFetcher>(fc);
          source = fetcher.get();
        } else {
          store_tiles = std::make_unique<StoreTileSource>(store, br.version);
          source = store_tiles.get();
        }
        LocalizeOptions lo;
        lo.fetcher = fetcher.get();
        if (cfg.write_trajectories) {
          lo.csv_path = dir / ("loc_" + drive_id + ".csv");
          lo.errors_csv_path = dir / ("errors_" + drive_id + ".csv");
        }
        lo.progress = [&](double f) { report("localize", seed, level, k, f, 1.0); };
        std::vector<Eigen::Vector2d> map_points;
        for (const auto& p : store.landmarks_in(br.version, std::nullopt, false).points) {
          map_points.push_back(world->frame.to_local(p.position));
        }
        const MapGeometry geo = map_geometry(map_points, truth_points);
        // A consumer-grade map with a survey-grade drive in it is anchored: its errors are
        // measured against truth; without one, in its own frame (StudyConfig::rtk_drives).
        const int anchors = cfg.rtk_drives - (k < cfg.rtk_drives ? 1 : 0);
        if (consumer && geo.status == MapGeometry::Status::Ok) {
          if (anchors <= 0) lo.truth_to_map = std::make_pair(geo.R_truth_map, geo.t_truth_map_m);
          const MapGeometryConfig gc;
          lo.truth_to_local_map = [&geo, gc](const Eigen::Vector2d& p)
              -> std::optional<std::pair<Eigen::Matrix2d, Eigen::Vector2d>> {
            const auto f =
                local_rigid_fit(geo.window_pairs, p, gc.window_m, gc.min_window_landmarks);
            if (!f) return std::nullopt;
            return std::make_pair(f->R_truth_map, f->t_truth_map_m);
          };
        }
        StudyDriveResult r =
            localize_simulated_drive(world, drive_sim_cfg(k), k, level, cfg, *source, lo);
        r.map_offset_m = geo.offset_m;
        r.map_rigid_rms_m = geo.global_rms_m;
        r.map_window_rms_m = geo.window_rms_m;
        r.map_window_share = geo.window_matched_share;
        r.map_worst_window_share = geo.worst_window_share;
        r.map_max_window_shift_m = geo.max_window_shift_m;
        r.errors_in_map_frame = lo.truth_to_map.has_value();
        r.seed = seed;
        r.point_candidates = processed[k].point_candidates;
        r.line_candidates = processed[k].line_candidates;
        r.simulate_process_s = processed[k].seconds;
        r.map_version = br.version;
        r.map_point_landmarks = br.stats.point_landmarks;
        r.map_line_landmarks = br.stats.line_landmarks;
        r.map_build_s = build_s;
        if (cfg.diagnose) {
          report("diagnose", seed, level, k, 0.0, 0.0);
          r.diagnosis =
              diagnose_drive(world, drive_sim_cfg(k), k, level, cfg, store, br.version, {},
                             cfg.write_trajectories ? dir / ("diag_" + drive_id + ".csv")
                                                    : std::filesystem::path{});
        }
        r.tile_bytes =
            fetcher ? fetcher->stats().bytes_downloaded : store_tiles->stats().bytes_read;
        r.tile_bytes_per_km =
            r.distance_m > 0 ? static_cast<double>(r.tile_bytes) / (r.distance_m / 1000.0) : 0.0;
        done_units += 1.0;
        result.results.push_back(std::move(r));
      }
    }
  }

  for (const PolLevel level : cfg.levels) {
    StudyLevelSummary s;
    s.level = level;
    std::vector<const StudyDriveResult*> ds;
    double gnss_w = 0, loc_s = 0, graph_sum = 0, bytes = 0, km = 0;
    std::int64_t graph_n = 0;
    for (const auto& r : result.results) {
      if (r.level != level) continue;
      ds.push_back(&r);
      ++s.drives;
      s.converged += r.converged ? 1 : 0;
      s.diverged += r.diverged ? 1 : 0;
      s.duration_s += r.duration_s;
      gnss_w += r.reliable_gnss_share * r.duration_s;
      loc_s += r.localizer_cpu_s;
      graph_sum += r.graph_update_mean_ms * static_cast<double>(r.graph_updates);
      graph_n += r.graph_updates;
      bytes += static_cast<double>(r.tile_bytes);
      km += r.distance_m / 1000.0;
    }
    s.errors = summarize_errors(ds);
    std::vector<ErrorSummary> local;
    for (const auto* d : ds) local.push_back(d->errors_local_frame);
    s.errors_local_frame = pool_error_summaries(local);
    s.reliable_gnss_share = s.duration_s > 0 ? gnss_w / s.duration_s : 0.0;
    s.realtime_factor = loc_s > 0 ? s.duration_s / loc_s : 0.0;
    s.graph_update_mean_ms = graph_n > 0 ? graph_sum / static_cast<double>(graph_n) : 0.0;
    s.tile_bytes_per_km = km > 0 ? bytes / km : 0.0;
    result.levels.push_back(s);
  }
  if (progress) {
    StudyProgress p;
    p.stage = "figures";
    p.fraction = 1.0;
    progress(p);
  }
  result.figures = write_ccdf_figures(result, cfg.out_dir);
  result.wall_s = seconds_since(t_start);
  return result;
}

// ------------------------------------------------------------------ output

std::string format_accuracy_table(const StudyResult& r, PolLevel level) {
  std::ostringstream o;
  o << "Localization accuracy, level " << to_string(level) << " (leave-one-out; world " << r.world
    << ", " << fmt("%.0f", r.length_m) << " m, " << r.drives << " drives per seed)\n";
  char buf[320];
  std::snprintf(buf, sizeof buf, "%-6s %-6s %6s %7s | %-17s | %-17s | %-17s | %6s %-4s\n", "seed",
                "drive", "reli.", "dur", "longitudinal", "lateral", "rotational", "conv", "div");
  o << buf;
  std::snprintf(buf, sizeof buf, "%-6s %-6s %6s %7s | %8s %8s | %8s %8s | %8s %8s | %6s %-4s\n", "",
                "", "GNSS", "[s]", "RMSE[m]", "max[m]", "RMSE[m]", "max[m]", "RMSE[°]", "max[°]",
                "[s]", "");
  o << buf;
  auto row = [&](const std::string& seed, const std::string& drive, double gnss, double dur,
                 const ErrorSummary& e, const std::string& conv, const std::string& div) {
    if (e.samples == 0) {
      std::snprintf(buf, sizeof buf, "%-6s %-6s %5.0f%% %7.1f | %-17s | %-17s | %-17s | %6s %-4s\n",
                    seed.c_str(), drive.c_str(), 100 * gnss, dur, "no samples", "", "",
                    conv.c_str(), div.c_str());
    } else {
      std::snprintf(
          buf, sizeof buf,
          "%-6s %-6s %5.0f%% %7.1f | %8.3f %8.3f | %8.3f %8.3f | %8.2f %8.2f | %6s %-4s\n",
          seed.c_str(), drive.c_str(), 100 * gnss, dur, e.long_rmse_m, e.long_max_m, e.lat_rmse_m,
          e.lat_max_m, e.rot_rmse_deg, e.rot_max_deg, conv.c_str(), div.c_str());
    }
    o << buf;
  };
  for (const auto& d : r.results) {
    if (d.level != level) continue;
    row(std::to_string(d.seed), "#" + std::to_string(d.drive + 1), d.reliable_gnss_share,
        d.duration_s, d.errors, d.converged ? fmt("%.1f", d.converge_time_s) : "never",
        d.diverged ? "YES" : "no");
  }
  for (const auto& s : r.levels) {
    if (s.level != level) continue;
    row("total", "", s.reliable_gnss_share, s.duration_s, s.errors,
        std::to_string(s.converged) + "/" + std::to_string(s.drives), std::to_string(s.diverged));
  }
  return o.str();
}

std::string format_level_table(const StudyResult& r) {
  std::ostringstream o;
  o << "Polarimetric levels (pooled over all left-out drives and seeds)\n";
  char buf[320];
  std::snprintf(buf, sizeof buf, "%-6s %7s | %8s %8s | %8s %8s | %8s %8s | %6s %5s\n", "level",
                "samples", "long RMS", "max[m]", "lat RMS", "max[m]", "rot RMS", "max[°]", "conv",
                "div");
  o << buf;
  for (const auto& s : r.levels) {
    std::snprintf(
        buf, sizeof buf, "%-6s %7lld | %8.3f %8.3f | %8.3f %8.3f | %8.2f %8.2f | %3d/%-2d %5d\n",
        std::string(to_string(s.level)).c_str(), static_cast<long long>(s.errors.samples),
        s.errors.long_rmse_m, s.errors.long_max_m, s.errors.lat_rmse_m, s.errors.lat_max_m,
        s.errors.rot_rmse_deg, s.errors.rot_max_deg, s.converged, s.drives, s.diverged);
    o << buf;
  }
  return o.str();
}

std::string format_uncertainty_table(const StudyResult& r) {
  std::ostringstream o;
  o << "Uncertainty (pooled): NEES of (long, lat, yaw) under the reported covariance (3 and "
       "95 % within chi2_3(0.95) when consistent), lateral protection level bounding the "
       "lateral error (target >= 99.9 %)\n";
  char buf[320];
  std::snprintf(buf, sizeof buf, "%-6s %8s | %9s %10s | %8s %10s %8s\n", "level", "samples",
                "mean NEES", "<= q95", "PL n", "bounded", "mean PL");
  o << buf;
  for (const auto& s : r.levels) {
    const ErrorSummary& e = s.errors;
    std::snprintf(buf, sizeof buf, "%-6s %8lld | %9.2f %9.1f%% | %8lld %9.2f%% %7.3fm\n",
                  std::string(to_string(s.level)).c_str(), static_cast<long long>(e.nees_samples),
                  e.nees_mean, 100 * e.nees_within_q95_share, static_cast<long long>(e.pl_samples),
                  100 * e.pl_bounded_share, e.pl_mean_m);
    o << buf;
  }
  return o.str();
}

std::string format_map_geometry_table(const StudyResult& r) {
  std::ostringstream o;
  o << "Map geometry of each leave-one-out map against truth (point landmarks; offset = mean "
       "truth - map, rms after one rigid fit and after a rigid fit per 200 m window; matched = "
       "share of the real landmarks (within 1 m of an object) that their window's own fit "
       "puts within 0.3 m, pooled and worst window; bend = largest shift of a window's own fit "
       "against the whole map's)\n";
  char buf[256];
  std::snprintf(buf, sizeof buf, "%-6s %-5s %-5s %9s %10s %10s %8s %8s %8s %-11s %s\n", "level",
                "seed", "drive", "offset m", "rigid rms", "200m rms", "matched", "worst", "bend m",
                "errors in", "local frame long / lat m, rot deg");
  o << buf;
  auto local = [](const ErrorSummary& e) {
    return e.samples > 0 ? fmt("%.3f / ", e.long_rmse_m) + fmt("%.3f / ", e.lat_rmse_m) +
                               fmt("%.2f", e.rot_rmse_deg)
                         : std::string("-");
  };
  for (const auto& d : r.results) {
    std::snprintf(
        buf, sizeof buf, "%-6s %-5llu #%-4d %9.3f %10.3f %10.3f %8.2f %8.2f %8.2f %-11s %s\n",
        std::string(to_string(d.level)).c_str(), static_cast<unsigned long long>(d.seed),
        d.drive + 1, d.map_offset_m, d.map_rigid_rms_m, d.map_window_rms_m, d.map_window_share,
        d.map_worst_window_share, d.map_max_window_shift_m,
        d.errors_in_map_frame ? "map frame" : "world frame", local(d.errors_local_frame).c_str());
    o << buf;
  }
  for (const auto& s : r.levels) {
    if (s.errors_local_frame.samples == 0) continue;
    o << "pooled, " << to_string(s.level) << ": " << local(s.errors)
      << " in the frames of 'errors in', " << local(s.errors_local_frame)
      << " in the local frame (rigid fit of the map within the 200 m around the car)\n";
  }
  return o.str();
}

std::string format_speed_table(const StudyResult& r) {
  std::ostringstream o;
  o << "Client speed (x real = drive time / localizer thread CPU time; wall in brackets, "
       "depends on machine load) and data (tiles: encoded bytes "
    << (r.http ? "downloaded over HTTP" : "read from the store") << ")\n";
  char buf[360];
  std::snprintf(buf, sizeof buf, "%-6s %-5s %-5s %14s %9s %8s %8s %8s %9s %9s %8s %10s %8s\n",
                "level", "seed", "drive", "x real (wall)", "frame ms", "p99 ms", "extr ms",
                "match ms", "graph ms", "graph p95", "matches", "tile B/km", "map pts");
  o << buf;
  for (const auto& d : r.results) {
    std::snprintf(
        buf, sizeof buf,
        "%-6s %-5llu #%-4d %6.1f (%5.1f) %9.2f %8.2f %8.2f %8.2f %9.2f %9.2f %8.1f %10.0f "
        "%8lld\n",
        std::string(to_string(d.level)).c_str(), static_cast<unsigned long long>(d.seed),
        d.drive + 1, d.realtime_factor, d.realtime_factor_wall, d.frame_mean_ms, d.frame_p99_ms,
        d.extraction_mean_ms, d.matching_mean_ms, d.graph_update_mean_ms, d.graph_update_p95_ms,
        d.mean_matched_points, d.tile_bytes_per_km, static_cast<long long>(d.map_point_landmarks));
    o << buf;
  }
  return o.str();
}

std::string format_calibration_table(const StudyResult& r) {
  bool any = false;
  for (const auto& d : r.results) any = any || d.calibration.has_value();
  if (!any) return {};
  std::ostringstream o;
  o << "Online mount calibration at the end of each drive against the simulator's true mounts "
       "(common yaw: estimated +- 1 sigma, true; relative yaws and time offsets: largest error "
       "over the sensors)\n";
  char buf[320];
  std::snprintf(buf, sizeof buf, "%-6s %-5s %-5s | %22s %9s %8s | %12s %11s | %s\n", "level",
                "seed", "drive", "common yaw est. [deg]", "true", "applied", "rel. yaw err",
                "rel. dt err", "converged after");
  o << buf;
  for (const auto& d : r.results) {
    if (!d.calibration) continue;
    const auto& c = *d.calibration;
    char conv[32];
    if (c.converged_after_s >= 0.0) {
      std::snprintf(conv, sizeof conv, "%.1f s", c.converged_after_s);
    } else {
      std::snprintf(conv, sizeof conv, "not converged");
    }
    std::snprintf(buf, sizeof buf,
                  "%-6s %-5llu #%-4d | %+9.3f +- %-9.3f %+9.3f %8s | %9.3f deg %8.2f ms | %s\n",
                  std::string(to_string(d.level)).c_str(), static_cast<unsigned long long>(d.seed),
                  d.drive + 1, c.common_yaw_deg, c.common_yaw_sigma_deg, c.common_yaw_true_deg,
                  c.common_yaw_applied ? "yes" : "no", c.relative_yaw_max_error_deg,
                  c.relative_time_max_error_ms, conv);
    o << buf;
  }
  return o.str();
}

std::string format_diagnosis_table(const StudyResult& r) {
  std::ostringstream o;
  bool any = false;
  for (const auto& d : r.results) any = any || d.diagnosis.has_value();
  if (!any) return {};
  o << "Stage diagnosis (odometry over 8 s windows vs truth; truth-posed sliding-window candidates "
       "vs the left-out map, pairs within 0.3 m; offsets candidate - landmark in the vehicle "
       "frame)\n";
  char buf[400];
  std::snprintf(buf, sizeof buf, "%-6s %-4s %-5s | %-24s | %-47s | %-16s | %s\n", "level", "seed",
                "drive", "odometry 8 s: pos lat yaw",
                "point candidates: n  match  pairs  <3  off.lo off.la rms", "lines: n match rms",
                "loc lat RMSE");
  o << buf;
  for (const auto& d : r.results) {
    if (!d.diagnosis) continue;
    const auto& g = *d.diagnosis;
    std::snprintf(buf, sizeof buf,
                  "%-6s %-4llu #%-4d | %6.3f m %6.3f m %5.2f° | %5.1f %5.0f%% %5.1f %4.0f%% %+6.3f "
                  "%+6.3f %5.3f | %4.1f %4.0f%% %5.3f | %.3f m\n",
                  std::string(to_string(d.level)).c_str(), static_cast<unsigned long long>(d.seed),
                  d.drive + 1, g.odo_window_pos_rms_m, g.odo_window_lat_rms_m,
                  g.odo_window_yaw_rms_deg, g.candidates_per_extraction, 100 * g.matched_share,
                  g.pairs_per_extraction, 100 * g.sparse_extraction_share, g.offset_long_mean_m,
                  g.offset_lat_mean_m, g.offset_rms_m, g.line_candidates_per_extraction,
                  100 * g.line_matched_share, g.line_offset_rms_m, d.errors.lat_rmse_m);
    o << buf;
  }
  return o.str();
}

std::vector<std::filesystem::path> write_ccdf_figures(const StudyResult& r,
                                                      const std::filesystem::path& dir) {
  struct Fig {
    const char* file;
    const char* title;
    const char* xlabel;
    int which;
  };
  const Fig figs[] = {{"ccdf_lat.svg", "CCDF of the lateral error", "|ε_lat| [m]", 0},
                      {"ccdf_long.svg", "CCDF of the longitudinal error", "|ε_long| [m]", 1},
                      {"ccdf_rot.svg", "CCDF of the rotational error", "ε_rot [°]", 2}};
  std::vector<std::filesystem::path> out;
  for (const auto& f : figs) {
    SvgPlot p;
    p.title = std::string(f.title) + " (" + r.world + ", leave-one-out)";
    p.x_label = f.xlabel;
    p.y_label = "P(error > x)";
    p.log_y = true;
    for (const auto& s : r.levels) {
      // Diverged drives are left out (and counted in the label): the tables
      // report them, and their metre-scale errors would set the x range and
      // flatten every other curve against the axis.
      std::vector<double> v;
      int diverged = 0, drives = 0;
      for (const auto& d : r.results) {
        if (d.level != s.level) continue;
        ++drives;
        if (d.diverged) {
          ++diverged;
          continue;
        }
        const auto& src = f.which == 0 ? d.abs_lat_m : f.which == 1 ? d.abs_long_m : d.rot_deg;
        v.insert(v.end(), src.begin(), src.end());
      }
      std::string label(to_string(s.level));
      if (diverged > 0) {
        label += " (" + std::to_string(diverged) + " of " + std::to_string(drives) +
                 " drives diverged, not shown)";
      }
      p.series.push_back(ccdf_series(label, v));
    }
    const auto path = dir / f.file;
    write_svg(render_svg(p), path);
    out.push_back(path);
  }
  return out;
}

nlohmann::json to_json(const ErrorSummary& s) {
  return {{"samples", s.samples},         {"long_rmse_m", s.long_rmse_m},
          {"long_max_m", s.long_max_m},   {"lat_rmse_m", s.lat_rmse_m},
          {"lat_max_m", s.lat_max_m},     {"rot_rmse_deg", s.rot_rmse_deg},
          {"rot_max_deg", s.rot_max_deg}, {"nees_samples", s.nees_samples},
          {"nees_mean", s.nees_mean},     {"nees_within_q95_share", s.nees_within_q95_share},
          {"pl_samples", s.pl_samples},   {"pl_bounded_share", s.pl_bounded_share},
          {"pl_mean_m", s.pl_mean_m}};
}

nlohmann::json to_json(const StudyResult& r) {
  nlohmann::json j;
  j["world"] = r.world;
  j["realism"] = r.realism;
  j["length_m"] = r.length_m;
  j["drives"] = r.drives;
  j["seeds"] = r.seeds;
  j["http"] = r.http;
  j["wall_s"] = r.wall_s;
  for (const auto& s : r.levels) {
    j["levels"].push_back(
        {{"level", to_string(s.level)},
         {"errors", to_json(s.errors)},
         {"errors_local_frame",
          s.errors_local_frame.samples > 0 ? to_json(s.errors_local_frame) : nlohmann::json()},
         {"drives", s.drives},
         {"converged", s.converged},
         {"diverged", s.diverged},
         {"duration_s", s.duration_s},
         {"reliable_gnss_share", s.reliable_gnss_share},
         {"realtime_factor", s.realtime_factor},
         {"graph_update_mean_ms", s.graph_update_mean_ms},
         {"tile_bytes_per_km", s.tile_bytes_per_km}});
  }
  for (const auto& d : r.results) {
    j["results"].push_back(
        {{"seed", d.seed},
         {"level", to_string(d.level)},
         {"drive", d.drive},
         {"drive_id", d.drive_id},
         {"duration_s", d.duration_s},
         {"distance_m", d.distance_m},
         {"reliable_gnss_share", d.reliable_gnss_share},
         {"point_candidates", d.point_candidates},
         {"line_candidates", d.line_candidates},
         {"map_version", d.map_version},
         {"map_point_landmarks", d.map_point_landmarks},
         {"map_line_landmarks", d.map_line_landmarks},
         {"map_build_s", d.map_build_s},
         {"map_geometry",
          {{"offset_m", d.map_offset_m},
           {"rigid_fit_rms_m", d.map_rigid_rms_m},
           {"window_200m_rms_m", d.map_window_rms_m},
           {"window_200m_matched_share", d.map_window_share},
           {"worst_window_matched_share", d.map_worst_window_share},
           {"max_window_shift_m", d.map_max_window_shift_m},
           {"errors_in_map_frame", d.errors_in_map_frame}}},
         {"errors", to_json(d.errors)},
         {"errors_local_frame",
          d.errors_local_frame.samples > 0 ? to_json(d.errors_local_frame) : nlohmann::json()},
         {"converged", d.converged},
         {"converge_time_s", d.converge_time_s},
         {"diverged", d.diverged},
         {"lost_events", d.lost_events},
         {"tracking_share", d.tracking_share},
         {"degraded_share", d.degraded_share},
         {"lost_share", d.lost_share},
         {"mean_matched_points", d.mean_matched_points},
         {"frames", d.frames},
         {"localizer_cpu_s", d.localizer_cpu_s},
         {"localizer_wall_s", d.localizer_wall_s},
         {"realtime_factor", d.realtime_factor},
         {"realtime_factor_wall", d.realtime_factor_wall},
         {"extraction_mean_ms", d.extraction_mean_ms},
         {"matching_mean_ms", d.matching_mean_ms},
         {"frame_mean_ms", d.frame_mean_ms},
         {"frame_p95_ms", d.frame_p95_ms},
         {"frame_p99_ms", d.frame_p99_ms},
         {"stage_ms_per_s",
          d.duration_s > 0 ? stage_budget_json(d.stage_cpu, d.duration_s, d.helper_threads_cpu_s)
                           : nlohmann::json()},
         {"frame_max_ms", d.frame_max_ms},
         {"graph_updates", d.graph_updates},
         {"graph_update_mean_ms", d.graph_update_mean_ms},
         {"graph_update_p95_ms", d.graph_update_p95_ms},
         {"graph_update_max_ms", d.graph_update_max_ms},
         {"tile_bytes", d.tile_bytes},
         {"tile_bytes_per_km", d.tile_bytes_per_km},
         {"simulate_process_s", d.simulate_process_s},
         {"calibration",
          d.calibration
              ? nlohmann::json{{"common_yaw_deg", d.calibration->common_yaw_deg},
                               {"common_yaw_sigma_deg", d.calibration->common_yaw_sigma_deg},
                               {"common_yaw_true_deg", d.calibration->common_yaw_true_deg},
                               {"common_yaw_applied", d.calibration->common_yaw_applied},
                               {"relative_yaw_max_error_deg",
                                d.calibration->relative_yaw_max_error_deg},
                               {"relative_time_max_error_ms",
                                d.calibration->relative_time_max_error_ms},
                               {"converged_after_s", d.calibration->converged_after_s}}
              : nlohmann::json()},
         {"diagnosis", d.diagnosis ? to_json(*d.diagnosis) : nlohmann::json()}});
  }
  for (const auto& f : r.figures) j["figures"].push_back(f.string());
  return j;
}

}  // namespace polmap::eval
