#include "polmap/tiles/polyline_simplify.hpp"

#include <gtest/gtest.h>
#include <pthread.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "polmap/tiles/local_frame.hpp"

namespace polmap::tiles {
namespace {

// Distance of q to the segment [a, b].
double segment_distance(const Eigen::Vector2d& q, const Eigen::Vector2d& a,
                        const Eigen::Vector2d& b) {
  const Eigen::Vector2d d = b - a;
  const double l2 = d.squaredNorm();
  const double t = l2 > 0 ? std::clamp((q - a).dot(d) / l2, 0.0, 1.0) : 0.0;
  return (q - (a + t * d)).norm();
}

// The textbook recursive Douglas–Peucker (segment distance), as the reference.
void reference(const std::vector<Eigen::Vector2d>& p, std::size_t a, std::size_t b, double tol,
               std::vector<bool>& keep) {
  if (b <= a + 1) return;
  double worst = -1.0;
  std::size_t at = a;
  for (std::size_t i = a + 1; i < b; ++i) {
    const double dist = segment_distance(p[i], p[a], p[b]);
    if (dist > worst) worst = dist, at = i;
  }
  if (worst > tol) {
    keep[at] = true;
    reference(p, a, at, tol, keep);
    reference(p, at, b, tol, keep);
  }
}

// Douglas–Peucker bounds the distance of a dropped vertex to the kept segment around it.
double line_distance(const Eigen::Vector2d& q, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return segment_distance(q, a, b);
}

TEST(DouglasPeucker, WindowsKeepTheirEndsAndTheTolerance) {
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Eigen::Vector2d> p;
  for (int i = 0; i < 2500; ++i) p.emplace_back(0.2 * i, 3.0 * u(rng));
  EXPECT_EQ(douglas_peucker_keep(p, 0.5, 0), douglas_peucker_keep(p, 0.5));
  EXPECT_EQ(douglas_peucker_keep(p, 0.5, 5000), douglas_peucker_keep(p, 0.5));
  const auto keep = douglas_peucker_keep(p, 0.5, 1000);
  for (std::size_t e : {0U, 1000U, 2000U, 2499U}) EXPECT_TRUE(keep[e]) << e;
  std::size_t last = 0;
  for (std::size_t i = 1; i < p.size(); ++i) {
    if (!keep[i]) continue;
    for (std::size_t j = last + 1; j < i; ++j)
      EXPECT_LE(line_distance(p[j], p[last], p[i]), 0.5 + 1e-9);
    last = i;
  }
}

TEST(DouglasPeucker, APathThatTurnsBackKeepsItsFarEnd) {
  // Out 100 m along x and back to x = 40: every vertex lies on the chord's line, but
  // the turn at x = 100 is 60 m beyond the chord's end.
  std::vector<Eigen::Vector2d> p;
  for (int i = 0; i <= 100; ++i) p.emplace_back(i, 0.0);
  for (int i = 99; i >= 40; --i) p.emplace_back(i, 0.0);
  const auto keep = douglas_peucker_keep(p, 0.5);
  EXPECT_TRUE(keep[100]);
  EXPECT_EQ(std::count(keep.begin(), keep.end(), true), 3);
}

TEST(DouglasPeucker, EqualsTheRecursiveReference) {
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0.0, 0.3);
  for (int trial = 0; trial < 50; ++trial) {
    std::vector<Eigen::Vector2d> p;
    for (int i = 0; i < 200; ++i) p.emplace_back(0.5 * i, std::sin(0.05 * i) * 5.0 + n(rng));
    std::vector<bool> ref(p.size(), false);
    ref.front() = ref.back() = true;
    reference(p, 0, p.size() - 1, 0.25, ref);
    EXPECT_EQ(douglas_peucker_keep(p, 0.25), ref) << trial;
  }
}

TEST(DouglasPeucker, DroppedVerticesStayWithinTolerance) {
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Eigen::Vector2d> p;
  for (int i = 0; i < 2000; ++i) p.emplace_back(0.2 * i, 3.0 * u(rng));
  const auto keep = douglas_peucker_keep(p, 0.5);
  std::size_t last = 0;
  for (std::size_t i = 1; i < p.size(); ++i) {
    if (!keep[i]) continue;
    for (std::size_t j = last + 1; j < i; ++j)
      EXPECT_LE(line_distance(p[j], p[last], p[i]), 0.5 + 1e-9);
    last = i;
  }
  EXPECT_TRUE(keep.front());
  EXPECT_TRUE(keep.back());
}

TEST(DouglasPeucker, HostileZigZagRunsOnASmallStack) {
  // A zig-zag of growing amplitude: every split peels off one vertex, so the recursive
  // version is 30,000 frames deep (a few MB of stack). Run on a 256 KiB thread stack.
  struct Job {
    std::vector<Eigen::Vector2d> p;
    std::vector<bool> keep;
  } job;
  const int n = 30'000;
  for (int i = 0; i < n; ++i) {
    job.p.emplace_back(1e-3 * i, (i % 2 == 0 ? 1.0 : -1.0) * (1.0 + 1e-3 * i));
  }
  pthread_attr_t attr;
  pthread_attr_init(&attr);
  pthread_attr_setstacksize(&attr, 256 * 1024);
  pthread_t t;
  ASSERT_EQ(pthread_create(
                &t, &attr,
                [](void* arg) -> void* {
                  auto* j = static_cast<Job*>(arg);
                  j->keep = douglas_peucker_keep(j->p, 0.01);
                  return nullptr;
                },
                &job),
            0);
  pthread_join(t, nullptr);
  pthread_attr_destroy(&attr);
  ASSERT_EQ(job.keep.size(), job.p.size());
  // Almost every vertex is a corner that must stay.
  EXPECT_GT(std::count(job.keep.begin(), job.keep.end(), true), n - n / 100);
}

TEST(SimplifyPolyline, StraightGeodeticLineKeepsItsEnds) {
  const LocalFrame f({48.0, 9.0, 0.0});
  std::vector<GeoPoint> line;
  for (int i = 0; i <= 100; ++i) line.push_back(f.to_geo(Eigen::Vector2d(2.0 * i, 0.01 * (i % 2))));
  const auto s = simplify_polyline(line, 0.25);
  ASSERT_EQ(s.size(), 2U);
  EXPECT_DOUBLE_EQ(s.front().lat_deg, line.front().lat_deg);
  EXPECT_DOUBLE_EQ(s.back().lon_deg, line.back().lon_deg);
  EXPECT_EQ(simplify_polyline({line[0], line[1]}, 0.25).size(), 2U);
}

}  // namespace
}  // namespace polmap::tiles
