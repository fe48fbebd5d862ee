#include "polmap/radar/line_extractor.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>
#include <opencv2/imgproc.hpp>
#include <opencv2/ximgproc.hpp>
#include <optional>
#include <set>

#include "block_regions.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::radar {
namespace {

double floor_power(const cv::Mat& power, double noise_power, int q,
                   const LineExtractorConfig& cfg) {
  if (noise_power > 0.0) return q * noise_power * std::pow(10.0, cfg.floor_db_over_noise / 10.0);
  double sum = 0.0;
  std::size_t n = 0;
  for (int r = 0; r < power.rows; ++r) {
    const float* p = power.ptr<float>(r);
    for (int c = 0; c < power.cols; ++c) {
      if (p[c] > 0.0F) {
        sum += p[c];
        ++n;
      }
    }
  }
  return n > 0 ? 1e-3 * sum / n : 1.0;
}

struct RidgeImages {
  cv::Mat db;      ///< dB over the floor (not median filtered: the median erodes ends)
  cv::Mat ridge;   ///< ridgeness R
  cv::Mat centre;  ///< CV_8U: 1 where a ridge centre passes through the cell
  /// Sparse filtering: the block groups outside which ridge and centre are 0.
  std::optional<BlockRegions> regions;
};

RidgeImages ridgeness(const cv::Mat& power, double cs, double noise_power, int q,
                      const LineExtractorConfig& cfg) {
  POLMAP_EXPECT(power.type() == CV_32F);
  POLMAP_EXPECT(cfg.median_kernel_cells == 3 || cfg.median_kernel_cells == 5 ||
                cfg.median_kernel_cells == 1);
  const double floor = floor_power(power, noise_power, q, cfg);
  // dB over the floor, vectorized: 10·log10(max(p, floor)/floor) = (10/ln 10)·ln(·).
  cv::Mat db;
  cv::max(power, floor, db);
  db.convertTo(db, CV_32F, 1.0 / floor);
  cv::log(db, db);
  db.convertTo(db, CV_32F, 10.0 / std::log(10.0));
  cv::max(db, 0.0, db);  // ln(1) may come out a rounding step below 0
  cv::Mat med;
  if (cfg.median_kernel_cells > 1) {
    cv::medianBlur(db, med, cfg.median_kernel_cells);
  } else {
    med = db;
  }
  const double sigma = cfg.sigma_m / cs;  // cells
  cv::Mat smooth;
  cv::GaussianBlur(med, smooth, cv::Size(0, 0), sigma, sigma, cv::BORDER_REPLICATE);
  cv::Mat out(power.size(), CV_32F);
  cv::Mat centre(power.size(), CV_8U);
  const float s2 = static_cast<float>(sigma * sigma);
  const int rows = power.rows, cols = power.cols;
  for (int r = 0; r < rows; ++r) {
    // Derivatives of the smoothed image by central differences, borders replicated:
    // dxx = [1 −2 1] along x, dyy along y, dxy = central cross difference / 4,
    // gradients [−1 0 1]/2 (one pass instead of five filtered images).
    const float* up = smooth.ptr<float>(std::max(r - 1, 0));
    const float* mid = smooth.ptr<float>(r);
    const float* dn = smooth.ptr<float>(std::min(r + 1, rows - 1));
    float* o = out.ptr<float>(r);
    std::uint8_t* m = centre.ptr<std::uint8_t>(r);
    for (int k = 0; k < cols; ++k) {
      const int kl = std::max(k - 1, 0), kr = std::min(k + 1, cols - 1);
      const float a = mid[kl] - 2.0F * mid[k] + mid[kr];  // dxx
      const float b = up[k] - 2.0F * mid[k] + dn[k];      // dyy
      const float c = 0.25F * ((dn[kr] - dn[kl]) - (up[kr] - up[kl]));
      const float gx = 0.5F * (mid[kr] - mid[kl]);
      const float gy = 0.5F * (dn[k] - up[k]);
      const float mean = 0.5F * (a + b);
      const float dev = std::sqrt(0.25F * (a - b) * (a - b) + c * c);
      const float l1 = mean - dev, l2 = mean + dev;  // l1 ≤ l2
      o[k] = std::max(0.0F, s2 * (-l1 - std::abs(l2)));
      m[k] = 0;
      if (!(l1 < 0.0F)) continue;
      // Eigenvector of l1 (across the ridge) and the Newton step to the profile's
      // maximum along it (Steger): the ridge centre lies in this cell iff the step
      // stays inside it. On the flank of a step edge the step is ~σ: rejected.
      float nx = c, ny = l1 - a;
      if (std::abs(nx) + std::abs(ny) < 1e-12F) {
        nx = l1 - b;
        ny = c;
      }
      if (std::abs(nx) + std::abs(ny) < 1e-12F) {
        nx = 1.0F;
        ny = 0.0F;
      }
      const float norm = std::sqrt(nx * nx + ny * ny);
      nx /= norm;
      ny /= norm;
      const float t = -(gx * nx + gy * ny) / l1;
      m[k] = std::abs(t * nx) <= 0.5F && std::abs(t * ny) <= 0.5F ? 1 : 0;
    }
  }
  return {db, out, centre, std::nullopt};
}

/// ridgeness() computed only where it can be non-zero. Below the floor a cell's dB is
/// exactly 0, and every filter of the chain (median, Gaussian truncated at OpenCV's
/// kernel radius, central differences) maps an all-zero neighbourhood to 0, so the
/// outputs vanish farther than `reach` cells from any cell above the floor — in a 2 s
/// localization window ~1 % of the cells are above it, in ~6 % of 16 × 16 blocks. Each
/// bounding box of the cells within `reach` of one (8-connected groups, at block
/// granularity: BlockRegions) is filtered as its own image, padded by `reach` more: what
/// the padding's border treatment changes stays inside the padding, and where the pad is
/// clipped by the image edge the border treatment is the whole image's. The result
/// equals ridgeness() of the whole image bit for bit (tests/radar/line_extractor_test.cpp).
RidgeImages ridgeness_sparse(const cv::Mat& power, double cs, double noise_power, int q,
                             const LineExtractorConfig& cfg) {
  if (cfg.dense_filters || !(noise_power > 0.0)) return ridgeness(power, cs, noise_power, q, cfg);
  const double floor = floor_power(power, noise_power, q, cfg);
  const double sigma = cfg.sigma_m / cs;
  // Median half-aperture + Gaussian radius (OpenCV: ksize = round(8σ + 1) | 1 for
  // float images) + the derivatives' cell, with a margin.
  const int gauss_radius = (static_cast<int>(std::lround(8.0 * sigma + 1.0)) | 1) / 2;
  const int reach = cfg.median_kernel_cells / 2 + gauss_radius + 1 + 2;
  // Seeds per block of 16 × 16 cells, dilated by `reach` (in blocks).
  constexpr int kBlock = 16;
  BlockRegions blocks(power.cols, power.rows, kBlock);
  const auto fl = static_cast<float>(floor);
  for (int row = 0; row < power.rows; ++row) {
    const float* p = power.ptr<float>(row);
    for (int b0 = 0; b0 < power.cols; b0 += kBlock) {
      const int b1 = std::min(power.cols, b0 + kBlock);
      bool any = false;
      for (int c = b0; c < b1; ++c) any |= p[c] > fl;
      if (any) blocks.mark(b0, row);
    }
  }
  blocks.group((reach + kBlock - 1) / kBlock);
  // Reused buffers: fresh full-size images would be page-faulted in at every call.
  thread_local cv::Mat db, ridge, centre;
  for (cv::Mat* m : {&db, &ridge}) m->create(power.size(), CV_32F);
  centre.create(power.size(), CV_8U);
  db.setTo(0);
  ridge.setTo(0);
  centre.setTo(0);
  const cv::Rect image(0, 0, power.cols, power.rows);
  for (const BlockRegion& b : blocks.regions) {
    const cv::Rect r(b.x0, b.y0, b.x1 - b.x0, b.y1 - b.y0);
    const cv::Rect padded =
        cv::Rect(r.x - reach, r.y - reach, r.width + 2 * reach, r.height + 2 * reach) & image;
    const RidgeImages sub = ridgeness(power(padded).clone(), cs, noise_power, q, cfg);
    const cv::Rect inner(r.x - padded.x, r.y - padded.y, r.width, r.height);
    sub.db(inner).copyTo(db(r));
    sub.ridge(inner).copyTo(ridge(r));
    sub.centre(inner).copyTo(centre(r));
  }
  // Callers keep the images only until their next call on this thread.
  return {db, ridge, centre, std::move(blocks)};
}

/// Ridge centres above the threshold, one-cell gaps closed and thickened to ≥ 3 cells
/// (a 3×3 dilation: keeps every ridge a connected skeleton), each connected ridge
/// thinned in its own bounding box and OR-ed into `skel` (same size as `ridge`). Thinning
/// iterates over its image until nothing changes and the ridges cover a small part of
/// the window, hence per component. Guo–Hall: OpenCV's Zhang–Suen collapses some 3-cell
/// diagonal bands to a single pixel.
void add_skeleton(const cv::Mat& ridge, const cv::Mat& centre, const LineExtractorConfig& cfg,
                  cv::Mat skel) {
  cv::Mat bin;
  cv::threshold(ridge, bin, cfg.ridge_threshold_db, 255.0, cv::THRESH_BINARY);
  bin.convertTo(bin, CV_8U);
  bin.setTo(0, centre == 0);
  cv::dilate(bin, bin, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(3, 3)));
  cv::Mat lab, st, cen;
  const int ncomp = cv::connectedComponentsWithStats(bin, lab, st, cen, 8, CV_32S);
  for (int k = 1; k < ncomp; ++k) {
    const int x = st.at<int>(k, cv::CC_STAT_LEFT), y = st.at<int>(k, cv::CC_STAT_TOP);
    const int bw = st.at<int>(k, cv::CC_STAT_WIDTH), bh = st.at<int>(k, cv::CC_STAT_HEIGHT);
    if (std::max(bw, bh) < 3) continue;  // too small to hold a line
    // One-cell zero border so the thinning sees the component's outline.
    cv::Mat roi = cv::Mat::zeros(bh + 2, bw + 2, CV_8U);
    roi(cv::Rect(1, 1, bw, bh)).setTo(255, lab(cv::Rect(x, y, bw, bh)) == k);
    cv::Mat thin;
    cv::ximgproc::thinning(roi, thin, cv::ximgproc::THINNING_GUOHALL);
    cv::Mat dst = skel(cv::Rect(x, y, bw, bh));
    cv::bitwise_or(dst, thin(cv::Rect(1, 1, bw, bh)), dst);
  }
}

