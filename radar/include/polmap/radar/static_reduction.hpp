#pragma once
/// @file static_reduction.hpp
/// Static reduction (paper §III-B1, "Fourier modulation theorem"): from the full
/// range × chirp × virtual-channel × polarization data cube of one sensor frame,
/// the image of the static world in polar coordinates. For every beam the ego-motion
/// predicts one radial velocity of static targets, independent of range; instead of
/// a full Doppler FFT the slow-time signal is demodulated by exactly that Doppler
/// and summed (the DTFT evaluated at the static Doppler), after beamforming over
/// the virtual channels.
///
/// Cube convention (recording.hpp DataCube, tools/sim/README.md "Data cube"): sample
/// (pol, v, c, r) of an echo with amplitude A at azimuth φ and radial velocity v_r is
///   A · W(r) · exp(+j2π·d·(v − (V−1)/2)·sin φ) · exp(−j2π·(2 v_r/λ)·T_c·(c − (C−1)/2)),
/// d = element spacing in wavelengths, T_c = chirp interval, phases referred to
/// the array and chirp-train centres. The reduction for beam φ_b is
///   s(pol, b, r) = Σ_v Σ_c w_v w_c · exp(−j2π d (v−(V−1)/2) sin φ_b)
///                  · exp(+j2π (2 v_static(φ_b)/λ) T_c (c−(C−1)/2)) · cube / (Σw_v Σw_c),
/// so a static point scatterer on the beam centre returns its amplitude A, and an
/// echo whose Doppler differs by more than ~2 Doppler bins is suppressed by the
/// window's sidelobes (Hann: ≤ −31 dB).
///
/// Static radial velocity (zero side slip, as in egomotion.hpp): sensor velocity in the
/// vehicle frame v_s = (v − ω·y_m, ω·x_m), rotated into the sensor frame;
/// v_static(φ) = −v_s·(cos φ, sin φ) (approaching targets negative).
#include <optional>
#include <vector>

#include "polmap/schema/radar_spec.hpp"
#include "polmap/schema/recording.hpp"

namespace polmap::radar {

struct StaticReductionConfig {
  /// Beam centres (sensor azimuth, ascending). Empty: uniform over ±spec.fov_half_rad
  /// at beam_spacing_rad.
  std::vector<float> azimuth_bins_rad;
  /// Spacing of the default beams: 1.5° (≤ half the ~3° beamwidth of RadarSpec).
  double beam_spacing_rad = 1.5 * 3.14159265358979323846 / 180.0;
  /// Array taper w_v = p + (1−p)·cos²(π x_v), x_v ∈ [−½, ½]: pedestal 0.7 gives ~3.5°
  /// beamwidth at boresight with −17 dB sidelobes from 31 elements at λ/2.
  double taper_pedestal = 0.7;
  /// Complex noise σ of the reduced spectrum per cell and channel; 0: estimate from
  /// the data (median power of all cells / ln 2, the exponential's median: robust
  /// while most cells hold noise only).
  double noise_sigma = 0.0;
  /// Cells whose strongest channel stays below (floor_sigmas·σ)² are dropped, as a
  /// recorder does (0 keeps every cell).
  double floor_sigmas = 3.0;
};

/// Static radial velocity at sensor azimuth φ for vehicle motion (v, ω) (zero side slip).
double static_radial_velocity(const SensorMount& mount, double v_mps, double yaw_rate_rps,
                              double azimuth_rad);

/// Reduces a data cube to a static-world PolSpectrum over the cube's range bins.
/// Throws ValidationError for an inconsistent cube (data size, zero dimensions).
PolSpectrum static_reduce(const DataCube& cube, const SensorMount& mount, double v_mps,
                          double yaw_rate_rps, const StaticReductionConfig& cfg = {});

}  // namespace polmap::radar
