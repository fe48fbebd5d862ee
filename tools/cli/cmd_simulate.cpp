// `polmap simulate --world urban|industrial|rural|FILE.osm|FILE.xodr [--length-m L]
//  [--drives N] [--seed S] [--max-speed-mps V] [--duration-s T] [--cube]
//  [--cube-seconds T] [--realism realistic|ideal] [--realism-sources LIST]
//  [--gnss rtk|consumer [--rtk-drives N]] --out DIR
//  [--dry-run]`: simulates N passes over one world and
// writes DIR/drive_<k>.pmrec plus the evaluation truth DIR/truth/world.json and
// DIR/truth/drive_<k>_trajectory.csv and drive_<k>_calibration.json (true mounts and
// sensor time offsets; tools/sim/README.md).
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <string>

#include "command.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/schema/recording_io.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/realism.hpp"
#include "polmap/sim/truth.hpp"
#include "polmap/sim/world.hpp"
#include "progress.hpp"

namespace polmap::cli {
namespace {

struct SimulateOptions {
  std::string world;
  double length_m = 1000.0;
  int drives = 1;
  std::uint64_t seed = 1;
  double max_speed_mps = 0.0;
  double duration_s = 0.0;
  bool cube = false;
  double cube_seconds = 0.5;
  std::string out;
  bool dry_run = false;
  std::string realism = "realistic";
  std::string realism_sources;
  std::string gnss = "rtk";
  int rtk_drives = 0;
};

struct DriveSummary {
  int drive = 0;
  std::uint64_t frames = 0, trajectory_samples = 0, cells = 0, detections = 0;
  double duration_s = 0, distance_m = 0, v_min = 0, v_max = 0, bytes = 0, wall_s = 0;
};

void run(const SimulateOptions& o) {
  if (o.drives < 1 || o.drives > 1000) {
    throw ValidationError("simulate: --drives must be within 1..1000, got " +
                          std::to_string(o.drives));
  }
  if (!(o.length_m > 0)) throw ValidationError("simulate: --length-m must be > 0");
  if (o.max_speed_mps < 0 || o.max_speed_mps > 40) {
    throw ValidationError("simulate: --max-speed-mps must be within 0..40 (0 = preset default)");
  }
  if (o.duration_s < 0 || o.cube_seconds < 0) {
    throw ValidationError("simulate: --duration-s and --cube-seconds must be >= 0");
  }
  sim::SimConfig cfg;
  cfg.seed = o.seed;
  cfg.drive.max_speed_mps = o.max_speed_mps;
  cfg.duration_s = o.duration_s;
  cfg.cube = o.cube;
  cfg.cube_seconds = o.cube_seconds;
  cfg.realism = sim::realism_preset(o.realism);
  if (!o.realism_sources.empty()) {
    if (o.realism != "realistic") {
      throw ValidationError("simulate: --realism-sources needs --realism realistic");
    }
    cfg.realism = sim::only_sources(cfg.realism, o.realism_sources);
  }

  cfg.gnss.grade = o.gnss == "consumer" ? sim::GnssGrade::Consumer : sim::GnssGrade::Rtk;
  if (o.rtk_drives < 0 || (o.rtk_drives > 0 && o.gnss != "consumer")) {
    throw ValidationError("simulate: --rtk-drives N (N >= 0) needs --gnss consumer");
  }

  const std::filesystem::path dir(o.out);
  if (!o.dry_run) {
    std::error_code ec;
    std::filesystem::create_directories(dir, ec);
    if (ec)
      throw IoError("simulate: cannot create output directory " + dir.string() + ": " +
                    ec.message());
  }
  std::shared_ptr<const sim::World> world = sim::load_world(o.world, o.length_m, o.seed, cfg);
  std::fprintf(stderr, "world %s: route %.0f m, %zu objects, %zu point and %zu line scatterers\n",
               world->name.c_str(), world->route.length_m(), world->objects.size(),
               world->points.size(), world->lines.size());
  if (!o.dry_run) sim::write_world_truth(dir, *world, o.drives, o.seed);

  std::vector<DriveSummary> summaries;
  for (int k = 0; k < o.drives; ++k) {
    sim::SimConfig drive_cfg = cfg;
    if (k < o.rtk_drives) drive_cfg.gnss.grade = sim::GnssGrade::Rtk;  // survey-grade anchors
    sim::DriveSimulator simulator(world, drive_cfg, k);
    DriveSummary s;
    s.drive = k;
    s.duration_s = simulator.duration_s();
    s.distance_m = simulator.plan().distance_m();
    const std::string name = "drive_" + std::to_string(k);
    std::unique_ptr<RecordingWriter> writer;
    if (!o.dry_run)
      writer = std::make_unique<RecordingWriter>(dir / (name + ".pmrec"), simulator.header());
    Progress progress("simulate " + name, s.duration_s);
    const auto t0 = std::chrono::steady_clock::now();
    s.v_min = std::numeric_limits<double>::max();
    while (auto rec = simulator.next()) {
      if (const auto* t = std::get_if<TrajectorySample>(&*rec)) {
        ++s.trajectory_samples;
        if (writer) writer->write(*t);
      } else {
        const auto& f = std::get<SensorFrame>(*rec);
        ++s.frames;
        s.cells += f.spectrum.cells.size();
        s.detections += f.detections.size();
        if (writer) writer->write(f);
      }
      progress.update(simulator.time_s(), name);
    }
    if (writer) {
      writer->close();
      s.bytes = static_cast<double>(writer->bytes_written());
    }
    s.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    progress.finish();
    const auto exact = simulator.exact_trajectory();
    for (const auto& e : exact) {
      s.v_min = std::min(s.v_min, e.v_mps);
      s.v_max = std::max(s.v_max, e.v_mps);
    }
    if (exact.empty()) s.v_min = 0;
    if (!o.dry_run) {
      sim::write_trajectory_csv(dir / "truth" / (name + "_trajectory.csv"), exact, world->frame);
      sim::write_calibration_truth(dir / "truth" / (name + "_calibration.json"),
                                   simulator.header().sensors, simulator.true_mounts(),
                                   simulator.time_offsets_s());
    }
    summaries.push_back(s);
  }

  const std::string realism =
      o.realism + (o.realism_sources.empty() ? "" : " (" + o.realism_sources + ")");
  const std::string gnss =
      o.gnss + (o.rtk_drives > 0 ? " (first " + std::to_string(o.rtk_drives) + " rtk)" : "");
  std::printf("world: %s (%s), route %.0f m, %zu objects, seed %llu, realism %s, gnss %s%s\n",
              world->name.c_str(), o.world.c_str(), world->route.length_m(), world->objects.size(),
              static_cast<unsigned long long>(o.seed), realism.c_str(), gnss.c_str(),
              o.dry_run ? ", dry run (nothing written)" : "");
  std::printf("%-8s %7s %9s %9s %13s %9s %9s %11s %10s %9s\n", "drive", "frames", "duration",
              "distance", "speed m/s", "cells/fr", "dets/fr", "file MB", "MB/min", "sim s/s");
  for (const auto& s : summaries) {
    const double minutes = s.duration_s / 60.0;
    std::printf("drive_%-2d %7llu %8.1fs %8.0fm %6.1f..%-6.1f %9.0f %9.0f %11.2f %10.2f %9.1f\n",
                s.drive, static_cast<unsigned long long>(s.frames), s.duration_s, s.distance_m,
                s.v_min, s.v_max, s.frames ? double(s.cells) / s.frames : 0.0,
                s.frames ? double(s.detections) / s.frames : 0.0, s.bytes / 1e6,
                minutes > 0 ? s.bytes / 1e6 / minutes : 0.0,
                s.wall_s > 0 ? s.duration_s / s.wall_s : 0.0);
  }
  if (!o.dry_run) {
    std::printf(
        "written: %s/drive_<k>.pmrec, %s/truth/world.json, "
        "%s/truth/drive_<k>_{trajectory.csv,calibration.json}\n",
        o.out.c_str(), o.out.c_str(), o.out.c_str());
  }
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<SimulateOptions>();
  auto* cmd = app.add_subcommand(
      "simulate", "Simulate polarimetric radar drives through a world (recordings + truth)");
  cmd->add_option("--world", opts->world,
                  "urban | industrial | rural | FILE.osm (Lanelet2) | FILE.xodr (OpenDRIVE)")
      ->required();
  cmd->add_option("--length-m", opts->length_m,
                  "route length (procedural worlds; HD maps: upper bound)")
      ->capture_default_str();
  cmd->add_option("--drives", opts->drives, "passes over the same route")->capture_default_str();
  cmd->add_option("--seed", opts->seed, "seed (same seed -> byte-identical output)")
      ->capture_default_str();
  cmd->add_option("--max-speed-mps", opts->max_speed_mps,
                  "ego speed limit (0 = preset default: 15 urban, 20 rural)")
      ->capture_default_str();
  cmd->add_option("--duration-s", opts->duration_s,
                  "stop each drive after T seconds (0 = whole route)")
      ->capture_default_str();
  cmd->add_flag("--cube", opts->cube, "attach full data cubes to the first --cube-seconds");
  cmd->add_option("--cube-seconds", opts->cube_seconds, "length of the cube sequence")
      ->capture_default_str();
  cmd->add_option("--realism", opts->realism,
                  "realistic (the error sources of tools/sim/README.md \"Realism\" all on) | "
                  "ideal (exact sensors: unit tests, and comparisons with earlier figures)")
      ->check(CLI::IsMember({"ideal", "realistic"}))
      ->capture_default_str();
  cmd->add_option("--realism-sources", opts->realism_sources,
                  "with --realism realistic: keep only these sources on, comma separated "
                  "(noise,mounts,timing,slip,multipath,elevation,ins)");
  cmd->add_option("--gnss", opts->gnss,
                  "positioning of the recorded trajectory: rtk (survey-grade GNSS/IMU, cm) | "
                  "consumer (a series car: metre-level slowly varying bias, outages, canyon "
                  "multipath that repeats at the same places)")
      ->check(CLI::IsMember({"rtk", "consumer"}))
      ->capture_default_str();
  cmd->add_option("--rtk-drives", opts->rtk_drives,
                  "with --gnss consumer: the first N drives are survey-grade (map anchors)")
      ->capture_default_str();
  cmd->add_option("--out", opts->out, "output directory")->required();
  cmd->add_flag("--dry-run", opts->dry_run, "simulate without writing (speed measurement)");
  cmd->callback([opts] { run(*opts); });
}

}  // namespace

POLMAP_REGISTER_COMMAND(simulate, setup);

}  // namespace polmap::cli