/// The skeleton of the ridge image (add_skeleton() of the whole image). With sparse
/// filtering each block group is processed on its own: its bounding box padded by the
/// dilation's cell, with the ridge cells of other groups (bounding boxes may overlap)
/// cleared. Groups are at least a block apart, so no dilated ridge joins two of them,
/// every component is the whole image's and is thinned alike: the same skeleton.
cv::Mat skeleton(const RidgeImages& ri, const LineExtractorConfig& cfg) {
  cv::Mat skel = cv::Mat::zeros(ri.ridge.size(), CV_8U);
  if (!ri.regions) {
    add_skeleton(ri.ridge, ri.centre, cfg, skel);
    return skel;
  }
  const BlockRegions& blocks = *ri.regions;
  const cv::Rect image(0, 0, ri.ridge.cols, ri.ridge.rows);
  for (const BlockRegion& b : blocks.regions) {
    const cv::Rect padded = cv::Rect(b.x0 - 1, b.y0 - 1, b.x1 - b.x0 + 2, b.y1 - b.y0 + 2) & image;
    cv::Mat ridge = ri.ridge(padded).clone();
    for (int row = 0; row < padded.height; ++row) {
      float* r = ridge.ptr<float>(row);
      for (int col = 0; col < padded.width; ++col) {
        if (blocks.label_at(padded.x + col, padded.y + row) != b.label) r[col] = 0.0F;
      }
    }
    add_skeleton(ridge, ri.centre(padded), cfg, skel(padded));
  }
  return skel;
}

