// `polmap doppler-residuals --recording R | --detections CSV --mounts JSON [--truth CSV]
//  [--json]`: Doppler residuals of a drive's detection lists against the static world at the
// reference motion (robust sigma of the static core, share with |residual| > 0.5 m/s), per
// sensor and in total: the statistics tools/sim/README.md "Realism" lists for real radars, to
// compare simulated presets with real recordings.
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
#include "polmap/sim/doppler_residuals.hpp"

namespace polmap::cli {
namespace {

struct ResidualOptions {
  std::string recording, detections, mounts, truth;
  bool json = false;
  double outlier_threshold_mps = 0.5;
  double min_speed_mps = 1.0;
};

nlohmann::json to_json(const sim::DopplerResidualStats& s) {
  return {{"frames", s.frames},
          {"detections", s.detections},
          {"detections_per_frame", s.detections_per_frame},
          {"median_mps", s.median_mps},
          {"robust_sigma_mps", s.robust_sigma_mps},
          {"outlier_share", s.outlier_share}};
}

void run(const ResidualOptions& o) {
  std::vector<SensorMount> mounts;
  std::vector<SensorFrame> frames;
  std::optional<GeoPoint> origin;
  std::filesystem::path truth_path = o.truth;
  if (!o.recording.empty()) {
    RecordingReader reader(o.recording);
    mounts = reader.header().sensors;
    origin = reader.header().origin;
    while (auto rec = reader.next()) {
      if (auto* f = std::get_if<SensorFrame>(&*rec)) {
        f->spectrum = {};  // only the detection lists are needed
        f->cube.reset();
        frames.push_back(std::move(*f));
      }
    }
    if (truth_path.empty()) {
      const std::filesystem::path rec(o.recording);
      truth_path = rec.parent_path() / "truth" / (rec.stem().string() + "_trajectory.csv");
    }
  } else {
    mounts = eval::read_sensor_mounts_json(o.mounts);
    frames = eval::read_detections_csv(o.detections);
  }
  if (truth_path.empty() || !std::filesystem::exists(truth_path)) {
    throw ValidationError("doppler-residuals: no truth CSV (give --truth)");
  }
  const eval::MotionTruth truth = eval::read_truth_csv(truth_path, origin);
  sim::DopplerResidualAccumulator acc(o.outlier_threshold_mps, o.min_speed_mps);
  for (const SensorFrame& f : frames) {
    const SensorMount* m = nullptr;
    for (const auto& c : mounts) m = c.sensor_id == f.sensor_id ? &c : m;
    if (m == nullptr) {
      throw ValidationError("doppler-residuals: sensor " + std::to_string(f.sensor_id) +
                            " has no mount");
    }
    const auto t = truth.at(f.time_s);
    if (!t) continue;
    acc.add(f, *m, t->v_mps, t->yaw_rate_rps);
  }
  const auto total = acc.total();
  if (o.json) {
    nlohmann::json j = to_json(total);
    nlohmann::json per = nlohmann::json::object();
    for (const auto& [id, s] : acc.per_sensor()) per[std::to_string(id)] = to_json(s);
    j["per_sensor"] = per;
    j["input"] = o.recording.empty() ? o.detections : o.recording;
    j["truth"] = truth_path.string();
    j["outlier_threshold_mps"] = o.outlier_threshold_mps;
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  std::printf("%-7s %8s %10s %8s %10s %10s\n", "sensor", "frames", "dets/fr", "median", "robust_sd",
              "outliers");
  auto line = [](const std::string& name, const sim::DopplerResidualStats& s) {
    std::printf("%-7s %8zu %10.1f %8.4f %10.4f %9.1f%%\n", name.c_str(), s.frames,
                s.detections_per_frame, s.median_mps, s.robust_sigma_mps, 100.0 * s.outlier_share);
  };
  for (const auto& [id, s] : acc.per_sensor()) line(std::to_string(id), s);
  line("all", total);
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<ResidualOptions>();
  auto* cmd = app.add_subcommand(
      "doppler-residuals",
      "Doppler residuals of detection lists against the static world at the reference motion");
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
                  "truth CSV (default for a recording: DIR/truth/<name>_trajectory.csv)")
      ->check(CLI::ExistingFile);
  cmd->add_option("--outlier-threshold-mps", opts->outlier_threshold_mps,
                  "|residual| above this counts as an outlier")
      ->capture_default_str();
  cmd->add_option("--min-speed-mps", opts->min_speed_mps, "skip frames slower than this")
      ->capture_default_str();
  cmd->add_flag("--json", opts->json, "print the statistics as one JSON object");
  cmd->callback([opts] {
    if (opts->recording.empty() && opts->detections.empty()) {
      throw ValidationError(
          "doppler-residuals: give --recording R or --detections CSV --mounts JSON");
    }
    run(*opts);
  });
}

}  // namespace

POLMAP_REGISTER_COMMAND(doppler_residuals, setup);

}  // namespace polmap::cli
