#pragma once
/// @file random.hpp
/// Deterministic random numbers: std::mt19937_64 with distributions implemented
/// here (so output is identical across standard libraries), and seed mixing so
/// that every drive, frame and object has its own independent stream.
#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdint>
#include <numbers>
#include <random>

namespace polmap::sim {

/// SplitMix64 finaliser: a well-mixed 64-bit hash.
inline std::uint64_t mix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ULL;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
  return x ^ (x >> 31);
}

/// Seed of a sub-stream, e.g. seed_of(seed, drive, cycle, sensor).
template <typename... T>
std::uint64_t seed_of(std::uint64_t base, T... parts) {
  std::uint64_t h = mix64(base);
  ((h = mix64(h ^ static_cast<std::uint64_t>(parts))), ...);
  return h;
}

/// Uniform [0,1) from a hash (stateless draws, e.g. per-object presence in a drive).
inline double hash_uniform(std::uint64_t h) {
  return static_cast<double>(mix64(h) >> 11) * 0x1.0p-53;
}

/// Tables of the Marsaglia-Tsang ziggurat (built once).
struct Ziggurat {
  static constexpr double kR = 3.442619855899;
  std::uint32_t kn[128];
  double wn[128], fn[128];
  Ziggurat() {
    const double m1 = 2147483648.0, vn = 9.91256303526217e-3;
    double dn = kR, tn = dn;
    const double q = vn / std::exp(-0.5 * dn * dn);
    kn[0] = static_cast<std::uint32_t>((dn / q) * m1);
    kn[1] = 0;
    wn[0] = q / m1;
    wn[127] = dn / m1;
    fn[0] = 1.0;
    fn[127] = std::exp(-0.5 * dn * dn);
    for (int i = 126; i >= 1; --i) {
      dn = std::sqrt(-2.0 * std::log(vn / dn + std::exp(-0.5 * dn * dn)));
      kn[i + 1] = static_cast<std::uint32_t>((dn / tn) * m1);
      tn = dn;
      fn[i] = std::exp(-0.5 * dn * dn);
      wn[i] = dn / m1;
    }
  }
};
inline const Ziggurat& ziggurat() {
  static const Ziggurat z;
  return z;
}

/// Standard normal by the Marsaglia-Tsang ziggurat (128 layers) from any generator with
/// bits() (64 random bits) and uniform() in [0, 1).
template <typename Gen>
double ziggurat_normal(Gen& g) {
  const Ziggurat& z = ziggurat();
  for (;;) {
    const std::uint64_t u = g.bits();
    const int iz = static_cast<int>(u & 127U);
    const auto hz = static_cast<std::int32_t>(static_cast<std::uint32_t>(u >> 32));
    const double x = hz * z.wn[iz];
    if (static_cast<std::uint32_t>(hz < 0 ? -static_cast<std::int64_t>(hz) : hz) < z.kn[iz])
      return x;
    if (iz == 0) {  // tail beyond r
      double xt, yt;
      do {
        xt = -std::log1p(-g.uniform()) / Ziggurat::kR;
        yt = -std::log1p(-g.uniform());
      } while (yt + yt < xt * xt);
      return hz > 0 ? Ziggurat::kR + xt : -Ziggurat::kR - xt;
    }
    if (z.fn[iz] + g.uniform() * (z.fn[iz - 1] - z.fn[iz]) < std::exp(-0.5 * x * x)) return x;
  }
}

class Rng {
 public:
  explicit Rng(std::uint64_t seed) : eng_(seed) {}

  std::uint64_t bits() { return eng_(); }
  /// Uniform in [0, 1).
  double uniform() { return static_cast<double>(eng_() >> 11) * 0x1.0p-53; }
  double uniform(double a, double b) { return a + (b - a) * uniform(); }
  /// Integer uniform in [0, n).
  std::uint64_t index(std::uint64_t n) { return static_cast<std::uint64_t>(uniform() * n) % n; }
  bool bernoulli(double p) { return uniform() < p; }
  /// Standard normal (ziggurat).
  double normal() { return ziggurat_normal(*this); }
  double normal(double mean, double sigma) { return mean + sigma * normal(); }
  /// Circular complex Gaussian with E|z|^2 = variance.
  std::complex<double> cnormal(double variance = 1.0) {
    const double s = std::sqrt(0.5 * variance);
    const double re = normal();
    const double im = normal();
    return {s * re, s * im};
  }
  /// Exponential with mean 1.
  double exponential() { return -std::log1p(-uniform()); }
  /// Poisson (inversion for small means, normal approximation above 50).
  int poisson(double mean) {
    if (mean <= 0) return 0;
    if (mean > 50) return std::max(0, static_cast<int>(std::lround(normal(mean, std::sqrt(mean)))));
    const double l = std::exp(-mean);
    int k = 0;
    double p = uniform();
    while (p > l) {
      ++k;
      p *= uniform();
    }
    return k;
  }
  /// Unit phasor with uniform phase.
  std::complex<double> phasor() {
    const double a = 2.0 * std::numbers::pi * uniform();
    return {std::cos(a), std::sin(a)};
  }

 private:
  std::mt19937_64 eng_;
};

/// Counter-based generator keyed by a hash: cheap to create per resolution cell, so the
/// speckle of a cell can be a function of (scene geometry, cell) - frozen while the
/// sensor stands still, fresh as soon as it moves.
class HashRng {
 public:
  explicit HashRng(std::uint64_t key) : key_(mix64(key)) {}
  std::uint64_t bits() { return mix64(key_ + 0x9E3779B97F4A7C15ULL * (++n_)); }
  double uniform() { return static_cast<double>(bits() >> 11) * 0x1.0p-53; }
  /// Standard normal (ziggurat).
  double normal() { return ziggurat_normal(*this); }
  std::complex<double> cnormal(double variance = 1.0) {
    const double s = std::sqrt(0.5 * variance);
    const double re = normal();
    const double im = normal();
    return {s * re, s * im};
  }

 private:
  std::uint64_t key_;
  std::uint64_t n_ = 0;
};

}  // namespace polmap::sim
