// bench_localizer: accuracy and per-frame cost of the Localizer on a simulated
// drive streamed straight from the simulator (no disk).
//
//   bench_localizer [--world urban|industrial|rural|FILE] [--length-m L] [--seed S]
//                   [--drive K] [--duration-s T] [--init-error-m E] [--init-error-deg D]
//                   [--json] [-v]
//   bench_localizer --recording R --server URL [...]   a recorded drive (exact truth from
//                   DIR/truth/drive_<k>_trajectory.csv) against a running mapping service
//
// Map: "oracle" = the world truth's permanent point objects (poles, posts, tree
// trunks, sign plates, facade corners/recesses) and extended objects (curbs,
// guardrails, walls) converted into localization tiles. It isolates the localizer from map-building
// errors; the real chain (drives -> consensus -> tiles over HTTP) is `polmap localize`. The
// Localizer itself never sees the truth: it gets sensor frames, the tiles, and an initial pose =
// exact start pose + a deliberate error (default 3 m along a random direction and 3°).
//
// Prints: time to the first confident match, status shares, errors (paper
// §IV-C: ε_long, ε_lat in the truth frame, ε_rot) RMSE/max over Tracking and
// Degraded frames with v > 0.5 m/s, compute time per frame and per extraction.
#include "polmap/localization_client/localizer.hpp"

#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <numbers>
#include <optional>
#include <random>

#include "polmap/eval/stage_budget.hpp"
#include "polmap/eval/trajectory_eval.hpp"
#include "polmap/localization_client/tile_fetcher.hpp"
#include "polmap/schema/recording_io.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/realism.hpp"
#include "polmap/sim/world.hpp"
#include "polmap/tiles/local_frame.hpp"

using namespace polmap;

namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

/// Point-like permanent objects: what a consensus map of repeated pCFAR
/// candidates contains (poles, posts, trunks, sign plates, facade corners and
/// recesses). Temporary objects (parked cars, bins) are excluded by `permanent`.
bool is_point_landmark(sim::ObjectClass c) {
  using C = sim::ObjectClass;
  return c != C::Vegetation && c != C::ParkedCar && c != C::Bin;
}

bool is_line_landmark(sim::ObjectClass c) {
  using C = sim::ObjectClass;
  return c == C::Curbstone || c == C::GuardrailBeam || c == C::Wall || c == C::RoadBorder;
}

/// Resident set size of this process, MiB (/proc/self/statm).
double resident_mb() {
  std::FILE* f = std::fopen("/proc/self/statm", "r");
  if (f == nullptr) return 0.0;
  long pages_total = 0, pages_resident = 0;
  const int n = std::fscanf(f, "%ld %ld", &pages_total, &pages_resident);
  std::fclose(f);
  return n == 2 ? static_cast<double>(pages_resident) * static_cast<double>(sysconf(_SC_PAGESIZE)) /
                      (1024.0 * 1024.0)
                : 0.0;
}

/// Oracle tiles: permanent truth objects in their tiles' frames.
void fill_oracle_tiles(const sim::World& world, loc::InMemoryTileSource& source) {
  std::map<tiles::TileKey, tiles::LocalizationTile> out;
  auto tile_of = [&](const GeoPoint& g) -> tiles::LocalizationTile& {
    const auto key = tiles::tile_at(g.lat_deg, g.lon_deg, tiles::kLocalizationZoom);
    auto& t = out[key];
    t.key = key;
    t.map_version = 1;
    return t;
  };
  for (const auto& o : world.objects) {
    if (!o.permanent) continue;
    if (is_point_landmark(o.cls) && o.geometry_m.size() == 1) {
      const GeoPoint g = world.frame.to_geo(o.geometry_m[0]);
      auto& t = tile_of(g);
      PointLandmark p;
      p.id = o.id;
      p.position_m = tiles::LocalFrame(tiles::tile_center(t.key)).to_local(g);
      p.support_drives = 3;
      t.points.push_back(p);
    } else if (is_line_landmark(o.cls) && o.geometry_m.size() >= 2) {
      // Stored in the tile of its first vertex and of every vertex's tile.
      std::map<tiles::TileKey, bool> keys;
      for (const auto& v : o.geometry_m) {
        const GeoPoint g = world.frame.to_geo(v);
        keys[tiles::tile_at(g.lat_deg, g.lon_deg, tiles::kLocalizationZoom)] = true;
      }
      for (const auto& [key, unused] : keys) {
        auto& t = out[key];
        t.key = key;
        t.map_version = 1;
        LineLandmark l;
        l.id = o.id;
        const tiles::LocalFrame tf(tiles::tile_center(key));
        for (const auto& v : o.geometry_m)
          l.polyline_m.push_back(tf.to_local(world.frame.to_geo(v)));
        t.lines.push_back(l);
      }
    }
  }
  for (auto& [k, t] : out) source.put(t);
}

