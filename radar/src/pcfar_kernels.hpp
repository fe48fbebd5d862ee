#pragma once
// Internal to polmap_radar: the arithmetic of the pCFAR test shared by the dense
// reference (point_extractor.cpp, one raster per chunk) and the streaming fast path
// (point_extractor_stream.cpp, row by row from the gridmap). Both must compute the same
// numbers in the same order, so that they find exactly the same candidates.
#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <complex>
#include <cstdint>
#include <numbers>
#include <utility>
#include <vector>

#include "polmap/radar/covariance_gridmap.hpp"
#include "polmap/radar/point_extractor.hpp"
#include "polmap/radar/polarimetry.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::radar::pcfar {

template <int Q>
using CMat = Eigen::Matrix<cdouble, Q, Q>;

/// Clips the cell rectangle [x0, x1) × [y0, y1) to a w × h raster; false if empty.
inline bool clip_to_raster(int w, int h, int& x0, int& y0, int& x1, int& y1) {
  x0 = std::clamp(x0, 0, w);
  x1 = std::clamp(x1, 0, w);
  y0 = std::clamp(y0, 0, h);
  y1 = std::clamp(y1, 0, h);
  return x1 > x0 && y1 > y0;
}

/// Planes of the CFAR sums per cell: plane 0 is the observed indicator (N > 0), then per
/// covariance layer its real part and, for off-diagonal layers, its imaginary part.
struct PlaneLayout {
  int q = 0;
  int num = 0;              ///< planes per cell
  std::vector<int> re, im;  ///< plane of layer l's real / imaginary part (−1: none)

  explicit PlaneLayout(int q_) : q(q_) {
    const int L = num_layers(q);
    num = 1;
    re.resize(L);
    im.resize(L);
    for (int i = 0; i < q; ++i) {
      for (int j = i; j < q; ++j) {
        const int l = layer_index(q, i, j);
        re[l] = num++;
        im[l] = i == j ? -1 : num++;
      }
    }
  }
};

/// trace(C) of a cell from its layers (stride: distance between layers), as a float
/// sum in diagonal order (CovarianceRaster::power).
inline float cell_power(const std::complex<float>* layers, std::size_t stride, int q) {
  float p = 0.0F;
  for (int i = 0; i < q; ++i) p += layers[layer_index(q, i, i) * stride].real();
  return p;
}

/// C of a cell from its layers (stride: distance between layers).
template <int Q>
CMat<Q> cell_matrix(const std::complex<float>* layers, std::size_t stride) {
  CMat<Q> c;
  int l = 0;
  for (int i = 0; i < Q; ++i) {
    for (int j = i; j < Q; ++j) {
      const std::complex<float> v = layers[l++ * stride];
      c(i, j) = cdouble(v.real(), i == j ? 0.0 : v.imag());
      c(j, i) = std::conj(c(i, j));
    }
  }
  return c;
}

/// Σ from plane sums (sums[0] = number of observed cells).
template <int Q>
CMat<Q> mean_matrix(const PlaneLayout& p, const double* sums) {
  CMat<Q> s;
  const double inv = 1.0 / sums[0];
  for (int i = 0; i < Q; ++i) {
    for (int j = i; j < Q; ++j) {
      const int l = layer_index(Q, i, j);
      const double re = sums[p.re[l]] * inv;
      const double im = p.im[l] >= 0 ? sums[p.im[l]] * inv : 0.0;
      s(i, j) = cdouble(i == j ? std::max(0.0, re) : re, im);
      s(j, i) = std::conj(s(i, j));
    }
  }
  return s;
}

/// d_ex by Cholesky factors: the straightforward form, the reference of excess().
template <int Q>
double excess_reference(const CMat<Q>& sigma, const CMat<Q>& c, bool& ok) {
  const Eigen::LLT<CMat<Q>> ls(sigma), lc(c);
  ok = ls.info() == Eigen::Success && lc.info() == Eigen::Success;
  if (!ok) return 0.0;
  double logdet = 0.0;  // ln|C| − ln|Σ|
  for (int i = 0; i < Q; ++i) {
    logdet += 2.0 * (std::log(lc.matrixLLT()(i, i).real()) - std::log(ls.matrixLLT()(i, i).real()));
  }
  const double tr = ls.solve(c).trace().real();
  return std::max(0.0, (tr - logdet - Q) / Q);
}

