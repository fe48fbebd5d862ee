// Benchmark of the covariance gridmap (radar/covariance_gridmap.hpp): time per
// sensor frame in mapping mode (full history) and localization mode (sliding
// window), and of point/line extraction, on a drive of three default front
// sensors at 10 Hz each.
//
// --world urban|industrial|rural (default urban): frames from the simulator
// (tools/sim, generated before timing, poses exact); --world synthetic: the
// built-in generator below.
//
// Spectra (generated outside the timed region): 81 beams over ±60°, 1067 range
// bins (80 m), noise σ = 1, a 3σ storage floor like the simulator's; a static
// synthetic world of facades (±14/15 m, 2/3 of the length), curbs (±4 m) and
// poles (every ~6 m), dense speckled sub-scatterers, Gaussian point spread.
// Static: consecutive frames hit the same map cells, as in a real drive.
// Times are CPU time of the benchmark thread (the machine is shared).
//
//   bench_gridmap [--world urban] [--seconds 60] [--window-s 2] [--speed 10] [--level full]
#include <time.h>

#include <CLI/CLI.hpp>
#include <Eigen/Geometry>
#include <chrono>
#include <cstdio>
#include <map>
#include <numbers>
#include <random>

#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/radar/line_extractor.hpp"
#include "polmap/radar/point_extractor.hpp"
#include "polmap/schema/radar_spec.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/world.hpp"

using namespace polmap;
using namespace polmap::radar;