/// Exact truth of either source, in the world frame of `frame`.
struct TruthPose {
  double x_m, y_m, yaw_rad, v_mps;
};

/// Linear interpolation in a reference trajectory (recording mode).
TruthPose interpolate(const std::vector<eval::ReferenceSample>& ref, const tiles::LocalFrame& frame,
                      double t) {
  auto it = std::lower_bound(ref.begin(), ref.end(), t,
                             [](const eval::ReferenceSample& s, double v) { return s.time_s < v; });
  if (it == ref.begin()) it = std::next(it);
  if (it == ref.end()) it = std::prev(it);
  const auto& a = *std::prev(it);
  const auto& b = *it;
  const double u = std::clamp((t - a.time_s) / std::max(b.time_s - a.time_s, 1e-9), 0.0, 1.0);
  const Eigen::Vector2d pa = frame.to_local(a.lat_deg, a.lon_deg);
  const Eigen::Vector2d pb = frame.to_local(b.lat_deg, b.lon_deg);
  const Eigen::Vector2d p = (1 - u) * pa + u * pb;
  const double yaw =
      a.yaw_enu_rad + u * wrap_angle_rad(b.yaw_enu_rad - a.yaw_enu_rad) + frame.convergence_rad(p);
  return {p.x(), p.y(), yaw, (1 - u) * a.speed_mps + u * b.speed_mps};
}

struct Stats {
  std::vector<double> e_long, e_lat, e_rot;
  void add(double lo, double la, double ro) {
    e_long.push_back(lo);
    e_lat.push_back(la);
    e_rot.push_back(ro);
  }
  static double rmse(const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x * x;
    return v.empty() ? 0.0 : std::sqrt(s / v.size());
  }
  static double maxabs(const std::vector<double>& v) {
    double m = 0;
    for (double x : v) m = std::max(m, std::abs(x));
    return m;
  }
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Localizer accuracy and cost on a simulated drive"};
  std::string world_name = "urban", map_kind = "oracle", recording, server;
  double length_m = 800.0, duration_s = 0.0, init_error_m = 3.0, init_error_deg = 3.0;
  std::uint64_t seed = 1;
  int drive = 0;
  bool json = false, verbose = false;
  app.add_option("--world", world_name, "urban | industrial | rural | FILE.osm | FILE.xodr");
  app.add_option("--length-m", length_m, "route length");
  app.add_option("--seed", seed, "world and drive seed");
  app.add_option("--drive", drive, "drive index");
  app.add_option("--duration-s", duration_s, "stop after this many seconds (0 = whole route)");
  app.add_option("--init-error-m", init_error_m, "initial position error");
  app.add_option("--init-error-deg", init_error_deg, "initial yaw error");
  app.add_option("--recording", recording, "replay a recording instead of simulating");
  app.add_option("--server", server, "mapping service URL (with --recording)");
  std::string realism = "realistic";
  app.add_option("--realism", realism,
                 "simulated drive's error sources: realistic (default) | ideal "
                 "(tools/sim/README.md)")
      ->check(CLI::IsMember({"ideal", "realistic"}));
  double slip_gradient_deg = -1.0;
  app.add_option("--slip-gradient-deg", slip_gradient_deg,
                 "the localizer's vehicle side-slip gradient, deg per m/s^2 (default: the "
                 "recording header's, else 0)");
  app.add_flag("--json", json, "one JSON document");
  app.add_flag("-v,--verbose", verbose, "one line per extraction");
  CLI11_PARSE(app, argc, argv);

