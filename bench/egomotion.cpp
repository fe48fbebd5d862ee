// bench_egomotion: accuracy and per-frame cost of the radar ego-motion
// estimator and odometry.
//
//   bench_egomotion DIR_OR_RECORDING...   simulated drives (`polmap simulate --out DIR`):
//                                         every DIR/drive_*.pmrec with its exact truth
//                                         DIR/truth/drive_<k>_trajectory.csv
//   bench_egomotion --synthetic [--seed S] a built-in kinematic drive (no simulator needed):
//                                         point scatterers beside a curved road, moving
//                                         cars, a truck ahead, stops, ±2.5 m/s²
//
// Prints per drive: velocity / yaw-rate RMSE, median, max, bias, drift (mean
// relative position error over 100 m sub-paths and end point), estimate
// statuses and compute time per frame (mean, p95, max); --json for one JSON
// document. Targets (task): v RMSE ≤ 0.05 m/s, yaw-rate RMSE ≤ 0.2 °/s, drift ≤ 1 %.
#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "polmap/eval/egomotion_eval.hpp"
#include "polmap/schema/recording_io.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace fs = std::filesystem;
using namespace polmap;

namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

// ------------------------------------------------------------ synthetic drive

struct SynthState {
  double t, x, y, yaw, v, w;
};

/// Smooth (jerk-limited) acceleration profile: phases of constant target
/// acceleration, blended over 0.5 s.
double accel_at(double t) {
  struct Phase {
    double until_s, a;
  };
  static const Phase phases[] = {{1, 0},    {7, 2.5},   {17, 0},    {20, -3.0}, {25, 0},
                                 {29.5, 2}, {40, 0},    {46, -2.5}, {48, 0},    {53, 2.0},
                                 {63, 0},   {66, -1.5}, {75, 0}};
  auto raw = [&](double tt) {
    for (const auto& p : phases) {
      if (tt < p.until_s) return p.a;
    }
    return 0.0;
  };
  // Moving average over 0.5 s (analytic enough at 10 ms resolution).
  double s = 0;
  for (int k = 0; k < 50; ++k) s += raw(t - 0.25 + 0.01 * k);
  return s / 50.0;
}

struct SynthDrive {
  std::vector<SensorFrame> frames;
  eval::MotionTruth truth;
};