namespace detail {
/// Cholesky factor L (lower, real diagonal) of a Hermitian q×q matrix from its lower
/// triangle, q ≤ 3; false if it is not positive definite (a pivot ≤ 0).
template <int Q>
bool cholesky(const CMat<Q>& m, cdouble (&L)[3][3]) {
  for (int j = 0; j < Q; ++j) {
    double d = m(j, j).real();
    for (int k = 0; k < j; ++k) d -= std::norm(L[j][k]);
    if (!(d > 0.0)) return false;
    const double ljj = std::sqrt(d);
    L[j][j] = ljj;
    for (int i = j + 1; i < Q; ++i) {
      cdouble t = m(i, j);
      for (int k = 0; k < j; ++k) t -= L[i][k] * std::conj(L[j][k]);
      L[i][j] = t / ljj;
    }
  }
  return true;
}
}  // namespace detail

/// d_ex (point_extractor.hpp); ok = false when either matrix is not positive definite.
/// The Cholesky form of excess_reference() written out for q ≤ 3: with Σ = L_Σ L_Σᴴ and
/// C = L_C L_Cᴴ, ln|C| − ln|Σ| = 2 ln(Π l_C,ii / Π l_Σ,ii) (one logarithm instead of 2q)
/// and tr(Σ⁻¹C) = ‖L_Σ⁻¹ L_C‖²_F (a triangular solve with a triangular right-hand side).
/// As stable as the factorization; equals excess_reference() to rounding
/// (tests/radar/pcfar_excess_test.cpp).
template <int Q>
double excess(const CMat<Q>& sigma, const CMat<Q>& c, bool& ok) {
  cdouble ls[3][3] = {}, lc[3][3] = {};
  ok = detail::cholesky<Q>(sigma, ls) && detail::cholesky<Q>(c, lc);
  if (!ok) return 0.0;
  double ratio = 1.0;  // Π l_C,ii / l_Σ,ii
  for (int i = 0; i < Q; ++i) ratio *= lc[i][i].real() / ls[i][i].real();
  // X = L_Σ⁻¹ L_C, lower triangular, column by column by forward substitution.
  double tr = 0.0;
  for (int j = 0; j < Q; ++j) {
    cdouble x[3] = {};
    for (int i = j; i < Q; ++i) {
      cdouble t = lc[i][j];
      for (int k = j; k < i; ++k) t -= ls[i][k] * x[k];
      x[i] = t / ls[i][i].real();
      tr += std::norm(x[i]);
    }
  }
  const double logdet = 2.0 * std::log(ratio);
  return std::max(0.0, (tr - logdet - Q) / Q);
}

/// Directions of the line strips (half-plane: a strip runs both ways).
inline constexpr int kStripDirections = 8;

/// Strip offsets (cells) per direction, both sides of the guard.
inline std::vector<std::vector<std::pair<int, int>>> strip_offsets(int guard, int train) {
  std::vector<std::vector<std::pair<int, int>>> strips(kStripDirections);
  for (int k = 0; k < kStripDirections; ++k) {
    const double a = std::numbers::pi * k / kStripDirections;
    for (int t = guard + 1; t <= train; ++t) {
      const int dx = static_cast<int>(std::lround(t * std::cos(a)));
      const int dy = static_cast<int>(std::lround(t * std::sin(a)));
      strips[k].push_back({dx, dy});
      strips[k].push_back({-dx, -dy});
    }
  }
  return strips;
}

