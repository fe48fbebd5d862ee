#include "polmap/sim/realism.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "polmap/schema/errors.hpp"
#include "polmap/sim/config.hpp"
#include "polmap/sim/random.hpp"
#include "polmap/sim/world.hpp"

namespace polmap::sim {

namespace {
constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180.0;
constexpr double kG = 9.80665;
// Stream tags of the realism draws: separate generators, so the ideal streams never move.
constexpr std::uint64_t kTagMountVehicle = 0x6d6f756e74ULL;
constexpr std::uint64_t kTagMountDrive = 0x6d6f756e7444ULL;
constexpr std::uint64_t kTagTimeOffset = 0x746f6666ULL;
constexpr std::uint64_t kTagJitter = 0x6a6974ULL;
constexpr std::uint64_t kTagOverhead = 0x6f766864ULL;
}  // namespace

RealismConfig realism_preset(std::string_view name) {
  RealismConfig c;
  if (name == "ideal") return c;
  if (name != "realistic") {
    throw ValidationError("realism preset must be ideal or realistic, got '" + std::string(name) +
                          "'");
  }
  c.radar_noise.enabled = true;
  c.mounts.enabled = true;
  c.timing.enabled = true;
  c.slip.enabled = true;
  c.multipath.enabled = true;
  c.elevation.enabled = true;
  c.ins.enabled = true;
  return c;
}

RealismConfig only_sources(RealismConfig c, std::string_view list) {
  bool on[7] = {};
  std::size_t pos = 0;
  while (pos <= list.size()) {
    const std::size_t end = std::min(list.find(',', pos), list.size());
    const std::string_view name = list.substr(pos, end - pos);
    if (!name.empty()) {
      const auto* it = std::find(std::begin(kRealismSources), std::end(kRealismSources), name);
      if (it == std::end(kRealismSources)) {
        throw ValidationError("unknown realism source '" + std::string(name) +
                              "' (noise, mounts, timing, slip, multipath, elevation, ins)");
      }
      on[it - std::begin(kRealismSources)] = true;
    }
    pos = end + 1;
  }
  c.radar_noise.enabled = c.radar_noise.enabled && on[0];
  c.mounts.enabled = c.mounts.enabled && on[1];
  c.timing.enabled = c.timing.enabled && on[2];
  c.slip.enabled = c.slip.enabled && on[3];
  c.multipath.enabled = c.multipath.enabled && on[4];
  c.elevation.enabled = c.elevation.enabled && on[5];
  c.ins.enabled = c.ins.enabled && on[6];
  return c;
}

RadarSimConfig apply_radar_noise(const RadarSimConfig& radar, const RadarNoiseRealism& n) {
  RadarSimConfig r = radar;
  if (!n.enabled) return r;
  r.det_sigma_range_m = n.sigma_range_m;
  r.det_sigma_azimuth_deg = n.sigma_azimuth_deg;
  r.det_sigma_azimuth_max_deg = n.max_sigma_azimuth_deg;
  r.det_sigma_azimuth_grows_off_boresight = true;
  r.det_sigma_vr_mps = n.sigma_vr_mps;
  r.doppler_outlier_share = n.doppler_outlier_share;
  r.doppler_outlier_sigma_mps = n.doppler_outlier_sigma_mps;
  r.false_alarms_per_frame = n.false_alarms_per_frame;
  return r;
}

std::vector<SensorMount> true_mounts(const std::vector<SensorMount>& nominal,
                                     const MountRealism& cfg, std::uint64_t seed, int drive) {
  std::vector<SensorMount> out = nominal;
  if (!cfg.enabled) return out;
  for (SensorMount& m : out) {
    Rng veh(seed_of(seed, kTagMountVehicle, m.sensor_id));
    Rng drv(seed_of(seed, kTagMountDrive, static_cast<std::uint64_t>(drive), m.sensor_id));
    m.T_vehicle_sensor.x_m +=
        veh.normal(0.0, cfg.position_sigma_m) + drv.normal(0.0, cfg.position_drive_sigma_m);
    m.T_vehicle_sensor.y_m +=
        veh.normal(0.0, cfg.position_sigma_m) + drv.normal(0.0, cfg.position_drive_sigma_m);
    m.T_vehicle_sensor.yaw_rad +=
        veh.normal(0.0, cfg.yaw_sigma_deg * kDeg) + drv.normal(0.0, cfg.yaw_drive_sigma_deg * kDeg);
  }
  return out;
}

std::vector<double> sensor_time_offsets_s(std::size_t n, const TimingRealism& cfg,
                                          std::uint64_t seed, int drive) {
  std::vector<double> out(n, 0.0);
  if (!cfg.enabled) return out;
  // Per sensor and drive: clocks are re-synchronised at every start.
  for (std::size_t k = 0; k < n; ++k) {
    Rng rng(seed_of(seed, kTagTimeOffset, static_cast<std::uint64_t>(drive), k));
    out[k] = rng.normal(0.0, cfg.offset_sigma_s);
  }
  return out;
}

double trigger_jitter_s(const TimingRealism& cfg, std::uint64_t seed, int drive,
                        std::uint32_t cycle, std::uint8_t sensor_id) {
  if (!cfg.enabled || cfg.jitter_sigma_s <= 0) return 0.0;
  Rng rng(seed_of(seed, kTagJitter, static_cast<std::uint64_t>(drive), cycle, sensor_id));
  return rng.normal(0.0, cfg.jitter_sigma_s);
}

double side_slip_rad(const SlipRealism& cfg, double a_y) {
  if (!cfg.enabled) return 0.0;
  return -cfg.side_slip_gradient_deg_per_mps2 * kDeg * a_y;
}

double wheel_speed_mps(const SlipRealism& cfg, double v, double a_x, double scale_error) {
  if (!cfg.enabled) return v;
  const double lambda = a_x / (kG * cfg.slip_stiffness);
  return std::max(0.0, v * (1.0 + lambda) * (1.0 + scale_error));
}

Eigen::Vector2d mirror_point(const Eigen::Vector2d& p, const Eigen::Vector2d& a,
                             const Eigen::Vector2d& b) {
  const Eigen::Vector2d d = (b - a).normalized();
  const Eigen::Vector2d ap = p - a;
  const Eigen::Vector2d foot = a + d * ap.dot(d);
  return 2.0 * foot - p;
}

std::optional<Eigen::Vector2d> specular_point(const Eigen::Vector2d& from,
                                              const Eigen::Vector2d& to, const Eigen::Vector2d& a,
                                              const Eigen::Vector2d& b) {
  const Eigen::Vector2d e = b - a;
  const double len = e.norm();
  if (len < 1e-9) return std::nullopt;
  const Eigen::Vector2d n(-e.y() / len, e.x() / len);
  const double hf = n.dot(from - a), ht = n.dot(to - a);
  if (hf * ht <= 0) return std::nullopt;  // different sides or on the line
  // The reflection point divides the projection in the ratio of the heights.
  const double tf = e.dot(from - a) / (len * len), tt = e.dot(to - a) / (len * len);
  const double t = tf + (tt - tf) * std::abs(hf) / (std::abs(hf) + std::abs(ht));
  if (t < 0 || t > 1) return std::nullopt;
  return a + t * e;
}

double ground_bounce_gain(double range_m, double hs, double ht, double g, double lambda) {
  if (range_m <= 0) return 1.0;
  const double d = 2.0 * hs * ht / range_m;
  const double ph = 2.0 * kPi * d / lambda;
  // One-way field |1 + G e^{j ph}|; two-way power = its fourth power (same path twice).
  const double f2 = 1.0 + g * g + 2.0 * g * std::cos(ph);
  const double g2 = g * g;
  return f2 * f2 / (1.0 + 4.0 * g2 + g2 * g2);
}

std::vector<OverheadStructure> overhead_structures(const World& world, const ElevationRealism& cfg,
                                                   std::uint64_t seed) {
  std::vector<OverheadStructure> out;
  if (!cfg.enabled || cfg.overhead_per_km <= 0) return out;
  Rng rng(seed_of(seed, kTagOverhead));
  const double len = world.route.length_m();
  const double mean_gap = 1000.0 / cfg.overhead_per_km;
  for (double s = rng.exponential() * mean_gap; s < len; s += rng.exponential() * mean_gap) {
    OverheadStructure o;
    o.p0_m = world.route.offset_point(s, -8.0);
    o.p1_m = world.route.offset_point(s, 10.0);
    o.height_m = rng.uniform(cfg.overhead_height_min_m, cfg.overhead_height_max_m);
    out.push_back(o);
  }
  return out;
}

}  // namespace polmap::sim
