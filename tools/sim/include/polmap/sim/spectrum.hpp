#pragma once
/// @file spectrum.hpp
/// Per-sensor-frame signal synthesis: echoes (complex LR-basis amplitudes at a
/// range, azimuth and radial velocity) -> static-reduced PreCFAR spectrum
/// (sparse PolSpectrum), detection list and optionally the full data cube.
/// Conventions (tools/sim/README.md "Signal model"):
///  - spectrum cell (i, b) of an echo = A * W(i - r/dr) * AF(sin(phi_b) - sin(phi)) *
///    D(wrap(v_r - v_static(phi_b))), W the Hann range response, AF the tapered array
///    factor (peak 1), D the Hann Doppler response evaluated at the static Doppler of the
///    beam centre (peak 1, periodic in 2 v_ua, zero beyond 2 Doppler bins);
///  - amplitudes are in units of the noise: |A_dominant|^2 = SNR (linear).
#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "polmap/schema/recording.hpp"
#include "polmap/sim/config.hpp"
#include "polmap/sim/random.hpp"

namespace polmap::sim {

/// One echo in the sensor frame.
struct Echo {
  double range_m = 0.0;
  double azimuth_rad = 0.0;
  /// LR-basis amplitudes in noise units (radar equation, aspect, carrier phase applied).
  ScatteringVector amplitude{};
  /// True (unaliased) radial velocity, negative = approaching.
  double radial_velocity_mps = 0.0;
};

/// A detection before measurement noise (for tests and statistics).
struct DetectionCandidate {
  double range_m = 0.0;
  double azimuth_rad = 0.0;
  double radial_velocity_mps = 0.0;
  double snr = 0.0;          ///< linear, relative to the detection reference (noise by default)
  bool distributed = false;  ///< aggregated cell sample (position known to a cell only)
};

class SpectrumSynthesizer {
 public:
  SpectrumSynthesizer(const RadarSimConfig& cfg, const RadarSpec& spec);

  // --- grid and responses ---
  [[nodiscard]] int num_range_bins() const { return num_range_; }
  [[nodiscard]] int num_beams() const { return num_beams_; }
  [[nodiscard]] double beam_azimuth_rad(int b) const { return beam_az_[b]; }
  [[nodiscard]] const std::vector<float>& beam_azimuths() const { return beam_az_f_; }
  [[nodiscard]] int nearest_beam(double azimuth_rad) const;
  /// Hann range response at x range bins from the echo (peak 1).
  [[nodiscard]] static double range_response(double x_bins);
  /// Array factor at du = sin(phi_b) - sin(phi) (peak 1).
  [[nodiscard]] double beam_response(double du) const;
  /// Doppler response at a radial-velocity difference (wrapped into [-v_ua, v_ua)).
  [[nodiscard]] double doppler_response(double dv_mps) const;
  /// Expected ground-clutter power (noise units, half span) of a cell of range bin i.
  [[nodiscard]] double clutter_power(int range_bin) const { return clutter_[range_bin]; }
  /// Linear SNR of a target of rcs_dbsm at range_m (radar equation, tools/sim/README.md).
  [[nodiscard]] double snr_linear(double rcs_dbsm, double range_m) const;
  /// Same for a linear RCS (m^2).
  [[nodiscard]] double snr_linear_sigma(double sigma_m2, double range_m) const {
    const double r2 = range_m * range_m;
    return k_radar_ * sigma_m2 / (r2 * r2);
  }
  [[nodiscard]] const RadarSimConfig& config() const { return cfg_; }
  [[nodiscard]] double v_unambiguous_mps() const { return v_ua_; }
  [[nodiscard]] double wavelength_m() const { return lambda_; }
  /// Wraps a radial velocity into [-v_ua, v_ua).
  [[nodiscard]] double alias(double v_mps) const;

  // --- one frame ---
  /// Starts a frame. sensor_velocity: velocity of the sensor over ground, in the sensor
  /// frame (static points have v_r(phi) = -v . (cos phi, sin phi)).
  /// scene_key: hash of the sensor pose; ground speckle of a cell is a function of
  /// (scene_key, cell), frozen while the sensor stands still.
  void begin(const Eigen::Vector2d& sensor_velocity_mps, bool with_cube,
             std::uint64_t scene_key = 0);
  /// Static radial velocity of azimuth phi in the current frame.
  [[nodiscard]] double static_velocity(double azimuth_rad) const;
  /// Adds a point echo (full PSF, Doppler-weighted) and a detection candidate.
  void add_echo(const Echo& e);
  /// Adds an aggregated distributed-target sample at the centre of cell (range_bin, beam),
  /// static Doppler; truncated PSF; detection candidate.
  void add_cell(int range_bin, int beam, const ScatteringVector& amplitude);
  /// In cube frames: ground clutter of range bins [0, n) is rendered explicitly as cell
  /// samples (consistent with the cube) instead of statistically.
  void add_explicit_ground(Rng& rng, double max_range_m);
  /// Noise, clutter, floor, sparse cells, detections, cube -> frame.
  void finish(Rng& rng, SensorFrame& out);
  /// Candidates of the last frame before local-maximum selection (tests).
  [[nodiscard]] const std::vector<DetectionCandidate>& candidates() const { return cands_; }

 private:
  void add_psf(const ScatteringVector& a, double x_bins, double sin_phi, double v_r, int rh,
               int bh);
  void touch(int idx);
  void make_detections(Rng& rng, SensorFrame& out);
  void make_cube(Rng& rng, SensorFrame& out);

  RadarSimConfig cfg_;
  RadarSpec spec_;
  int num_range_ = 0, num_beams_ = 0;
  double dr_ = 0.075, v_ua_ = 5.0, lambda_ = 0.0038;
  double k_radar_ = 0.0;  ///< SNR = k * sigma / r^4
  std::vector<double> beam_az_, beam_sin_;
  std::vector<float> beam_az_f_;
  std::vector<double> af_table_;  ///< AF over du in [-af_max, af_max]
  double af_step_ = 1e-4, af_max_ = 0.4;
  std::vector<double> dop_table_;
  double dop_step_ = 1e-3, dop_max_ = 0.0;
  std::vector<double> taper_, doppler_window_;
  std::vector<double> clutter_;           ///< per range bin, half-span power
  std::array<double, 4> clutter_frac_{};  ///< per channel share (sum 2)
  std::vector<double> floor_;             ///< per range bin, threshold on |s_c|^2
  std::vector<double> exceed_cdf_;        ///< per range bin cumulative exceedance rate
  double exceed_total_ = 0.0;
  std::vector<double> ref_;             ///< per range bin, detection reference level
  std::vector<double> ground_det_cdf_;  ///< per range bin cumulative ground-peak rate
  double ground_det_total_ = 0.0;
  double thr_ground_ = 0.0;  ///< linear ground-peak threshold over the reference

  // frame state
  Eigen::Vector2d vs_ = Eigen::Vector2d::Zero();
  std::uint64_t scene_key_ = 0;
  std::vector<double> static_vr_beam_;
  std::vector<std::array<cfloat, 4>> image_;
  std::vector<std::uint8_t> touched_flag_;
  std::vector<int> touched_;
  int explicit_ground_bins_ = 0;
  bool with_cube_ = false;
  std::vector<DetectionCandidate> cands_;
  struct CubeEcho {
    ScatteringVector a;
    double x_bins, sin_phi, v_r;
    int rh;
  };
  std::vector<CubeEcho> cube_echoes_;
};

}  // namespace polmap::sim