SynthDrive make_synthetic_drive(std::uint64_t seed, double duration_s) {
  std::mt19937_64 rng(seed);
  const auto mounts = default_front_mounts();
  // Integrate the truth at 1 ms; keep 100 Hz samples and states at frame times.
  const double dt = 0.001;
  std::vector<SynthState> states;
  SynthState s{0, 0, 0, 0, 0, 0};
  double dist = 0;
  for (int k = 0; s.t <= duration_s + 8.0; ++k) {  // beyond the end: scenery ahead
    const double kappa = 0.008 * std::sin(2 * std::numbers::pi * dist / 200.0) +
                         0.03 * std::exp(-std::pow((dist - 300.0) / 15.0, 2));  // one sharp bend
    s.w = s.v * kappa;
    if (k % 10 == 0) states.push_back(s);
    const Pose2 step = integrate_motion(s.v, s.w, dt);
    const Pose2 T = Pose2{s.x, s.y, s.yaw} * step;
    s.x = T.x_m;
    s.y = T.y_m;
    s.yaw = T.yaw_rad;
    dist += s.v * dt;
    s.v = std::max(0.0, s.v + accel_at(s.t) * dt);
    s.t += dt;
  }
  std::vector<eval::MotionTruthSample> ts;
  for (const auto& st : states) ts.push_back({st.t, st.v, st.w, Pose2{st.x, st.y, st.yaw}});
  SynthDrive drive;
  drive.truth = eval::MotionTruth(ts, true);

  // Static scatterers: both road sides (2-25 m out) plus a sparse field.
  std::vector<Eigen::Vector2d> statics;
  std::uniform_real_distribution<double> u01(0, 1);
  for (std::size_t k = 0; k + 1 < states.size(); k += 5) {  // every 50 ms of driving
    const auto& st = states[k];
    const double ds = st.v * 0.05;
    const int n = std::poisson_distribution<int>(1.2 * ds + 0.02)(rng);
    for (int i = 0; i < n; ++i) {
      const double side = u01(rng) < 0.5 ? -1 : 1;
      const double off = side * (2.5 + 22.5 * u01(rng) * u01(rng));
      statics.push_back({st.x - off * std::sin(st.yaw), st.y + off * std::cos(st.yaw)});
    }
  }
  // Extend ahead of the start / end so the field of view is never empty.
  for (int i = 0; i < 400; ++i) {
    statics.push_back({-20.0 + 120.0 * u01(rng), -30.0 + 60.0 * u01(rng)});
  }
  // Moving cars: oncoming (lane +3.5 m) and same direction (lane −3.5 m), each
  // defined by a path offset and speed; a truck ahead in our lane 10-60 s.
  struct Car {
    double s0, speed, lateral, length;
    int points;
  };
  std::vector<Car> cars;
  for (int i = 0; i < 40; ++i) {
    const bool oncoming = i % 2 == 0;
    cars.push_back({800.0 * u01(rng), (oncoming ? -1 : 1) * (6 + 8 * u01(rng)),
                    oncoming ? 3.5 : -3.5, 4.5, 6});
  }
  // Path lookup by distance for moving objects (world position on the ego path).
  std::vector<double> path_s(states.size(), 0);
  for (std::size_t k = 1; k < states.size(); ++k) {
    path_s[k] =
        path_s[k - 1] + std::hypot(states[k].x - states[k - 1].x, states[k].y - states[k - 1].y);
  }
  auto path_at = [&](double sq, Eigen::Vector2d& p, double& yaw) {
    if (sq <= 0 || path_s.back() <= 0) {
      p = {sq, 0};
      yaw = 0;
      return;
    }
    auto it = std::lower_bound(path_s.begin(), path_s.end(), sq);
    if (it == path_s.end()) it = std::prev(it);
    const auto& st = states[it - path_s.begin()];
    p = {st.x, st.y};
    yaw = st.yaw;
    if (sq > path_s.back())
      p += (sq - path_s.back()) * Eigen::Vector2d(std::cos(yaw), std::sin(yaw));
  };

  std::normal_distribution<double> n_vr(0, 0.05), n_az(0, 0.5 * kDeg), n_r(0, 0.03);
  for (int cycle = 0; 0.1 * cycle + 0.07 < duration_s; ++cycle) {
    for (const SensorMount& m : mounts) {
      const double t = 0.1 * cycle + m.trigger_offset_s;
      const auto tr = drive.truth.at(t);
      if (!tr) continue;
      const Pose2 T_w_s = tr->T_frame_vehicle * m.T_vehicle_sensor;
      // Sensor velocity in the world frame: v·x̂ + ω ẑ × r (vehicle frame), rotated.
      const Eigen::Vector2d v_s_vehicle(tr->v_mps - tr->yaw_rate_rps * m.T_vehicle_sensor.y_m,
                                        tr->yaw_rate_rps * m.T_vehicle_sensor.x_m);
      const Eigen::Vector2d v_s = tr->T_frame_vehicle.rotation() * v_s_vehicle;
      const Pose2 T_s_w = T_w_s.inverse();
      SensorFrame f;
      f.sensor_id = m.sensor_id;
      f.time_s = t;
      f.cycle_index = static_cast<std::uint32_t>(cycle);
      auto emit = [&](const Eigen::Vector2d& p_w, const Eigen::Vector2d& v_target, double pd) {
        const Eigen::Vector2d p_s = T_s_w * p_w;
        const double r = p_s.norm();
        const double az = std::atan2(p_s.y(), p_s.x());
        if (r < 1.0 || r > 80.0 || std::abs(az) > 60 * kDeg || u01(rng) > pd) return;
        const Eigen::Vector2d u = (p_w - T_w_s.translation()) / r;
        const double vr = (v_target - v_s).dot(u) + n_vr(rng);
        const double vua = m.spec.v_unambiguous_mps;
        Detection d;
        d.range_m = static_cast<float>(r + n_r(rng));
        d.azimuth_rad = static_cast<float>(az + n_az(rng));
        d.radial_velocity_mps =
            static_cast<float>(vr - 2 * vua * std::floor((vr + vua) / (2 * vua)));
        d.snr_db = static_cast<float>(12 + 20 * u01(rng));
        f.detections.push_back(d);
      };
      for (const auto& p : statics) emit(p, Eigen::Vector2d::Zero(), 0.6);
      const double s_ego = [&] {
        auto it = std::lower_bound(states.begin(), states.end(), t,
                                   [](const SynthState& a, double tt) { return a.t < tt; });
        return path_s[std::min<std::size_t>(it - states.begin(), path_s.size() - 1)];
      }();
      for (const Car& c : cars) {
        const double sc = c.s0 + c.speed * t;
        if (std::abs(sc - s_ego) > 90) continue;
        Eigen::Vector2d p;
        double yaw = 0;
        path_at(sc, p, yaw);
        const Eigen::Vector2d dir(std::cos(yaw), std::sin(yaw)),
            left(-std::sin(yaw), std::cos(yaw));
        for (int i = 0; i < c.points; ++i) {
          emit(p + c.lateral * left + (u01(rng) - 0.5) * c.length * dir +
                   (u01(rng) - 0.5) * 1.8 * left,
               c.speed * dir, 0.8);
        }
      }
      if (t > 10 && t < 60) {  // truck 15-25 m ahead in our lane at 80 % of our speed
        const double gap = 20 + 5 * std::sin(0.3 * t);
        Eigen::Vector2d p;
        double yaw = 0;
        path_at(s_ego + gap, p, yaw);
        const Eigen::Vector2d dir(std::cos(yaw), std::sin(yaw)),
            left(-std::sin(yaw), std::cos(yaw));
        for (int i = 0; i < 40; ++i) {
          emit(p + (u01(rng) - 0.5) * 2.5 * left + u01(rng) * 1.0 * dir, 0.8 * tr->v_mps * dir,
               0.9);
        }
      }
      const int n_fa = std::poisson_distribution<int>(2.0)(rng);
      for (int i = 0; i < n_fa; ++i) {
        f.detections.push_back({static_cast<float>(80 * u01(rng)),
                                static_cast<float>((u01(rng) - 0.5) * 120 * kDeg),
                                static_cast<float>(10 * u01(rng) - 5), 12.0F});
      }
      drive.frames.push_back(std::move(f));
    }
  }
  return drive;
}

