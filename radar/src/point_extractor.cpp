#include "polmap/radar/point_extractor.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <set>

#include "polmap/schema/errors.hpp"

namespace polmap::radar {
namespace {

template <int Q>
using CMat = Eigen::Matrix<cdouble, Q, Q>;

int floor_div(int a, int b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

/// Ring sums of every layer (real and imaginary parts) and of the observed-cell indicator.
struct Ring {
  int guard = 0;
  int train = 0;
  double area = 0.0;                // cells of the ring
  std::vector<cv::Mat> re, im;      // per layer, CV_32F ring sums
  cv::Mat observed;                 // CV_32F ring count of observed cells
};

cv::Mat ring_sum(const cv::Mat& plane64, int guard, int train) {
  cv::Mat outer, inner;
  cv::boxFilter(plane64, outer, CV_64F, cv::Size(2 * train + 1, 2 * train + 1), cv::Point(-1, -1),
                false, cv::BORDER_CONSTANT);
  cv::boxFilter(plane64, inner, CV_64F, cv::Size(2 * guard + 1, 2 * guard + 1), cv::Point(-1, -1),
                false, cv::BORDER_CONSTANT);
  cv::Mat ring;
  cv::Mat(outer - inner).convertTo(ring, CV_32F);
  return ring;
}

Ring make_ring(const CovarianceRaster& r, int guard, int train) {
  const int w = r.box.width(), h = r.box.height();
  const int L = num_layers(r.q);
  const std::size_t plane = r.plane_size();
  Ring ring;
  ring.guard = guard;
  ring.train = train;
  ring.area = double(2 * train + 1) * (2 * train + 1) - double(2 * guard + 1) * (2 * guard + 1);
  cv::Mat obs(h, w, CV_64F);
  for (std::size_t i = 0; i < plane; ++i) obs.ptr<double>()[i] = r.count[i] > 0 ? 1.0 : 0.0;
  ring.observed = ring_sum(obs, guard, train);
  cv::Mat re(h, w, CV_64F), im(h, w, CV_64F);
  for (int l = 0; l < L; ++l) {
    const std::complex<float>* src = r.layers.data() + l * plane;
    bool diag = false;
    for (int i = 0; i < r.q; ++i) diag = diag || layer_index(r.q, i, i) == l;
    for (std::size_t i = 0; i < plane; ++i) {
      re.ptr<double>()[i] = src[i].real();
      im.ptr<double>()[i] = src[i].imag();
    }
    ring.re.push_back(ring_sum(re, guard, train));
    ring.im.push_back(diag ? cv::Mat() : ring_sum(im, guard, train));
  }
  return ring;
}

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

template <int Q>
CMat<Q> ring_matrix(const Ring& ring, std::size_t idx, double inv_n) {
  CMat<Q> s;
  int l = 0;
  for (int i = 0; i < Q; ++i) {
    for (int j = i; j < Q; ++j, ++l) {
      const double re = ring.re[l].ptr<float>()[idx] * inv_n;
      const double im = i == j ? 0.0 : ring.im[l].ptr<float>()[idx] * inv_n;
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

template <int Q>
Detection detect(const CovarianceRaster& r, const Ring& ring, const PointExtractorConfig& cfg,
                 double eps) {
  const int w = r.box.width(), h = r.box.height();
  Detection d;
  d.stat = cv::Mat::zeros(h, w, CV_32F);
  d.mask = cv::Mat::zeros(h, w, CV_8U);
  const double contrast = std::pow(10.0, cfg.min_contrast_db / 10.0);
  const double min_power =
      r.noise_power > 0.0 ? std::pow(10.0, cfg.min_snr_db / 10.0) * Q * r.noise_power : 0.0;
  const double min_ring = cfg.min_training_fraction * ring.area;
  const CMat<Q> load = CMat<Q>::Identity() * eps;
  for (int row = 0; row < h; ++row) {
    for (int col = 0; col < w; ++col) {
      const std::size_t idx = static_cast<std::size_t>(row) * w + col;
      if (r.count[idx] < std::max<std::uint32_t>(1, cfg.min_count)) continue;
      const double tr_c = r.power(idx);
      if (!(tr_c > min_power)) continue;
      const double n_ring = ring.observed.ptr<float>()[idx];
      if (n_ring < min_ring || n_ring < 1.0) continue;
      double tr_s = 0.0;
      for (int i = 0; i < Q; ++i) {
        tr_s += ring.re[layer_index(Q, i, i)].ptr<float>()[idx];
      }
      tr_s /= n_ring;
      if (!(tr_c > contrast * tr_s)) continue;
      const CMat<Q> sigma = ring_matrix<Q>(ring, idx, 1.0 / n_ring) + load;
      const CMat<Q> c = cell_matrix<Q>(r, idx) + load;
      bool ok = false;
      const double e = excess<Q>(sigma, c, ok);
      if (!ok) continue;
      d.stat.ptr<float>(row)[col] = static_cast<float>(e);
      if (e > cfg.threshold) d.mask.ptr<std::uint8_t>(row)[col] = 1;
    }
  }
  return d;
}

Detection detect_any(const CovarianceRaster& r, const Ring& ring, const PointExtractorConfig& cfg,
                     double eps) {
  switch (r.q) {
    case 1: return detect<1>(r, ring, cfg, eps);
    case 2: return detect<2>(r, ring, cfg, eps);
    case 3: return detect<3>(r, ring, cfg, eps);
    default: throw ContractViolation("pCFAR: unsupported q");
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
  const Ring ring = make_ring(raster, guard, train);
  return detect_any(raster, ring, cfg, loading_eps(raster, cfg)).stat;
}

std::vector<PointCandidate> extract_points(const CovarianceRaster& r,
                                           const PointExtractorConfig& cfg, const CellBox* core) {
  int guard = 0, train = 0;
  check_config(cfg, r.cell_size_m, guard, train);
  const Ring ring = make_ring(r, guard, train);
  const double eps = loading_eps(r, cfg);
  const Detection det = detect_any(r, ring, cfg, eps);

  cv::Mat labels, stats, centroids;
  const int n = cv::connectedComponentsWithStats(det.mask, labels, stats, centroids, 8, CV_32S);
  if (n <= 1) return {};
  const int w = r.box.width();
  const int L = num_layers(r.q);
  const std::size_t plane = r.plane_size();
  struct Acc {
    double wsum = 0.0, wx = 0.0, wy = 0.0, peak = 0.0;
    std::uint32_t cells = 0;
    std::vector<cdouble> cov;  // Σ over cells of (C − Σ_ring), upper triangle
  };
  std::vector<Acc> acc(n);
  for (auto& a : acc) a.cov.assign(L, cdouble(0, 0));
  for (int row = 0; row < labels.rows; ++row) {
    const int* lab = labels.ptr<int>(row);
    for (int col = 0; col < w; ++col) {
      const int k = lab[col];
      if (k == 0) continue;
      const std::size_t idx = static_cast<std::size_t>(row) * w + col;
      const double n_ring = ring.observed.ptr<float>()[idx];
      Acc& a = acc[k];
      double tr_s = 0.0;
      for (int l = 0; l < L; ++l) {
        const std::complex<float> v = r.layers[l * plane + idx];
        const double sre = ring.re[l].ptr<float>()[idx] / n_ring;
        const double sim = ring.im[l].empty() ? 0.0 : ring.im[l].ptr<float>()[idx] / n_ring;
        a.cov[l] += cdouble(v.real() - sre, ring.im[l].empty() ? 0.0 : v.imag() - sim);
      }
      for (int i = 0; i < r.q; ++i) tr_s += ring.re[layer_index(r.q, i, i)].ptr<float>()[idx] / n_ring;
      // Power weight with the neighbourhood level removed (the point's own power).
      const double wgt = std::max(1e-12, r.power(idx) - tr_s);
      const Eigen::Vector2d c = r.cell_center(idx);
      a.wsum += wgt;
      a.wx += wgt * c.x();
      a.wy += wgt * c.y();
      a.peak = std::max(a.peak, double(det.stat.ptr<float>(row)[col]));
      a.cells += 1;
    }
  }
  std::vector<PointCandidate> out;
  const double cs = r.cell_size_m;
  for (int k = 1; k < n; ++k) {
    const Acc& a = acc[k];
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
  const int halo =
      static_cast<int>(std::ceil((cfg.training_radius_m + cfg.max_extent_m) / cs)) + 2;
  std::set<std::pair<int, int>> chunks;
  for (const auto& t : map.tile_indices()) {
    chunks.insert({floor_div(t[0], cfg.chunk_tiles), floor_div(t[1], cfg.chunk_tiles)});
  }
  std::vector<PointCandidate> out;
  for (const auto& [cx, cy] : chunks) {
    const CellBox core{cx * chunk_cells, cy * chunk_cells, (cx + 1) * chunk_cells,
                       (cy + 1) * chunk_cells};
    const CellBox box{core.min_ix - halo, core.min_iy - halo, core.max_ix + halo,
                      core.max_iy + halo};
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
