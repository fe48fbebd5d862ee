#include "polmap/radar/point_extractor.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>
#include <opencv2/imgproc.hpp>
#include <set>
#include <unordered_map>

#include "polmap/schema/errors.hpp"

namespace polmap::radar {
namespace {

template <int Q>
using CMat = Eigen::Matrix<cdouble, Q, Q>;

int floor_div(int a, int b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

/// Clips the cell rectangle [x0, x1) × [y0, y1) to a w × h raster; false if empty.
bool clip_to_raster(int w, int h, int& x0, int& y0, int& x1, int& y1) {
  x0 = std::clamp(x0, 0, w);
  x1 = std::clamp(x1, 0, w);
  y0 = std::clamp(y0, 0, h);
  y1 = std::clamp(y1, 0, h);
  return x1 > x0 && y1 > y0;
}

/// Per-cell planes of a raster used by the CFAR, interleaved per cell: plane 0 is the
/// observed indicator (N > 0), then per covariance layer its real part and, for
/// off-diagonal layers, its imaginary part. Sums over rectangles come from one
/// double-precision integral image of all planes.
struct Planes {
  int q = 0;
  int num = 0;              // planes per cell
  std::vector<int> re, im;  // plane index of layer l's real / imaginary part (−1: none)
  int w = 0, h = 0;
  std::vector<double> integral;  // (h+1)·(w+1)·num

  Planes(const CovarianceRaster& r) : q(r.q), w(r.box.width()), h(r.box.height()) {
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
    const std::size_t W = static_cast<std::size_t>(w) + 1;
    integral.assign(W * (h + 1) * num, 0.0);
    const std::size_t plane = r.plane_size();
    std::vector<double> row(num);
    for (int y = 0; y < h; ++y) {
      std::fill(row.begin(), row.end(), 0.0);
      const double* above = integral.data() + (static_cast<std::size_t>(y) * W) * num;
      double* out = integral.data() + (static_cast<std::size_t>(y + 1) * W) * num;
      for (int x = 0; x < w; ++x) {
        const std::size_t idx = static_cast<std::size_t>(y) * w + x;
        if (r.count[idx] > 0) {
          row[0] += 1.0;
          for (int l = 0; l < L; ++l) {
            const std::complex<float> v = r.layers[l * plane + idx];
            row[re[l]] += v.real();
            if (im[l] >= 0) row[im[l]] += v.imag();
          }
        }
        const double* a = above + (x + 1) * num;
        double* o = out + (x + 1) * num;
        for (int k = 0; k < num; ++k) o[k] = a[k] + row[k];
      }
    }
  }
  /// Adds sign·(sum over cells [x0, x1) × [y0, y1), clipped) to acc.
  void box(int x0, int y0, int x1, int y1, double sign, double* acc) const {
    if (!clip_to_raster(w, h, x0, y0, x1, y1)) return;
    const std::size_t W = static_cast<std::size_t>(w) + 1;
    const double* a = integral.data() + (y1 * W + x1) * num;
    const double* b = integral.data() + (y0 * W + x1) * num;
    const double* c = integral.data() + (y1 * W + x0) * num;
    const double* d = integral.data() + (y0 * W + x0) * num;
    for (int k = 0; k < num; ++k) acc[k] += sign * (a[k] - b[k] - c[k] + d[k]);
  }
};

/// Integral image of the observed indicator and trace(C) only (2 planes), for the
/// pre-screen of detect().
struct TracePlanes {
  int w = 0, h = 0;
  std::vector<double> integral;  // (h+1)·(w+1)·2

  explicit TracePlanes(const CovarianceRaster& r) : w(r.box.width()), h(r.box.height()) {
    const std::size_t W = static_cast<std::size_t>(w) + 1;
    integral.assign(W * (h + 1) * 2, 0.0);
    for (int y = 0; y < h; ++y) {
      double n = 0.0, t = 0.0;
      const double* above = integral.data() + static_cast<std::size_t>(y) * W * 2;
      double* out = integral.data() + static_cast<std::size_t>(y + 1) * W * 2;
      for (int x = 0; x < w; ++x) {
        const std::size_t idx = static_cast<std::size_t>(y) * w + x;
        if (r.count[idx] > 0) {
          n += 1.0;
          t += r.power(idx);
        }
        out[(x + 1) * 2] = above[(x + 1) * 2] + n;
        out[(x + 1) * 2 + 1] = above[(x + 1) * 2 + 1] + t;
      }
    }
  }
  void box(int x0, int y0, int x1, int y1, double sign, double* acc) const {
    if (!clip_to_raster(w, h, x0, y0, x1, y1)) return;
    const std::size_t W = static_cast<std::size_t>(w) + 1;
    for (int k = 0; k < 2; ++k) {
      acc[k] += sign * (integral[(y1 * W + x1) * 2 + k] - integral[(y0 * W + x1) * 2 + k] -
                        integral[(y1 * W + x0) * 2 + k] + integral[(y0 * W + x0) * 2 + k]);
    }
  }
};

template <int Q>
CMat<Q> cell_matrix(const CovarianceRaster& r, std::size_t idx) {
  CMat<Q> c;
  const std::size_t plane = r.plane_size();
  int l = 0;
  for (int i = 0; i < Q; ++i) {
    for (int j = i; j < Q; ++j) {
      const std::complex<float> v = r.layers[l++ * plane + idx];
      c(i, j) = cdouble(v.real(), i == j ? 0.0 : v.imag());
      c(j, i) = std::conj(c(i, j));
    }
  }
  return c;
}

/// Σ from plane sums (sums[0] = number of observed cells).
template <int Q>
CMat<Q> mean_matrix(const Planes& p, const double* sums) {
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

template <int Q>
double excess(const CMat<Q>& sigma, const CMat<Q>& c, bool& ok) {
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

struct Detection {
  cv::Mat stat;  // CV_32F d_ex
  cv::Mat mask;  // CV_8U
  /// Neighbourhood mean used for each detected cell (raster index -> upper-triangle layers).
  std::unordered_map<std::size_t, std::vector<cdouble>> sigma;
};

/// Loading ε per component: loading·σ²; without a noise figure (synthetic rasters),
/// 1e-3 of the mean observed power per component.
double loading_eps(const CovarianceRaster& r, const PointExtractorConfig& cfg) {
  if (r.noise_power > 0.0) return cfg.loading * r.noise_power;
  double sum = 0.0;
  std::size_t n = 0;
  for (std::size_t i = 0; i < r.plane_size(); ++i) {
    if (r.count[i] == 0) continue;
    sum += r.power(i);
    ++n;
  }
  const double mean = n > 0 ? sum / n / r.q : 1.0;
  return cfg.loading * 1e-3 * (mean > 0.0 ? mean : 1.0);
}

/// Directions of the line strips (half-plane: a strip runs both ways).
constexpr int kStripDirections = 8;

template <int Q>
Detection detect(const CovarianceRaster& r, const PointExtractorConfig& cfg, int guard, int train,
                 double eps) {
  const int w = r.box.width(), h = r.box.height();
  const std::size_t plane = r.plane_size();
  Detection d;
  d.stat = cv::Mat::zeros(h, w, CV_32F);
  d.mask = cv::Mat::zeros(h, w, CV_8U);
  const double contrast = std::pow(10.0, cfg.min_contrast_db / 10.0);
  const double min_power =
      r.noise_power > 0.0 ? std::pow(10.0, cfg.min_snr_db / 10.0) * Q * r.noise_power : 0.0;
  const double ring_area =
      double(2 * train + 1) * (2 * train + 1) - double(2 * guard + 1) * (2 * guard + 1);
  const double min_ring = std::max(1.0, cfg.min_training_fraction * ring_area);
  // Cheap pre-pass: only cells bright enough can be detections.
  std::vector<std::size_t> cand;
  for (std::size_t idx = 0; idx < plane; ++idx) {
    if (r.count[idx] < std::max<std::uint32_t>(1, cfg.min_count)) continue;
    if (!r.hits.empty() && r.hits[idx] < cfg.min_persistence * r.count[idx]) continue;
    if (r.power(idx) > min_power) cand.push_back(idx);
  }
  if (cand.empty()) return d;
  {
    // Trace-only pre-screen: the ring's observed-cell count and mean trace decide
    // two necessary conditions of a detection at a fraction of the full planes' cost.
    const TracePlanes tp(r);
    std::size_t kept = 0;
    for (std::size_t idx : cand) {
      const int x = static_cast<int>(idx % w), y = static_cast<int>(idx / w);
      double s[2] = {0.0, 0.0};
      tp.box(x - train, y - train, x + train + 1, y + train + 1, 1.0, s);
      tp.box(x - guard, y - guard, x + guard + 1, y + guard + 1, -1.0, s);
      if (s[0] < min_ring) continue;
      // Slightly relaxed against rounding: the exact test follows below.
      if (!(r.power(idx) > contrast * (s[1] / s[0]) * (1.0 - 1e-9))) continue;
      cand[kept++] = idx;
    }
    cand.resize(kept);
  }
  if (cand.empty()) return d;
  const Planes p(r);
  const CMat<Q> load = CMat<Q>::Identity() * eps;
  std::vector<double> sums(p.num), strip(p.num), best(p.num);
  // Strip offsets (cells) per direction, both sides of the guard.
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
  for (std::size_t idx : cand) {
    const int x = static_cast<int>(idx % w), y = static_cast<int>(idx / w);
    std::fill(sums.begin(), sums.end(), 0.0);
    p.box(x - train, y - train, x + train + 1, y + train + 1, 1.0, sums.data());
    p.box(x - guard, y - guard, x + guard + 1, y + guard + 1, -1.0, sums.data());
    if (sums[0] < min_ring) continue;
    const double tr_c = r.power(idx);
    double tr_s = 0.0;
    for (int i = 0; i < Q; ++i) tr_s += sums[p.re[layer_index(Q, i, i)]];
    tr_s /= sums[0];
    if (!(tr_c > contrast * tr_s)) continue;
    const CMat<Q> c = cell_matrix<Q>(r, idx) + load;
    bool ok = false;
    double e = excess<Q>(mean_matrix<Q>(p, sums.data()) + load, c, ok);
    if (!ok) continue;
    d.stat.ptr<float>(y)[x] = static_cast<float>(e);
    if (!(e > cfg.threshold)) continue;
    const double* chosen = sums.data();
    if (cfg.line_aware) {
      // Greatest-of with the brightest line strip through the cell (file comment).
      double best_tr = tr_s;
      for (const auto& s : strips) {
        std::fill(strip.begin(), strip.end(), 0.0);
        for (const auto& [dx, dy] : s) {
          const int xx = x + dx, yy = y + dy;
          if (xx < 0 || yy < 0 || xx >= w || yy >= h) continue;
          const std::size_t j = static_cast<std::size_t>(yy) * w + xx;
          if (r.count[j] == 0) continue;
          strip[0] += 1.0;
          for (int l = 0; l < num_layers(Q); ++l) {
            const std::complex<float> v = r.layers[l * plane + j];
            strip[p.re[l]] += v.real();
            if (p.im[l] >= 0) strip[p.im[l]] += v.imag();
          }
        }
        if (strip[0] < 0.5 * static_cast<double>(s.size())) continue;
        double tr = 0.0;
        for (int i = 0; i < Q; ++i) tr += strip[p.re[layer_index(Q, i, i)]];
        tr /= strip[0];
        if (tr > best_tr) {
          best_tr = tr;
          best = strip;
          chosen = best.data();
        }
      }
      if (chosen != sums.data()) {
        if (!(tr_c > contrast * best_tr)) {
          d.stat.ptr<float>(y)[x] = 0.0F;
          continue;
        }
        e = excess<Q>(mean_matrix<Q>(p, chosen) + load, c, ok);
        d.stat.ptr<float>(y)[x] = static_cast<float>(e);
        if (!ok || !(e > cfg.threshold)) continue;
      }
    }
    d.mask.ptr<std::uint8_t>(y)[x] = 1;
    const CMat<Q> sg = mean_matrix<Q>(p, chosen);
    std::vector<cdouble> layers(num_layers(Q));
    for (int i = 0; i < Q; ++i) {
      for (int j = i; j < Q; ++j) layers[layer_index(Q, i, j)] = sg(i, j);
    }
    d.sigma.emplace(idx, std::move(layers));
  }
  return d;
}

Detection detect_any(const CovarianceRaster& r, const PointExtractorConfig& cfg, int guard,
                     int train, double eps) {
  switch (r.q) {
    case 1:
      return detect<1>(r, cfg, guard, train, eps);
    case 2:
      return detect<2>(r, cfg, guard, train, eps);
    case 3:
      return detect<3>(r, cfg, guard, train, eps);
    default:
      throw ContractViolation("pCFAR: unsupported q");
  }
}

void check_config(const PointExtractorConfig& cfg, double cs, int& guard, int& train) {
  POLMAP_EXPECT(cfg.guard_radius_m >= 0.0 && cfg.training_radius_m > cfg.guard_radius_m);
  guard = static_cast<int>(std::lround(cfg.guard_radius_m / cs));
  train = std::max(guard + 1, static_cast<int>(std::lround(cfg.training_radius_m / cs)));
}

}  // namespace

double wishart_distance(const Eigen::MatrixXcd& sigma, const Eigen::MatrixXcd& c) {
  POLMAP_EXPECT(sigma.rows() == c.rows() && sigma.cols() == c.cols() && c.rows() == c.cols());
  const Eigen::LLT<Eigen::MatrixXcd> ls(sigma);
  POLMAP_EXPECT(ls.info() == Eigen::Success);
  double logdet = 0.0;
  for (int i = 0; i < sigma.rows(); ++i) logdet += 2.0 * std::log(ls.matrixLLT()(i, i).real());
  return (logdet + ls.solve(c).trace().real()) / static_cast<double>(c.rows());
}

double wishart_excess(const Eigen::MatrixXcd& sigma, const Eigen::MatrixXcd& c) {
  POLMAP_EXPECT(sigma.rows() == c.rows() && sigma.cols() == c.cols() && c.rows() == c.cols());
  const Eigen::LLT<Eigen::MatrixXcd> ls(sigma), lc(c);
  POLMAP_EXPECT(ls.info() == Eigen::Success && lc.info() == Eigen::Success);
  double logdet = 0.0;
  for (int i = 0; i < c.rows(); ++i) {
    logdet += 2.0 * (std::log(lc.matrixLLT()(i, i).real()) - std::log(ls.matrixLLT()(i, i).real()));
  }
  const double q = static_cast<double>(c.rows());
  return std::max(0.0, (ls.solve(c).trace().real() - logdet - q) / q);
}

cv::Mat pcfar_statistic(const CovarianceRaster& raster, const PointExtractorConfig& cfg) {
  int guard = 0, train = 0;
  check_config(cfg, raster.cell_size_m, guard, train);
  return detect_any(raster, cfg, guard, train, loading_eps(raster, cfg)).stat;
}

std::vector<PointCandidate> extract_points(const CovarianceRaster& r,
                                           const PointExtractorConfig& cfg, const CellBox* core) {
  int guard = 0, train = 0;
  check_config(cfg, r.cell_size_m, guard, train);
  const Detection det = detect_any(r, cfg, guard, train, loading_eps(r, cfg));
  if (det.sigma.empty()) return {};

  cv::Mat labels, stats, centroids;
  const int n = cv::connectedComponentsWithStats(det.mask, labels, stats, centroids, 8, CV_32S);
  if (n <= 1) return {};
  const int w = r.box.width();
  const int L = num_layers(r.q);
  const std::size_t plane = r.plane_size();
  struct Acc {
    double wsum = 0.0, wx = 0.0, wy = 0.0, peak = 0.0;
    std::uint32_t cells = 0;
    std::vector<cdouble> cov;  // Σ over cells of (C − Σ_neighbourhood), upper triangle
  };
  std::vector<Acc> acc(n);
  for (auto& a : acc) a.cov.assign(L, cdouble(0, 0));
  for (const auto& [idx, sigma] : det.sigma) {
    const int row = static_cast<int>(idx / w), col = static_cast<int>(idx % w);
    const int k = labels.ptr<int>(row)[col];
    if (k <= 0) continue;
    Acc& a = acc[k];
    double tr_s = 0.0;
    for (int l = 0; l < L; ++l) {
      const std::complex<float> v = r.layers[l * plane + idx];
      a.cov[l] += cdouble(v.real(), v.imag()) - sigma[l];
    }
    for (int i = 0; i < r.q; ++i) tr_s += sigma[layer_index(r.q, i, i)].real();
    // Power weight with the neighbourhood level removed (the point's own power).
    const double wgt = std::max(1e-12, r.power(idx) - tr_s);
    const Eigen::Vector2d c = r.cell_center(idx);
    a.wsum += wgt;
    a.wx += wgt * c.x();
    a.wy += wgt * c.y();
    a.peak = std::max(a.peak, double(det.stat.ptr<float>(row)[col]));
    a.cells += 1;
  }
  std::vector<PointCandidate> out;
  const double cs = r.cell_size_m;
  for (int k = 1; k < n; ++k) {
    const Acc& a = acc[k];
    if (a.cells == 0) continue;
    const double ext_w = stats.at<int>(k, cv::CC_STAT_WIDTH) * cs;
    const double ext_h = stats.at<int>(k, cv::CC_STAT_HEIGHT) * cs;
    if (std::hypot(ext_w, ext_h) > cfg.max_extent_m) continue;
    const Eigen::Vector2d pos(a.wx / a.wsum, a.wy / a.wsum);
    const int cix = static_cast<int>(std::floor(pos.x() / cs));
    const int ciy = static_cast<int>(std::floor(pos.y() / cs));
    if (core != nullptr && !core->contains(cix, ciy)) continue;
    PointCandidate p;
    p.position_m = pos;
    p.strength = a.peak;
    p.num_cells = a.cells;
    double power = 0.0;
    if (r.box.contains(cix, ciy)) {
      power = r.power(static_cast<std::size_t>(ciy - r.box.min_iy) * w + (cix - r.box.min_ix));
    }
    p.power_db = 10.0 * std::log10(std::max(power, 1e-30));
    Eigen::MatrixXcd c(r.q, r.q);
    int l = 0;
    for (int i = 0; i < r.q; ++i) {
      for (int j = i; j < r.q; ++j) {
        c(i, j) = a.cov[l++];
        c(j, i) = std::conj(c(i, j));
      }
    }
    p.scattering = classify_scattering(c, r.level, cfg.classes);
    out.push_back(p);
  }
  return out;
}

std::vector<PointCandidate> extract_points(const CovarianceGridmap& map,
                                           const PointExtractorConfig& cfg) {
  POLMAP_EXPECT(cfg.chunk_tiles >= 1);
  const double cs = map.cell_size_m();
  const int chunk_cells = cfg.chunk_tiles * kTileSizeCells;
  const int halo = static_cast<int>(std::ceil((cfg.training_radius_m + cfg.max_extent_m) / cs)) + 2;
  // Per chunk, the bounding box of its populated tiles: cells outside are empty
  // (N = 0) and can neither be detections nor contribute to a neighbourhood, so
  // the result equals processing the whole chunk; a sliding-window map fills
  // only part of each chunk.
  std::map<std::pair<int, int>, CellBox> chunks;
  for (const auto& t : map.tile_indices()) {
    const CellBox tb{t[0] * kTileSizeCells, t[1] * kTileSizeCells, (t[0] + 1) * kTileSizeCells,
                     (t[1] + 1) * kTileSizeCells};
    const auto key =
        std::make_pair(floor_div(t[0], cfg.chunk_tiles), floor_div(t[1], cfg.chunk_tiles));
    const auto [it, inserted] = chunks.try_emplace(key, tb);
    if (!inserted) {
      CellBox& b = it->second;
      b = CellBox{std::min(b.min_ix, tb.min_ix), std::min(b.min_iy, tb.min_iy),
                  std::max(b.max_ix, tb.max_ix), std::max(b.max_iy, tb.max_iy)};
    }
  }
  std::vector<PointCandidate> out;
  for (const auto& [key, populated] : chunks) {
    const auto [cx, cy] = key;
    const CellBox core{cx * chunk_cells, cy * chunk_cells, (cx + 1) * chunk_cells,
                       (cy + 1) * chunk_cells};
    const CellBox box{populated.min_ix - halo, populated.min_iy - halo, populated.max_ix + halo,
                      populated.max_iy + halo};
    const CovarianceRaster r = map.raster(box);
    auto pts = extract_points(r, cfg, &core);
    out.insert(out.end(), pts.begin(), pts.end());
  }
  std::sort(out.begin(), out.end(), [](const PointCandidate& a, const PointCandidate& b) {
    return a.position_m.y() != b.position_m.y() ? a.position_m.y() < b.position_m.y()
                                                : a.position_m.x() < b.position_m.x();
  });
  return out;
}

}  // namespace polmap::radar