  // Source of frames and truth: the simulator (oracle map) or a recording
  // (exact truth beside it, tiles from a server).
  std::unique_ptr<RecordSource> source;
  std::shared_ptr<const sim::World> world;
  const sim::DriveSimulator* simulator = nullptr;
  std::vector<eval::ReferenceSample> reference;
  std::optional<tiles::LocalFrame> frame;
  loc::InMemoryTileSource oracle;
  std::unique_ptr<loc::TileFetcher> fetcher;
  loc::TileSource* tiles_src = &oracle;
  if (!recording.empty()) {
    auto reader = std::make_unique<RecordingReader>(recording);
    frame.emplace(reader->header().origin);
    const std::filesystem::path rec(recording);
    reference = eval::reference_from_truth_csv(
        rec.parent_path() / "truth" / (rec.stem().string() + "_trajectory.csv"), {});
    source = std::move(reader);
    loc::TileFetcherConfig fcfg;
    fcfg.server_url = server;
    fetcher = std::make_unique<loc::TileFetcher>(fcfg);
    tiles_src = fetcher.get();
    map_kind = "server";
    world_name = recording;
  } else {
    sim::SimConfig scfg;
    scfg.seed = seed;
    scfg.duration_s = duration_s;
    scfg.realism = sim::realism_preset(realism);
    world = sim::load_world(world_name, length_m, seed, scfg);
    auto sim_source = std::make_unique<sim::DriveSimulator>(world, scfg, drive);
    simulator = sim_source.get();
    frame.emplace(world->frame);
    fill_oracle_tiles(*world, oracle);
    source = std::move(sim_source);
  }
  auto truth_at = [&](double t) -> TruthPose {
    if (simulator != nullptr) {
      const sim::ExactState s = simulator->plan().state(t);
      return {s.x_m, s.y_m, s.yaw_rad, s.v_mps};
    }
    return interpolate(reference, *frame, t);
  };

  loc::LocalizerConfig cfg;
  // The side-slip gradient is a vehicle parameter the localizer is given, like its mounts (the
  // recording declares it; the simulator writes the simulated car's nominal value).
  cfg.egomotion.side_slip_gradient_rad_per_mps2 =
      slip_gradient_deg >= 0.0 ? slip_gradient_deg * std::numbers::pi / 180.0
                               : source->header().side_slip_gradient_rad_per_mps2.value_or(0.0);
  loc::Localizer localizer(cfg, source->header().sensors, *tiles_src);

  // Initial pose: exact start + deliberate error.
  std::mt19937 rng(seed * 7 + drive);
  const double dir =
      std::uniform_real_distribution<double>(-std::numbers::pi, std::numbers::pi)(rng);
  const double sign = std::uniform_int_distribution<int>(0, 1)(rng) ? 1.0 : -1.0;
  const TruthPose s0 = truth_at(0.0);
  const Eigen::Vector2d p0 = Eigen::Vector2d(s0.x_m, s0.y_m) +
                             init_error_m * Eigen::Vector2d(std::cos(dir), std::sin(dir));
  GeoPose init;
  init.position = frame->to_geo(p0);
  init.yaw_enu_rad = s0.yaw_rad + sign * init_error_deg * kDeg - frame->convergence_rad(p0);
  if (fetcher) {
    const auto keys = loc::tiles_around(init.position, 150.0);
    fetcher->wait_for(keys, 15.0);
  }
  localizer.set_initial_pose(init, std::max(init_error_m, 0.5),
                             std::max(init_error_deg, 0.5) * kDeg);

