// Consumer-grade GNSS (--gnss consumer): metre-level, slowly varying errors with the
// configured sigma, outages that drift with distance, and canyon multipath that follows
// the place, so two drives through the same canyon share their error there.
#include "polmap/sim/consumer_gnss.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "polmap/sim/drive.hpp"
#include "sim_test_util.hpp"

namespace polmap::sim {
namespace {

/// A straight street along +x with a facade on both sides (y = +-half_width) from x0 to x1.
std::shared_ptr<World> canyon_world(double x0, double x1, double half_width) {
  auto w = test::empty_world(1000);
  for (const double y : {-half_width, half_width}) {
    WorldObject o;
    o.cls = ObjectClass::Facade;
    o.geometry_m = {{x0, y}, {x1, y}};
    LineScatterer l;
    l.opaque = true;
    l.object = w->add_object(o);
    w->add_line_pieces(o.geometry_m, l);
  }
  w->build_index();
  return w;
}

TEST(ConsumerGnss, BiasHasConfiguredSigmaAndIsSlowlyVarying) {
  GnssSimConfig cfg;
  cfg.grade = GnssGrade::Consumer;
  cfg.consumer.outages_per_km = 0.0;
  const tiles::LocalFrame frame(GeoPoint{48.0, 11.0, 0.0});
  double s2 = 0, n = 0, lag_num = 0, lag_den = 0;
  for (std::uint64_t seed = 1; seed <= 40; ++seed) {
    GnssErrorModel m(cfg, 3600.0, seed);
    double prev = 0;
    for (double t = 0; t < 3600.0; t += 1.0) {
      const TrajectorySample g = m.sample(test::state_at(0.0, 0.0, 0.0, 0.0, 0.0, t), frame);
      EXPECT_EQ(g.solution, GnssSolution::Standalone);
      EXPECT_FLOAT_EQ(g.std_east_m, 2.0F);
      const Eigen::Vector2d e = frame.to_local(g.lat_deg, g.lon_deg);
      s2 += e.squaredNorm();
      n += 2;
      if (t > 0) {
        lag_num += prev * e.x();
        lag_den += e.x() * e.x();
      }
      prev = e.x();
    }
  }
  EXPECT_NEAR(std::sqrt(s2 / n), 1.5, 0.2);
  // First-order Gauss-Markov with tau 300 s: lag-1 s correlation exp(-1/300) ~ 0.997.
  EXPECT_GT(lag_num / lag_den, 0.99);
}

TEST(ConsumerGnss, TheFusedErrorChangesAtCentimetresPerSecond) {
  // At 100 Hz, the trajectory's error changes as a Doppler-aided navigation solution's
  // does: increments over 1 s of RMS sigma * sqrt(1 / (tau * fusion_tau)) ~ 0.027 m, not
  // the raw Gauss-Markov bias's sigma * sqrt(2 / tau) ~ 0.12 m.
  GnssSimConfig cfg;
  cfg.grade = GnssGrade::Consumer;
  cfg.consumer.outages_per_km = 0.0;
  cfg.consumer.heading_sigma_deg = 0.0;
  const tiles::LocalFrame frame(GeoPoint{48.0, 11.0, 0.0});
  auto increment_rms = [&](double fusion_tau_s) {
    cfg.consumer.fusion_tau_s = fusion_tau_s;
    double s2 = 0, n = 0;
    for (std::uint64_t seed = 1; seed <= 10; ++seed) {
      GnssErrorModel m(cfg, 600.0, seed);
      Eigen::Vector2d prev = Eigen::Vector2d::Zero();
      int k = 0;
      for (double t = 0; t < 600.0; t += 0.01, ++k) {
        const TrajectorySample g = m.sample(test::state_at(0.0, 0.0, 0.0, 0.0, 0.0, t), frame);
        if (k % 100 != 0) continue;
        const Eigen::Vector2d e = frame.to_local(g.lat_deg, g.lon_deg);
        if (t > 60.0) s2 += (e - prev).squaredNorm(), n += 2;
        prev = e;
      }
    }
    return std::sqrt(s2 / n);
  };
  const double fused = increment_rms(10.0), raw = increment_rms(1e-9);
  EXPECT_NEAR(fused, 1.5 / std::sqrt(300.0 * 10.0), 0.01);
  EXPECT_NEAR(raw, 1.5 * std::sqrt(2.0 / 300.0), 0.02);
}

TEST(ConsumerGnss, OutagesDriftWithDistanceAndRecover) {
  GnssSimConfig cfg;
  cfg.grade = GnssGrade::Consumer;
  cfg.consumer.bias_sigma_m = 0.0;
  cfg.consumer.heading_sigma_deg = 0.0;
  cfg.consumer.outages_per_km = 2.0;
  const tiles::LocalFrame frame(GeoPoint{48.0, 11.0, 0.0});
  GnssErrorModel m(cfg, 1000.0, 5);
  double max_err = 0;
  double t = 0;
  for (; t < 1000.0; t += 0.1) {
    const double x = 10.0 * t;  // 10 m/s along +x
    const TrajectorySample g = m.sample(test::state_at(x, 0.0, 0.0, 10.0, 0.0, t), frame);
    max_err =
        std::max(max_err, (frame.to_local(g.lat_deg, g.lon_deg) - Eigen::Vector2d(x, 0)).norm());
  }
  // 10 km at 2 outages per km: some outage time, and each drifts by <= 1 % of its distance
  // (at most 20 s * 10 m/s = 200 m -> 2 m; stacked outages during recovery add a little).
  EXPECT_GT(m.consumer_outage_s(), 20.0);
  EXPECT_GT(max_err, 0.2);
  EXPECT_LT(max_err, 4.0);
}

TEST(ConsumerGnss, CanyonFactorIsOneBetweenFacadesAndZeroInTheOpen) {
  const auto w = canyon_world(100.0, 300.0, 8.0);
  const CanyonMultipathField f(*w, ConsumerGnssConfig{}, 1);
  EXPECT_NEAR(f.canyon_factor({200.0, 0.0}, 0.0), 1.0, 1e-9);
  EXPECT_EQ(f.canyon_factor({600.0, 0.0}, 0.0), 0.0);
  EXPECT_EQ(f.error_m({600.0, 0.0}, 0.0), Eigen::Vector2d::Zero());
  // Beside one facade only (the left one is 2 m away, the right 18 m, both count).
  EXPECT_GT(f.canyon_factor({200.0, 6.0}, 0.0), 0.25);
}

TEST(ConsumerGnss, MultipathFieldHasUnitVarianceAndDecorrelatesWithDistance) {
  const auto w = test::empty_world(100);
  ConsumerGnssConfig c;
  const CanyonMultipathField f(*w, c, 3);
  double s2 = 0, near = 0, far = 0, n = 0;
  for (int i = 0; i < 20000; ++i) {
    const Eigen::Vector2d p(37.3 * i, 11.1 * (i % 97));
    const Eigen::Vector2d a = f.unit_field(p);
    s2 += a.squaredNorm();
    near += a.dot(f.unit_field(p + Eigen::Vector2d(2.0, 0.0)));
    far += a.dot(f.unit_field(p + Eigen::Vector2d(10.0 * c.multipath_correlation_m, 0.0)));
    n += 2;
  }
  EXPECT_NEAR(s2 / n, 1.0, 0.08);
  EXPECT_GT(near / n, 0.9);  // 2 m apart: almost the same error
  EXPECT_LT(std::abs(far / n), 0.05);
}

TEST(ConsumerGnss, TwoDrivesShareTheCanyonErrorAtTheSamePlace) {
  const auto w = canyon_world(100.0, 300.0, 8.0);
  GnssSimConfig cfg;
  cfg.grade = GnssGrade::Consumer;
  cfg.consumer.bias_sigma_m = 0.0;  // isolate the place-dependent part
  cfg.consumer.heading_sigma_deg = 0.0;
  cfg.consumer.outages_per_km = 0.0;
  const auto field = std::make_shared<CanyonMultipathField>(*w, cfg.consumer, 7);
  const tiles::LocalFrame& frame = w->frame;
  Eigen::Vector2d err[2];
  for (int d = 0; d < 2; ++d) {
    GnssErrorModel m(cfg, 100.0, 100 + d);  // different drives: different random streams
    m.set_multipath(field);
    // Drive 1 passes 5 s later and 0.3 m further left: the same place.
    const TrajectorySample g =
        m.sample(test::state_at(200.0, 0.3 * d, 0.0, 10.0, 0.0, 5.0 * d), frame);
    err[d] = frame.to_local(g.lat_deg, g.lon_deg) - Eigen::Vector2d(200.0, 0.3 * d);
  }
  EXPECT_GT(err[0].norm(), 0.05);
  EXPECT_LT((err[0] - err[1]).norm(), 0.1 * err[0].norm() + 0.02);
}

TEST(ConsumerGnss, NavigationFilterSmoothsTheCanyonError) {
  const auto w = canyon_world(0.0, 1000.0, 8.0);
  GnssSimConfig cfg;
  cfg.grade = GnssGrade::Consumer;
  cfg.consumer.bias_sigma_m = 0.0;
  cfg.consumer.heading_sigma_deg = 0.0;
  cfg.consumer.outages_per_km = 0.0;
  const auto field = std::make_shared<CanyonMultipathField>(*w, cfg.consumer, 9);
  GnssErrorModel m(cfg, 100.0, 1);
  m.set_multipath(field);
  double d_rec = 0, d_raw = 0, s_rec = 0, s_raw = 0;
  Eigen::Vector2d prev_rec, prev_raw;
  for (int i = 0; i < 900; ++i) {  // 10 Hz at 10 m/s: 1 m per sample
    const double x = 50.0 + i;
    const TrajectorySample g = m.sample(test::state_at(x, 0.0, 0.0, 10.0, 0.0, 0.1 * i), w->frame);
    const Eigen::Vector2d rec = w->frame.to_local(g.lat_deg, g.lon_deg) - Eigen::Vector2d(x, 0);
    const Eigen::Vector2d raw = field->error_m({x, 0.0}, 0.0);
    if (i > 100) {  // after the filter's start-up
      d_rec += (rec - prev_rec).squaredNorm();
      d_raw += (raw - prev_raw).squaredNorm();
      s_rec += rec.squaredNorm();
      s_raw += raw.squaredNorm();
    }
    prev_rec = rec;
    prev_raw = raw;
  }
  // The recorded error changes several times slower per metre than the raw field, and
  // keeps a good part of its size (100 m filter length vs 40 m field correlation).
  EXPECT_LT(std::sqrt(d_rec), 0.3 * std::sqrt(d_raw));
  EXPECT_GT(std::sqrt(s_rec), 0.2 * std::sqrt(s_raw));
}

}  // namespace
}  // namespace polmap::sim
