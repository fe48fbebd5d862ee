// bench_graph: the sliding-window problem of paper Table II on a synthetic drive, solved
// by loc::SlidingWindowGraph (Ceres), every frame, as a vehicle would.
//
//   bench_graph [--frames 3000] [--seed 7] [--window-s 10] [--no-covariance] [--json]
//
// Drive: 10 Hz, 10 m/s on a gentle curve (yaw rate 0.03·sin(2π t / 60 s) rad/s). Point
// landmarks every ~4 m along the path on both sides, 4–12 m lateral offset; a frame
// observes those within 40 m and ±60° of the heading, at most the 12 nearest, as
// bearing-range with Table II noise (σ_φ = 0.03 rad, σ_r = 0.5 m); odometry between
// frames with σ_t = 0.05 m, σ_φ = 0.01 rad; each landmark gets a prior at its map position
// (true + N(0, 0.1 m)) when it first enters the window; 10 s window, the first pose
// fixed by a tight prior. Every frame is solved (none skipped); the figures are the CPU
// time per frame of add + truncate + solve (mean, max) and the position RMSE of the
// latest pose over all frames (the estimate a vehicle would use). The generator is
// deterministic for a seed.
//
// Reference on this machine's class of CPU for the same problem (GTSAM, from the issue):
// iSAM2 (relinearize every 10 steps) 0.78 ms/frame at 0.124 m, BatchFixedLagSmoother
// (10 s) 10 ms/frame at 0.123 m.
#include "polmap/localization_client/graph.hpp"

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <numbers>
#include <random>
#include <vector>

#include "polmap/util/cpu_time.hpp"

using namespace polmap;

