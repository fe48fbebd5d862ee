// `polmap eval --recording R --trajectory TRAJ.csv [--truth CSV] [--errors-csv FILE]
//  [--all-gt] [--json]`: localization accuracy as in the paper (§IV-C): longitudinal and
// lateral errors in the reference frame and the rotation error, RMSE and maximum over
// samples with reference speed > 0.5 m/s and a carrier-phase fixed reference.
//
// Reference: --truth CSV if given; else the simulator's exact truth beside the
// recording (DIR/truth/drive_<k>_trajectory.csv) when it exists; else the
// recording's GNSS/IMU samples. The carrier-phase flags always come from the
// recording's GNSS samples (--all-gt ignores them). Rows the localizer marked
// "initializing" are not evaluated (time to the first "tracking" row is
// reported instead).
#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "command.hpp"
#include "polmap/eval/trajectory_eval.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/schema/recording_io.hpp"

namespace polmap::cli {
namespace {

namespace fs = std::filesystem;

struct EvalOptions {
  std::string recording;
  std::string trajectory;
  std::string truth;
  std::string errors_csv;
  bool all_gt = false;
  bool json = false;
};

void run(const EvalOptions& o) {
  std::vector<TrajectorySample> gnss;
  {
    RecordingReader reader(o.recording);
    while (auto rec = reader.next()) {
      if (const auto* t = std::get_if<TrajectorySample>(&*rec)) gnss.push_back(*t);
    }
  }
  std::vector<eval::ReferenceSample> reference;
  std::string reference_source;
  fs::path truth = o.truth;
  if (truth.empty()) {
    const fs::path rec(o.recording);
    const fs::path sibling =
        rec.parent_path() / "truth" / (rec.stem().string() + "_trajectory.csv");
    if (fs::exists(sibling)) truth = sibling;
  }
  if (!truth.empty()) {
    reference = eval::reference_from_truth_csv(truth, gnss);
    reference_source = truth.string();
  } else {
    reference = eval::reference_from_samples(gnss);
    reference_source = o.recording + " (GNSS/IMU samples)";
  }
  if (reference.size() < 2) {
    throw ValidationError(reference_source + ": fewer than 2 reference samples");
  }
  const auto rows = eval::read_trajectory_csv(o.trajectory);
  eval::TrajectoryEvalOptions opts;
  opts.require_carrier_phase = !o.all_gt;
  const eval::TrajectoryMetrics m = eval::evaluate_trajectory(rows, reference, opts);

  if (!o.errors_csv.empty()) {
    std::ofstream out(o.errors_csv);
    if (!out) throw IoError("cannot create " + o.errors_csv);
    out << "time_s,status,speed_mps,long_m,lat_m,rot_deg\n";
    for (const auto& e : m.errors) {
      out << e.time_s << ',' << e.status << ',' << e.speed_mps << ',' << e.long_m << ',' << e.lat_m
          << ',' << e.rot_rad * 180.0 / 3.14159265358979323846 << '\n';
    }
    if (!out) throw IoError("cannot write " + o.errors_csv);
  }

  if (o.json) {
    nlohmann::json j;
    j["recording"] = o.recording;
    j["trajectory"] = o.trajectory;
    j["reference"] = reference_source;
    j["long_rmse_m"] = m.long_rmse_m;
    j["long_max_m"] = m.long_max_m;
    j["lat_rmse_m"] = m.lat_rmse_m;
    j["lat_max_m"] = m.lat_max_m;
    j["rot_rmse_deg"] = m.rot_rmse_deg;
    j["rot_max_deg"] = m.rot_max_deg;
    j["reliable_gt_share"] = m.reliable_gt_share;
    j["rows"] = m.rows;
    j["evaluated"] = m.evaluated;
    j["excluded_speed"] = m.excluded_speed;
    j["excluded_not_carrier_phase"] = m.excluded_not_carrier_phase;
    j["excluded_status"] = m.excluded_status;
    j["time_to_tracking_s"] = m.time_to_tracking_s;
    j["status_share"] = {{"tracking", m.share_tracking},
                         {"degraded", m.share_degraded},
                         {"lost", m.share_lost},
                         {"initializing", m.share_initializing}};
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  std::printf("trajectory:  %s (%d rows)\n", o.trajectory.c_str(), m.rows);
  std::printf("reference:   %s\n", reference_source.c_str());
  std::printf("evaluated:   %d rows (excluded: %d v <= 0.5 m/s, %d no carrier phase, %d status)\n",
              m.evaluated, m.excluded_speed, m.excluded_not_carrier_phase, m.excluded_status);
  std::printf("reliable GT: %.1f %%\n", 100.0 * m.reliable_gt_share);
  std::printf(
      "status:      tracking %.1f %%, degraded %.1f %%, lost %.1f %%, initializing %.1f %% "
      "(tracking after %.2f s)\n",
      100.0 * m.share_tracking, 100.0 * m.share_degraded, 100.0 * m.share_lost,
      100.0 * m.share_initializing, m.time_to_tracking_s);
  std::printf("longitudinal RMSE %.3f m, max %.3f m\n", m.long_rmse_m, m.long_max_m);
  std::printf("lateral      RMSE %.3f m, max %.3f m\n", m.lat_rmse_m, m.lat_max_m);
  std::printf("rotational   RMSE %.3f deg, max %.3f deg\n", m.rot_rmse_deg, m.rot_max_deg);
}

void setup(CLI::App& app) {
  auto o = std::make_shared<EvalOptions>();
  auto* cmd = app.add_subcommand(
      "eval", "Localization accuracy of a trajectory CSV against the drive's ground truth");
  cmd->add_option("--recording", o->recording, "recording (.pmrec) the trajectory was made from")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_option("--trajectory", o->trajectory, "trajectory CSV (schema/trajectory_csv.md)")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_option("--truth", o->truth, "reference CSV time_s,lat_deg,lon_deg,yaw_enu_rad,v_mps,...")
      ->check(CLI::ExistingFile);
  cmd->add_option("--errors-csv", o->errors_csv, "write the per-sample errors");
  cmd->add_flag("--all-gt", o->all_gt, "also evaluate samples without carrier-phase reference");
  cmd->add_flag("--json", o->json, "JSON output");
  cmd->callback([o] { run(*o); });
}

}  // namespace

POLMAP_REGISTER_COMMAND(eval, setup);

}  // namespace polmap::cli