/// Value of img at the cell containing a point (metres); −1 outside the image.
float value_at(const cv::Mat& img, const CellBox& box, double cs, const Eigen::Vector2d& p) {
  const int col = static_cast<int>(std::floor(p.x() / cs)) - box.min_ix;
  const int row = static_cast<int>(std::floor(p.y() / cs)) - box.min_iy;
  if (col < 0 || row < 0 || col >= img.cols || row >= img.rows) return -1.0F;
  return img.ptr<float>(row)[col];
}

/// Moves the ends of a segment to where the bright structure ends: the ridge
/// filter loses ~σ at each end (the along-line curvature of an end looks like a
/// blob) and the skeleton breaks on speckle. Walks outward in cell steps while,
/// within max_gap, the dB-over-floor (maximum over ±1 cell across the line; the
/// median filter would erode the end by a cell) stays above end_level_fraction of the
/// segment's median; also trims ends that fall below it.
void fit_ends(LineCandidate& l, const cv::Mat& db, const CellBox& box, double cs,
              const LineExtractorConfig& cfg) {
  const Eigen::Vector2d a = l.start_m, b = l.end_m;
  const double len = (b - a).norm();
  if (len < cs) return;
  const Eigen::Vector2d d = (b - a) / len;
  const Eigen::Vector2d n(-d.y(), d.x());
  // Max across the line only (±1 cell): along it, a neighbourhood would lengthen the end.
  auto across_max = [&](const Eigen::Vector2d& p) {
    float best = -1.0F;
    for (int k = -1; k <= 1; ++k) best = std::max(best, value_at(db, box, cs, p + k * cs * n));
    return best;
  };
  std::vector<float> prof;
  for (double t = 0.0; t <= len; t += cs) {
    const float v = across_max(a + t * d);
    if (v >= 0.0F) prof.push_back(v);
  }
  if (prof.empty()) return;
  std::nth_element(prof.begin(), prof.begin() + prof.size() / 2, prof.end());
  const float level = prof[prof.size() / 2] * static_cast<float>(cfg.end_level_fraction);
  const double max_ext = cfg.max_end_extension_m;
  auto walk = [&](const Eigen::Vector2d& from, const Eigen::Vector2d& dir, double inner) {
    // Last good position along dir, starting `inner` metres inside the segment.
    double last = -inner;
    bool seen = false;
    for (double t = -inner; t <= max_ext; t += cs) {
      if (across_max(from + t * dir) >= level) {
        last = t;
        seen = true;
      } else if (seen && t - last > cfg.max_gap_m) {
        break;
      }
    }
    return last;
  };
  const double inner = std::min(0.5 * len, max_ext);
  const double eb = walk(b, d, inner);
  const double ea = walk(a, -d, inner);
  l.start_m = a - ea * d;
  l.end_m = b + eb * d;
}

