// `polmap study --world urban|industrial|rural|FILE.osm|FILE.xodr [--length-m L]
//  [--drives N] [--seeds S1,S2,..] [--pol full,ll-lr,hh-vv,lr,rr,hh] [--out DIR]
//  [--http] [--json]`: the leave-one-out localization study of paper §IV-B..F on
// simulated drives (tools/eval/include/polmap/eval/study.hpp): per seed and level,
// simulate + process + package + ingest N drives into a real SQLite store, build a
// map without each drive, localize that drive against it, and evaluate against the
// exact simulated trajectory. Prints paper Table IV per level, the level
// comparison (§IV-F) and client speed; writes DIR/study.json, DIR/table.txt and
// the CCDF figures DIR/ccdf_{lat,long,rot}.svg.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <fstream>
#include <memory>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "command.hpp"
#include "polmap/eval/study.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/sim/realism.hpp"
#include "progress.hpp"

namespace polmap::cli {
namespace {

struct StudyOptions {
  int package_format = 2;
  std::string world = "urban";
  double length_m = 600.0;
  int drives = 3;
  std::string seeds = "1";
  std::string pol = "full";
  std::string out = "study-out";
  std::string realism = "realistic";
  double slip_gradient_deg = -1.0;
  bool no_common_yaw = false;
  std::string realism_sources;
  std::string gnss = "rtk";
  int rtk_drives = 0;
  int held_out = 0;
  bool http = false;
  bool json = false;
  bool keep_packages = false;
  bool diagnose = false;
  double initial_error_m = 3.0;
  double initial_error_deg = 3.0;
  double tracking_heading_span_deg = -1.0;
};

std::vector<std::string> split_list(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, ',')) {
    if (!item.empty()) out.push_back(item);
  }
  return out;
}

