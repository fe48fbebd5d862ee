#pragma once
/// @file config.hpp
/// Every noise model, physical constant and default of the simulator in ONE
/// place (mirrored in tools/sim/README.md, which describes the physics). Values
/// are the paper's or common 77 GHz practice; where a value is our own choice, its
/// reason is documented here. Units are in the names.
#include <cstdint>
#include <vector>

#include "polmap/schema/radar_spec.hpp"
#include "polmap/sim/realism.hpp"

namespace polmap::sim {

/// Signal model of one sensor frame (spectrum, detections, cube).
struct RadarSimConfig {
  // --- radar equation (tools/sim/README.md) -------------------------------
  /// SNR of a 0 dBsm point target at r_ref_m in the processed (static-reduced) domain.
  double snr_ref_db = 20.0;
  double r_ref_m = 50.0;
  /// Complex thermal-noise std per spectrum cell and channel (E|n|^2 = sigma^2).
  /// Amplitudes are in these units: a target of SNR s has |S_dominant| = sigma*sqrt(s).
  double noise_sigma = 1.0;
  /// Thermal noise on/off (off only for tests that compare noise-free signals).
  bool thermal_noise = true;
  /// Echoes closer than this are ignored (antenna near field / bumper).
  double min_range_m = 0.3;

  // --- spectrum grid ------------------------------------------------------
  /// Range bin i is at i*range_bin_m, bins 0..floor(max_range/bin) (1067 bins).
  double range_bin_m = 0.075;
  double max_range_m = 80.0;
  /// Beams uniform in azimuth angle over [-fov, +fov] (81 beams at 1.5 deg).
  double beam_spacing_deg = 1.5;
  double fov_half_deg = 60.0;

  // --- point spread -------------------------------------------------------
  /// Virtual uniform linear array: elements, spacing, taper w_n = p + (1-p) cos^2(pi x_n),
  /// x_n in [-1/2, 1/2]. Pedestal 0.7 gives -3 dB width 3.49 deg at boresight and -17 dB
  /// sidelobes; 31 elements at lambda/2 cannot go below 3.28 deg (uniform), so this is the
  /// closest tapered beam to the paper's ~3 deg. Width grows as 1/cos(phi).
  int array_elements = 31;
  double element_spacing_wavelengths = 0.5;
  double taper_pedestal = 0.7;
  /// Range response: Hann-windowed FFT, W(x) = sinc(x)/(1-x^2), x in bins (-3 dB 1.44 bins).
  /// Truncation of the PSF of point echoes (taps each side) and of aggregated cells.
  int point_psf_range_half_taps = 3;
  int point_psf_beam_half_taps = 5;
  int cell_psf_range_half_taps = 1;
  int cell_psf_beam_half_taps = 2;
  /// PSF taps whose amplitude falls below this many noise sigmas are skipped (speed).
  double psf_skip_below_sigma = 0.2;
  /// Step of the walk along extended objects (sub-scatterer integration length).
  double extended_step_m = 0.04;

  // --- Doppler / static reduction -----------------------------------------
  /// Chirps per frame; with v_ua = 5 m/s the Doppler bin is 2*v_ua/C = 0.156 m/s.
  /// The static reduction evaluates the Hann-windowed Doppler DTFT at the static Doppler of
  /// each beam centre; echoes whose aliased Doppler differs are weighted by that response
  /// (zero beyond 2 Doppler bins), so moving objects vanish unless their Doppler coincides.
  int num_chirps = 64;

  // --- storage floor ------------------------------------------------------
  /// A cell is stored if max_c |s_c|^2 > (floor_sigmas)^2 * (sigma^2 + g(r)), g(r) the
  /// expected ground-clutter power of the range ring (noise+clutter relative floor, as a
  /// real recorder's per-ring noise estimate). Without the clutter term every near-range
  /// ground cell would be stored (~0.5 MB per frame).
  double floor_sigmas = 3.0;
  bool floor_includes_clutter = true;