/// Greatest-of line strip (PointExtractorConfig::line_aware) through cell (x, y) of a
/// w × h raster: of the strips with at least half their cells observed, the one whose
/// mean trace is highest and above best_tr. layers_at(xx, yy) gives the cell's layers
/// (`stride` apart) or nullptr when the cell is unobserved. On a find, `best` holds that
/// strip's plane sums and best_tr its mean trace; returns whether one was found.
/// The strips are compared by their diagonal planes only and the winner's full plane
/// sums formed once: each plane is summed over the same cells in the same order as a
/// one-pass version would, so the sums are the same bit for bit at a third of the work.
/// diag_at(xx, yy) gives the cell's Q diagonal layers (real parts, contiguous) or nullptr
/// when the cell is unobserved: the comparison reads those only.
template <int Q, typename LayersAt, typename DiagAt>
bool brightest_strip(const std::vector<std::vector<std::pair<int, int>>>& strips,
                     const PlaneLayout& p, int x, int y, int w, int h, std::size_t stride,
                     LayersAt&& layers_at, DiagAt&& diag_at, std::vector<double>& strip,
                     std::vector<double>& best, double& best_tr) {
  constexpr int L = num_layers(Q);
  const std::vector<std::pair<int, int>>* winner = nullptr;
  for (const auto& s : strips) {
    double n = 0.0;
    double diag[Q] = {};
    for (const auto& [dx, dy] : s) {
      const int xx = x + dx, yy = y + dy;
      if (xx < 0 || yy < 0 || xx >= w || yy >= h) continue;
      const float* v = diag_at(xx, yy);
      if (v == nullptr) continue;
      n += 1.0;
      for (int i = 0; i < Q; ++i) diag[i] += v[i];
    }
    if (n < 0.5 * static_cast<double>(s.size())) continue;
    double tr = 0.0;
    for (int i = 0; i < Q; ++i) tr += diag[i];
    tr /= n;
    if (tr > best_tr) {
      best_tr = tr;
      winner = &s;
    }
  }
  if (winner == nullptr) return false;
  std::fill(strip.begin(), strip.end(), 0.0);
  for (const auto& [dx, dy] : *winner) {
    const int xx = x + dx, yy = y + dy;
    if (xx < 0 || yy < 0 || xx >= w || yy >= h) continue;
    const std::complex<float>* v = layers_at(xx, yy);
    if (v == nullptr) continue;
    strip[0] += 1.0;
    for (int l = 0; l < L; ++l) {
      const std::complex<float> c = v[l * stride];
      strip[p.re[l]] += c.real();
      if (p.im[l] >= 0) strip[p.im[l]] += c.imag();
    }
  }
  best = strip;
  return true;
}

inline void check_config(const PointExtractorConfig& cfg, double cs, int& guard, int& train) {
  POLMAP_EXPECT(cfg.guard_radius_m >= 0.0 && cfg.training_radius_m > cfg.guard_radius_m);
  guard = static_cast<int>(std::lround(cfg.guard_radius_m / cs));
  train = std::max(guard + 1, static_cast<int>(std::lround(cfg.training_radius_m / cs)));
}

/// Thresholds of the test derived from the configuration.
struct Thresholds {
  double contrast = 0.0;   ///< linear trace contrast over the ring
  double min_power = 0.0;  ///< minimum trace(C) (0 without a noise figure)
  double min_ring = 0.0;   ///< minimum observed ring cells
  std::uint32_t min_count = 1;

  Thresholds(const PointExtractorConfig& cfg, int q, double noise_power, int guard, int train)
      : contrast(std::pow(10.0, cfg.min_contrast_db / 10.0)),
        min_power(noise_power > 0.0 ? std::pow(10.0, cfg.min_snr_db / 10.0) * q * noise_power
                                    : 0.0),
        min_count(std::max<std::uint32_t>(1, cfg.min_count)) {
    const double ring_area =
        double(2 * train + 1) * (2 * train + 1) - double(2 * guard + 1) * (2 * guard + 1);
    min_ring = std::max(1.0, cfg.min_training_fraction * ring_area);
  }
};

/// One detected cell of a raster (index = row·w + col), kept in raster order.
struct DetectedCell {
  std::size_t idx = 0;
  float stat = 0.0F;                        ///< final d_ex
  float power = 0.0F;                       ///< trace(C)
  std::vector<std::complex<float>> layers;  ///< C, upper triangle
  std::vector<cdouble> sigma;               ///< neighbourhood mean used, upper triangle
};