/// Whether a segment is the azimuth spread of a point target (file comment of the
/// header): its dB profile decays away from its brightest point.
bool point_spread(const LineCandidate& l, const cv::Mat& db, const CellBox& box, double cs,
                  const LineExtractorConfig& cfg) {
  if (!(cfg.spread_min_decay_db_per_m > 0.0)) return false;
  const Eigen::Vector2d a = l.start_m, b = l.end_m;
  const double len = (b - a).norm();
  if (len < 4.0 * cs) return false;
  const Eigen::Vector2d d = (b - a) / len;
  const Eigen::Vector2d n(-d.y(), d.x());
  std::vector<double> prof;
  for (double t = 0.0; t <= len; t += cs) {
    float best = 0.0F;  // outside the image: the floor
    for (int k = -1; k <= 1; ++k)
      best = std::max(best, value_at(db, box, cs, a + t * d + k * cs * n));
    prof.push_back(best);
  }
  const int m = static_cast<int>(prof.size());
  // Brightest point of the profile smoothed over ±2 cells (a single speckle spike
  // does not decide where the peak is).
  int peak = 0;
  double best = -1.0;
  for (int i = 0; i < m; ++i) {
    double s = 0.0;
    int c = 0;
    for (int j = std::max(0, i - 2); j <= std::min(m - 1, i + 2); ++j) s += prof[j], ++c;
    if (s / c > best) best = s / c, peak = i;
  }
  // Theil–Sen slope of level against distance from the peak (median of pairwise
  // slopes; robust to the bumps where the spread crosses a curb or another target).
  // At most ~100 samples: the pairs grow quadratically.
  const int stride = std::max(1, m / 100);
  std::vector<double> slopes;
  for (int i = 0; i < m; i += stride) {
    for (int j = i + stride; j < m; j += stride) {
      const double dx = (std::abs(j - peak) - std::abs(i - peak)) * cs;
      if (std::abs(dx) > 0.25) slopes.push_back((prof[j] - prof[i]) / dx);
    }
  }
  if (slopes.empty()) return false;
  auto mid = slopes.begin() + static_cast<std::ptrdiff_t>(slopes.size() / 2);
  std::nth_element(slopes.begin(), mid, slopes.end());
  return *mid <= -cfg.spread_min_decay_db_per_m;
}

