// The per-stage CPU budget: ms of CPU per second of driving by stage, "other" the part of
// the call no stage claims, helper threads added to the total, real-time factor =
// drive time over all CPU; the text table carries the same numbers.
#include "polmap/eval/stage_budget.hpp"

#include <gtest/gtest.h>

#include <string>

#include "polmap/schema/errors.hpp"

namespace polmap::eval {
namespace {

loc::StageCpuTimes sample() {
  loc::StageCpuTimes s;
  s.egomotion_s = 1.0;
  s.gridmap_s = 2.0;
  s.points_s = 3.0;
  s.lines_s = 0.5;
  s.clustering_s = 0.25;
  s.tiles_s = 0.125;
  s.matching_s = 1.5;
  s.smoothing_s = 0.125;
  s.graph_s = 0.5;
  s.total_s = 10.0;  // 1.0 s outside the listed stages
  return s;
}

TEST(StageBudget, MillisecondsPerSecondOfDrivingAndRealTimeFactor) {
  const nlohmann::json j = stage_budget_json(sample(), 100.0, 2.5);
  EXPECT_DOUBLE_EQ(j["egomotion"].get<double>(), 10.0);
  EXPECT_DOUBLE_EQ(j["points"].get<double>(), 30.0);
  EXPECT_DOUBLE_EQ(j["tiles"].get<double>(), 1.25);
  EXPECT_DOUBLE_EQ(j["other"].get<double>(), 10.0);
  EXPECT_DOUBLE_EQ(j["helper_threads"].get<double>(), 25.0);
  EXPECT_DOUBLE_EQ(j["total"].get<double>(), 125.0);
  EXPECT_DOUBLE_EQ(j["realtime_factor"].get<double>(), 8.0);
}

TEST(StageBudget, SumsOfOutputsAddUp) {
  loc::StageCpuTimes sum;
  for (int i = 0; i < 4; ++i) sum += sample();
  EXPECT_DOUBLE_EQ(sum.points_s, 12.0);
  EXPECT_DOUBLE_EQ(sum.total_s, 40.0);
  const nlohmann::json j = stage_budget_json(sum, 400.0);
  EXPECT_DOUBLE_EQ(j["total"].get<double>(), 100.0);
  EXPECT_DOUBLE_EQ(j["realtime_factor"].get<double>(), 10.0);
}

TEST(StageBudget, TextTableShowsTheSameFigures) {
  const std::string t = format_stage_budget(sample(), 100.0, 2.5);
  EXPECT_NE(t.find("points             30.0"), std::string::npos) << t;
  EXPECT_NE(t.find("total             125.0"), std::string::npos) << t;
  EXPECT_NE(t.find("8.0x"), std::string::npos) << t;
}

TEST(StageBudget, NoDriveTimeIsAContractViolation) {
  EXPECT_THROW((void)stage_budget_json(sample(), 0.0), ContractViolation);
}

}  // namespace
}  // namespace polmap::eval