  Stats stats;
  std::map<std::string, int> status_count;
  double first_track_s = -1.0, proc_sum = 0.0, proc_max = 0.0, extract_sum = 0.0, graph_sum = 0.0;
  int frames = 0, extractions = 0, graph_updates = 0;
  loc::StageCpuTimes stage_cpu;
  std::vector<double> frame_cpu_ms;
  double t_first = -1.0, t_last = 0.0;
  // Resident memory every 10 s of driving (the whole process: localizer, simulator
  // and oracle tiles): flat after the first minute is the client's requirement.
  std::vector<std::pair<double, double>> rss_mb;
  double next_rss_s = 0.0;
  while (auto rec = source->next()) {
    const auto* f = std::get_if<SensorFrame>(&*rec);
    if (f == nullptr) continue;  // the localizer never reads GNSS
    const auto out = localizer.process(*f);
    stage_cpu += out.cpu;
    frame_cpu_ms.push_back(1e3 * out.cpu.total_s);
    if (t_first < 0) t_first = f->time_s;
    t_last = f->time_s;
    if (t_last - t_first >= next_rss_s) {
      rss_mb.emplace_back(t_last - t_first, resident_mb());
      next_rss_s += 10.0;
    }
    ++frames;
    proc_sum += out.processing_time_s;
    proc_max = std::max(proc_max, out.processing_time_s);
    if (out.extracted) {
      ++extractions;
      extract_sum += out.processing_time_s;
    }
    if (out.graph_updated) {
      ++graph_updates;
      graph_sum += out.graph_update_time_s;
    }
    if (!out.extracted || !out.has_pose) continue;
    ++status_count[std::string(loc::to_string(out.status))];
    if (duration_s > 0 && f->time_s > duration_s) break;
    const TruthPose s = truth_at(f->time_s);
    const Eigen::Vector2d est = frame->to_local(out.pose.position);
    const double est_yaw = out.pose.yaw_enu_rad + frame->convergence_rad(est);
    const Eigen::Vector2d d =
        Pose2{0, 0, s.yaw_rad}.rotation().transpose() * (est - Eigen::Vector2d(s.x_m, s.y_m));
    const double e_rot = std::abs(wrap_angle_rad(est_yaw - s.yaw_rad));
    if (out.status == loc::LocalizationOutput::Status::Tracking && first_track_s < 0) {
      first_track_s = f->time_s;
    }
    const bool tracked = out.status == loc::LocalizationOutput::Status::Tracking ||
                         out.status == loc::LocalizationOutput::Status::Degraded;
    if (tracked && s.v_mps > 0.5) stats.add(d.x(), d.y(), e_rot);
    if (verbose) {
      std::printf(
          "t=%7.2f %-12s v=%5.2f long=%7.3f lat=%7.3f rot=%6.3f° sig=%.2f clusters=%3d map=%4d "
          "pts=%2d lines=%d/%d/%d maplines=%d match=%s cand=%d extract=%.0fms match=%.0fms "
          "graph=%.1fms\n",
          f->time_s, std::string(loc::to_string(out.status)).c_str(), s.v_mps, d.x(), d.y(),
          e_rot / kDeg, std::sqrt(out.covariance(0, 0) + out.covariance(1, 1)),
          out.local_point_clusters, out.map_points, out.matched_points, out.line_candidates,
          out.match_line_associations, out.matched_lines, out.map_lines,
          out.match_status ? std::string(loc::to_string(*out.match_status)).c_str() : "-",
          out.candidates, out.extraction_time_s * 1e3, out.matching_time_s * 1e3,
          out.graph_update_time_s * 1e3);
    }
  }
  nlohmann::json j;
  j["world"] = world_name;
  j["length_m"] = length_m;
  j["seed"] = seed;
  j["realism"] = recording.empty() ? realism : "recording";
  j["slip_gradient_deg"] = cfg.egomotion.side_slip_gradient_rad_per_mps2 * 180.0 / std::numbers::pi;
  j["drive"] = drive;
  j["map"] = map_kind;
  j["frames"] = frames;
  j["extractions"] = extractions;
  j["time_to_tracking_s"] = first_track_s;
  j["status_extractions"] = status_count;
  j["evaluated_extractions"] = stats.e_long.size();
  j["long_rmse_m"] = Stats::rmse(stats.e_long);
  j["long_max_m"] = Stats::maxabs(stats.e_long);
  j["lat_rmse_m"] = Stats::rmse(stats.e_lat);
  j["lat_max_m"] = Stats::maxabs(stats.e_lat);
  j["rot_rmse_deg"] = Stats::rmse(stats.e_rot) / kDeg;
  j["rot_max_deg"] = Stats::maxabs(stats.e_rot) / kDeg;
  j["mean_frame_ms"] = frames ? 1e3 * proc_sum / frames : 0.0;
  j["max_frame_ms"] = 1e3 * proc_max;
  j["mean_extraction_frame_ms"] = extractions ? 1e3 * extract_sum / extractions : 0.0;
  j["mean_graph_ms"] = graph_updates ? 1e3 * graph_sum / graph_updates : 0.0;
  // CPU time (the figures above are wall time): per frame and by stage, with the
  // fetcher's worker thread when tiles come over HTTP.
  std::sort(frame_cpu_ms.begin(), frame_cpu_ms.end());
  if (!frame_cpu_ms.empty()) {
    j["frame_cpu_p99_ms"] =
        frame_cpu_ms[static_cast<std::size_t>(0.99 * (frame_cpu_ms.size() - 1))];
    j["frame_cpu_max_ms"] = frame_cpu_ms.back();
  }
  if (!rss_mb.empty()) {
    double at_60 = rss_mb.front().second, max_after_60 = 0.0;
    for (const auto& [t, mb] : rss_mb) {
      if (t <= 60.0) at_60 = mb;
      if (t > 60.0) max_after_60 = std::max(max_after_60, mb);
    }
    j["rss_mb_at_60s"] = at_60;
    j["rss_mb_max_after_60s"] = max_after_60;
    j["rss_mb_end"] = rss_mb.back().second;
  }
  if (t_last > t_first) {
    j["stage_ms_per_s"] = eval::stage_budget_json(stage_cpu, t_last - t_first,
                                                  fetcher ? fetcher->stats().worker_cpu_s : 0.0);
  }
  if (json) {
    std::printf("%s\n", j.dump(2).c_str());
  } else {
    for (auto it = j.begin(); it != j.end(); ++it) {
      std::printf("%-26s %s\n", it.key().c_str(), it.value().dump().c_str());
    }
  }
  return 0;
}