/// Candidates from labelled detections: label[i] ≥ 1 is the 8-connected component of
/// dets[i]; bbox[k] = {min_col, min_row, max_col, max_row} of component k (cells). Sums
/// run over dets in raster order (the order both paths produce). power_at(ix, iy) gives
/// trace(C) of any cell of the box (0 outside). Output in label order.
template <typename PowerAt>
std::vector<PointCandidate> candidates_from_components(
    const std::vector<DetectedCell>& dets, const std::vector<int>& label,
    const std::vector<std::array<int, 4>>& bbox, const CellBox& box, double cs, PolLevel level,
    const PointExtractorConfig& cfg, const CellBox* core, PowerAt&& power_at) {
  const int q = pol_dimension(level);
  const int L = num_layers(q);
  const int w = box.width();
  struct Acc {
    double wsum = 0.0, wx = 0.0, wy = 0.0, peak = 0.0;
    std::uint32_t cells = 0;
    std::vector<cdouble> cov;  // Σ over cells of (C − Σ_neighbourhood), upper triangle
  };
  std::vector<Acc> acc(bbox.size());
  for (auto& a : acc) a.cov.assign(L, cdouble(0, 0));
  for (std::size_t i = 0; i < dets.size(); ++i) {
    const int k = label[i];
    if (k <= 0) continue;
    const DetectedCell& d = dets[i];
    Acc& a = acc[k];
    double tr_s = 0.0;
    for (int l = 0; l < L; ++l) {
      a.cov[l] += cdouble(d.layers[l].real(), d.layers[l].imag()) - d.sigma[l];
    }
    for (int j = 0; j < q; ++j) tr_s += d.sigma[layer_index(q, j, j)].real();
    // Power weight with the neighbourhood level removed (the point's own power).
    const double wgt = std::max(1e-12, d.power - tr_s);
    const int ix = box.min_ix + static_cast<int>(d.idx % w);
    const int iy = box.min_iy + static_cast<int>(d.idx / w);
    const double cx = (ix + 0.5) * cs, cy = (iy + 0.5) * cs;
    a.wsum += wgt;
    a.wx += wgt * cx;
    a.wy += wgt * cy;
    a.peak = std::max(a.peak, double(d.stat));
    a.cells += 1;
  }
  std::vector<PointCandidate> out;
  for (std::size_t k = 1; k < bbox.size(); ++k) {
    const Acc& a = acc[k];
    if (a.cells == 0) continue;
    const double ext_w = (bbox[k][2] - bbox[k][0] + 1) * cs;
    const double ext_h = (bbox[k][3] - bbox[k][1] + 1) * cs;
    if (std::hypot(ext_w, ext_h) > cfg.max_extent_m) continue;
    const Eigen::Vector2d pos(a.wx / a.wsum, a.wy / a.wsum);
    const int cix = static_cast<int>(std::floor(pos.x() / cs));
    const int ciy = static_cast<int>(std::floor(pos.y() / cs));
    if (core != nullptr && !core->contains(cix, ciy)) continue;
    PointCandidate p;
    p.position_m = pos;
    p.strength = a.peak;
    p.num_cells = a.cells;
    const double power = box.contains(cix, ciy) ? double(power_at(cix, ciy)) : 0.0;
    p.power_db = 10.0 * std::log10(std::max(power, 1e-30));
    Eigen::MatrixXcd c(q, q);
    int l = 0;
    for (int i = 0; i < q; ++i) {
      for (int j = i; j < q; ++j) {
        c(i, j) = a.cov[l++];
        c(j, i) = std::conj(c(i, j));
      }
    }
    p.scattering = classify_scattering(c, level, cfg.classes);
    out.push_back(p);
  }
  return out;
}

/// Position order of extract_points(map): y, then x.
inline void sort_by_position(std::vector<PointCandidate>& pts) {
  std::sort(pts.begin(), pts.end(), [](const PointCandidate& a, const PointCandidate& b) {
    return a.position_m.y() != b.position_m.y() ? a.position_m.y() < b.position_m.y()
                                                : a.position_m.x() < b.position_m.x();
  });
}

/// Chunks of a gridmap (PointExtractorConfig::chunk_tiles) with the bounding box of their
/// populated tiles: cells outside are empty (N = 0) and can neither be detections nor
/// contribute to a neighbourhood, so processing that box equals processing the chunk.
struct Chunk {
  CellBox core;  ///< the chunk's cells: candidates whose centroid lies here are its own
  CellBox box;   ///< populated tiles plus the halo: the cells read
};
std::vector<Chunk> chunks_of(const CovarianceGridmap& map, const PointExtractorConfig& cfg);

/// The streaming fast path over one chunk (point_extractor_stream.cpp).
std::vector<PointCandidate> extract_chunk_streaming(const CovarianceGridmap& map,
                                                    const Chunk& chunk,
                                                    const PointExtractorConfig& cfg);

}  // namespace polmap::radar::pcfar
