// `polmap detect-eval --dir DIR [--drives K] [--pol LEVEL|all] [--max-range M] [--json]`:
// processes the simulated drives DIR/drive_<k>.pmrec in mapping mode (radar::process_drive)
// and scores the landmark candidates against DIR/truth/world.json (eval/detect_eval.hpp):
// point precision / recall within 0.3 m, mechanism-class accuracy, line coverage of true
// curbs, walls, facades, guardrails and fences, and point repeatability between drives,
// per polarimetric level.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "command.hpp"
#include "polmap/eval/detect_eval.hpp"
#include "polmap/radar/drive_processor.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/schema/recording_io.hpp"
#include "progress.hpp"

namespace polmap::cli {
namespace {

namespace fs = std::filesystem;

struct DetectEvalOptions {
  std::string dir;
  int drives = 0;  // 0: all drive_<k>.pmrec found
  std::string pol = "full";
  double max_range_m = 0.0;
  double cell_size_m = 0.1;
  bool json = false;
};

struct DriveRun {
  int index;
  std::vector<PointCandidate> points;
  std::vector<Eigen::Vector2d> trajectory;
  eval::DetectEval ev;
  double seconds;
};

nlohmann::json to_json(const eval::DetectEval& e) {
  nlohmann::json j;
  const auto& p = e.points;
  j["points"] = {{"candidates", p.candidates},
                 {"precision", p.precision},
                 {"structure_precision", p.structure_precision},
                 {"recall", p.recall},
                 {"truth_observable", p.truth_observable},
                 {"truth_found", p.truth_found},
                 {"rms_error_m", p.rms_error_m},
                 {"class_accuracy", p.class_accuracy},
                 {"class_pairs", p.class_pairs}};
  for (const auto& [c, v] : p.recall_by_class) {
    j["points"]["recall_by_class"][c] = {{"observable", v.first}, {"found", v.second}};
  }
  const auto& l = e.lines;
  j["lines"] = {{"candidates", l.candidates},
                {"candidate_length_m", l.candidate_length_m},
                {"precision", l.precision},
                {"truth_length_m", l.truth_length_m},
                {"coverage", l.coverage}};
  for (const auto& [c, v] : l.coverage_by_class) {
    j["lines"]["coverage_by_class"][c] = {{"length_m", v.first}, {"covered_m", v.second}};
  }
  return j;
}

void run(const DetectEvalOptions& o) {
  const fs::path dir(o.dir);
  const fs::path truth_file = dir / "truth" / "world.json";
  if (!fs::exists(truth_file))
    throw IoError(truth_file.string() + ": not found (simulate with --out DIR)");
  std::vector<fs::path> recordings;
  for (int k = 0; o.drives <= 0 || k < o.drives; ++k) {
    const fs::path p = dir / ("drive_" + std::to_string(k) + ".pmrec");
    if (!fs::exists(p)) {
      if (o.drives > 0)
        throw IoError(p.string() + ": not found (--drives " + std::to_string(o.drives) + ")");
      break;
    }
    recordings.push_back(p);
  }
  if (recordings.empty()) throw IoError(o.dir + ": no drive_0.pmrec");
  std::vector<PolLevel> levels;
  if (o.pol == "all") {
    for (const auto& n : pol_level_names()) levels.push_back(*parse_pol_level(n));
  } else if (auto l = parse_pol_level(o.pol)) {
    levels.push_back(*l);
  } else {
    throw ValidationError("--pol '" + o.pol + "': expected all, full, ll-lr, hh-vv, lr, rr or hh");
  }

  nlohmann::json report = nlohmann::json::array();
  for (PolLevel level : levels) {
    radar::DriveProcessingConfig cfg;
    cfg.gridmap.level = level;
    cfg.gridmap.cell_size_m = o.cell_size_m;
    cfg.gridmap.max_range_m = o.max_range_m;
    std::vector<DriveRun> runs;
    for (std::size_t k = 0; k < recordings.size(); ++k) {
      RecordingReader reader(recordings[k]);
      Progress progress(
          "detect-eval " + std::string(to_string(level)) + " " + recordings[k].filename().string(),
          static_cast<double>(reader.file_size()));
      auto res = radar::process_drive(
          reader, cfg, [&](double) { progress.update(static_cast<double>(reader.offset())); });
      progress.finish();
      const eval::WorldTruth truth = eval::read_world_truth(truth_file, res.frame);
      DriveRun r{static_cast<int>(k), res.points, {}, {}, res.stats.total_seconds};
      for (const auto& s : res.trajectory)
        r.trajectory.push_back(res.frame.to_local(s.lat_deg, s.lon_deg));
      r.ev = eval::evaluate_detections(res.points, res.lines, truth, r.index, r.trajectory);
      runs.push_back(std::move(r));
    }
    for (const DriveRun& r : runs) {
      nlohmann::json j = to_json(r.ev);
      j["level"] = std::string(to_string(level));
      j["drive"] = r.index;
      j["processing_s"] = r.seconds;
      if (!o.json) {
        const auto& p = r.ev.points;
        const auto& l = r.ev.lines;
        std::printf(
            "%-6s drive %d: points %zu, precision %.2f (structure %.2f), recall %.2f (%zu/%zu), "
            "rms %.3f m, class %.2f | lines %zu, precision %.2f, coverage %.2f of %.0f m\n",
            std::string(to_string(level)).c_str(), r.index, p.candidates, p.precision,
            p.structure_precision, p.recall, p.truth_found, p.truth_observable, p.rms_error_m,
            p.class_accuracy, l.candidates, l.precision, l.coverage, l.truth_length_m);
      }
      report.push_back(j);
    }
    for (std::size_t k = 1; k < runs.size(); ++k) {
      const double rep = eval::point_repeatability(runs[0].points, runs[0].trajectory,
                                                   runs[k].points, runs[k].trajectory);
      if (!o.json) {
        std::printf("%-6s repeatability drive 0 vs %zu: %.2f\n",
                    std::string(to_string(level)).c_str(), k, rep);
      }
      report.push_back({{"level", std::string(to_string(level))},
                        {"repeatability", {{"drive_a", 0}, {"drive_b", k}, {"value", rep}}}});
    }
  }
  if (o.json) std::printf("%s\n", report.dump(1).c_str());
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<DetectEvalOptions>();
  auto* cmd = app.add_subcommand(
      "detect-eval", "Score landmark candidates of simulated drives against the world truth");
  cmd->add_option("--dir", opts->dir, "Simulation output (drive_<k>.pmrec, truth/world.json)")
      ->required();
  cmd->add_option("--drives", opts->drives, "Number of drives to use (default: all found)");
  cmd->add_option("--pol", opts->pol, "Polarimetric level, or 'all'");
  cmd->add_option("--max-range", opts->max_range_m, "Use range bins up to this range (0: all)");
  cmd->add_option("--cell-size", opts->cell_size_m, "Gridmap cell size, metres");
  cmd->add_flag("--json", opts->json, "Print the results as JSON");
  cmd->callback([opts] { run(*opts); });
}

}  // namespace

POLMAP_REGISTER_COMMAND(detect_eval, setup);

}  // namespace polmap::cli