void run(const StudyOptions& o) {
  eval::StudyConfig cfg;
  cfg.world = o.world;
  cfg.length_m = o.length_m;
  cfg.drives = o.drives;
  cfg.held_out_drives = o.held_out;
  cfg.out_dir = o.out;
  cfg.http = o.http;
  cfg.package_format = static_cast<std::uint32_t>(o.package_format);
  cfg.keep_packages = o.keep_packages;
  cfg.diagnose = o.diagnose;
  cfg.initial_error_m = o.initial_error_m;
  cfg.initial_error_yaw_deg = o.initial_error_deg;
  // The simulator's error sources (tools/sim/README.md "Realism"): ideal, or realistic.
  cfg.sim.realism = sim::realism_preset(o.realism);
  if (!o.realism_sources.empty()) {
    if (o.realism != "realistic") {
      throw ValidationError("study: --realism-sources needs --realism realistic");
    }
    cfg.sim.realism = sim::only_sources(cfg.sim.realism, o.realism_sources);
  }
  if (o.no_common_yaw) cfg.localizer.mount_calibration.estimate_common_yaw = false;
  if (o.tracking_heading_span_deg >= 0.0) {
    cfg.localizer.tracking_max_heading_span_rad =
        o.tracking_heading_span_deg * std::numbers::pi / 180.0;
  }
  // Positioning of the drives' recorded trajectories: survey-grade, or a series car's
  // consumer GNSS (the build aligns those drives; errors are measured in the map's frame,
  // and every sample counts: the simulator's truth is exact, whatever the GNSS fix).
  if (o.rtk_drives < 0 || (o.rtk_drives > 0 && o.gnss != "consumer")) {
    throw ValidationError("study: --rtk-drives N (N >= 0) needs --gnss consumer");
  }
  if (o.gnss == "consumer") {
    cfg.sim.gnss.grade = sim::GnssGrade::Consumer;
    cfg.rtk_drives = o.rtk_drives;
    cfg.require_carrier_phase = false;
  }
  // The simulated vehicle's side-slip gradient is a vehicle parameter the localizer is
  // given, like its mounts (the nominal value of the vehicle, not the drive's truth).
  cfg.localizer.egomotion.side_slip_gradient_rad_per_mps2 =
      o.slip_gradient_deg >= 0.0 ? o.slip_gradient_deg * std::numbers::pi / 180.0
      : cfg.sim.realism.slip.enabled
          ? cfg.sim.realism.slip.side_slip_gradient_deg_per_mps2 * std::numbers::pi / 180.0
          : 0.0;
  cfg.seeds.clear();
  for (const auto& s : split_list(o.seeds)) {
    try {
      std::size_t pos = 0;
      const unsigned long long v = std::stoull(s, &pos);
      if (pos != s.size()) throw std::invalid_argument(s);
      cfg.seeds.push_back(v);
    } catch (const std::exception&) {
      throw ValidationError("study: --seeds: '" + s + "' is not a non-negative integer");
    }
  }
  cfg.levels.clear();
  for (const auto& s : split_list(o.pol)) {
    const auto l = parse_pol_level(s);
    if (!l) {
      throw ValidationError("study: --pol: unknown level '" + s +
                            "' (full, ll-lr, hh-vv, lr, rr, hh)");
    }
    cfg.levels.push_back(*l);
  }

  Progress progress("study", 1.0);
  const eval::StudyResult r = eval::run_study(cfg, [&](const eval::StudyProgress& p) {
    std::string note =
        p.stage + " seed " + std::to_string(p.seed) + " " + std::string(to_string(p.level));
    if (p.drive >= 0) note += " drive #" + std::to_string(p.drive + 1);
    progress.update(p.fraction, note);
  });
  progress.finish();

  std::ostringstream text;
  text << "world " << r.world << ", simulator realism: " << r.realism << "\n\n";
  for (const PolLevel l : cfg.levels) text << eval::format_accuracy_table(r, l) << '\n';
  if (cfg.levels.size() > 1) text << eval::format_level_table(r) << '\n';
  text << eval::format_uncertainty_table(r) << '\n';
  text << eval::format_map_geometry_table(r) << '\n';
  text << eval::format_speed_table(r) << '\n';
  if (const std::string cal = eval::format_calibration_table(r); !cal.empty()) {
    text << cal << '\n';
  }
  if (cfg.diagnose) text << eval::format_diagnosis_table(r) << '\n';
  text << "figures: ";
  for (std::size_t i = 0; i < r.figures.size(); ++i) {
    text << (i ? ", " : "") << r.figures[i].string();
  }
  text << "\nstudy took " << static_cast<long long>(r.wall_s + 0.5) << " s; details in " << o.out
       << "/study.json\n";

  const std::filesystem::path dir(o.out);
  {
    std::ofstream f(dir / "table.txt");
    if (!f) throw IoError("study: cannot write " + (dir / "table.txt").string());
    f << text.str();
  }
  const std::string json = eval::to_json(r).dump(2);
  {
    std::ofstream f(dir / "study.json");
    if (!f) throw IoError("study: cannot write " + (dir / "study.json").string());
    f << json << '\n';
  }
  if (o.json) {
    std::printf("%s\n", json.c_str());
  } else {
    std::printf("%s", text.str().c_str());
  }
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<StudyOptions>();
  auto* cmd = app.add_subcommand(
      "study",
      "Leave-one-out localization study on simulated drives (paper Table IV, polarimetric "
      "levels, CCDF figures)");
  cmd->add_option("--world", opts->world,
                  "urban | industrial | rural | FILE.osm (Lanelet2) | FILE.xodr (OpenDRIVE)")
      ->capture_default_str();
  cmd->add_option("--length-m", opts->length_m, "route length")->capture_default_str();
  cmd->add_option("--drives", opts->drives, "passes over the route (>= 3), each left out once")
      ->capture_default_str();
  cmd->add_option("--seeds", opts->seeds, "comma-separated seeds, one world + drive set each")
      ->capture_default_str();
  cmd->add_option("--pol", opts->pol,
                  "comma-separated polarimetric levels: full, ll-lr, hh-vv, lr, rr, hh")
      ->capture_default_str();
  cmd->add_option("--out", opts->out, "study directory (stores, figures, CSVs)")
      ->capture_default_str();
  cmd->add_flag("--http", opts->http,
                "fetch tiles through a real server on loopback (TileFetcher) instead of the store");
  cmd->add_flag("--json", opts->json, "print the results as JSON");
  cmd->add_option(
         "--realism", opts->realism,
         "simulator error sources: realistic (tools/sim/README.md) or ideal (exact sensors)")
      ->capture_default_str();
  cmd->add_option("--realism-sources", opts->realism_sources,
                  "with --realism realistic: keep only these sources on (comma separated)");
  cmd->add_option("--gnss", opts->gnss,
                  "positioning of the mapping drives: rtk (survey-grade) | consumer (a series "
                  "car's GNSS; the build aligns the drives, errors in the map's frame)")
      ->check(CLI::IsMember({"rtk", "consumer"}))
      ->capture_default_str();
  cmd->add_option("--held-out", opts->held_out,
                  "leave out and localize only the last N drives, each against the map of all "
                  "others (0: every drive)")
      ->capture_default_str();
  cmd->add_option("--rtk-drives", opts->rtk_drives,
                  "with --gnss consumer: the first N drives are survey-grade (anchors)")
      ->capture_default_str();
  cmd->add_flag("--no-calibrate-common-yaw", opts->no_common_yaw,
                "the localizer calibrates relative mount yaws only, not the yaw common to "
                "all mounts (radar/mount_calibration.hpp)");
  cmd->add_option("--slip-gradient-deg", opts->slip_gradient_deg,
                  "the localizer's vehicle side-slip gradient, deg per m/s^2 (default: the "
                  "simulated vehicle's, 0 without slip)");
  cmd->add_option("--tracking-heading-span-deg", opts->tracking_heading_span_deg,
                  "while tracking, match only the local map taken since the odometry heading "
                  "was within this many degrees of the current one (LocalizerConfig::"
                  "tracking_max_heading_span_rad; 0 = the whole window; default: the "
                  "localizer's)");
  cmd->add_flag("--keep-packages", opts->keep_packages, "keep the drive package directories");
  cmd->add_flag("--diagnose", opts->diagnose,
                "per drive: odometry drift, truth-posed candidates vs the map (stage diagnosis)");
  cmd->add_option("--package-format", opts->package_format,
                  "drive package format of the mapping uploads (2 compact, 1 lossless)")
      ->check(CLI::Range(1, 2))
      ->capture_default_str();
  cmd->add_option("--initial-error-m", opts->initial_error_m,
                  "deliberate position error of the initial (GNSS) pose")
      ->capture_default_str();
  cmd->add_option("--initial-error-deg", opts->initial_error_deg,
                  "deliberate heading error of the initial pose")
      ->capture_default_str();
  cmd->callback([opts] { run(*opts); });
}

}  // namespace

POLMAP_REGISTER_COMMAND(study, setup);

}  // namespace polmap::cli
