// `polmap localize --server URL --recording R --out TRAJ.csv [--pol LEVEL]
//  [--initial-pose LAT,LON,YAW_DEG | --initial-from-gnss-with-error E_M,E_DEG] [--seed S]
//  [--cache DIR] [--map-version V] [--publication-key KEY.pub] [--json]`: radar-only
// localization of a recorded drive against the tiles served by a mapping service, or by a
// static host or CDN serving a signed `polmap publish` publication (--publication-key: the
// publisher's public key; --server is then the publication's URL) (loc::Localizer +
// loc::TileFetcher), writing the trajectory CSV of schema/trajectory_csv.md.
//
// Initial pose. A vehicle starts from a coarse GNSS fix. --initial-pose gives it
// directly (uncertainty --initial-sigma, default 3 m / 3°). Otherwise
// (--initial-from-gnss-with-error, default 3,3) the first GNSS/IMU sample of the
// recording (the one closest in time to the first radar frame) is perturbed by a
// deliberate error: E_M metres in a direction and E_DEG degrees of yaw with a sign
// drawn from --seed, and the localizer is told σ = (E_M, E_DEG). That single sample
// is the only ground truth this command ever reads: every later GNSS/IMU record is
// skipped unread by the localization.
//
// Tiles. Before the first frame the tiles within 150 m of the initial pose are
// fetched (waiting at most 15 s, like a vehicle warming its cache); afterwards the
// localizer only uses the non-blocking TileSource and the fetcher prefetches
// ahead in the background. The cache directory (default
// $XDG_CACHE_HOME/polmap/tiles or ~/.cache/polmap/tiles) makes later runs work
// offline.
//
// Run report (--report URL --api-key KEY): after the drive, a summary of the run
// (schema/localization_run.md: the trajectory decimated to 5 Hz with status and
// covariance) is sent to the mapping service (POST /v1/runs), where the web console draws
// it. With --truth CSV (the simulator's exact poses) or --report-errors-from-recording
// (the recording's GNSS/INS), the report carries the errors against that reference,
// computed after the run as `polmap eval` computes them; the localization never sees it.
#include <CLI/CLI.hpp>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <numbers>
#include <optional>
#include <random>
#include <string>

#include "command.hpp"
#include "polmap/eval/run_errors.hpp"
#include "polmap/eval/stage_budget.hpp"
#include "polmap/eval/trajectory_eval.hpp"
#include "polmap/localization_client/localizer.hpp"
#include "polmap/localization_client/run_recorder.hpp"
#include "polmap/localization_client/run_reporter.hpp"
#include "polmap/localization_client/tile_fetcher.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/schema/recording_io.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "progress.hpp"