  // --- ground clutter -----------------------------------------------------
  bool ground_clutter = true;
  double ground_sigma0_db = -25.0;  ///< at grazing incidence (tools/sim/README.md)
  /// Ground seen through a Gaussian elevation beam (two-way) from this mount height.
  double sensor_height_m = 0.5;
  double elevation_beamwidth_deg = 20.0;

  // --- detection list (CFAR-like peak detector; README "Detection list") ---
  /// Detection threshold over the local reference level (CA-CFAR-like). The reference is the
  /// thermal noise sigma^2 by default: ground clutter at short range is what a real CFAR
  /// detects there (static returns ego-motion relies on). THE density knob: lower -> more
  /// detections (each dB roughly +10-15 % in urban scenes, mostly ground and walls).
  double detection_threshold_db = 12.0;
  /// Reference level includes the expected ring clutter g(r) (the old, much sparser model:
  /// ground never crosses, near walls need g + 12 dB). Off = noise-referenced (default).
  bool detection_reference_includes_clutter = false;
  /// Peak (local-maximum) neighbourhood: a candidate is suppressed if a stronger accepted one
  /// lies within +-range bins, +-beams AND +-Doppler bins (aliased). 1/1/2 = one peak per
  /// resolution cell (range -3 dB width 1.44 bins, beam 2.3 beams), as a 3x3 peak search.
  int detection_suppress_range_bins = 1;
  int detection_suppress_beams = 1;
  int detection_suppress_doppler_bins = 2;
  /// Ground clutter produces detections (speckle peaks of the ground, static Doppler of the
  /// beam centre), drawn statistically per range ring (cells without other echoes).
  bool ground_detections = true;
  /// Threshold of ground-clutter peaks over the noise. The ground is 15-22 dB above the noise
  /// at 2-8 m (sigma0 = -25 dB, 7.5 cm x 1.5 deg cells), so over detection_threshold_db it
  /// would give ~1500 peaks per frame (every near cell), more than the cap; a real sensor's
  /// list holds the strongest ground peaks (CFAR reference windows that contain clutter, list
  /// limits). 25 dB gives ~210 ground peaks per frame (~165 after suppression; 20 dB: 630,
  /// 28 dB: 30), mostly at
  /// 2-10 m and all azimuths -- the second density knob.
  double ground_detection_threshold_db = 25.0;
  double det_sigma_range_m = 0.03;
  double det_sigma_azimuth_deg = 0.5;
  double det_sigma_vr_mps = 0.05;  ///< before aliasing
  /// Azimuth sigma grows as 1/cos(phi) up to det_sigma_azimuth_max_deg (realistic noise,
  /// realism.hpp); off = constant det_sigma_azimuth_deg (ideal).
  bool det_sigma_azimuth_grows_off_boresight = false;
  double det_sigma_azimuth_max_deg = 1.5;
  /// Share of detections with a gross Doppler error N(0, doppler_outlier_sigma_mps), drawn
  /// from a separate generator (0 = ideal: no draw at all).
  double doppler_outlier_share = 0.0;
  double doppler_outlier_sigma_mps = 2.0;
  /// Mean false alarms per frame (Poisson), uniform in range/azimuth/Doppler,
  /// SNR = threshold + exponential(mean 2 dB).
  double false_alarms_per_frame = 2.0;
  /// Cap per frame: the strongest (by SNR) are kept, as a sensor's detection-list limit.
  int max_detections = 800;

  // --- occlusion ----------------------------------------------------------
  double occlusion_bin_deg = 0.25;
  /// Echoes up to this far behind the nearest opaque surface of their ray stay visible
  /// (the surface's own scatterers, recesses).
  double occlusion_margin_m = 0.4;
  /// Two-way loss of echoes behind vegetation (partial occluder).
  double vegetation_loss_db = 15.0;

