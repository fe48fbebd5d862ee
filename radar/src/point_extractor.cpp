#include "polmap/radar/point_extractor.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>
#include <opencv2/imgproc.hpp>

#include "pcfar_kernels.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::radar {
namespace {

using pcfar::clip_to_raster;
using pcfar::CMat;
using pcfar::PlaneLayout;

/// Per-cell planes of a raster used by the CFAR (PlaneLayout), as one double-precision
/// integral image of all planes.
struct Planes : PlaneLayout {
  int w = 0, h = 0;
  std::vector<double> integral;  // (h+1)·(w+1)·num

  explicit Planes(const CovarianceRaster& r)
      : PlaneLayout(r.q), w(r.box.width()), h(r.box.height()) {
    const int L = num_layers(q);
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

struct Detection {
  cv::Mat mask;                            // CV_8U
  std::vector<pcfar::DetectedCell> cells;  // raster order
  cv::Mat stat;                            // CV_32F d_ex (pcfar_statistic)
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
Detection detect(const CovarianceRaster& r, const PointExtractorConfig& cfg, int guard, int train,
                 double eps) {
  const int w = r.box.width(), h = r.box.height();
  const std::size_t plane = r.plane_size();
  const int L = num_layers(Q);
  Detection d;
  d.stat = cv::Mat::zeros(h, w, CV_32F);
  d.mask = cv::Mat::zeros(h, w, CV_8U);
  const pcfar::Thresholds th(cfg, Q, r.noise_power, guard, train);
  // Cheap pre-pass: only cells bright enough can be detections.
  std::vector<std::size_t> cand;
  for (std::size_t idx = 0; idx < plane; ++idx) {
    if (r.count[idx] < th.min_count) continue;
    if (!r.hits.empty() && r.hits[idx] < cfg.min_persistence * r.count[idx]) continue;
    if (r.power(idx) > th.min_power) cand.push_back(idx);
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
      if (s[0] < th.min_ring) continue;
      // Slightly relaxed against rounding: the exact test follows below.
      if (!(r.power(idx) > th.contrast * (s[1] / s[0]) * (1.0 - 1e-9))) continue;
      cand[kept++] = idx;
    }
    cand.resize(kept);
  }
  if (cand.empty()) return d;
  const Planes p(r);
  const CMat<Q> load = CMat<Q>::Identity() * eps;
  std::vector<double> sums(p.num), strip(p.num), best(p.num);
  const auto strips = pcfar::strip_offsets(guard, train);
  for (std::size_t idx : cand) {
    const int x = static_cast<int>(idx % w), y = static_cast<int>(idx / w);
    std::fill(sums.begin(), sums.end(), 0.0);
    p.box(x - train, y - train, x + train + 1, y + train + 1, 1.0, sums.data());
    p.box(x - guard, y - guard, x + guard + 1, y + guard + 1, -1.0, sums.data());
    if (sums[0] < th.min_ring) continue;
    const double tr_c = r.power(idx);
    double tr_s = 0.0;
    for (int i = 0; i < Q; ++i) tr_s += sums[p.re[layer_index(Q, i, i)]];
    tr_s /= sums[0];
    if (!(tr_c > th.contrast * tr_s)) continue;
    const CMat<Q> c = pcfar::cell_matrix<Q>(r.layers.data() + idx, plane) + load;
    bool ok = false;
    double e = pcfar::excess<Q>(pcfar::mean_matrix<Q>(p, sums.data()) + load, c, ok);
    if (!ok) continue;
    d.stat.ptr<float>(y)[x] = static_cast<float>(e);
    if (!(e > cfg.threshold)) continue;
    const double* chosen = sums.data();
    if (cfg.line_aware) {
      // Greatest-of with the brightest line strip through the cell (file comment).
      double best_tr = tr_s;
      float diag_buf[Q];
      if (pcfar::brightest_strip<Q>(
              strips, p, x, y, w, h, plane,
              [&](int xx, int yy) -> const std::complex<float>* {
                const std::size_t j = static_cast<std::size_t>(yy) * w + xx;
                return r.count[j] == 0 ? nullptr : r.layers.data() + j;
              },
              [&](int xx, int yy) -> const float* {
                const std::size_t j = static_cast<std::size_t>(yy) * w + xx;
                if (r.count[j] == 0) return nullptr;
                for (int i = 0; i < Q; ++i) {
                  diag_buf[i] = r.layers[layer_index(Q, i, i) * plane + j].real();
                }
                return diag_buf;
              },
              strip, best, best_tr)) {
        chosen = best.data();
      }
      if (chosen != sums.data()) {
        if (!(tr_c > th.contrast * best_tr)) {
          d.stat.ptr<float>(y)[x] = 0.0F;
          continue;
        }
        e = pcfar::excess<Q>(pcfar::mean_matrix<Q>(p, chosen) + load, c, ok);
        d.stat.ptr<float>(y)[x] = static_cast<float>(e);
        if (!ok || !(e > cfg.threshold)) continue;
      }
    }
    d.mask.ptr<std::uint8_t>(y)[x] = 1;
    const CMat<Q> sg = pcfar::mean_matrix<Q>(p, chosen);
    pcfar::DetectedCell cell;
    cell.idx = idx;
    cell.stat = static_cast<float>(e);
    cell.power = r.power(idx);
    cell.layers.resize(L);
    cell.sigma.resize(L);
    for (int l = 0; l < L; ++l) cell.layers[l] = r.layers[l * plane + idx];
    for (int i = 0; i < Q; ++i) {
      for (int j = i; j < Q; ++j) cell.sigma[layer_index(Q, i, j)] = sg(i, j);
    }
    d.cells.push_back(std::move(cell));
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

}  // namespace

namespace pcfar {

std::vector<Chunk> chunks_of(const CovarianceGridmap& map, const PointExtractorConfig& cfg) {
  POLMAP_EXPECT(cfg.chunk_tiles >= 1);
  const double cs = map.cell_size_m();
  const int chunk_cells = cfg.chunk_tiles * kTileSizeCells;
  const int halo = static_cast<int>(std::ceil((cfg.training_radius_m + cfg.max_extent_m) / cs)) + 2;
  std::vector<Chunk> out;
  for (const auto& c : map.populated_chunks(cfg.chunk_tiles)) {
    const CellBox& b = c.populated;
    out.push_back({CellBox{c.chunk_x * chunk_cells, c.chunk_y * chunk_cells,
                           (c.chunk_x + 1) * chunk_cells, (c.chunk_y + 1) * chunk_cells},
                   CellBox{b.min_ix - halo, b.min_iy - halo, b.max_ix + halo, b.max_iy + halo}});
  }
  return out;
}

}  // namespace pcfar

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
  pcfar::check_config(cfg, raster.cell_size_m, guard, train);
  return detect_any(raster, cfg, guard, train, loading_eps(raster, cfg)).stat;
}

std::vector<PointCandidate> extract_points(const CovarianceRaster& r,
                                           const PointExtractorConfig& cfg, const CellBox* core) {
  int guard = 0, train = 0;
  pcfar::check_config(cfg, r.cell_size_m, guard, train);
  const Detection det = detect_any(r, cfg, guard, train, loading_eps(r, cfg));
  if (det.cells.empty()) return {};
  cv::Mat labels, stats, centroids;
  const int n = cv::connectedComponentsWithStats(det.mask, labels, stats, centroids, 8, CV_32S);
  if (n <= 1) return {};
  const int w = r.box.width();
  std::vector<int> label(det.cells.size());
  for (std::size_t i = 0; i < det.cells.size(); ++i) {
    const std::size_t idx = det.cells[i].idx;
    label[i] = labels.ptr<int>(static_cast<int>(idx / w))[idx % w];
  }
  std::vector<std::array<int, 4>> bbox(n);
  for (int k = 0; k < n; ++k) {
    const int x = stats.at<int>(k, cv::CC_STAT_LEFT), y = stats.at<int>(k, cv::CC_STAT_TOP);
    bbox[k] = {x, y, x + stats.at<int>(k, cv::CC_STAT_WIDTH) - 1,
               y + stats.at<int>(k, cv::CC_STAT_HEIGHT) - 1};
  }
  return pcfar::candidates_from_components(
      det.cells, label, bbox, r.box, r.cell_size_m, r.level, cfg, core, [&](int ix, int iy) {
        return r.power(static_cast<std::size_t>(iy - r.box.min_iy) * w + (ix - r.box.min_ix));
      });
}

std::vector<PointCandidate> extract_points_reference(const CovarianceGridmap& map,
                                                     const PointExtractorConfig& cfg) {
  std::vector<PointCandidate> out;
  for (const pcfar::Chunk& c : pcfar::chunks_of(map, cfg)) {
    const auto pts = extract_points(map.raster(c.box), cfg, &c.core);
    out.insert(out.end(), pts.begin(), pts.end());
  }
  pcfar::sort_by_position(out);
  return out;
}

std::vector<PointCandidate> extract_points(const CovarianceGridmap& map,
                                           const PointExtractorConfig& cfg) {
  std::vector<PointCandidate> out;
  for (const pcfar::Chunk& c : pcfar::chunks_of(map, cfg)) {
    const auto pts = pcfar::extract_chunk_streaming(map, c, cfg);
    out.insert(out.end(), pts.begin(), pts.end());
  }
  pcfar::sort_by_position(out);
  return out;
}

}  // namespace polmap::radar
