// `polmap egomotion --recording R | --detections CSV --mounts JSON [--truth CSV]
//  [--json] [--out CSV]`: runs the radar ego-motion estimator and odometry over a
// drive and reports velocity / yaw-rate errors and odometry drift against truth.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
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
  radar::EgoMotionConfig cfg;
};

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
    runner.emplace(reader.header().sensors, o.cfg);
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
    runner.emplace(mounts, o.cfg);
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
    std::printf("%s\n", j.dump(2).c_str());
    return;
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
  cmd->callback([opts] {
    if (opts->recording.empty() && opts->detections.empty()) {
      throw ValidationError("egomotion: give --recording R or --detections CSV --mounts JSON");
    }
    run(*opts);
  });
}

}  // namespace

POLMAP_REGISTER_COMMAND(egomotion, setup);

}  // namespace polmap::cli
