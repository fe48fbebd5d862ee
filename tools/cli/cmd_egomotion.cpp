// `polmap egomotion --recording R | --detections CSV --mounts JSON [--truth CSV]
//  [--calibrate on|off] [--json] [--out CSV]`: runs the radar ego-motion estimator and
// odometry over a drive and reports velocity / yaw-rate errors and odometry drift against
// truth, and the online mount calibration (relative mount yaws and time offsets with 1-σ;
// against the simulator's DIR/truth/<name>_calibration.json when present — evaluation only).
#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <numbers>
#include <optional>
#include <string>

#include "command.hpp"
#include "polmap/eval/detections_csv.hpp"
#include "polmap/eval/egomotion_eval.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/schema/recording_io.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "progress.hpp"

namespace polmap::cli {
namespace {

struct EgoMotionOptions {
  std::string recording;
  std::string detections;
  std::string mounts;
  std::string truth;
  std::string out;
  bool json = false;
  std::string calibrate = "on";
  radar::EgoMotionConfig cfg;
  double slip_gradient_deg = -1.0;
  radar::MountCalibrationConfig calib;
};

/// The simulator's true calibration DIR/truth/<name>_calibration.json (evaluation only):
/// per sensor id the true yaw offset and time offset, each relative to the mean over the
/// sensors (what the calibration can observe).
struct CalibrationTruth {
  std::string source;
  std::map<int, std::pair<double, double>> relative;  // sensor_id -> (yaw rad, time s)
  double mean_yaw_rad = 0.0;                          // added back for absolute yaws
};
std::optional<CalibrationTruth> sibling_calibration_truth(const std::filesystem::path& recording) {
  const auto p =
      recording.parent_path() / "truth" / (recording.stem().string() + "_calibration.json");
  if (!std::filesystem::exists(p)) return std::nullopt;
  std::ifstream in(p);
  const nlohmann::json j = nlohmann::json::parse(in);
  CalibrationTruth t;
  t.source = p.string();
  double my = 0, mt = 0;
  const auto& sensors = j.at("sensors");
  for (const auto& s : sensors) {
    my += s.at("yaw_offset_rad").get<double>() / static_cast<double>(sensors.size());
    mt += s.at("time_offset_s").get<double>() / static_cast<double>(sensors.size());
  }
  t.mean_yaw_rad = my;
  for (const auto& s : sensors) {
    t.relative[s.at("sensor_id").get<int>()] = {s.at("yaw_offset_rad").get<double>() - my,
                                                s.at("time_offset_s").get<double>() - mt};
  }
  return t;
}

/// The simulator writes exact truth beside a recording DIR/drive_<k>.pmrec as
/// DIR/truth/drive_<k>_trajectory.csv; prefer it over the (noisy) GNSS samples.
std::optional<std::filesystem::path> sibling_truth(const std::filesystem::path& recording) {
  const auto p =
      recording.parent_path() / "truth" / (recording.stem().string() + "_trajectory.csv");
  if (std::filesystem::exists(p)) return p;
  return std::nullopt;
}

void run(const EgoMotionOptions& o) {
  std::optional<eval::EgoMotionRunner> runner;
  eval::MotionTruth truth;
  std::string truth_source = "none";
  std::optional<GeoPoint> origin;
  std::vector<TrajectorySample> trajectory;

  if (!o.recording.empty()) {
    RecordingReader reader(o.recording);
    if (reader.header().sensors.empty()) {
      throw ValidationError(o.recording + ": recording header lists no sensors");
    }
    origin = reader.header().origin;
    // A vehicle parameter: the recording's declared value unless --slip-gradient-deg is given.
    radar::EgoMotionConfig cfg = o.cfg;
    radar::MountCalibrationConfig calib = o.calib;
    if (o.slip_gradient_deg < 0.0) {
      cfg.side_slip_gradient_rad_per_mps2 =
          reader.header().side_slip_gradient_rad_per_mps2.value_or(0.0);
      calib.side_slip_gradient_rad_per_mps2 = cfg.side_slip_gradient_rad_per_mps2;
    }
    runner.emplace(reader.header().sensors, cfg, radar::OdometryConfig{}, calib);
    Progress progress("egomotion " + o.recording, static_cast<double>(reader.file_size()));
    while (auto rec = reader.next()) {
      progress.update(static_cast<double>(reader.offset()));
      if (const auto* f = std::get_if<SensorFrame>(&*rec)) {
        runner->process(*f);
      } else if (const auto* t = std::get_if<TrajectorySample>(&*rec)) {
        trajectory.push_back(*t);
      }
    }
  } else {
    const auto mounts = eval::read_sensor_mounts_json(o.mounts);
    runner.emplace(mounts, o.cfg, radar::OdometryConfig{}, o.calib);
    eval::DetectionsCsvReader reader{std::filesystem::path(o.detections)};
    Progress progress("egomotion " + o.detections, 0);
    double n = 0;
    while (auto f = reader.next()) {
      bool known = false;
      for (const auto& m : mounts) known = known || m.sensor_id == f->sensor_id;
      if (!known) {
        throw ValidationError(o.detections + ": sensor_id " + std::to_string(f->sensor_id) +
                              " (frame at " + std::to_string(f->time_s) + " s) is not in " +
                              o.mounts);
      }
      runner->process(*f);
      progress.update(++n);
    }
  }

  if (!o.truth.empty()) {
    truth = eval::read_truth_csv(o.truth, origin);
    truth_source = o.truth;
  } else if (!o.recording.empty()) {
    if (const auto p = sibling_truth(o.recording)) {
      truth = eval::read_truth_csv(*p, origin);
      truth_source = p->string();
    } else if (!trajectory.empty()) {
      truth = eval::truth_from_trajectory(trajectory, tiles::LocalFrame(*origin));
      truth_source = "recording trajectory (GNSS/IMU samples)";
    }
  }

  const eval::EgoMotionMetrics m = eval::evaluate_egomotion(runner->records(), truth);
  if (!o.out.empty()) eval::write_egomotion_csv(o.out, runner->records(), truth);

  const bool have_truth = !truth.empty() && m.compared > 0;
  const std::optional<CalibrationTruth> calib_truth =
      o.recording.empty() ? std::nullopt : sibling_calibration_truth(o.recording);
  constexpr double kDeg = 180.0 / std::numbers::pi;
  const radar::MountCalibrationResult cal = runner->calibrator()->result();
  const double t_first =
      runner->records().empty() ? 0.0 : runner->records().front().estimate.time_s;
  nlohmann::json jc{
      {"applied", o.calib.calibrate_mounts},
      {"status", radar::to_string(cal.status)},
      {"observed_s", cal.observed_s},
      {"blocks", cal.blocks},
      {"residual_sigma_factor", cal.residual_sigma_factor},
      {"converged_after_s", runner->converged_at_s()
                                ? nlohmann::json(*runner->converged_at_s() - t_first)
                                : nlohmann::json(nullptr)},
      {"gauge", o.calib.side_slip_nuisance && !o.calib.estimate_common_yaw
                    ? "relative: mean yaw offset and mean time offset over the "
                      "sensors are 0"
                    : "mean time offset over the sensors is 0 (yaws absolute)"},
      {"common_yaw_deg", cal.common_yaw_rad * kDeg},
      {"common_yaw_sigma_deg", cal.common_yaw_sigma_rad * kDeg},
      {"common_yaw_applied", o.calib.calibrate_mounts && o.calib.estimate_common_yaw},
      {"true_common_yaw_deg",
       calib_truth ? nlohmann::json(calib_truth->mean_yaw_rad * kDeg) : nlohmann::json(nullptr)},
      {"truth", calib_truth ? nlohmann::json(calib_truth->source) : nullptr}};
  nlohmann::json js = nlohmann::json::array();
  double yaw_err2 = 0, dt_err2 = 0;
  for (const auto& s : cal.sensors) {
    nlohmann::json e{{"sensor_id", s.sensor_id},
                     {"yaw_offset_deg", s.yaw_offset_rad * kDeg},
                     {"yaw_sigma_deg", s.yaw_sigma_rad * kDeg},
                     {"yaw_status", radar::to_string(s.yaw_status)},
                     {"time_offset_ms", s.time_offset_s * 1e3},
                     {"time_sigma_ms", s.time_sigma_s * 1e3},
                     {"time_status", radar::to_string(s.time_status)},
                     {"detections", s.detections}};
    if (calib_truth && calib_truth->relative.contains(s.sensor_id)) {
      auto [ty, tt] = calib_truth->relative.at(s.sensor_id);
      if (o.calib.estimate_common_yaw) ty += calib_truth->mean_yaw_rad;
      e["true_yaw_offset_deg"] = ty * kDeg;
      e["true_time_offset_ms"] = tt * 1e3;
      e["yaw_error_deg"] = (s.yaw_offset_rad - ty) * kDeg;
      e["time_error_ms"] = (s.time_offset_s - tt) * 1e3;
      yaw_err2 = std::max(yaw_err2, std::abs(s.yaw_offset_rad - ty) * kDeg);
      dt_err2 = std::max(dt_err2, std::abs(s.time_offset_s - tt) * 1e3);
    }
    js.push_back(e);
  }
  jc["sensors"] = js;
  // Convergence: the largest |error| against the truth (or the largest σ) every 5 s.
  nlohmann::json jh = nlohmann::json::array();
  for (const auto& [t, c] : runner->calibration_history()) {
    double yaw_err = 0, dt_err = 0, yaw_sig = 0, dt_sig = 0;
    for (const auto& s : c.sensors) {
      yaw_sig = std::max(yaw_sig, s.yaw_sigma_rad * kDeg);
      dt_sig = std::max(dt_sig, s.time_sigma_s * 1e3);
      if (calib_truth && calib_truth->relative.contains(s.sensor_id)) {
        auto [ty, tt] = calib_truth->relative.at(s.sensor_id);
        if (o.calib.estimate_common_yaw) ty += calib_truth->mean_yaw_rad;
        yaw_err = std::max(yaw_err, std::abs(s.yaw_offset_rad - ty) * kDeg);
        dt_err = std::max(dt_err, std::abs(s.time_offset_s - tt) * 1e3);
      }
    }
    nlohmann::json h{{"time_s", t - t_first},
                     {"status", radar::to_string(c.status)},
                     {"max_yaw_sigma_deg", yaw_sig},
                     {"max_time_sigma_ms", dt_sig}};
    if (calib_truth) {
      h["max_abs_yaw_error_deg"] = yaw_err;
      h["max_abs_time_error_ms"] = dt_err;
    }
    jh.push_back(h);
  }
  jc["history"] = jh;
  if (calib_truth) {
    jc["max_abs_yaw_error_deg"] = yaw_err2;
    jc["max_abs_time_error_ms"] = dt_err2;
  }
  if (o.json) {
    nlohmann::json j = eval::to_json(m);
    if (!have_truth) {
      for (const char* k :
           {"v_rmse_mps", "v_max_err_mps", "v_median_err_mps", "v_bias_mps", "yaw_rate_rmse_dps",
            "yaw_rate_max_err_dps", "yaw_rate_median_err_dps", "yaw_rate_bias_dps", "distance_m"}) {
        j[k] = nullptr;
      }
    }
    j["input"] = o.recording.empty() ? o.detections : o.recording;
    j["truth"] = truth_source;
    j["calibration"] = jc;
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  std::printf("calibration: %s (%s), %.1f s observed, residual sigma factor %.2f%s\n",
              radar::to_string(cal.status), o.calib.calibrate_mounts ? "applied" : "not applied",
              cal.observed_s, cal.residual_sigma_factor,
              calib_truth ? ", truth relative to the sensor mean" : "");
  for (const auto& e : js) {
    std::printf("  sensor %d: yaw %+.3f +- %.3f deg (%s), time %+.2f +- %.2f ms (%s)",
                e["sensor_id"].get<int>(), e["yaw_offset_deg"].get<double>(),
                e["yaw_sigma_deg"].get<double>(), e["yaw_status"].get<std::string>().c_str(),
                e["time_offset_ms"].get<double>(), e["time_sigma_ms"].get<double>(),
                e["time_status"].get<std::string>().c_str());
    if (e.contains("true_yaw_offset_deg")) {
      std::printf("; truth %+.3f deg, %+.2f ms", e["true_yaw_offset_deg"].get<double>(),
                  e["true_time_offset_ms"].get<double>());
    }
    std::printf("\n");
  }
  std::printf("input:      %s\n", (o.recording.empty() ? o.detections : o.recording).c_str());
  std::printf("truth:      %s\n", truth_source.c_str());
  std::printf("frames:     %d (ok %d, rejected %d, too few detections %d)\n", m.frames,
              m.estimates_ok, m.estimates_rejected, m.estimates_too_few);
  std::printf("compute:    %.3f ms/frame mean, %.3f p95, %.3f max\n", m.compute_mean_ms,
              m.compute_p95_ms, m.compute_max_ms);
  std::printf("odometry:   %.1f m integrated\n", m.odometry_distance_m);
  if (!have_truth) {
    std::printf("no ground truth: errors not computed (give --truth CSV)\n");
    return;
  }
  std::printf(
      "velocity:   RMSE %.4f m/s, median |e| %.4f, max |e| %.4f, bias %+.4f (%d estimates)\n",
      m.v_rmse_mps, m.v_median_err_mps, m.v_max_err_mps, m.v_bias_mps, m.compared);
  std::printf("yaw rate:   RMSE %.4f deg/s, median |e| %.4f, max |e| %.4f, bias %+.4f\n",
              m.yaw_rate_rmse_dps, m.yaw_rate_median_err_dps, m.yaw_rate_max_err_dps,
              m.yaw_rate_bias_dps);
  if (m.drift_segment_pct) {
    std::printf(
        "drift:      %.3f %% (mean relative position error over %d sub-paths of 100 m), "
        "heading %.3f deg/100 m\n",
        *m.drift_segment_pct, m.drift_segments, *m.heading_drift_deg_per_100m);
  }
  if (m.drift_endpoint_pct) {
    std::printf("drift:      %.3f %% end point over %.1f m (true path)\n", *m.drift_endpoint_pct,
                m.distance_m);
  }
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<EgoMotionOptions>();
  auto* cmd = app.add_subcommand(
      "egomotion",
      "Radar ego-motion (v, yaw rate) and odometry over a drive, evaluated against ground truth");
  auto* rec = cmd->add_option("--recording", opts->recording, "recording (.pmrec)")
                  ->check(CLI::ExistingFile);
  auto* det = cmd->add_option("--detections", opts->detections,
                              "detections CSV of another radar (schema/detections_csv.md)")
                  ->check(CLI::ExistingFile);
  auto* mnt = cmd->add_option("--mounts", opts->mounts, "sensor mounts JSON (with --detections)")
                  ->check(CLI::ExistingFile);
  rec->excludes(det)->excludes(mnt);
  det->needs(mnt);
  mnt->needs(det);
  cmd->add_option("--truth", opts->truth,
                  "truth CSV: time_s,v_mps,yaw_rate_rps or the simulator's "
                  "time_s,lat_deg,lon_deg,yaw_enu_rad,v_mps,yaw_rate_rps (default for a "
                  "recording: DIR/truth/<name>_trajectory.csv if present, else its trajectory)")
      ->check(CLI::ExistingFile);
  cmd->add_flag("--json", opts->json, "print the metrics as one JSON object");
  cmd->add_option("--out", opts->out, "write per-estimate CSV");
  cmd->add_option("--max-speed-mps", opts->cfg.max_speed_mps,
                  "highest speed considered (Nyquist zones)")
      ->capture_default_str();
  cmd->add_option("--inlier-threshold-mps", opts->cfg.inlier_threshold_mps,
                  "RANSAC inlier threshold at sigma_vr")
      ->capture_default_str();
  cmd->add_option("--combine-window-s", opts->cfg.combine_window_s,
                  "combine frames of other sensors at most this much older (0 = per frame)")
      ->capture_default_str();
  cmd->add_option("--seed", opts->cfg.seed, "RANSAC seed")->capture_default_str();
  cmd->add_option("--slip-gradient-deg", opts->slip_gradient_deg,
                  "the vehicle's rear-axle side-slip gradient, deg per m/s^2 (default: the "
                  "recording header's, else 0 = kinematic model; the simulator's realistic "
                  "preset: 0.23)");
  cmd->add_option("--calibrate", opts->calibrate,
                  "online mount calibration (relative mount yaws, time offsets): on = estimate "
                  "and apply once converged, off = estimate and report only")
      ->check(CLI::IsMember({"on", "off"}))
      ->capture_default_str();
  cmd->add_flag("--calibrate-common-yaw", opts->calib.estimate_common_yaw,
                "also estimate the common mount yaw (assumes zero side slip when driving "
                "straight; see radar/include/polmap/radar/mount_calibration.hpp)");
  cmd->callback([opts] {
    if (opts->recording.empty() && opts->detections.empty()) {
      throw ValidationError("egomotion: give --recording R or --detections CSV --mounts JSON");
    }
    opts->calib.calibrate_mounts = opts->calibrate == "on";
    opts->cfg.side_slip_gradient_rad_per_mps2 =
        std::max(0.0, opts->slip_gradient_deg) * std::numbers::pi / 180.0;
    opts->calib.side_slip_gradient_rad_per_mps2 = opts->cfg.side_slip_gradient_rad_per_mps2;
    // The calibrator's noise model follows the estimator's.
    opts->calib.vr_sigma_mps = opts->cfg.vr_sigma_mps;
    opts->calib.azimuth_sigma_rad = opts->cfg.azimuth_sigma_rad;
    run(*opts);
  });
}

}  // namespace

POLMAP_REGISTER_COMMAND(egomotion, setup);

}  // namespace polmap::cli