// ------------------------------------------------------------ reporting

void print_metrics(const std::string& name, const eval::EgoMotionMetrics& m) {
  std::printf("%s\n", name.c_str());
  std::printf("  frames %d: ok %d, rejected %d, too few %d; compared %d\n", m.frames,
              m.estimates_ok, m.estimates_rejected, m.estimates_too_few, m.compared);
  std::printf("  v:        RMSE %.4f m/s  median %.4f  max %.4f  bias %+.4f\n", m.v_rmse_mps,
              m.v_median_err_mps, m.v_max_err_mps, m.v_bias_mps);
  std::printf("  yaw rate: RMSE %.4f deg/s  median %.4f  max %.4f  bias %+.4f\n",
              m.yaw_rate_rmse_dps, m.yaw_rate_median_err_dps, m.yaw_rate_max_err_dps,
              m.yaw_rate_bias_dps);
  std::printf(
      "  drift:    %s %% (mean over %d sub-paths of 100 m), end point %s %% over %.1f m; "
      "heading %s deg/100 m\n",
      m.drift_segment_pct ? std::to_string(*m.drift_segment_pct).c_str() : "n/a", m.drift_segments,
      m.drift_endpoint_pct ? std::to_string(*m.drift_endpoint_pct).c_str() : "n/a", m.distance_m,
      m.heading_drift_deg_per_100m ? std::to_string(*m.heading_drift_deg_per_100m).c_str() : "n/a");
  std::printf("  compute:  %.3f ms/frame mean, %.3f p95, %.3f max\n", m.compute_mean_ms,
              m.compute_p95_ms, m.compute_max_ms);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"bench_egomotion: radar ego-motion accuracy and per-frame cost"};
  std::vector<std::string> inputs;
  bool synthetic = false, json = false;
  std::uint64_t seed = 1;
  double duration_s = 75.0;
  radar::EgoMotionConfig cfg;
  app.add_option("inputs", inputs, "simulation output directories or .pmrec recordings");
  app.add_flag("--synthetic", synthetic, "run the built-in kinematic drive");
  app.add_option("--seed", seed, "seed of the synthetic drive")->capture_default_str();
  app.add_option("--duration-s", duration_s, "length of the synthetic drive")
      ->capture_default_str();
  app.add_option("--combine-window-s", cfg.combine_window_s)->capture_default_str();
  app.add_option("--accel-window-s", cfg.accel_window_s)->capture_default_str();
  app.add_option("--inlier-threshold-mps", cfg.inlier_threshold_mps)->capture_default_str();
  app.add_option("--accel-uncertainty-mps2", cfg.accel_uncertainty_mps2)->capture_default_str();
  app.add_option("--yaw-accel-uncertainty-rps2", cfg.yaw_accel_uncertainty_rps2)
      ->capture_default_str();
  app.add_flag("--json", json, "print one JSON document");
  std::string out_csv;
  app.add_option("--out", out_csv,
                 "per-estimate CSV of the synthetic drive (or the last recording)");
  CLI11_PARSE(app, argc, argv);

  nlohmann::json out = nlohmann::json::array();
  try {
    if (synthetic) {
      const SynthDrive drive = make_synthetic_drive(seed, duration_s);
      eval::EgoMotionRunner runner(default_front_mounts(), cfg);
      for (const auto& f : drive.frames) runner.process(f);
      const auto m = eval::evaluate_egomotion(runner.records(), drive.truth);
      if (!out_csv.empty()) eval::write_egomotion_csv(out_csv, runner.records(), drive.truth);
      const std::string name = "synthetic seed=" + std::to_string(seed);
      if (json) {
        auto j = eval::to_json(m);
        j["input"] = name;
        out.push_back(j);
      } else {
        print_metrics(name, m);
      }
    }
    std::vector<fs::path> recordings;
    for (const auto& in : inputs) {
      if (fs::is_directory(in)) {
        for (const auto& e : fs::directory_iterator(in)) {
          if (e.path().extension() == ".pmrec") recordings.push_back(e.path());
        }
      } else {
        recordings.emplace_back(in);
      }
    }
    std::sort(recordings.begin(), recordings.end());
    for (const fs::path& rec : recordings) {
      RecordingReader reader(rec);
      eval::EgoMotionRunner runner(reader.header().sensors, cfg);
      std::vector<TrajectorySample> traj;
      while (auto r = reader.next()) {
        if (const auto* f = std::get_if<SensorFrame>(&*r)) runner.process(*f);
        if (const auto* t = std::get_if<TrajectorySample>(&*r)) traj.push_back(*t);
      }
      const fs::path truth_csv =
          rec.parent_path() / "truth" / (rec.stem().string() + "_trajectory.csv");
      const bool exact = fs::exists(truth_csv);
      const eval::MotionTruth truth =
          exact ? eval::read_truth_csv(truth_csv, reader.header().origin)
                : eval::truth_from_trajectory(traj, tiles::LocalFrame(reader.header().origin));
      const auto m = eval::evaluate_egomotion(runner.records(), truth);
      if (!out_csv.empty()) eval::write_egomotion_csv(out_csv, runner.records(), truth);
      const std::string name = rec.string() + " (world " + reader.header().world + ", truth " +
                               (exact ? "exact" : "GNSS trajectory") + ")";
      if (json) {
        auto j = eval::to_json(m);
        j["input"] = rec.string();
        j["world"] = reader.header().world;
        out.push_back(j);
      } else {
        print_metrics(name, m);
      }
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_egomotion: %s\n", e.what());
    return 1;
  }
  if (json) std::printf("%s\n", out.dump(2).c_str());
  return 0;
}
