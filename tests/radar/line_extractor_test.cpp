// Ridge/Hough line extraction on synthetic power images: a bright line in speckled
// clutter is recovered within 0.3 m at its ends and 1° in direction, at any
// orientation; point-like blobs give no lines; a wall crossing gridmap chunk
// borders comes out as one segment; filtering only around cells above the floor gives
// what filtering the whole image gives; the azimuth spread of a point target is no
// line, a wall with a bright spot is.
#include "polmap/radar/line_extractor.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>
#include <sstream>

namespace polmap::radar {
namespace {

constexpr double kCell = 0.1;

double dist_to_segment(const Eigen::Vector2d& p, const Eigen::Vector2d& a,
                       const Eigen::Vector2d& b) {
  const Eigen::Vector2d d = b - a;
  const double t = std::clamp(d.dot(p - a) / d.squaredNorm(), 0.0, 1.0);
  return (a + t * d - p).norm();
}

/// Speckled background (mean 0.3) plus lines of peak power `peak` (Gaussian
/// cross-section σ = 0.6 cells), speckle of `looks` looks everywhere (1: exponential,
/// a single frame; accumulated gridmaps average several decorrelated looks).
cv::Mat scene(std::mt19937& rng, const CellBox& box,
              const std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>>& lines, double peak,
              int looks = 1) {
  cv::Mat img(box.height(), box.width(), CV_32F);
  std::gamma_distribution<double> g(looks, 1.0 / looks);
  auto speckle = [&](std::mt19937& r) { return g(r); };
  for (int row = 0; row < img.rows; ++row) {
    for (int col = 0; col < img.cols; ++col) {
      const Eigen::Vector2d c((box.min_ix + col + 0.5) * kCell, (box.min_iy + row + 0.5) * kCell);
      double p = 0.3 * speckle(rng);
      for (const auto& [a, b] : lines) {
        const double dd = dist_to_segment(c, a, b) / kCell;
        p += peak * std::exp(-0.5 * dd * dd / 0.36) * speckle(rng);
      }
      img.ptr<float>(row)[col] = static_cast<float>(p);
    }
  }
  return img;
}

std::string describe(const std::vector<LineCandidate>& lines) {
  std::ostringstream os;
  for (const auto& l : lines) {
    os << "\n  (" << l.start_m.transpose() << ") -> (" << l.end_m.transpose() << ") R "
       << l.strength;
  }
  return os.str();
}

double angle_deg(const Eigen::Vector2d& u, const Eigen::Vector2d& v) {
  return std::acos(std::min(1.0, std::abs(u.normalized().dot(v.normalized())))) * 180.0 /
         std::numbers::pi;
}

void expect_segment(const LineCandidate& l, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  const bool flip = (l.start_m - a).norm() > (l.start_m - b).norm();
  const Eigen::Vector2d s = flip ? l.end_m : l.start_m, e = flip ? l.start_m : l.end_m;
  EXPECT_LT((s - a).norm(), 0.3) << s.transpose() << " vs " << a.transpose();
  EXPECT_LT((e - b).norm(), 0.3) << e.transpose() << " vs " << b.transpose();
  EXPECT_LT(angle_deg(l.end_m - l.start_m, b - a), 1.0);
  EXPECT_GT(l.strength, LineExtractorConfig{}.ridge_threshold_db);
}

TEST(LineExtractor, RecoversSegmentsAtAnyOrientation) {
  std::mt19937 rng(1);
  const CellBox box{0, 0, 200, 200};
  for (double deg : {0.0, 17.0, 45.0, 90.0, 133.0}) {
    const double th = deg * std::numbers::pi / 180.0;
    const Eigen::Vector2d mid(10.03, 9.97), d(std::cos(th), std::sin(th));
    const Eigen::Vector2d a = mid - 6.0 * d, b = mid + 6.0 * d;
    const cv::Mat img = scene(rng, box, {{a, b}}, 100.0);
    const auto lines = extract_lines(img, box, kCell, 1.0 / 3.0, 3);
    ASSERT_EQ(lines.size(), 1U) << deg << " deg" << describe(lines);
    expect_segment(lines[0], a, b);
  }
}

TEST(LineExtractor, WeakCurbAndStrongWallBothFound) {
  std::mt19937 rng(2);
  const CellBox box{-50, -30, 150, 170};
  const Eigen::Vector2d a1(-3.0, 2.0), b1(12.0, 4.0);
  const Eigen::Vector2d a2(-2.0, 10.0), b2(13.0, 14.5);
  const cv::Mat img = scene(rng, box, {{a1, b1}}, 30.0, 4);
  const cv::Mat wall = scene(rng, box, {{a2, b2}}, 3000.0, 4);
  const auto lines = extract_lines(img + wall, box, kCell, 2.0 / 3.0, 3);
  ASSERT_EQ(lines.size(), 2U);
  const bool first_is_curb = lines[0].start_m.y() < 6.0;
  expect_segment(lines[first_is_curb ? 0 : 1], a1, b1);
  expect_segment(lines[first_is_curb ? 1 : 0], a2, b2);
}

TEST(LineExtractor, PointBlobsGiveNoLines) {
  std::mt19937 rng(3);
  const CellBox box{0, 0, 200, 200};
  cv::Mat img = scene(rng, box, {}, 0.0);
  for (int k = 0; k < 8; ++k) {
    const int cx = 20 + 20 * k, cy = 30 + 17 * k;
    for (int r = -3; r <= 3; ++r) {
      for (int c = -3; c <= 3; ++c) {
        img.ptr<float>(cy + r)[cx + c] +=
            static_cast<float>(1000.0 * std::exp(-0.5 * (r * r + c * c)));
      }
    }
  }
  EXPECT_TRUE(extract_lines(img, box, kCell, 1.0 / 3.0, 3).empty());
}

/// A ridge whose power decays from a peak at `centre` by `decay_db_per_m` along
/// direction d (the azimuth spread of a point target seen from afar: sharp across the
/// range direction, long across it), down to the background, plus speckle.
void add_spread(std::mt19937& rng, const CellBox& box, cv::Mat& img, const Eigen::Vector2d& centre,
                const Eigen::Vector2d& d, double peak, double decay_db_per_m) {
  std::gamma_distribution<double> g(4, 0.25);
  const Eigen::Vector2d n(-d.y(), d.x());
  for (int row = 0; row < img.rows; ++row) {
    for (int col = 0; col < img.cols; ++col) {
      const Eigen::Vector2d c((box.min_ix + col + 0.5) * kCell, (box.min_iy + row + 0.5) * kCell);
      const double along = std::abs(d.dot(c - centre)), across = n.dot(c - centre) / kCell;
      const double level = peak * std::pow(10.0, -0.1 * decay_db_per_m * along);
      img.ptr<float>(row)[col] +=
          static_cast<float>(level * std::exp(-0.5 * across * across / 0.36) * g(rng));
    }
  }
}

TEST(LineExtractor, PointTargetSpreadIsNoLineWallWithBrightSpotIs) {
  // Spread of a point target: 40 dB over the floor at the target, 10 dB/m decay (the
  // median of simulated urban drives), about 8 m of ridge. A wall 20 dB over the floor
  // with a bright spot (a recess, 40 dB) in its middle stays a line.
  std::mt19937 rng(7);
  const CellBox box{0, 0, 300, 200};
  const double noise = 1.0 / 3.0;  // floor: q·σ² = 1
  cv::Mat img = scene(rng, box, {{{3.0, 14.0}, {27.0, 14.0}}}, 100.0, 4);
  for (int r = -2; r <= 2; ++r) {
    for (int c = -2; c <= 2; ++c) img.ptr<float>(140 + r)[150 + c] += 1e4F;
  }
  const Eigen::Vector2d target(12.0, 6.0);
  const double th = 80.0 * std::numbers::pi / 180.0;
  add_spread(rng, box, img, target, {std::cos(th), std::sin(th)}, 1e4, 10.0);
  LineExtractorConfig off;
  off.spread_min_decay_db_per_m = 0.0;
  const auto all = extract_lines(img, box, kCell, noise, 3, off);
  auto is_spread = [&](const LineCandidate& l) {
    return dist_to_segment(target, l.start_m, l.end_m) < 0.5 &&
           angle_deg(l.end_m - l.start_m, {std::cos(th), std::sin(th)}) < 10.0;
  };
  ASSERT_EQ(std::count_if(all.begin(), all.end(), is_spread), 1) << describe(all);
  const auto lines = extract_lines(img, box, kCell, noise, 3);
  EXPECT_EQ(std::count_if(lines.begin(), lines.end(), is_spread), 0) << describe(lines);
  // Every other segment (the wall, broken at its bright spot into overlapping pieces
  // with or without the rejection) is kept unchanged, and together they span the wall.
  ASSERT_EQ(lines.size() + 1, all.size()) << describe(lines) << " vs" << describe(all);
  double lo = 1e9, hi = -1e9;
  for (const auto& l : all) {
    if (is_spread(l)) continue;
    EXPECT_TRUE(std::any_of(lines.begin(), lines.end(), [&](const LineCandidate& k) {
      return k.start_m == l.start_m && k.end_m == l.end_m;
    })) << describe({l});
    EXPECT_LT(std::abs(l.start_m.y() - 14.0) + std::abs(l.end_m.y() - 14.0), 0.5);
    lo = std::min({lo, l.start_m.x(), l.end_m.x()});
    hi = std::max({hi, l.start_m.x(), l.end_m.x()});
  }
  EXPECT_LT(std::abs(lo - 3.0), 0.3);
  EXPECT_LT(std::abs(hi - 27.0), 0.3);
}

TEST(LineExtractor, WallAcrossChunkBordersIsOneSegment) {
  // Chunk = 8 tiles = 51.2 m; the wall crosses x = 51.2 m and y = 51.2 m.
  GridmapConfig cfg;
  cfg.level = PolLevel::SingleRR;
  CovarianceGridmap map(cfg);
  std::mt19937 rng(4);
  std::normal_distribution<double> n(0.0, std::sqrt(0.5));
  const Eigen::Vector2d a(45.0, 44.0), b(58.0, 57.5);
  for (int iy = 420; iy < 600; ++iy) {
    for (int ix = 430; ix < 600; ++ix) {
      const Eigen::Vector2d c((ix + 0.5) * kCell, (iy + 0.5) * kCell);
      const double dd = dist_to_segment(c, a, b) / kCell;
      const double amp = 10.0 * std::exp(-0.25 * dd * dd / 0.36);
      for (int look = 0; look < 3; ++look) {
        // Empty surroundings far below the wall (as cells under the recorder floor).
        const std::vector<cdouble> v{cdouble(n(rng), n(rng)) * (0.01 + amp)};
        map.add_cell_sample(ix, iy, v);
      }
    }
  }
  const auto lines = extract_lines(map);
  ASSERT_EQ(lines.size(), 1U) << describe(lines);
  expect_segment(lines[0], a, b);
}

TEST(LineExtractor, SparseFiltersEqualDenseFilters) {
  // The fast path filters only around cells above the floor (ridgeness_sparse); the
  // straightforward one the whole image. Same ridge image and lines, bit for bit, with
  // structures far apart, near each other, and cut by the image border.
  std::mt19937 rng(6);
  const CellBox box{0, 0, 420, 260};
  const std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> walls{
      {{2.0, 3.0}, {14.0, 5.0}},   {{3.0, 8.0}, {12.0, 7.2}},   {{30.0, 20.0}, {41.0, 24.0}},
      {{-1.0, 12.0}, {6.0, 18.0}}, {{36.0, -1.0}, {43.0, 6.0}}, {{20.0, 12.5}, {20.5, 25.9}}};
  cv::Mat img = scene(rng, box, walls, 50.0, 4);
  for (int k = 0; k < 6; ++k) img.ptr<float>(40 + 30 * k % 200)[300 + 13 * k] += 400.0F;
  LineExtractorConfig dense;
  dense.dense_filters = true;
  const double noise = 1.0 / 3.0;
  const cv::Mat r_fast = ridgeness_image(img, kCell, noise, 3, {});
  const cv::Mat r_ref = ridgeness_image(img, kCell, noise, 3, dense);
  EXPECT_GT(cv::countNonZero(r_ref > 1.5), 200);
  EXPECT_EQ(cv::norm(r_fast, r_ref, cv::NORM_INF), 0.0);
  const auto fast = extract_lines(img, box, kCell, noise, 3);
  const auto ref = extract_lines(img, box, kCell, noise, 3, dense);
  ASSERT_GE(ref.size(), 5U) << describe(ref);
  ASSERT_EQ(fast.size(), ref.size()) << describe(fast) << " vs " << describe(ref);
  for (std::size_t i = 0; i < ref.size(); ++i) {
    EXPECT_EQ(fast[i].start_m, ref[i].start_m) << i;
    EXPECT_EQ(fast[i].end_m, ref[i].end_m) << i;
  }
}

TEST(LineExtractor, MergeCollinearJoinsPiecesOnly) {
  LineExtractorConfig cfg;
  std::vector<LineCandidate> in(3);
  in[0].start_m = {0.0, 0.0};
  in[0].end_m = {5.0, 0.0};
  in[1].start_m = {5.3, 0.05};
  in[1].end_m = {9.0, 0.05};
  in[2].start_m = {0.0, 1.0};  // parallel, 1 m away: stays separate
  in[2].end_m = {9.0, 1.0};
  const auto out = merge_collinear(in, cfg);
  ASSERT_EQ(out.size(), 2U);
}

}  // namespace
}  // namespace polmap::radar
