#pragma once
// Internal to polmap_radar: the inner loop of the ego-motion RANSAC (egomotion.cpp), in a
// header of its own so that its test can hold it against the straightforward loop.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <limits>

namespace polmap::radar::detail {

/// Radial-velocity rows of the augmented detections (structure of arrays, n entries):
/// v_r = h0·v + h1·ω predicted, ∂v_r/∂θ = g0·v + g1·ω, ext = extrapolation variance / σ².
struct DopplerRows {
  const double* vr = nullptr;
  const double* h0 = nullptr;
  const double* h1 = nullptr;
  const double* g0 = nullptr;
  const double* g1 = nullptr;
  const double* ext = nullptr;
  std::size_t n = 0;
};

/// Support of one motion hypothesis: inliers = −1 when scoring gave up early.
struct DopplerSupport {
  int inliers = -1;
  double cost = std::numeric_limits<double>::infinity();  ///< Σ_in (q − 1), q = r²/t²
};

/// Rows are tested in blocks of this many; the early exit is checked per block.
inline constexpr std::size_t kDopplerBlock = 64;

/// Inliers of (v, ω): a row is one when q = r² / t² < 1, r = v_r − h·m and
/// t² = thr2·(1 + az2·(g·m)² + ext). Gives up (inliers = −1) once the remaining rows could
/// not reach `to_beat`. Per block, a division-free pass keeps the rows with r² < t² (a
/// superset of q < 1: rounding cannot turn r² ≥ t² into q < 1), then q is formed and summed
/// for those only, in row order: the count and cost of dividing every row
/// (doppler_support_reference), without a division per outlier (most rows are outliers).
inline DopplerSupport doppler_support(const DopplerRows& p, double v, double w, double thr2,
                                      double az2, int to_beat = -1) {
  int inl = 0;
  double cost = 0.0;
  double r2s[kDopplerBlock], t2s[kDopplerBlock];
  for (std::size_t j0 = 0; j0 < p.n; j0 += kDopplerBlock) {
    const std::size_t j1 = std::min(p.n, j0 + kDopplerBlock);
    int kept = 0;
    for (std::size_t j = j0; j < j1; ++j) {
      const double r = p.vr[j] - (p.h0[j] * v + p.h1[j] * w);
      const double d = p.g0[j] * v + p.g1[j] * w;
      const double t2 = thr2 * (1.0 + az2 * d * d + p.ext[j]);
      const double r2 = r * r;
      r2s[kept] = r2;
      t2s[kept] = t2;
      kept += r2 < t2 ? 1 : 0;
    }
    for (int k = 0; k < kept; ++k) {
      const double q = r2s[k] / t2s[k];
      if (q < 1.0) {
        ++inl;
        cost += q;
      }
    }
    if (inl + static_cast<std::int64_t>(p.n - j1) < to_beat) return {};
  }
  return {inl, cost - inl};
}

/// The straightforward version of doppler_support (one division per row), for tests.
inline DopplerSupport doppler_support_reference(const DopplerRows& p, double v, double w,
                                                double thr2, double az2, int to_beat = -1) {
  int inl = 0;
  double cost = 0.0;
  for (std::size_t j0 = 0; j0 < p.n; j0 += kDopplerBlock) {
    const std::size_t j1 = std::min(p.n, j0 + kDopplerBlock);
    for (std::size_t j = j0; j < j1; ++j) {
      const double r = p.vr[j] - (p.h0[j] * v + p.h1[j] * w);
      const double d = p.g0[j] * v + p.g1[j] * w;
      const double q = r * r / (thr2 * (1.0 + az2 * d * d + p.ext[j]));
      inl += q < 1.0 ? 1 : 0;
      cost += q < 1.0 ? q : 0.0;
    }
    if (inl + static_cast<std::int64_t>(p.n - j1) < to_beat) return {};
  }
  return {inl, cost - inl};
}

}  // namespace polmap::radar::detail