namespace polmap::cli {
namespace {

namespace fs = std::filesystem;
constexpr double kDeg = std::numbers::pi / 180.0;

struct LocalizeOptions {
  std::string server;
  std::string recording;
  std::string out;
  std::string pol = "full";
  std::string initial_pose;
  std::string initial_from_gnss = "3,3";
  std::string initial_sigma = "3,3";
  std::string cache;
  std::string publication_key;
  std::int64_t map_version = 0;
  std::uint64_t seed = 1;
  bool json = false;
  std::string report;
  std::string api_key;
  std::string truth;
  bool report_errors_from_recording = false;
  double slip_gradient_deg = -1.0;
  std::string label;
};

/// After the run: the report's errors against the chosen reference, then POST /v1/runs.
/// Returns the report's JSON summary for the command's output.
nlohmann::json send_report(const LocalizeOptions& o, LocalizationRun run) {
  nlohmann::json j;
  if (!o.truth.empty() || o.report_errors_from_recording) {
    std::vector<TrajectorySample> gnss;  // read only now: the run is over
    RecordingReader reader(o.recording);
    while (auto rec = reader.next()) {
      if (const auto* t = std::get_if<TrajectorySample>(&*rec)) gnss.push_back(*t);
    }
    const bool truth = !o.truth.empty();
    const auto reference =
        truth ? eval::reference_from_truth_csv(o.truth, gnss) : eval::reference_from_samples(gnss);
    const auto m = eval::attach_run_errors(
        run, reference, truth ? RunReference::SimulatorTruth : RunReference::GnssIns);
    j["evaluated"] = m.evaluated;
    j["lat_rmse_m"] = m.lat_rmse_m;
  }
  const auto r = loc::report_localization_run(o.report, o.api_key, run);
  if (r.status != loc::RunReportResult::Status::Stored) {
    throw IoError("--report " + o.report + ": the run report was not stored: " + r.message);
  }
  j["run_id"] = r.id;
  j["samples"] = run.samples.size();
  j["url"] = o.report + "/v1/runs/" + std::to_string(r.id);
  return j;
}

std::vector<double> parse_numbers(const std::string& s, std::size_t n, const std::string& option) {
  std::vector<double> out;
  std::size_t pos = 0;
  while (pos <= s.size()) {
    const std::size_t c = s.find(',', pos);
    const std::string item = s.substr(pos, c == std::string::npos ? std::string::npos : c - pos);
    char* end = nullptr;
    const double v = std::strtod(item.c_str(), &end);
    if (item.empty() || end != item.c_str() + item.size() || !std::isfinite(v)) {
      throw ValidationError(option + ": '" + item + "' is not a number (expected " +
                            std::to_string(n) + " comma-separated numbers)");
    }
    out.push_back(v);
    if (c == std::string::npos) break;
    pos = c + 1;
  }
  if (out.size() != n) {
    throw ValidationError(option + ": expected " + std::to_string(n) +
                          " comma-separated numbers, got " + std::to_string(out.size()));
  }
  return out;
}

fs::path default_cache_dir() {
  if (const char* x = std::getenv("XDG_CACHE_HOME"); x != nullptr && *x != '\0') {
    return fs::path(x) / "polmap" / "tiles";
  }
  if (const char* h = std::getenv("HOME"); h != nullptr && *h != '\0') {
    return fs::path(h) / ".cache" / "polmap" / "tiles";
  }
  return fs::temp_directory_path() / "polmap-tiles";
}

void run(const LocalizeOptions& o) {
  const auto level = parse_pol_level(o.pol);
  if (!level) throw ValidationError("--pol: unknown polarimetric level '" + o.pol + "'");
  RecordingReader reader(o.recording);
  const RecordingHeader header = reader.header();
  if (header.sensors.empty()) {
    throw ValidationError(o.recording + ": recording header lists no sensors");
  }

  // Buffer records up to the first sensor frame (and, for the GNSS start, up
  // to the first GNSS sample) to pick the initial pose.
  std::vector<SensorFrame> pending;
  std::optional<TrajectorySample> before, after;
  while (auto rec = reader.next()) {
    if (auto* f = std::get_if<SensorFrame>(&*rec)) {
      pending.push_back(std::move(*f));
      if (before || !o.initial_pose.empty()) break;
    } else if (auto* t = std::get_if<TrajectorySample>(&*rec)) {
      (pending.empty() ? before : after) = *t;
      if (!pending.empty()) break;
    }
  }
  if (pending.empty()) throw ValidationError(o.recording + ": recording has no sensor frames");

  GeoPose initial;
  double sigma_xy_m = 3.0, sigma_yaw_rad = 3.0 * kDeg;
  std::string initial_source;
  if (!o.initial_pose.empty()) {
    const auto v = parse_numbers(o.initial_pose, 3, "--initial-pose");
    initial.position = {v[0], v[1], header.origin.alt_m};
    initial.yaw_enu_rad = v[2] * kDeg;
    const auto s = parse_numbers(o.initial_sigma, 2, "--initial-sigma");
    sigma_xy_m = s[0];
    sigma_yaw_rad = s[1] * kDeg;
    initial_source = "--initial-pose";
  } else {
    const auto e = parse_numbers(o.initial_from_gnss, 2, "--initial-from-gnss-with-error");
    const double t0 = pending.front().time_s;
    std::optional<TrajectorySample> g = before;
    if (!g || (after && std::abs(after->time_s - t0) < std::abs(before->time_s - t0))) g = after;
    if (!g) {
      throw ValidationError(o.recording +
                            ": no GNSS/IMU sample for the initial pose (give --initial-pose)");
    }
    // The deliberate error, reproducible from --seed.
    std::mt19937_64 rng(o.seed);
    const double dir =
        std::uniform_real_distribution<double>(-std::numbers::pi, std::numbers::pi)(rng);
    const double sign = std::uniform_int_distribution<int>(0, 1)(rng) != 0 ? 1.0 : -1.0;
    const tiles::LocalFrame f(GeoPoint{g->lat_deg, g->lon_deg, header.origin.alt_m});
    initial.position = f.to_geo(e[0] * Eigen::Vector2d(std::cos(dir), std::sin(dir)));
    initial.yaw_enu_rad = g->yaw_enu_rad + sign * e[1] * kDeg;
    sigma_xy_m = std::max(e[0], 0.5);
    sigma_yaw_rad = std::max(e[1], 0.5) * kDeg;
    initial_source = "GNSS sample at " + std::to_string(g->time_s) + " s + error " +
                     std::to_string(e[0]) + " m, " + std::to_string(e[1]) + " deg (seed " +
                     std::to_string(o.seed) + ")";
  }

  loc::TileFetcherConfig fcfg;
  fcfg.server_url = o.server;
  fcfg.cache_dir = o.cache.empty() ? default_cache_dir() : fs::path(o.cache);
  if (o.map_version > 0) fcfg.query = "version=" + std::to_string(o.map_version);
  fcfg.publication_public_key = o.publication_key;
  loc::TileFetcher fetcher(fcfg);
  const auto start_keys = loc::tiles_around(initial.position, 150.0);
  const bool warm = fetcher.wait_for(start_keys, 15.0);

  loc::LocalizerConfig cfg;
  cfg.gridmap.level = *level;
  // A vehicle parameter: the recording's declared value unless overridden.
  cfg.egomotion.side_slip_gradient_rad_per_mps2 =
      o.slip_gradient_deg >= 0.0 ? o.slip_gradient_deg * kDeg
                                 : header.side_slip_gradient_rad_per_mps2.value_or(0.0);
  loc::Localizer localizer(cfg, header.sensors, fetcher);
  localizer.set_initial_pose(initial, sigma_xy_m, sigma_yaw_rad);

  eval::TrajectoryCsvWriter writer(o.out);
  loc::RunRecorder recorder;
  std::map<std::string, int> status_rows;
  int frames = 0, rows = 0, extractions = 0, graph_solves = 0;
  double proc_sum = 0.0, proc_max = 0.0, graph_sum = 0.0, first_tracking = -1.0;
  double t_first = pending.front().time_s, t_last = t_first;
  std::uint64_t map_version = 0;
  loc::StageCpuTimes stage_cpu;
  const auto wall0 = std::chrono::steady_clock::now();
  Progress progress("localize " + o.recording, static_cast<double>(reader.file_size()));
  auto handle = [&](const SensorFrame& f) {
    const loc::LocalizationOutput out = localizer.process(f);
    if (!o.report.empty()) recorder.add(out);
    stage_cpu += out.cpu;
    ++frames;
    t_last = f.time_s;
    proc_sum += out.processing_time_s;
    proc_max = std::max(proc_max, out.processing_time_s);
    if (out.extracted) ++extractions;
    if (out.graph_updated) {
      ++graph_solves;
      graph_sum += out.graph_update_time_s;
    }
    map_version = std::max(map_version, out.map_version);
    if (!out.has_pose) return;
    const eval::TrajectoryRow r = eval::to_trajectory_row(out);
    writer.write(r);
    ++rows;
    ++status_rows[r.status];
    if (first_tracking < 0 && out.status == loc::LocalizationOutput::Status::Tracking) {
      first_tracking = f.time_s - t_first;
    }
    progress.update(static_cast<double>(reader.offset()), r.status);
  };
  for (const auto& f : pending) handle(f);
  pending.clear();
  while (auto rec = reader.next()) {
    // GNSS/IMU records are skipped: localization is radar-only.
    if (const auto* f = std::get_if<SensorFrame>(&*rec)) handle(*f);
  }
  writer.close();
  progress.finish();
  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  const auto fs_stats = fetcher.stats();

  nlohmann::json j;
  j["recording"] = o.recording;
  j["trajectory"] = o.out;
  j["server"] = o.server;
  j["pol"] = o.pol;
  j["initial_pose"] = {{"source", initial_source},
                       {"lat_deg", initial.position.lat_deg},
                       {"lon_deg", initial.position.lon_deg},
                       {"yaw_enu_deg", initial.yaw_enu_rad / kDeg},
                       {"sigma_xy_m", sigma_xy_m},
                       {"sigma_yaw_deg", sigma_yaw_rad / kDeg}};
  j["start_tiles_ready"] = warm;
  j["frames"] = frames;
  j["rows"] = rows;
  j["duration_s"] = t_last - t_first;
  j["extractions"] = extractions;
  j["time_to_tracking_s"] = first_tracking;
  nlohmann::json shares = nlohmann::json::object();
  for (const auto& [s, n] : status_rows) shares[s] = rows > 0 ? static_cast<double>(n) / rows : 0.0;
  j["status_share"] = shares;
  j["map_version"] = map_version;
  j["mean_frame_ms"] = frames > 0 ? 1e3 * proc_sum / frames : 0.0;
  j["max_frame_ms"] = 1e3 * proc_max;
  j["mean_graph_ms"] = graph_solves > 0 ? 1e3 * graph_sum / graph_solves : 0.0;
  j["wall_s"] = wall_s;
  j["realtime_factor"] = wall_s > 0 ? (t_last - t_first) / wall_s : 0.0;
  const double drive_s = t_last - t_first;
  // CPU of the localizer's thread by stage plus the fetcher's worker thread.
  if (drive_s > 0)
    j["stage_ms_per_s"] = eval::stage_budget_json(stage_cpu, drive_s, fs_stats.worker_cpu_s);
  j["tiles"] = {{"responses_200", fs_stats.responses_200},
                {"responses_304", fs_stats.responses_304},
                {"responses_204", fs_stats.responses_204},
                {"responses_404", fs_stats.responses_404},
                {"disk_loads", fs_stats.disk_loads},
                {"transport_errors", fs_stats.transport_errors},
                {"bytes_downloaded", fs_stats.bytes_downloaded},
                {"cache_dir", fcfg.cache_dir.string()}};
  if (const auto cal = localizer.mount_calibration()) {
    // The online mount calibration the front end applied (relative yaws and time offsets).
    nlohmann::json sensors = nlohmann::json::array();
    for (const auto& s : cal->sensors) {
      sensors.push_back({{"sensor_id", s.sensor_id},
                         {"yaw_offset_deg", s.yaw_offset_rad / kDeg},
                         {"yaw_sigma_deg", s.yaw_sigma_rad / kDeg},
                         {"yaw_status", radar::to_string(s.yaw_status)},
                         {"time_offset_ms", 1e3 * s.time_offset_s},
                         {"time_sigma_ms", 1e3 * s.time_sigma_s},
                         {"time_status", radar::to_string(s.time_status)}});
    }
    j["mount_calibration"] = {{"status", radar::to_string(cal->status)},
                              {"observed_s", cal->observed_s},
                              {"sensors", sensors}};
  }
  if (!o.report.empty()) {
    std::string label = o.label.empty() ? fs::path(o.recording).stem().string() : o.label;
    if (label.size() > LocalizationRunLimits::kMaxLabelBytes) {
      label.resize(LocalizationRunLimits::kMaxLabelBytes);  // a label, not an identity
    }
    j["report"] = send_report(
        o, recorder.run(label, o.pol,
                        wall_s > 0 ? std::optional((t_last - t_first) / wall_s) : std::nullopt));
  }
  if (o.json) {
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  std::printf("recording:   %s (%d frames, %.1f s)\n", o.recording.c_str(), frames,
              t_last - t_first);
  std::printf("initial:     %s\n", initial_source.c_str());
  std::printf("trajectory:  %s (%d rows)\n", o.out.c_str(), rows);
  std::printf("tracking:    after %.2f s; status shares", first_tracking);
  for (const auto& [s, n] : status_rows) std::printf(" %s %.1f%%", s.c_str(), 100.0 * n / rows);
  std::printf("\n");
  std::printf("compute:     %.1f ms/frame mean, %.1f max, graph %.1f ms/solve, %.2fx real time\n",
              1e3 * proc_sum / std::max(frames, 1), 1e3 * proc_max,
              1e3 * graph_sum / std::max(graph_solves, 1),
              wall_s > 0 ? (t_last - t_first) / wall_s : 0.0);
  std::printf(
      "tiles:       map version %llu, %llu x 200, %llu x 304, %llu x 204, %llu x 404, %llu "
      "from disk, %llu bytes (cache %s)\n",
      static_cast<unsigned long long>(map_version),
      static_cast<unsigned long long>(fs_stats.responses_200),
      static_cast<unsigned long long>(fs_stats.responses_304),
      static_cast<unsigned long long>(fs_stats.responses_204),
      static_cast<unsigned long long>(fs_stats.responses_404),
      static_cast<unsigned long long>(fs_stats.disk_loads),
      static_cast<unsigned long long>(fs_stats.bytes_downloaded), fcfg.cache_dir.string().c_str());
  if (drive_s > 0) {
    std::printf("%s", eval::format_stage_budget(stage_cpu, drive_s, fs_stats.worker_cpu_s).c_str());
  }
  if (j.contains("mount_calibration")) {
    std::printf("mounts:      online calibration %s",
                j["mount_calibration"]["status"].get<std::string>().c_str());
    for (const auto& s : j["mount_calibration"]["sensors"]) {
      std::printf("; sensor %d yaw %+.3f° ± %.3f, time %+.2f ms ± %.2f", s["sensor_id"].get<int>(),
                  s["yaw_offset_deg"].get<double>(), s["yaw_sigma_deg"].get<double>(),
                  s["time_offset_ms"].get<double>(), s["time_sigma_ms"].get<double>());
    }
    std::printf("\n");
  }
  if (j.contains("report")) {
    std::printf("report:      run %lld (%zu samples) at %s\n",
                static_cast<long long>(j["report"]["run_id"].get<std::int64_t>()),
                j["report"]["samples"].get<std::size_t>(),
                j["report"]["url"].get<std::string>().c_str());
  }
}

void setup(CLI::App& app) {
  auto o = std::make_shared<LocalizeOptions>();
  auto* cmd = app.add_subcommand(
      "localize", "Radar-only localization of a recorded drive against a mapping service's tiles");
  cmd->add_option("--server", o->server, "mapping service base URL, e.g. http://127.0.0.1:8080")
      ->required();
  cmd->add_option("--recording", o->recording, "recording (.pmrec)")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_option("--out", o->out, "trajectory CSV to write (schema/trajectory_csv.md)")
      ->required();
  cmd->add_option("--pol", o->pol, "polarimetric level: full, ll-lr, hh-vv, lr, rr, hh")
      ->capture_default_str();
  auto* ip = cmd->add_option("--initial-pose", o->initial_pose,
                             "initial pose LAT_DEG,LON_DEG,YAW_ENU_DEG (yaw counter-clockwise "
                             "from east)");
  auto* ig = cmd->add_option("--initial-from-gnss-with-error", o->initial_from_gnss,
                             "initial pose = first GNSS sample + E_M metres, E_DEG degrees of "
                             "deliberate error")
                 ->capture_default_str();
  ip->excludes(ig);
  cmd->add_option("--initial-sigma", o->initial_sigma,
                  "with --initial-pose: 1-sigma SIGMA_M,SIGMA_DEG")
      ->capture_default_str();
  cmd->add_option("--seed", o->seed, "seed of the deliberate initial error")->capture_default_str();
  cmd->add_option("--cache", o->cache, "tile cache directory");
  cmd->add_option("--publication-key", o->publication_key,
                  "publisher's Ed25519 public key (PEM): --server is a static publication "
                  "(polmap publish) whose signed manifest and tile hashes are checked")
      ->check(CLI::ExistingFile);
  cmd->add_option("--map-version", o->map_version, "pin a map version (default: current)");
  cmd->add_flag("--json", o->json, "print a JSON summary");
  cmd->add_option("--slip-gradient-deg", o->slip_gradient_deg,
                  "the vehicle's rear-axle side-slip gradient, deg per m/s^2 (default: the "
                  "recording header's, else 0 = kinematic model; a passenger car: about "
                  "0.2-0.3)");
  auto* rep = cmd->add_option("--report", o->report,
                              "after the run, send a run report to this mapping service "
                              "(POST /v1/runs; schema/localization_run.md)");
  auto* key = cmd->add_option("--api-key", o->api_key, "vehicle (or operator) key for --report");
  rep->needs(key);
  key->needs(rep);
  auto* truth = cmd->add_option("--truth", o->truth,
                                "with --report: the simulator's exact poses (truth CSV); the "
                                "report carries the errors against them")
                    ->check(CLI::ExistingFile);
  auto* from_rec = cmd->add_flag("--report-errors-from-recording", o->report_errors_from_recording,
                                 "with --report: errors against the recording's GNSS/INS");
  truth->needs(rep);
  from_rec->needs(rep);
  truth->excludes(from_rec);
  cmd->add_option("--label", o->label, "with --report: the run's label (default: recording name)")
      ->needs(rep);
  cmd->callback([o] { run(*o); });
}

}  // namespace

POLMAP_REGISTER_COMMAND(localize, setup);

}  // namespace polmap::cli