Eigen::Vector2d pixel_xy(const CellBox& box, double cs, double col, double row) {
  return {(box.min_ix + col + 0.5) * cs, (box.min_iy + row + 0.5) * cs};
}

/// Clips a segment to an axis-aligned box (Liang–Barsky); false if nothing remains.
bool clip(Eigen::Vector2d& a, Eigen::Vector2d& b, const Eigen::Vector2d& lo,
          const Eigen::Vector2d& hi) {
  double t0 = 0.0, t1 = 1.0;
  const Eigen::Vector2d d = b - a;
  for (int k = 0; k < 2; ++k) {
    const double p[2] = {-d[k], d[k]};
    const double qv[2] = {a[k] - lo[k], hi[k] - a[k]};
    for (int s = 0; s < 2; ++s) {
      if (std::abs(p[s]) < 1e-15) {
        if (qv[s] < 0) return false;
        continue;
      }
      const double t = qv[s] / p[s];
      if (p[s] < 0) {
        t0 = std::max(t0, t);
      } else {
        t1 = std::min(t1, t);
      }
    }
  }
  if (t0 >= t1) return false;
  const Eigen::Vector2d a0 = a;
  a = a0 + t0 * d;
  b = a0 + t1 * d;
  return true;
}

double sample_mean(const cv::Mat& img, const CellBox& box, double cs, const Eigen::Vector2d& a,
                   const Eigen::Vector2d& b) {
  const double len = (b - a).norm();
  const int n = std::max(2, static_cast<int>(len / cs) + 1);
  double sum = 0.0;
  int cnt = 0;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector2d p = a + (b - a) * (double(i) / (n - 1));
    const int col = static_cast<int>(std::floor(p.x() / cs)) - box.min_ix;
    const int row = static_cast<int>(std::floor(p.y() / cs)) - box.min_iy;
    if (col < 0 || row < 0 || col >= img.cols || row >= img.rows) continue;
    // Max over the 3×3 neighbourhood: the skeleton may sit one cell off the fitted line.
    float best = 0.0F;
    for (int dr = -1; dr <= 1; ++dr) {
      for (int dc = -1; dc <= 1; ++dc) {
        const int rr = row + dr, cc = col + dc;
        if (rr >= 0 && cc >= 0 && rr < img.rows && cc < img.cols) {
          best = std::max(best, img.ptr<float>(rr)[cc]);
        }
      }
    }
    sum += best;
    ++cnt;
  }
  return cnt > 0 ? sum / cnt : 0.0;
}

}  // namespace

cv::Mat ridgeness_image(const cv::Mat& power, double cell_size_m, double noise_power, int q,
                        const LineExtractorConfig& cfg) {
  return ridgeness_sparse(power, cell_size_m, noise_power, q, cfg).ridge.clone();
}

