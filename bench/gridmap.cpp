// Benchmark of the covariance gridmap (radar/covariance_gridmap.hpp): time per
// sensor frame in mapping mode (full history) and localization mode (sliding
// window), on a synthetic drive of three default front sensors at 10 Hz each.
//
// Spectra (generated outside the timed region): 81 beams over ±60°, 1067 range
// bins (80 m), noise σ = 1, a 3σ storage floor like the simulator's; a static
// synthetic world of facades (±14/15 m, 2/3 of the length), curbs (±4 m) and
// poles (every ~6 m), dense speckled sub-scatterers, Gaussian point spread.
// Static: consecutive frames hit the same map cells, as in a real drive.
// Times are CPU time of the benchmark thread (the machine is shared).
//
//   bench_gridmap [--seconds 60] [--window-s 2] [--speed 10] [--level full]
#include <CLI/CLI.hpp>
#include <time.h>

#include <chrono>
#include <cstdio>
#include <numbers>
#include <random>

#include <Eigen/Geometry>

#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/schema/radar_spec.hpp"

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
        const float g = static_cast<float>(std::exp(-0.5 * ((b - fr) * (b - fr) / 0.4 +
                                                            (k - fa) * (k - fa) / 0.6)));
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

struct Result {
  double ms_per_frame;
  double max_ms;
  double bins_per_frame;
  std::size_t tiles;
  std::size_t bytes;
};

Result run(const World& world, const GridmapConfig& cfg, double seconds, double speed_mps) {
  CovarianceGridmap map(cfg);
  const auto mounts = default_front_mounts();
  const int cycles = static_cast<int>(seconds * 10.0);
  double total_ms = 0.0, max_ms = 0.0, bins = 0.0;
  std::mt19937 rng(3);
  std::vector<std::array<cfloat, 4>> polar;
  std::vector<std::uint8_t> on;
  for (int cycle = 0; cycle < cycles; ++cycle) {
    for (const auto& m : mounts) {
      const double t = cycle * 0.1 + m.trigger_offset_s;
      const double s = speed_mps * t;
      const Eigen::Vector2d p = path(s), d = path(s + 0.01) - p;
      const Pose2 T_map_vehicle{p.x(), p.y(), std::atan2(d.y(), d.x())};
      const Pose2 T_map_sensor = T_map_vehicle * m.T_vehicle_sensor;
      const PolSpectrum spectrum = observe(world, T_map_sensor, rng, polar, on);
      bins += spectrum.cells.size();
      const double t0 = thread_cpu_ms();
      map.add(spectrum, T_map_sensor, t);
      const double ms = thread_cpu_ms() - t0;
      total_ms += ms;
      max_ms = std::max(max_ms, ms);
    }
  }
  const double frames = cycles * 3.0;
  return {total_ms / frames, max_ms, bins / frames, map.num_tiles(), map.memory_bytes()};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"covariance gridmap benchmark"};
  double seconds = 60.0, window_s = 2.0, speed = 10.0;
  std::string level_name = "full";
  app.add_option("--seconds", seconds, "simulated drive length (mapping mode)");
  app.add_option("--window-s", window_s, "localization window");
  app.add_option("--speed", speed, "vehicle speed, m/s");
  app.add_option("--level", level_name, "polarimetric level");
  CLI11_PARSE(app, argc, argv);
  const auto level = parse_pol_level(level_name);
  if (!level) {
    std::fprintf(stderr, "unknown level %s\n", level_name.c_str());
    return 2;
  }
  std::mt19937 rng(1);
  const World world = make_world(rng, speed * seconds);

  GridmapConfig map_cfg;
  map_cfg.level = *level;
  const Result m = run(world, map_cfg, seconds, speed);
  std::printf("stored bins per sensor frame: %.0f (of %d), level %s, cell 0.1 m, %.0f m/s\n",
              m.bins_per_frame, kBeams * kBins, level_name.c_str(), speed);
  std::printf("mapping      : %.3f ms/sensor frame (max %.2f), %zu tiles, %.1f MB after %.0f s "
              "-> 10-min drive (18000 frames) = %.1f s\n",
              m.ms_per_frame, m.max_ms, m.tiles, m.bytes / 1e6, seconds, m.ms_per_frame * 18.0);

  GridmapConfig loc_cfg;
  loc_cfg.level = *level;
  loc_cfg.window_s = window_s;
  const Result l = run(world, loc_cfg, std::min(seconds, 30.0), speed);
  std::printf("localization : %.3f ms/sensor frame incl. expiry (max %.2f) = %.2f ms per "
              "three-sensor cycle, window %.1f s, %zu tiles, %.1f MB\n",
              l.ms_per_frame, l.max_ms, 3.0 * l.ms_per_frame, window_s, l.tiles, l.bytes / 1e6);
  return 0;
}
