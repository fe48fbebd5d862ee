// Compact gridmap codes (package format 2): see gridmap_codec.hpp.
#include "polmap/mapping_service/gridmap_codec.hpp"

#include <algorithm>
#include <bit>
#include <cmath>

#include "polmap/schema/errors.hpp"

namespace polmap::mapping {

namespace {
/// Off-diagonal codes are zigzag-coded (0, -1, 1, -2, ... -> 0, 1, 2, 3, ...) so that an
/// empty cell is all zeros in every band (sparse blocks stay zero).
std::uint16_t zigzag(std::int32_t k) {
  return static_cast<std::uint16_t>(k >= 0 ? 2 * k : -2 * k - 1);
}
std::int32_t unzigzag(std::uint16_t z) { return (z & 1) != 0 ? -(std::int32_t(z) + 1) / 2 : z / 2; }
int layer_of(int q, int i, int j) { return i * q - i * (i - 1) / 2 + (j - i); }

/// n rounded to nearest with `bits` significant bits (n < 2^bits exact), at least 1.
std::uint32_t round_significant(std::uint32_t n, int bits) {
  if (n < (1U << bits)) return n;
  const int drop = std::bit_width(n) - bits;
  const std::uint32_t half = 1U << (drop - 1);
  const std::uint64_t r = ((static_cast<std::uint64_t>(n) + half) >> drop) << drop;
  return static_cast<std::uint32_t>(std::min<std::uint64_t>(r, kCompactMaxCount));
}
}  // namespace

GridmapCodec::GridmapCodec(int q, double noise_power, const GridmapCodecConfig& cfg)
    : q_(q),
      b_(cfg.zero_step_noise * std::sqrt(noise_power) / cfg.relative_step),
      s_(cfg.relative_step),
      offdiag_min_power_(q * noise_power * std::pow(10.0, cfg.offdiag_min_snr_db / 10.0)),
      floor_power_(q * noise_power * std::pow(10.0, cfg.floor_snr_db / 10.0)),
      power_step_(cfg.power_step),
      empty_count_bits_(cfg.empty_count_bits) {
  POLMAP_EXPECT(cfg.power_step >= 1e-4 && cfg.power_step <= 0.05);
  POLMAP_EXPECT(q >= 1 && q <= 4);
  POLMAP_EXPECT(std::isfinite(noise_power) && noise_power > 0.0);
  POLMAP_EXPECT(cfg.relative_step >= 0.001 && cfg.relative_step <= 0.05);
  POLMAP_EXPECT(cfg.zero_step_noise >= 0.001 && cfg.zero_step_noise <= 1.0);
  POLMAP_EXPECT(cfg.empty_count_bits >= 1 && cfg.empty_count_bits <= 16);
  POLMAP_EXPECT(std::isfinite(b_) && b_ > 0.0);
  const double kmax = std::asinh(1e15 / b_) / s_;
  max_code_ = static_cast<std::uint16_t>(std::clamp(std::floor(kmax), 1.0, 32767.0));
}

std::int32_t GridmapCodec::encode_value(double v) const {
  const double k = std::round(std::asinh(v / b_) / s_);
  return static_cast<std::int32_t>(std::clamp(k, -double(max_code_), double(max_code_)));
}

double GridmapCodec::decode_value(std::int32_t k) const { return b_ * std::sinh(k * s_); }

namespace {
/// Upper Cholesky factor U of a Hermitian PSD C (C = Uᴴ U, U_ii ≥ 0), layer order. A pivot
/// below 1e-9 of the trace (rank deficiency, float rounding) ends that row with zeros.
std::array<cdouble, 10> upper_factor(int q, std::span<const std::complex<float>> c) {
  std::array<cdouble, 10> u{};
  double trace = 0.0;
  for (int i = 0; i < q; ++i) trace += std::max(0.0F, c[layer_of(q, i, i)].real());
  for (int i = 0; i < q; ++i) {
    double pivot = std::max(0.0F, c[layer_of(q, i, i)].real());
    for (int k = 0; k < i; ++k) pivot -= std::norm(u[layer_of(q, k, i)]);
    if (!(pivot > 1e-9 * trace)) continue;  // row i stays zero
    const double uii = std::sqrt(pivot);
    u[layer_of(q, i, i)] = uii;
    for (int j = i + 1; j < q; ++j) {
      cdouble v = cdouble(c[layer_of(q, i, j)]);
      for (int k = 0; k < i; ++k) v -= std::conj(u[layer_of(q, k, i)]) * u[layer_of(q, k, j)];
      u[layer_of(q, i, j)] = v / uii;
    }
  }
  return u;
}
}  // namespace

void GridmapCodec::encode_cell(std::uint32_t n, std::uint32_t hits,
                               std::span<const std::complex<float>> layers,
                               std::span<std::uint16_t> out) const {
  POLMAP_EXPECT(out.size() == static_cast<std::size_t>(codes_per_cell()));
  POLMAP_EXPECT(layers.size() >= static_cast<std::size_t>(q_ * (q_ + 1) / 2));
  std::fill(out.begin(), out.end(), std::uint16_t{0});
  if (n == 0) return;
  hits = std::min(hits, n);
  if (n > kCompactMaxCount) {  // keep hits/N
    hits = static_cast<std::uint32_t>(std::llround(double(hits) * kCompactMaxCount / n));
    n = kCompactMaxCount;
  }
  double trace = 0.0;
  for (int i = 0; i < q_; ++i) trace += layers[layer_of(q_, i, i)].real();
  const bool keep_offdiag = trace >= offdiag_min_power_;
  std::array<cdouble, 10> u{};
  if (!(trace >= floor_power_)) {
    // below the floor: all codes stay zero (empty)
  } else if (keep_offdiag) {
    u = upper_factor(q_, layers);
  } else {  // diagonal only
    for (int i = 0; i < q_; ++i) {
      u[layer_of(q_, i, i)] = std::sqrt(std::max(0.0F, layers[layer_of(q_, i, i)].real()));
    }
  }
  bool any = false;
  int band = 3;
  for (int i = 0; i < q_; ++i) {
    for (int j = i; j < q_; ++j) {
      const cdouble v = u[layer_of(q_, i, j)];
      if (i == j) {
        const std::int32_t k = std::max(0, encode_value(v.real()));
        any = any || k != 0;
        out[band++] = static_cast<std::uint16_t>(k);
      } else {
        const std::int32_t kr = encode_value(v.real());
        const std::int32_t ki = encode_value(v.imag());
        any = any || kr != 0 || ki != 0;
        out[band++] = zigzag(kr);
        out[band++] = zigzag(ki);
      }
    }
  }
  if (any) {
    out[0] = static_cast<std::uint16_t>(n);
    out[1] = static_cast<std::uint16_t>(hits);
    const double k = std::round(std::log(trace / floor_power_) / power_step_);
    out[2] = static_cast<std::uint16_t>(1.0 + std::clamp(k, 0.0, 65534.0));
  } else {  // the noise-floor mask: observed, nothing kept
    out[0] = static_cast<std::uint16_t>(std::max(1U, round_significant(n, empty_count_bits_)));
    out[1] = 0;
  }
}

bool GridmapCodec::valid_codes(std::span<const std::uint16_t> codes) const {
  if (codes.size() != static_cast<std::size_t>(codes_per_cell())) return false;
  const std::uint16_t n = codes[0];
  const bool empty = codes[2] == 0;  // nothing stored (also every N = 0 cell)
  if (codes[1] > n || (empty && codes[1] != 0)) return false;
  int band = 3;
  for (int i = 0; i < q_; ++i) {
    for (int j = i; j < q_; ++j) {
      if (i == j) {
        const std::uint16_t k = codes[band++];
        if (k > max_code_ || (empty && k != 0)) return false;
      } else {
        for (int part = 0; part < 2; ++part) {
          const int k = unzigzag(codes[band++]);
          if (std::abs(k) > max_code_ || (empty && k != 0)) return false;
        }
      }
    }
  }
  return true;
}

GridmapCodec::Cell GridmapCodec::decode_cell(std::span<const std::uint16_t> codes) const {
  POLMAP_EXPECT(codes.size() == static_cast<std::size_t>(codes_per_cell()));
  Cell c;
  c.n = codes[0];
  c.hits = codes[1];
  if (c.n == 0) return c;
  if (codes[2] == 0) return c;  // empty: observed, nothing stored
  std::array<cdouble, 10> u{};
  int band = 3;
  for (int i = 0; i < q_; ++i) {
    for (int j = i; j < q_; ++j) {
      if (i == j) {
        u[layer_of(q_, i, i)] = {decode_value(codes[band++]), 0.0};
      } else {
        const double re = decode_value(unzigzag(codes[band]));
        const double im = decode_value(unzigzag(codes[band + 1]));
        band += 2;
        u[layer_of(q_, i, j)] = {re, im};
      }
    }
  }
  // C = Uᴴ U (positive semi-definite whatever the rounding of U), scaled to the power code.
  const double power = floor_power_ * std::exp((codes[2] - 1) * power_step_);
  double trace = 0.0;
  for (int i = 0; i < q_; ++i) {
    for (int j = i; j < q_; ++j) {
      cdouble v{};
      for (int k = 0; k <= i; ++k) v += std::conj(u[layer_of(q_, k, i)]) * u[layer_of(q_, k, j)];
      c.layers[layer_of(q_, i, j)] = i == j ? cdouble(v.real(), 0.0) : v;
      if (i == j) trace += v.real();
    }
  }
  if (trace > 0.0) {
    for (int l = 0; l < q_ * (q_ + 1) / 2; ++l) c.layers[l] *= power / trace;
  } else {  // every factor code rounded to zero: unpolarized at the coded power
    for (int i = 0; i < q_; ++i) c.layers[layer_of(q_, i, i)] = power / q_;
  }
  return c;
}

}  // namespace polmap::mapping