namespace {

struct Truth {
  double t, x, y, yaw;
};

struct Landmark {
  Eigen::Vector2d true_m;
  Eigen::Vector2d map_m;  // prior mean: true + noise
};

std::vector<Truth> drive(int frames) {
  std::vector<Truth> out;
  double x = 0.0, y = 0.0, yaw = 0.0;
  const double dt = 0.1, v = 10.0;
  for (int k = 0; k < frames; ++k) {
    const double t = k * dt;
    out.push_back({t, x, y, yaw});
    // Midpoint integration of the unicycle.
    const double w = 0.03 * std::sin(2.0 * std::numbers::pi * t / 60.0);
    const double ym = yaw + 0.5 * w * dt;
    x += v * dt * std::cos(ym);
    y += v * dt * std::sin(ym);
    yaw += w * dt;
  }
  return out;
}

std::vector<Landmark> landmarks(const std::vector<Truth>& path, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> lateral(4.0, 12.0), jitter(-1.0, 1.0);
  std::normal_distribution<double> prior(0.0, 0.1);
  std::vector<Landmark> out;
  // Path samples are 1 m apart (10 m/s at 10 Hz): every 4th, both sides.
  for (std::size_t k = 0; k < path.size(); k += 4) {
    for (int side : {-1, 1}) {
      const Truth& p = path[std::min(
          path.size() - 1, k + static_cast<std::size_t>(std::max(0.0, 2.0 + jitter(rng))))];
      const Eigen::Vector2d n(-std::sin(p.yaw), std::cos(p.yaw));
      Landmark l;
      l.true_m = Eigen::Vector2d(p.x, p.y) + side * lateral(rng) * n;
      l.map_m = l.true_m + Eigen::Vector2d(prior(rng), prior(rng));
      out.push_back(l);
    }
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"bench_graph: sliding-window graph on the paper's Table II problem"};
  int frames = 3000;
  unsigned long long seed = 7;
  double window_s = 10.0;
  bool no_covariance = false, json = false;
  app.add_option("--frames", frames, "frames at 10 Hz")->check(CLI::Range(10, 100000));
  app.add_option("--seed", seed, "generator seed");
  app.add_option("--window-s", window_s, "sliding window")->check(CLI::PositiveNumber);
  app.add_flag("--no-covariance", no_covariance, "skip the marginal covariance of the latest pose");
  app.add_flag("--json", json, "one JSON document");
  CLI11_PARSE(app, argc, argv);

  std::mt19937_64 rng(seed);
  const std::vector<Truth> path = drive(frames);
  const std::vector<Landmark> lms = landmarks(path, rng);
  std::normal_distribution<double> n01(0.0, 1.0);

  loc::GraphConfig gcfg;  // Table II noise
  gcfg.odometry_sigma_translation_m = 0.05;
  gcfg.odometry_sigma_yaw_rad = 0.01;
  gcfg.bearing_sigma_rad = 0.03;
  gcfg.range_sigma_m = 0.5;
  gcfg.point_prior_sigma_m = 0.1;
  gcfg.window_s = window_s;
  gcfg.compute_covariance = !no_covariance;
  loc::SlidingWindowGraph graph(gcfg);

  double sum_ms = 0.0, max_ms = 0.0, sq_err = 0.0;
  int solved = 0, observations = 0;
  Pose2 estimate{path[0].x, path[0].y, path[0].yaw};
  for (int k = 0; k < frames; ++k) {
    const Truth& tr = path[k];
    const Pose2 T_true{tr.x, tr.y, tr.yaw};
    std::optional<Pose2> odo;
    if (k > 0) {
      const Truth& pv = path[k - 1];
      const Pose2 rel = Pose2{pv.x, pv.y, pv.yaw}.inverse() * T_true;
      odo = Pose2{rel.x_m + 0.05 * n01(rng), rel.y_m + 0.05 * n01(rng),
                  rel.yaw_rad + 0.01 * n01(rng)};
    }
    // Observations: within 40 m and ±60°, the 12 nearest.
    std::vector<std::pair<double, std::size_t>> seen;
    const Pose2 T_vehicle_map = T_true.inverse();
    for (std::size_t i = 0; i < lms.size(); ++i) {
      const Eigen::Vector2d p = T_vehicle_map * lms[i].true_m;
      const double r = p.norm();
      if (r > 40.0 || std::abs(std::atan2(p.y(), p.x())) > std::numbers::pi / 3.0) continue;
      seen.emplace_back(r, i);
    }
    std::sort(seen.begin(), seen.end());
    if (seen.size() > 12) seen.resize(12);
    std::vector<std::pair<std::size_t, Eigen::Vector2d>> obs;
    for (const auto& [r, i] : seen) {
      const Eigen::Vector2d p = T_vehicle_map * lms[i].true_m;
      const double b = std::atan2(p.y(), p.x()) + 0.03 * n01(rng);
      const double rn = r + 0.5 * n01(rng);
      obs.emplace_back(i, Eigen::Vector2d(rn * std::cos(b), rn * std::sin(b)));
    }

    const double c0 = util::thread_cpu_s();
    const Pose2 guess = odo ? estimate * *odo : estimate;
    const auto key = graph.add_pose(tr.t, guess, odo);
    if (k == 0) graph.add_pose_prior(key, T_true, Eigen::Matrix3d::Identity() * 1e-6);
    for (const auto& [i, o] : obs) {
      graph.add_point_observation(key, static_cast<std::int64_t>(i), lms[i].map_m, o);
    }
    graph.truncate_before(tr.t - window_s);
    const loc::GraphSolution sol = graph.solve();
    const double ms = 1e3 * (util::thread_cpu_s() - c0);
    observations += static_cast<int>(obs.size());
    if (sol.status == loc::GraphSolution::Status::Ok) {
      estimate = sol.T_map_vehicle;
      ++solved;
    } else {
      estimate = guess;
    }
    sum_ms += ms;
    max_ms = std::max(max_ms, ms);
    sq_err += (estimate.translation() - T_true.translation()).squaredNorm();
    if (!json && (k + 1) % 500 == 0) {
      std::fprintf(stderr, "bench_graph: %d/%d frames, %.2f ms/frame so far\n", k + 1, frames,
                   sum_ms / (k + 1));
    }
  }
  nlohmann::json j;
  j["frames"] = frames;
  j["seed"] = seed;
  j["window_s"] = window_s;
  j["covariance"] = !no_covariance;
  j["solved_frames"] = solved;
  j["mean_observations_per_frame"] = static_cast<double>(observations) / frames;
  j["landmarks"] = lms.size();
  j["ms_per_frame_mean"] = sum_ms / frames;
  j["ms_per_frame_max"] = max_ms;
  j["position_rmse_m"] = std::sqrt(sq_err / frames);
  if (json) {
    std::printf("%s\n", j.dump(2).c_str());
  } else {
    for (auto it = j.begin(); it != j.end(); ++it) {
      std::printf("%-28s %s\n", it.key().c_str(), it.value().dump().c_str());
    }
  }
  return solved == frames ? 0 : 1;
}
