// RunRecorder: decimation to min_interval_s with every status change kept, samples without
// a pose skipped, the covariance kept inside the PSD cone, yaw in (-180, 180], and a report
// the one parser accepts.
#include "polmap/localization_client/run_recorder.hpp"

#include <gtest/gtest.h>

#include <numbers>

namespace polmap::loc {
namespace {

LocalizationOutput output(double t_s, LocalizationOutput::Status status, double yaw_rad = 0.3) {
  LocalizationOutput o;
  o.time_s = t_s;
  o.status = status;
  o.has_pose = true;
  o.pose.position = {48.4 + 1e-6 * t_s, 9.99, 0.0};
  o.pose.yaw_enu_rad = yaw_rad;
  o.covariance = Eigen::Matrix3d::Identity() * 0.01;
  o.map_version = 3;
  return o;
}

TEST(RunRecorder, KeepsOneSamplePerIntervalAndEveryStatusChange) {
  RunRecorder rec({.min_interval_s = 0.2, .max_samples = 1000});
  using S = LocalizationOutput::Status;
  for (int i = 0; i < 100; ++i) {  // 20 Hz for 5 s
    const double t = 0.05 * i;
    S s = t < 1.0 ? S::Initializing : S::Tracking;
    if (i == 61) s = S::Degraded;  // one frame degraded
    rec.add(output(t, s));
    rec.add(output(t, s));  // a second sensor at the same instant: not a new sample
  }
  LocalizationOutput none = output(10.0, S::Tracking);
  none.has_pose = false;
  rec.add(none);
  const auto& s = rec.samples();
  ASSERT_GT(s.size(), 20u);
  ASSERT_LT(s.size(), 35u);
  for (std::size_t i = 1; i < s.size(); ++i) {
    ASSERT_GT(s[i].t_s, s[i - 1].t_s);
    if (s[i].status == s[i - 1].status) {
      EXPECT_GE(s[i].t_s - s[i - 1].t_s, 0.2 - 1e-9);
    }
  }
  // The status changes are all there, at their exact times.
  auto at = [&](double t) {
    for (const auto& x : s) {
      if (std::abs(x.t_s - t) < 1e-9) return x.status;
    }
    return RunStatus::Initializing;
  };
  EXPECT_EQ(at(1.0), RunStatus::Tracking);
  EXPECT_EQ(at(0.05 * 61), RunStatus::Degraded);
  EXPECT_EQ(at(0.05 * 62), RunStatus::Tracking);
  EXPECT_EQ(s.back().t_s < 10.0, true);

  const LocalizationRun run = rec.run("drive_1", "full", 11.0);
  EXPECT_EQ(run.map_version, 3);
  const auto parsed = parse_localization_run(encode_localization_run(run));
  ASSERT_TRUE(parsed) << parsed.error().what();
  EXPECT_EQ(parsed->samples.size(), s.size());
}

TEST(RunRecorder, YawAndCovarianceFitTheReportFormat) {
  RunRecorder rec;
  LocalizationOutput o = output(1.0, LocalizationOutput::Status::Tracking, 3.0 * std::numbers::pi);
  o.covariance << 0.04, 0.05, 0.0, 0.05, 0.01, 0.0, 0.0, 0.0,
      -1e-12;  // rounding made it indefinite
  rec.add(o);
  rec.add(output(2.0, LocalizationOutput::Status::Tracking, -std::numbers::pi));
  const auto& s = rec.samples();
  ASSERT_EQ(s.size(), 2u);
  EXPECT_NEAR(s[0].yaw_enu_deg, 180.0, 1e-9);
  EXPECT_NEAR(s[1].yaw_enu_deg, 180.0, 1e-9);  // -180 is written as 180
  EXPECT_LE(s[0].cov_xy_m2 * s[0].cov_xy_m2, s[0].cov_xx_m2 * s[0].cov_yy_m2 + 1e-15);
  EXPECT_GE(s[0].cov_yaw_rad2, 0.0);
  const auto parsed = parse_localization_run(encode_localization_run(rec.run("x", "full")));
  ASSERT_TRUE(parsed) << parsed.error().what();
}

TEST(RunRecorder, StopsAtItsCapAndSaysSo) {
  RunRecorder rec({.min_interval_s = 0.0, .max_samples = 5});
  for (int i = 0; i < 10; ++i) rec.add(output(i, LocalizationOutput::Status::Tracking));
  EXPECT_EQ(rec.samples().size(), 5u);
  EXPECT_TRUE(rec.truncated());
}

}  // namespace
}  // namespace polmap::loc
