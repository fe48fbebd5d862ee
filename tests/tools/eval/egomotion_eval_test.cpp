// Ego-motion evaluation: truth handling and the error / drift metrics on
// records with known errors.
#include "polmap/eval/egomotion_eval.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>

#include "polmap/schema/errors.hpp"
#include "test_dir.hpp"

namespace polmap::eval {
namespace {

constexpr double kRadToDeg = 180.0 / std::numbers::pi;

MotionTruth constant_truth(double v, double w, double duration_s) {
  std::vector<MotionTruthSample> s;
  for (int k = 0; k * 0.01 <= duration_s + 1e-9; ++k) s.push_back({k * 0.01, v, w, {}});
  return MotionTruth(std::move(s), false);
}

/// Records as the runner would produce them, from estimates (v·scale + bias, ω + w_bias)
/// integrated by a real Odometry.
std::vector<EgoMotionRecord> records(double v, double w, double v_scale, double v_bias,
                                     double w_bias, double duration_s) {
  radar::Odometry odo;
  std::vector<EgoMotionRecord> out;
  for (int k = 0; k * 0.05 <= duration_s + 1e-9; ++k) {
    EgoMotionRecord r;
    r.estimate.status = radar::MotionEstimate::Status::Ok;
    r.estimate.time_s = k * 0.05;
    r.estimate.v_mps = v * v_scale + v_bias;
    r.estimate.yaw_rate_rps = w + w_bias;
    odo.add(r.estimate);
    r.T_odom_vehicle = odo.try_T_odom_vehicle(r.estimate.time_s);
    r.compute_s = 1e-3;
    out.push_back(r);
  }
  return out;
}

TEST(MotionTruth, IntegratedPosesFollowTheArc) {
  const MotionTruth t = constant_truth(10.0, 0.1, 20.0);
  EXPECT_TRUE(t.poses_integrated());
  const auto s = t.at(12.345);
  ASSERT_TRUE(s.has_value());
  const double r = 10.0 / 0.1;
  // Linear interpolation between 10 ms samples on a 100 m radius: < 1 mm off.
  EXPECT_NEAR(s->T_frame_vehicle.x_m, r * std::sin(0.1 * 12.345), 1e-3);
  EXPECT_NEAR(s->T_frame_vehicle.y_m, r * (1 - std::cos(0.1 * 12.345)), 1e-3);
  EXPECT_FALSE(t.at(-0.1).has_value());
  EXPECT_FALSE(t.at(20.5).has_value());
}

TEST(EgoMotionEval, PerfectEstimatesGiveZeroErrors) {
  const auto m = evaluate_egomotion(records(10.0, 0.05, 1.0, 0.0, 0.0, 30.0),
                                    constant_truth(10.0, 0.05, 30.0));
  EXPECT_EQ(m.estimates_ok, m.frames);
  EXPECT_EQ(m.compared, m.frames);
  EXPECT_NEAR(m.v_rmse_mps, 0.0, 1e-12);
  EXPECT_NEAR(m.yaw_rate_rmse_dps, 0.0, 1e-12);
  ASSERT_TRUE(m.drift_segment_pct.has_value());
  EXPECT_NEAR(*m.drift_segment_pct, 0.0, 1e-3);
  EXPECT_NEAR(m.distance_m, 300.0, 0.01);
  // Starts at 0, 10, ..., 200 m (the last one may miss by rounding of the path length).
  EXPECT_GE(m.drift_segments, 20);
  EXPECT_LE(m.drift_segments, 21);
}

TEST(EgoMotionEval, KnownErrorsGiveKnownMetrics) {
  // 1 % speed scale error on a straight drive: 1 % drift on every sub-path.
  const auto scale =
      evaluate_egomotion(records(10.0, 0.0, 1.01, 0.0, 0.0, 40.0), constant_truth(10.0, 0.0, 40.0));
  EXPECT_NEAR(scale.v_rmse_mps, 0.1, 1e-9);
  EXPECT_NEAR(scale.v_median_err_mps, 0.1, 1e-9);
  EXPECT_NEAR(scale.v_bias_mps, 0.1, 1e-9);
  ASSERT_TRUE(scale.drift_pct.has_value());
  EXPECT_NEAR(*scale.drift_pct, 1.0, 0.01);
  EXPECT_NEAR(*scale.drift_endpoint_pct, 1.0, 0.01);

  // Yaw-rate bias b: over a 100 m sub-path at 10 m/s (10 s) the lateral error
  // is v·b·T²/2 = 10·b·50 -> drift ≈ 5·b·100 %.
  const double b = 0.2 / kRadToDeg;  // 0.2 °/s
  const auto yaw =
      evaluate_egomotion(records(10.0, 0.0, 1.0, 0.0, b, 40.0), constant_truth(10.0, 0.0, 40.0));
  EXPECT_NEAR(yaw.yaw_rate_rmse_dps, 0.2, 1e-9);
  EXPECT_NEAR(yaw.yaw_rate_bias_dps, 0.2, 1e-9);
  ASSERT_TRUE(yaw.drift_segment_pct.has_value());
  EXPECT_NEAR(*yaw.drift_segment_pct, 100.0 * 10.0 * b * 50.0 / 100.0, 0.01);
  EXPECT_NEAR(*yaw.heading_drift_deg_per_100m, 2.0, 0.01);  // 0.2 °/s × 10 s
}

TEST(EgoMotionEval, NonOkEstimatesAreCountedNotCompared) {
  auto recs = records(5.0, 0.0, 1.0, 0.0, 0.0, 10.0);
  recs[3].estimate.status = radar::MotionEstimate::Status::Rejected;
  recs[4].estimate.status = radar::MotionEstimate::Status::TooFewDetections;
  const auto m = evaluate_egomotion(recs, constant_truth(5.0, 0.0, 10.0));
  EXPECT_EQ(m.estimates_rejected, 1);
  EXPECT_EQ(m.estimates_too_few, 1);
  EXPECT_EQ(m.compared, m.frames - 2);
  EXPECT_FALSE(m.drift_segment_pct.has_value());  // 50 m < 100 m
  EXPECT_TRUE(m.drift_endpoint_pct.has_value());
  EXPECT_EQ(to_json(m)["drift_segment_pct"], nullptr);
}

TEST(TruthCsv, ReadsBothFormatsAndNamesBadCells) {
  const util::ScopedTempDir owned(polmap::test::unique_test_dir("truth-csv"));
  const auto dir = owned.path();
  const auto simple = dir / "polmap_truth_simple.csv";
  {
    std::ofstream f(simple);
    f << "time_s,v_mps,yaw_rate_rps\n0,10,0\n1,10,0\n2,10,0\n";
  }
  const MotionTruth a = read_truth_csv(simple);
  EXPECT_NEAR(a.at(2.0)->T_frame_vehicle.x_m, 20.0, 1e-9);

  const auto geo = dir / "polmap_truth_geo.csv";
  {
    std::ofstream f(geo);
    f << "time_s,lat_deg,lon_deg,yaw_enu_rad,v_mps,yaw_rate_rps\n"
         "0.0,50.0,8.0,0.0,10.0,0.0\n"
         "1.0,50.0,8.00013986,0.0,10.0,0.0\n";
  }
  const MotionTruth g = read_truth_csv(geo);
  EXPECT_FALSE(g.poses_integrated());
  // WGS84: one degree of longitude at 50°N is 71.696 km.
  EXPECT_NEAR(g.at(1.0)->T_frame_vehicle.x_m, 0.00013986 * 71696.0, 0.01);
  EXPECT_NEAR(g.at(1.0)->T_frame_vehicle.y_m, 0.0, 0.01);

  const auto bad = dir / "polmap_truth_bad.csv";
  {
    std::ofstream f(bad);
    f << "time_s,v_mps,yaw_rate_rps\n0,10,0\n1,x,0\n";
  }
  try {
    (void)read_truth_csv(bad);
    FAIL() << "no FormatError";
  } catch (const FormatError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("line 3"), std::string::npos) << msg;
    EXPECT_NE(msg.find("column 2"), std::string::npos) << msg;
    EXPECT_NE(msg.find("v_mps"), std::string::npos) << msg;
  }
  std::filesystem::remove(simple);
  std::filesystem::remove(geo);
  std::filesystem::remove(bad);
}

}  // namespace
}  // namespace polmap::eval
