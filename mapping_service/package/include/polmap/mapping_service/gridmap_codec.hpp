#pragma once
/// @file gridmap_codec.hpp
/// The compact gridmap encoding of drive package format 2 (schema/drive_package.md,
/// "Compact gridmap"): per cell 16-bit codes of N, hits, the total power and the upper
/// Cholesky factor of the covariance, quantized relative to the drive's noise power, so
/// that a 1 km drive at full polarimetry takes ~5 MB instead of ~95 MB. Pure values in,
/// values out.
///
/// Power: P = tr C in log steps, k = 1 + round(ln(P / P_floor) / power_step) (0 = empty).
/// Shape: C = Uᴴ U (U upper triangular, U_ii ≥ 0); every real scalar u of U (a diagonal
/// U_ii, or Re/Im of an off-diagonal) is companded,
///     k = round(asinh(u / b) / s),  û = b · sinh(k · s),  b = zero_step_noise · σ / s
/// (σ² = noise power per component): near zero the step is zero_step_noise·σ, for |u| ≫ b
/// it is relative, s. Decoded C = Ûᴴ Û scaled to the coded power: positive semi-definite
/// whatever the rounding (rounding C itself makes the rank-one covariance of a strong
/// return seen in few looks indefinite, and pCFAR's Cholesky then fails), and its power
/// is kept to ±power_step/2 (the line extractor needs the power image nearly exact).
/// Diagonal codes are stored as k, off-diagonal ones zigzag-coded (0, −1, 1, … → 0, 1, 2, …).
/// Cells below floor_snr_db over q·σ² are stored empty (P = 0, hits = 0: the noise-floor
/// mask); N and hits are exact up to 65535 (above, both are scaled so that N = 65535 and
/// hits/N is kept); N of an empty cell keeps `empty_count_bits` significant bits (it only
/// weights the cell's zero in fleet means). Cells below offdiag_min_snr_db keep only the
/// diagonal of U (their phases are noise).
#include <array>
#include <complex>
#include <cstdint>
#include <span>

#include "polmap/schema/polarimetry.hpp"

namespace polmap::mapping {

/// Parameters of the compact encoding; recorded in the manifest (gridmap.codec).
struct GridmapCodecConfig {
  /// Relative step s of the factor entries of strong cells (0.01: ±0.5 %, so components
  /// keep ±0.05 dB of their share of the power and phases about ±0.6°). 0.001..0.05.
  double relative_step = 0.01;
  /// Step of the factor entries at zero, in units of the noise amplitude σ. 0.001..1.
  double zero_step_noise = 0.05;
  /// Relative step of the cell's total power trace(C), coded on its own in log steps
  /// (0.001: ±0.05 %, ±0.002 dB). The line extractor's median/ridge/thinning chain needs
  /// the power image nearly exact; the polarimetric shape (the factor codes) is coarser.
  double power_step = 0.001;
  /// Cells with trace(C) below this many dB over q·σ² keep only their diagonal (their
  /// polarimetric phases are noise; pCFAR's decisions did not change on simulated drives).
  double offdiag_min_snr_db = 5.0;
  /// Cells with trace(C) below this many dB over q·σ² are stored empty (the noise-floor
  /// mask; the line extractor reads everything below 0 dB as its floor anyway).
  double floor_snr_db = -3.0;
  /// Significant bits of N kept in empty cells (1..16; 16 = exact): 2 keeps it to ±12.5 %,
  /// enough for the weight of a zero in fleet means, and halves the N band.
  int empty_count_bits = 2;
};

/// Largest N (and hits) a code holds.
inline constexpr std::uint32_t kCompactMaxCount = 65535;

/// Encoder/decoder of one drive's cells (q and σ² fixed).
class GridmapCodec {
 public:
  /// noise_power: σ² per component (> 0). Contract: cfg within the documented ranges.
  GridmapCodec(int q, double noise_power, const GridmapCodecConfig& cfg = {});

  [[nodiscard]] int q() const { return q_; }
  /// Codes per cell: N, hits, P (power), then the q² scalars of the upper Cholesky factor
  /// U (C ∝ Uᴴ U) in layer order (diagonal: 1, off-diagonal: Re, Im).
  [[nodiscard]] int codes_per_cell() const { return 3 + q_ * q_; }
  /// Largest |k| whose value is finite and ≤ 1e30 (larger codes are invalid).
  [[nodiscard]] std::uint16_t max_magnitude_code() const { return max_code_; }

  [[nodiscard]] std::int32_t encode_value(double v) const;
  [[nodiscard]] double decode_value(std::int32_t k) const;

  /// Encodes a cell (n looks, hits stored bins, upper-triangle layers C in layer order).
  /// `out` has codes_per_cell() entries. n = 0 gives all-zero codes.
  void encode_cell(std::uint32_t n, std::uint32_t hits, std::span<const std::complex<float>> layers,
                   std::span<std::uint16_t> out) const;
  /// Decoded cell: layers in layer order, |C_ij| clamped to sqrt(C_ii C_jj).
  struct Cell {
    std::uint32_t n = 0;
    std::uint32_t hits = 0;
    std::array<cdouble, 10> layers{};  ///< q(q+1)/2 used (q ≤ 4)
  };
  /// Decodes codes_per_cell() codes (contract: each code is valid_codes()).
  [[nodiscard]] Cell decode_cell(std::span<const std::uint16_t> codes) const;
  /// True if the codes of a cell are consistent: N = 0 ⇒ all zero; hits ≤ N; value codes
  /// within max_magnitude_code() (diagonal ≥ 0).
  [[nodiscard]] bool valid_codes(std::span<const std::uint16_t> codes) const;

 private:
  int q_;
  double b_;
  double s_;
  double offdiag_min_power_;
  double floor_power_;
  double power_step_;
  int empty_count_bits_;
  std::uint16_t max_code_;
};

}  // namespace polmap::mapping
