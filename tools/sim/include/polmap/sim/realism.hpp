#pragma once
/// @file realism.hpp
/// Error sources of real vehicles that the ideal simulator leaves out (issue 15 item 1):
/// radar measurement noise at the level of production 77 GHz sensors, mount misalignment the
/// vehicle does not know, sensor time offsets and trigger jitter, side slip and wheel slip,
/// multipath ghosts from walls and guardrails, elevation effects (overhead structures, ground
/// bounce) and errors of the reference INS. Each source is its own struct with an `enabled`
/// switch and documented defaults (sources in tools/sim/README.md "Realism"); the `ideal`
/// preset turns all of them off and reproduces the ideal simulator bit for bit, `realistic`
/// turns all of them on. Core computations take values and return values.
#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "polmap/schema/radar_spec.hpp"

namespace polmap::sim {

struct RadarSimConfig;
class World;

/// 1. Detection noise of a production 77 GHz corner radar (replaces the ideal 3 cm / 0.5 deg /
/// 0.05 m/s of RadarSimConfig when enabled).
struct RadarNoiseRealism {
  bool enabled = false;
  /// Range accuracy: Continental ARS 408-21 datasheet +-0.10 m (near range), Bosch MRR
  /// +-0.12 m; taken as 1 sigma.
  double sigma_range_m = 0.10;
  /// Azimuth accuracy at boresight: ARS 408-21 +-0.3 deg (near, 0 deg), TI AWR1843 (12
  /// virtual channels) ~0.3-0.5 deg at high SNR; grows off boresight as 1/cos(phi) (array
  /// aperture shrinks; ARS 408-21: +-1 deg at +-45 deg), capped at max_sigma_azimuth_deg.
  double sigma_azimuth_deg = 0.4;
  double max_sigma_azimuth_deg = 1.5;
  /// Doppler accuracy: ARS 408-21 +-0.1 km/h (0.03 m/s) at high SNR, resolution 0.1-0.4 km/h;
  /// range-Doppler coupling of FMCW ramps and finite Doppler bins give a static-core residual
  /// of 0.08-0.12 m/s on RadarScenes (SIMULATION.md); the residual also contains the azimuth
  /// term v sin(phi) d(phi), so the Doppler part alone is set lower.
  double sigma_vr_mps = 0.07;
  /// Share of detections with a gross Doppler error (interference, Doppler sidelobes of strong
  /// movers, wheel micro-Doppler, wrong peak association): residual ~ N(0, outlier_sigma).
  /// Real lists show 6-18 % with |residual| > 0.5 m/s including moving objects and multipath
  /// (SIMULATION.md); this is the unexplained remainder.
  double doppler_outlier_share = 0.04;
  double doppler_outlier_sigma_mps = 2.0;
  /// False alarms per frame (the ideal default is 2); production lists carry more weak,
  /// random detections (RadarScenes: ~3-5 % of a list is unexplained clutter).
  double false_alarms_per_frame = 6.0;
};

/// 2. Mount misalignment: the true mounts deviate from the nominal ones written to the
/// recording header (the vehicle's stored calibration). Per vehicle (seed) plus a per-drive
/// change (re-mounting, bumper knocks, temperature).
struct MountRealism {
  bool enabled = false;
  /// End-of-line / service alignment tolerance of ACC corner radars is +-1 deg (ISO 15622
  /// ACC practice, OEM service manuals); drawn N(0, sigma) so 95 % lie within +-0.6 deg, in the
  /// range the RadarScenes residuals imply after calibration (0.05-0.3 deg, SIMULATION.md).
  double yaw_sigma_deg = 0.3;
  /// Mount position error per axis (bracket and bumper tolerances of centimetres).
  double position_sigma_m = 0.01;
  /// Change between drives (added per drive on top of the per-vehicle error).
  double yaw_drive_sigma_deg = 0.05;
  double position_drive_sigma_m = 0.002;
};

/// 3. Timing: each sensor's time stamps are offset from the true measurement time (CAN/
/// Ethernet transport latency compensated to within a few ms, free-running sensor clocks),
/// plus per-frame trigger jitter.
struct TimingRealism {
  bool enabled = false;
  /// Per-sensor constant offset: true measurement time = stamp + offset (N(0, sigma)).
  double offset_sigma_s = 0.003;
  /// Per-frame jitter (white, N(0, sigma)).
  double jitter_sigma_s = 0.0005;
};

/// 4. Vehicle side slip (rear axle) in curves and wheel slip under acceleration and braking.
struct SlipRealism {
  bool enabled = false;
  /// Rear-axle side-slip gradient: beta = -gradient * a_y (the rear drifts out of the turn).
  /// Linear single-track model with Rajamani's passenger car (Vehicle Dynamics and Control,
  /// 2nd ed. 2012, ch. 2-3: m = 1573 kg, l_f = 1.10 m, l = 2.68 m, C_alpha,r = 2 x 80 kN/rad):
  /// alpha_r = m l_f a_y / (l C_alpha,r) = 0.0040 rad per m/s^2 = 0.23 deg per m/s^2.
  /// Sign convention ISO 8855: beta = atan(v_y / v_x) in the vehicle frame.
  double side_slip_gradient_deg_per_mps2 = 0.23;
  /// Longitudinal wheel slip: lambda = a_x / (g * slip_stiffness). Slope of mu over slip on
  /// dry asphalt ~ 30 (Gustafsson, "Slip-based tire-road friction estimation", Automatica
  /// 1997): 2.5 m/s^2 braking gives -0.85 % slip. Applies to the recorded speed only.
  double slip_stiffness = 30.0;
  /// Wheel-radius scale error of the recorded speed (tyre wear and pressure, +-0.5 %): sigma.
  double wheel_scale_sigma = 0.003;
};

/// 5. Multipath: specular reflections at walls, facades and guardrail beams.
struct MultipathRealism {
  bool enabled = false;
  /// One-way power loss of a specular bounce: concrete/brick at 77 GHz 5-10 dB (e.g.
  /// Piesiewicz et al. / Kurner group building-material reflection measurements), metal
  /// guardrails ~1 dB.
  double wall_loss_db = 7.0;
  double guardrail_loss_db = 1.0;
  /// Mirror ghosts (sensor -> wall -> target -> wall -> sensor: a virtual target at the
  /// mirrored position, two bounces) and mixed paths (one bounce, range and Doppler the mean
  /// of direct and mirrored path, arriving from the mirror direction).
  bool mirror_ghosts = true;
  bool mixed_paths = true;
  /// Reflections only from targets at least this strong (dBsm), and via reflectors within
  /// this range of the sensor (beyond, ghosts sink below the threshold anyway).
  double min_target_rcs_dbsm = -5.0;
  double max_reflector_range_m = 40.0;
};

/// 6. Elevation: overhead structures and ground-bounce multipath.
struct ElevationRealism {
  bool enabled = false;
  /// Overhead structures across the road (sign gantries, traffic-light mast arms,
  /// footbridges) per km of route, at height_min..max above the road.
  double overhead_per_km = 2.0;
  double overhead_height_min_m = 5.0;
  double overhead_height_max_m = 6.5;
  /// RCS per metre of a gantry beam (steel truss, diffuse), at normal incidence.
  double overhead_rcs_per_m_dbsm = 0.0;
  /// Ground bounce (two-ray model, sensor height from RadarSimConfig): coherent reflection
  /// coefficient of asphalt at grazing incidence (|Gamma| 0.5-0.8 at 77 GHz, e.g. Sarabandi
  /// et al., IEEE TAP 1997), normalised so the mean gain over phase is 1 (the radar equation's
  /// reference already holds the average multipath).
  bool ground_bounce = true;
  double ground_reflection = 0.6;
  /// Heights of point-like scattering centres above the road: drawn per centre in [min,max].
  double target_height_min_m = 0.3;
  double target_height_max_m = 1.5;
};

/// 7. Errors of the reference INS (the GNSS/IMU trajectory the recording carries; the
/// evaluation uses the exact truth). Added to the GnssSimConfig errors.
struct InsRealism {
  bool enabled = false;
  /// Lever-arm error INS -> rear-axle centre per axis (vehicle frame), per drive: OxTS RT3000
  /// and NovAtel SPAN manuals ask for lever arms measured to 1-2 cm.
  double lever_arm_sigma_m = 0.02;
  /// Heading boresight error INS -> vehicle axis, per drive: dual-antenna heading 0.1 deg
  /// (2 m baseline, OxTS RT3000 v3 / NovAtel SPAN CPT7 datasheets).
  double heading_bias_sigma_deg = 0.1;
  /// Gyro yaw-rate bias, per drive (tactical MEMS IMU in-run bias ~1-3 deg/h, post-
  /// calibration residual): 0.003 deg/s.
  double yaw_rate_bias_sigma_dps = 0.003;
  /// Dead-reckoning drift while without carrier-phase fix: accelerometer bias per axis
  /// (tactical grade ~1-2 mg; OxTS RT3000: ~0.1-0.2 m after 10 s outage) integrated twice.
  double outage_accel_bias_mps2 = 0.002;
  /// After the fix returns the INS filter pulls the drift back with this time constant.
  double recovery_tau_s = 2.0;
  /// Latency error of the INS time stamps (constant per drive, N(0, sigma)).
  double latency_sigma_s = 0.001;
};

/// All realism sources. Default-constructed = everything off (the ideal preset).
struct RealismConfig {
  RadarNoiseRealism radar_noise;
  MountRealism mounts;
  TimingRealism timing;
  SlipRealism slip;
  MultipathRealism multipath;
  ElevationRealism elevation;
  InsRealism ins;
  [[nodiscard]] bool any() const {
    return radar_noise.enabled || mounts.enabled || timing.enabled || slip.enabled ||
           multipath.enabled || elevation.enabled || ins.enabled;
  }
};

/// Names of the sources for --realism-sources: noise, mounts, timing, slip, multipath,
/// elevation, ins.
inline constexpr std::string_view kRealismSources[] = {"noise",     "mounts",    "timing", "slip",
                                                       "multipath", "elevation", "ins"};

/// "ideal" (all off) or "realistic" (all on, defaults above). Throws ValidationError otherwise.
RealismConfig realism_preset(std::string_view name);
/// Keeps only the named sources of cfg enabled (names from kRealismSources, comma separated);
/// throws ValidationError for an unknown name.
RealismConfig only_sources(RealismConfig cfg, std::string_view comma_separated);

/// RadarSimConfig with the realistic detection noise applied (unchanged when disabled).
RadarSimConfig apply_radar_noise(const RadarSimConfig& radar, const RadarNoiseRealism& noise);

/// True mounts of a drive: nominal mounts perturbed by the per-vehicle error (seed) and the
/// per-drive change (seed, drive). Unchanged when disabled.
std::vector<SensorMount> true_mounts(const std::vector<SensorMount>& nominal,
                                     const MountRealism& cfg, std::uint64_t seed, int drive);

/// Constant time offset per sensor (index as in mounts): true time = stamp + offset.
std::vector<double> sensor_time_offsets_s(std::size_t num_sensors, const TimingRealism& cfg,
                                          std::uint64_t seed, int drive);
/// Trigger jitter of one frame (0 when disabled).
double trigger_jitter_s(const TimingRealism& cfg, std::uint64_t seed, int drive,
                        std::uint32_t cycle, std::uint8_t sensor_id);

/// Rear-axle side-slip angle (ISO 8855 beta = atan(v_y / v_x)) at lateral acceleration a_y
/// (left positive): negative in left turns (velocity points out of the turn).
double side_slip_rad(const SlipRealism& cfg, double lateral_accel_mps2);
/// Wheel-speed reading at true speed v and longitudinal acceleration a_x with the vehicle's
/// wheel scale error (relative, e.g. +0.003).
double wheel_speed_mps(const SlipRealism& cfg, double v_mps, double accel_mps2, double scale_error);

/// Mirror image of p across the infinite line through a and b.
Eigen::Vector2d mirror_point(const Eigen::Vector2d& p, const Eigen::Vector2d& a,
                             const Eigen::Vector2d& b);
/// Specular reflection point on segment [a, b] of the path from `from` to `to` (both on the
/// same side of the line); nullopt if the reflection point lies outside the segment or the
/// points are on different sides.
std::optional<Eigen::Vector2d> specular_point(const Eigen::Vector2d& from,
                                              const Eigen::Vector2d& to, const Eigen::Vector2d& a,
                                              const Eigen::Vector2d& b);

/// Two-way power gain of the ground-bounce two-ray model for a scattering centre at
/// target_height_m seen from sensor_height_m at ground range range_m: |1 + G e^{j k d}|^4 with
/// d = 2 h_s h_t / R, normalised by its mean over the phase (1 + 4 G^2 + G^4).
double ground_bounce_gain(double range_m, double sensor_height_m, double target_height_m,
                          double reflection, double wavelength_m);

/// An overhead structure (gantry beam) across the road, world frame.
struct OverheadStructure {
  Eigen::Vector2d p0_m, p1_m;
  double height_m = 5.5;
};
/// Overhead structures of a world (deterministic per seed): Poisson along the route at
/// overhead_per_km, each spanning the road (route offset -8 m .. +10 m) at a height drawn
/// in [min, max]. Empty when disabled.
std::vector<OverheadStructure> overhead_structures(const World& world, const ElevationRealism& cfg,
                                                   std::uint64_t seed);

}  // namespace polmap::sim