namespace {

constexpr int kBeams = 81;
constexpr int kBins = 1067;
constexpr double kDr = 0.075;

/// A static synthetic world along the drive: poles and walls on both sides.
struct World {
  std::vector<Eigen::Vector2d> points;
  std::vector<float> amplitude;  // at 10 m, noise σ = 1
};

Eigen::Vector2d path(double s) { return {s, 20.0 * std::sin(s * 0.005)}; }

World make_world(std::mt19937& rng, double length_m) {
  World w;
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (double s = -100.0; s < length_m + 100.0; s += 0.04) {
    const Eigen::Vector2d p = path(s);
    const Eigen::Vector2d d = (path(s + 0.01) - p).normalized();
    const Eigen::Vector2d n(-d.y(), d.x());
    // Walls/facades at ±14 m with gaps, curbs at ±4 m (weak), dense sub-scatterers.
    if (std::fmod(s, 60.0) < 40.0) {
      w.points.push_back(p + 14.0 * n);
      w.amplitude.push_back(8.0F);
      w.points.push_back(p - 15.0 * n);
      w.amplitude.push_back(8.0F);
    }
    w.points.push_back(p + 4.0 * n);
    w.amplitude.push_back(3.0F);
    w.points.push_back(p - 4.0 * n);
    w.amplitude.push_back(3.0F);
    // Poles every ~12 m.
    if (u(rng) < 0.04 / 12.0 * 2.0) {
      w.points.push_back(p + (u(rng) < 0.5 ? 1.0 : -1.0) * (5.0 + 6.0 * u(rng)) * n);
      w.amplitude.push_back(60.0F);
    }
  }
  return w;
}

PolSpectrum observe(const World& w, const Pose2& T_map_sensor, std::mt19937& rng,
                    std::vector<std::array<cfloat, 4>>& polar, std::vector<std::uint8_t>& on) {
  PolSpectrum s;
  s.range_bin_m = kDr;
  s.num_range_bins = kBins;
  s.noise_sigma = 1.0F;
  for (int k = 0; k < kBeams; ++k) {
    s.azimuth_bins_rad.push_back(static_cast<float>((-60.0 + 1.5 * k) * std::numbers::pi / 180.0));
  }
  polar.assign(kBeams * kBins, {});
  on.assign(kBeams * kBins, 0);
  const Pose2 inv = T_map_sensor.inverse();
  std::uniform_real_distribution<float> ph(0.0F, 6.2831853F);
  for (std::size_t i = 0; i < w.points.size(); ++i) {
    const Eigen::Vector2d v = inv * w.points[i];
    const double r = v.norm();
    if (r < 0.5 || r > 79.5) continue;
    const double az = std::atan2(v.y(), v.x()) * 180.0 / std::numbers::pi;
    if (std::abs(az) > 60.0) continue;
    const double fr = r / kDr, fa = (az + 60.0) / 1.5;
    const float a = static_cast<float>(w.amplitude[i] * 100.0 / (r * r));  // 40 log r in power
    const cfloat e = std::polar(a, ph(rng));
    for (int k = static_cast<int>(fa) - 1; k <= static_cast<int>(fa) + 2; ++k) {
      for (int b = static_cast<int>(fr) - 1; b <= static_cast<int>(fr) + 2; ++b) {
        if (k < 0 || k >= kBeams || b < 0 || b >= kBins) continue;
        const float g = static_cast<float>(
            std::exp(-0.5 * ((b - fr) * (b - fr) / 0.4 + (k - fa) * (k - fa) / 0.6)));
        auto& c = polar[k * kBins + b];
        c[1] += e * g;
        c[2] += e * g;
        on[k * kBins + b] = 1;
      }
    }
  }
  std::normal_distribution<float> n(0.0F, 0.70710678F);
  std::uniform_real_distribution<float> u(0.0F, 1.0F);
  for (int k = 0; k < kBeams; ++k) {
    for (int b = 0; b < kBins; ++b) {
      const int i = k * kBins + b;
      // Noise-only exceedances of the 3σ floor (P ≈ 5e-4 per bin) without drawing noise everywhere.
      if (!on[i] && u(rng) > 5e-4F) continue;
      auto c = polar[i];
      float peak = 0.0F;
      for (auto& x : c) {
        x += cfloat(n(rng), n(rng));
        peak = std::max(peak, std::norm(x));
      }
      if (on[i] && peak < 9.0F) continue;
      SpectrumCell sc;
      sc.azimuth_bin = static_cast<std::uint16_t>(k);
      sc.range_bin = static_cast<std::uint16_t>(b);
      sc.s = c;
      s.cells.push_back(sc);
    }
  }
  return s;
}

/// CPU time of this thread: the machine is shared, wall time would measure the neighbours.
double thread_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

struct Frame {
  PolSpectrum spectrum;
  Pose2 T_map_sensor;
  double time_s;
};

std::vector<Frame> synthetic_frames(double seconds, double speed_mps) {
  std::mt19937 rng(1);
  const World world = make_world(rng, speed_mps * seconds);
  std::vector<Frame> frames;
  std::vector<std::array<cfloat, 4>> polar;
  std::vector<std::uint8_t> on;
  const auto mounts = default_front_mounts();
  for (int cycle = 0; cycle < static_cast<int>(seconds * 10.0); ++cycle) {
    for (const auto& m : mounts) {
      const double t = cycle * 0.1 + m.trigger_offset_s;
      const double s = speed_mps * t;
      const Eigen::Vector2d p = path(s), d = path(s + 0.01) - p;
      const Pose2 T_map_vehicle{p.x(), p.y(), std::atan2(d.y(), d.x())};
      const Pose2 T_map_sensor = T_map_vehicle * m.T_vehicle_sensor;
      frames.push_back({observe(world, T_map_sensor, rng, polar, on), T_map_sensor, t});
    }
  }
  return frames;
}

/// Frames of a simulated drive with exact poses (the drive frame = world frame).
std::vector<Frame> simulated_frames(const std::string& preset, double seconds) {
  sim::SimConfig cfg;
  cfg.duration_s = seconds;
  sim::WorldSpec spec;
  spec.preset = preset;
  spec.length_m = 20.0 * seconds + 200.0;
  auto world = sim::make_world(spec, cfg);
  sim::DriveSimulator drive(world, cfg, 0);
  std::map<std::uint8_t, Pose2> mounts;
  for (const auto& m : drive.header().sensors) mounts[m.sensor_id] = m.T_vehicle_sensor;
  std::vector<Frame> frames;
  while (auto rec = drive.next()) {
    if (auto* f = std::get_if<SensorFrame>(&*rec)) {
      const sim::ExactState st = drive.plan().state(f->time_s);
      const Pose2 T_map_vehicle{st.x_m, st.y_m, st.yaw_rad};
      frames.push_back({std::move(f->spectrum), T_map_vehicle * mounts[f->sensor_id], f->time_s});
    }
  }
  return frames;
}

struct Result {
  double ms_per_frame;
  double max_ms;
  std::size_t tiles;
  std::size_t bytes;
  double points_ms;
  double lines_ms;
  std::size_t points;
  std::size_t lines;
};

Result run(const std::vector<Frame>& frames, const GridmapConfig& cfg) {
  CovarianceGridmap map(cfg);
  double total_ms = 0.0, max_ms = 0.0;
  for (const Frame& f : frames) {
    const double t0 = thread_cpu_ms();
    map.add(f.spectrum, f.T_map_sensor, f.time_s);
    const double ms = thread_cpu_ms() - t0;
    total_ms += ms;
    max_ms = std::max(max_ms, ms);
  }
  Result r{total_ms / frames.size(), max_ms, map.num_tiles(), map.memory_bytes(), 0, 0, 0, 0};
  double t0 = thread_cpu_ms();
  r.points = extract_points(map).size();
  r.points_ms = thread_cpu_ms() - t0;
  t0 = thread_cpu_ms();
  r.lines = extract_lines(map).size();
  r.lines_ms = thread_cpu_ms() - t0;
  return r;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"covariance gridmap benchmark"};
  double seconds = 60.0, window_s = 2.0, speed = 10.0;
  std::string level_name = "full", world = "urban";
  app.add_option("--world", world, "urban | industrial | rural (simulator) | synthetic");
  app.add_option("--seconds", seconds, "drive length");
  app.add_option("--window-s", window_s, "localization window");
  app.add_option("--speed", speed, "vehicle speed of the synthetic drive, m/s");
  app.add_option("--level", level_name, "polarimetric level");
  CLI11_PARSE(app, argc, argv);
  const auto level = parse_pol_level(level_name);
  if (!level) {
    std::fprintf(stderr, "unknown level %s\n", level_name.c_str());
    return 2;
  }
  const std::vector<Frame> frames =
      world == "synthetic" ? synthetic_frames(seconds, speed) : simulated_frames(world, seconds);
  double bins = 0.0, dist = 0.0;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    bins += frames[i].spectrum.cells.size();
    if (i >= 3)
      dist +=
          (frames[i].T_map_sensor.translation() - frames[i - 3].T_map_sensor.translation()).norm() /
          3.0;
  }
  std::printf(
      "%s drive: %zu sensor frames (%.0f s, ~%.0f m), %.0f stored bins per frame (of %d), "
      "level %s, cell 0.1 m; CPU time of this thread\n",
      world.c_str(), frames.size(), frames.size() / 30.0, dist, bins / frames.size(),
      kBeams * kBins, level_name.c_str());

  GridmapConfig map_cfg;
  map_cfg.level = *level;
  const Result m = run(frames, map_cfg);
  std::printf(
      "mapping      : %.3f ms/sensor frame (max %.2f) -> 10-min drive (18000 frames) %.1f s; "
      "%zu tiles, %.1f MB; extraction: points %.0f ms (%zu), lines %.0f ms (%zu)\n",
      m.ms_per_frame, m.max_ms, m.ms_per_frame * 18.0, m.tiles, m.bytes / 1e6, m.points_ms,
      m.points, m.lines_ms, m.lines);

  GridmapConfig loc_cfg;
  loc_cfg.level = *level;
  loc_cfg.window_s = window_s;
  const Result l = run(frames, loc_cfg);
  std::printf(
      "localization : %.3f ms/sensor frame incl. expiry (max %.2f) = %.2f ms per "
      "three-sensor cycle, window %.1f s, %zu tiles, %.1f MB; extraction on the last "
      "window: points %.0f ms (%zu), lines %.0f ms (%zu)\n",
      l.ms_per_frame, l.max_ms, 3.0 * l.ms_per_frame, window_s, l.tiles, l.bytes / 1e6, l.points_ms,
      l.points, l.lines_ms, l.lines);
  return 0;
}