std::vector<LineCandidate> merge_collinear(std::vector<LineCandidate> lines,
                                           const LineExtractorConfig& cfg) {
  const double cos_tol = std::cos(cfg.merge_angle_deg * std::numbers::pi / 180.0);
  bool merged = true;
  while (merged) {
    merged = false;
    std::sort(lines.begin(), lines.end(), [](const LineCandidate& a, const LineCandidate& b) {
      return (a.end_m - a.start_m).squaredNorm() > (b.end_m - b.start_m).squaredNorm();
    });
    for (std::size_t i = 0; i < lines.size() && !merged; ++i) {
      const Eigen::Vector2d a = lines[i].start_m;
      const double la = (lines[i].end_m - a).norm();
      if (la < 1e-9) continue;
      const Eigen::Vector2d d = (lines[i].end_m - a) / la;
      const Eigen::Vector2d n(-d.y(), d.x());
      for (std::size_t j = i + 1; j < lines.size(); ++j) {
        const Eigen::Vector2d b0 = lines[j].start_m, b1 = lines[j].end_m;
        const double lb = (b1 - b0).norm();
        if (lb < 1e-9) continue;
        if (std::abs(d.dot((b1 - b0) / lb)) < cos_tol) continue;
        if (std::abs(n.dot(b0 - a)) > cfg.merge_offset_m ||
            std::abs(n.dot(b1 - a)) > cfg.merge_offset_m) {
          continue;
        }
        const double t0 = std::min(d.dot(b0 - a), d.dot(b1 - a));
        const double t1 = std::max(d.dot(b0 - a), d.dot(b1 - a));
        if (t0 > la + cfg.merge_gap_m || t1 < -cfg.merge_gap_m) continue;
        const double s0 = std::min(0.0, t0), s1 = std::max(la, t1);
        LineCandidate m;
        m.start_m = a + s0 * d;
        m.end_m = a + s1 * d;
        m.strength = (lines[i].strength * la + lines[j].strength * lb) / (la + lb);
        lines[i] = m;
        lines.erase(lines.begin() + static_cast<std::ptrdiff_t>(j));
        merged = true;
        break;
      }
    }
  }
  return lines;
}

std::vector<LineCandidate> extract_lines(const cv::Mat& power, const CellBox& box, double cs,
                                         double noise_power, int q, const LineExtractorConfig& cfg,
                                         const CellBox* core) {
  POLMAP_EXPECT(power.rows == box.height() && power.cols == box.width());
  const RidgeImages ri = ridgeness_sparse(power, cs, noise_power, q, cfg);
  const cv::Mat& r = ri.ridge;
  const cv::Mat skel = skeleton(ri, cfg);
  std::vector<cv::Vec4i> hough;
  const int min_votes = std::max(2, static_cast<int>(cfg.hough_min_votes_m / cs));
  cv::HoughLinesP(skel, hough, cfg.hough_rho_m / cs, cfg.hough_theta_deg * std::numbers::pi / 180.0,
                  min_votes, cfg.min_length_m / cs * 0.5, cfg.max_gap_m / cs);

  // Skeleton pixels for the refinement.
  std::vector<cv::Point> pix;
  cv::findNonZero(skel, pix);
  const double rad = cfg.refine_radius_m / cs;

  // Longest first; a segment most of whose support a longer one already explains is a
  // Hough duplicate of the same ridge and is dropped.
  std::sort(hough.begin(), hough.end(), [](const cv::Vec4i& a, const cv::Vec4i& b) {
    return std::hypot(a[2] - a[0], a[3] - a[1]) > std::hypot(b[2] - b[0], b[3] - b[1]);
  });
  cv::Mat claimed = cv::Mat::zeros(skel.size(), CV_8U);
  std::vector<LineCandidate> out;
  for (const cv::Vec4i& h : hough) {
    const Eigen::Vector2d p0(h[0], h[1]), p1(h[2], h[3]);
    const double len = (p1 - p0).norm();
    if (len < 1.0) continue;
    const Eigen::Vector2d d = (p1 - p0) / len, n(-d.y(), d.x());
    // Weighted total-least-squares fit to supporting skeleton pixels.
    double wsum = 0.0;
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    std::vector<std::pair<Eigen::Vector2d, double>> support;
    const double gap = cfg.max_gap_m / cs;
    for (const cv::Point& p : pix) {
      const Eigen::Vector2d v(p.x, p.y);
      const double t = d.dot(v - p0);
      if (t < -gap || t > len + gap || std::abs(n.dot(v - p0)) > rad) continue;
      const double w = std::max(1e-6, double(r.ptr<float>(p.y)[p.x]));
      support.push_back({v, w});
    }
    // Only support no longer segment explains yet: a duplicate keeps just the part
    // of the ridge it adds (e.g. its extension beyond the longer segment's end).
    std::erase_if(support, [&](const auto& sp) {
      return claimed.ptr<std::uint8_t>(int(sp.first.y()))[int(sp.first.x())] != 0;
    });
    if (static_cast<int>(support.size()) < min_votes) continue;
    wsum = 0.0;
    mean.setZero();
    for (const auto& sp : support) {
      claimed.ptr<std::uint8_t>(int(sp.first.y()))[int(sp.first.x())] = 1;
      wsum += sp.second;
      mean += sp.second * sp.first;
    }
    Eigen::Vector2d dir = d, c0 = p0;
    double tmin = 0.0, tmax = len;
    if (support.size() >= 3) {
      mean /= wsum;
      Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
      for (const auto& [v, w] : support) cov += w * (v - mean) * (v - mean).transpose();
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(cov);
      dir = es.eigenvectors().col(1);
      if (dir.dot(d) < 0) dir = -dir;
      c0 = mean;
      tmin = std::numeric_limits<double>::infinity();
      tmax = -tmin;
      for (const auto& [v, w] : support) {
        const double t = dir.dot(v - c0);
        tmin = std::min(tmin, t);
        tmax = std::max(tmax, t);
      }
    } else {
      c0 = p0;
    }
    Eigen::Vector2d a = c0 + tmin * dir, b = c0 + tmax * dir;
    LineCandidate lc;
    lc.start_m = pixel_xy(box, cs, a.x(), a.y());
    lc.end_m = pixel_xy(box, cs, b.x(), b.y());
    fit_ends(lc, ri.db, box, cs, cfg);
    out.push_back(lc);
  }
  out = merge_collinear(std::move(out), cfg);
  std::vector<LineCandidate> kept;
  for (LineCandidate& lc : out) {
    if (point_spread(lc, ri.db, box, cs, cfg)) continue;
    if (core != nullptr) {
      const Eigen::Vector2d lo(core->min_ix * cs, core->min_iy * cs);
      const Eigen::Vector2d hi(core->max_ix * cs, core->max_iy * cs);
      if (!clip(lc.start_m, lc.end_m, lo, hi)) continue;
    } else if ((lc.end_m - lc.start_m).norm() < cfg.min_length_m) {
      continue;
    }
    lc.strength = sample_mean(r, box, cs, lc.start_m, lc.end_m);
    kept.push_back(lc);
  }
  return kept;
}