  // --- full data cube (--cube) --------------------------------------------
  /// Cube range bins 0..cube_max_range_m (keeps the cube small: 161 x 64 x 31 x 4).
  double cube_max_range_m = 12.0;
};

/// Receiver grade of the simulated vehicle's positioning (`polmap simulate --gnss`).
/// Rtk: the survey-grade GNSS/IMU of a mapping vehicle (paper §IV-A); Consumer: the
/// navigation solution of a series car (ConsumerGnssConfig).
enum class GnssGrade : std::uint8_t { Rtk, Consumer };

/// A series car's navigation solution: a consumer single-frequency GNSS receiver fused with
/// the car's IMU and wheel odometry. Its errors are metre-level and slowly varying, and in
/// street canyons multipath adds an error that depends on the place, so it repeats on every
/// drive there (errors of different drives are not independent). Defaults from published
/// specifications (tools/sim/README.md, "Consumer GNSS").
struct ConsumerGnssConfig {
  /// Per axis: u-blox NEO-M8 / ZED-F9P (single band SPS) give 2.0-2.5 m CEP horizontal,
  /// i.e. sigma ~ 1.5 m per axis in open sky.
  double bias_sigma_m = 1.5;
  /// Correlation time of that error (ionosphere, troposphere and orbit residuals change over
  /// minutes; a fused solution does not jump): first-order Gauss-Markov.
  double bias_tau_s = 300.0;
  /// Heading of the fused solution (GNSS course + gyro), first-order Gauss-Markov.
  double heading_sigma_deg = 0.3;
  double heading_tau_s = 60.0;
  /// Extra error where facades block the sky on both sides (street canyon): amplitude per
  /// axis at full blockage (urban canyon studies report 2-10 m for SPS; a fused solution
  /// with wheel odometry keeps the lower end).
  double canyon_multipath_m = 2.0;
  /// Spatial correlation length of the multipath error (it follows the place, not time).
  double multipath_correlation_m = 40.0;
  /// Facades within this distance left and right count as a canyon.
  double canyon_radius_m = 30.0;
  /// The car's navigation filter weighs GNSS against wheel odometry and IMU: receiver
  /// errors (bias and multipath) that change faster than this time constant are smoothed
  /// out (first-order low-pass of the receiver error along the drive; the trajectory's
  /// error then changes at ~0.03 m/s, as a Doppler-aided solution's velocity error).
  double fusion_tau_s = 10.0;
  /// Outages (tunnels, underpasses, receiver resets) per km; during one the solution dead-
  /// reckons with wheel odometry and gyro and drifts by this share of the distance driven.
  double outages_per_km = 0.5;
  double outage_min_s = 5.0;
  double outage_max_s = 20.0;
  double outage_drift_fraction = 0.01;
  /// After an outage the filter pulls the drift back with this time constant.
  double recovery_tau_s = 10.0;
  /// The per-axis standard deviation the receiver reports (std_east_m, std_north_m).
  double reported_sigma_m = 2.0;
};

/// GNSS/IMU trajectory error model (paper §IV-A).
struct GnssSimConfig {
  /// Rtk (default): the fields below; Consumer: `consumer` instead.
  GnssGrade grade = GnssGrade::Rtk;
  ConsumerGnssConfig consumer;
  double rate_hz = 100.0;             ///< trajectory samples per second (>= 50 Hz)
  double sigma_fixed_m = 0.014;       ///< per axis (east, north), carrier-phase fixed
  double sigma_float_m = 0.086;       ///< per axis, no fix
  double position_tau_s = 10.0;       ///< first-order Gauss-Markov correlation time
  double no_fix_fraction_min = 0.10;  ///< share of a drive without fix, uniform in [min,max]
  double no_fix_fraction_max = 0.20;
  double no_fix_stretch_min_s = 8.0;  ///< length of one stretch without fix
  double no_fix_stretch_max_s = 30.0;
  double heading_sigma_deg = 0.05;
  double heading_tau_s = 30.0;
  double speed_sigma_mps = 0.01;       ///< white
  double yaw_rate_sigma_rps = 0.0005;  ///< white
};

/// Ego driving behaviour.
struct DriveSimConfig {
  /// 0 = preset default: 15 m/s urban/industrial/HD maps, 20 m/s rural.
  double max_speed_mps = 0.0;
  /// Per drive the cruise speed is max_speed * U(min_speed_factor, 1).
  double min_speed_factor = 0.85;
  double accel_mps2 = 2.0;
  double decel_mps2 = 2.5;
  double lateral_accel_mps2 = 2.0;  ///< curve speed limit v <= sqrt(a_lat / |kappa|)
  double red_light_probability = 0.5;
  double red_min_s = 5.0;
  double red_max_s = 20.0;
  double stop_before_light_m = 6.0;
  /// Lateral wander within the lane: A sin(2 pi s / L + phase), A <= amplitude.
  double lane_wander_amplitude_m = 0.25;
  double lane_wander_wavelength_min_m = 120.0;
  double lane_wander_wavelength_max_m = 300.0;
  double trajectory_step_m = 0.1;  ///< path sampling
};

/// Moving traffic (per drive) and temporary objects.
struct TrafficSimConfig {
  /// Vehicles per km of route, oncoming and same-direction (neighbour lane), per preset.
  double oncoming_per_km_urban = 10.0;
  double same_dir_per_km_urban = 5.0;
  double oncoming_per_km_industrial = 6.0;
  double same_dir_per_km_industrial = 2.0;
  double oncoming_per_km_rural = 4.0;
  double oncoming_per_km_hdmap = 6.0;
  double min_speed_mps = 6.0;
  double max_speed_mps = 14.0;  ///< rural: +5 m/s
  /// Probability a temporary object (parked car, bin) is present in a drive.
  double parked_presence = 0.6;
  double bin_presence = 0.5;
  /// Where a temporary object stands in a drive it is present in: uniformly within +- this
  /// of its place, along the curb (WorldObject::drive_shift_max_m). A parked car is a
  /// different car in the same space from one drive to the next, a bin is put out where
  /// its owner puts it; 0 puts the same object at the same centimetre in every drive,
  /// which real streets do not. Parking bays here are 5.6-7 m apart for 4-4.9 m cars,
  /// which leaves about a metre either way; a bin moves by about half of that.
  double parked_shift_m = 1.0;
  double bin_shift_m = 0.5;
  /// Probability a low-vegetation patch (hiding guide posts) is grown in a drive.
  double vegetation_presence = 0.5;
};

/// Object densities of HD-map worlds (what the map implies but does not contain).
struct HdMapDensityConfig {
  double guardrail_post_spacing_m = 3.0;
  double fence_post_spacing_m = 2.5;
  double lamp_spacing_m = 30.0;  ///< along road borders and curbstones
  double lamp_offset_m = 0.6;    ///< outward from the border
  /// Default origin of OpenDRIVE files without a geoReference (Ingolstadt).
  double xodr_default_lat_deg = 48.7665;
  double xodr_default_lon_deg = 11.4258;
};

/// The complete simulator configuration.
struct SimConfig {
  RadarSimConfig radar;
  GnssSimConfig gnss;
  DriveSimConfig drive;
  TrafficSimConfig traffic;
  HdMapDensityConfig hdmap;
  std::vector<SensorMount> sensors = default_front_mounts();
  std::uint64_t seed = 1;
  /// 0 = the whole route; otherwise the drive ends after this many seconds.
  double duration_s = 0.0;
  /// Attach a full data cube to every sensor frame with time < cube_seconds.
  bool cube = false;
  double cube_seconds = 0.5;
  /// Error sources of real vehicles (realism.hpp); default = ideal preset (all off).
  RealismConfig realism;
};

}  // namespace polmap::sim