std::vector<LineCandidate> extract_lines(const CovarianceGridmap& map,
                                         const LineExtractorConfig& cfg) {
  POLMAP_EXPECT(cfg.chunk_tiles >= 1);
  const double cs = map.cell_size_m();
  const int chunk_cells = cfg.chunk_tiles * kTileSizeCells;
  // Halo: the filters' support plus a minimum segment, so segments crossing the
  // border are found whole on both sides and only clipped.
  const int halo = static_cast<int>(std::ceil((4.0 * cfg.sigma_m + cfg.min_length_m) / cs)) + 4;
  // Per chunk, the bounding box of its populated tiles plus the halo: cells outside
  // populated tiles read as the floor (0 dB), where the filters give nothing, so this
  // finds what the whole chunk would; a sliding-window map fills only part of a chunk.
  std::vector<LineCandidate> all;
  for (const auto& [cx, cy, populated] : map.populated_chunks(cfg.chunk_tiles)) {
    const CellBox core{cx * chunk_cells, cy * chunk_cells, (cx + 1) * chunk_cells,
                       (cy + 1) * chunk_cells};
    const CellBox box{std::max(core.min_ix, populated.min_ix) - halo,
                      std::max(core.min_iy, populated.min_iy) - halo,
                      std::min(core.max_ix, populated.max_ix) + halo,
                      std::min(core.max_iy, populated.max_iy) + halo};
    const cv::Mat p = map.trace_image(box, cfg.min_persistence);
    auto lines = extract_lines(p, box, cs, map.noise_power(), map.q(), cfg, &core);
    all.insert(all.end(), lines.begin(), lines.end());
  }
  // Join the clipped pieces of segments that cross chunk borders.
  LineExtractorConfig join = cfg;
  join.merge_gap_m = std::max(cfg.merge_gap_m, 2.0 * cs);
  all = merge_collinear(std::move(all), join);
  std::vector<LineCandidate> out;
  for (const auto& l : all) {
    if ((l.end_m - l.start_m).norm() >= cfg.min_length_m) out.push_back(l);
  }
  std::sort(out.begin(), out.end(), [](const LineCandidate& a, const LineCandidate& b) {
    return a.start_m.y() != b.start_m.y() ? a.start_m.y() < b.start_m.y()
                                          : a.start_m.x() < b.start_m.x();
  });
  return out;
}

}  // namespace polmap::radar
