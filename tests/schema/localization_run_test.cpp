// The localization run report (schema/localization_run.md): canonical round trip, and every
// refusal naming its field with the right HTTP status.
#include "polmap/schema/localization_run.hpp"

#include <gtest/gtest.h>

#include <functional>
#include <nlohmann/json.hpp>

namespace polmap {
namespace {

using nlohmann::json;

LocalizationRun sample_run(std::size_t n = 20) {
  LocalizationRun r;
  r.label = "drive_3 (Ulm)";
  r.map_version = 4;
  r.pol = "ll-lr";
  r.reference = RunReference::SimulatorTruth;
  r.realtime_factor = 12.5;
  for (std::size_t i = 0; i < n; ++i) {
    LocalizationRunSample s;
    s.t_s = 100.0 + 0.2 * static_cast<double>(i) + 1e-7;
    s.lat_deg = 48.4 + 1e-5 * static_cast<double>(i);
    s.lon_deg = 9.99 + 3e-6 * static_cast<double>(i);
    s.yaw_enu_deg = i == 3 ? 180.0 : 12.345678901234;
    s.status =
        i < 2 ? RunStatus::Initializing : (i == 7 ? RunStatus::Degraded : RunStatus::Tracking);
    s.cov_xx_m2 = 0.01 + 1e-4 * static_cast<double>(i);
    s.cov_yy_m2 = 0.02;
    s.cov_xy_m2 = -0.005;
    s.cov_yaw_rad2 = 1e-5;
    if (i >= 2) s.error = RunSampleError{0.031 * static_cast<double>(i), -0.017, 0.2};
    r.samples.push_back(s);
  }
  return r;
}

void expect_same(const LocalizationRun& a, const LocalizationRun& b) {
  EXPECT_EQ(a.label, b.label);
  EXPECT_EQ(a.map_version, b.map_version);
  EXPECT_EQ(a.pol, b.pol);
  EXPECT_EQ(a.reference, b.reference);
  EXPECT_EQ(a.realtime_factor, b.realtime_factor);
  ASSERT_EQ(a.samples.size(), b.samples.size());
  for (std::size_t i = 0; i < a.samples.size(); ++i) {
    const auto &x = a.samples[i], &y = b.samples[i];
    EXPECT_EQ(x.t_s, y.t_s);  // exact: the text keeps every double
    EXPECT_EQ(x.lat_deg, y.lat_deg);
    EXPECT_EQ(x.lon_deg, y.lon_deg);
    EXPECT_EQ(x.yaw_enu_deg, y.yaw_enu_deg);
    EXPECT_EQ(x.status, y.status);
    EXPECT_EQ(x.cov_xx_m2, y.cov_xx_m2);
    EXPECT_EQ(x.cov_xy_m2, y.cov_xy_m2);
    EXPECT_EQ(x.cov_yy_m2, y.cov_yy_m2);
    EXPECT_EQ(x.cov_yaw_rad2, y.cov_yaw_rad2);
    ASSERT_EQ(x.error.has_value(), y.error.has_value());
    if (x.error) {
      EXPECT_EQ(x.error->long_m, y.error->long_m);
      EXPECT_EQ(x.error->lat_m, y.error->lat_m);
      EXPECT_EQ(x.error->rot_deg, y.error->rot_deg);
    }
  }
}

TEST(LocalizationRun, EncodesToTheCanonicalCopyThatParsesBackExactly) {
  const LocalizationRun r = sample_run();
  const std::string bytes = encode_localization_run(r);
  const auto parsed = parse_localization_run(bytes);
  ASSERT_TRUE(parsed) << parsed.error().what();
  expect_same(r, *parsed);
  EXPECT_EQ(encode_localization_run(*parsed), bytes);  // fixed point
}

TEST(LocalizationRun, StatusAndReferenceNamesRoundTrip) {
  for (int i = 0; i < kRunStatusCount; ++i) {
    const auto s = static_cast<RunStatus>(i);
    EXPECT_EQ(parse_run_status(to_string(s)), s);
  }
  EXPECT_FALSE(parse_run_status("Tracking"));
  for (const auto r : {RunReference::None, RunReference::SimulatorTruth, RunReference::GnssIns}) {
    EXPECT_EQ(parse_run_reference(to_string(r)), r);
  }
}

/// The sample run's JSON with `edit` applied, parsed: the refusal expected.
LocalizationRunError refusal(const std::function<void(json&)>& edit,
                             const LocalizationRunLimits& limits = {}) {
  json j = json::parse(encode_localization_run(sample_run()));
  edit(j);
  const auto r = parse_localization_run(j.dump(), limits);
  EXPECT_FALSE(r.has_value());
  return r ? LocalizationRunError{} : r.error();
}

TEST(LocalizationRun, RefusesBadFieldsNamingThem) {
  struct Case {
    std::function<void(json&)> edit;
    std::string field;
  } cases[] = {
      {[](json& j) { j["format"] = "gpx"; }, "format"},
      {[](json& j) { j["version"] = 2; }, "version"},
      {[](json& j) { j["colour"] = "red"; }, "colour"},
      {[](json& j) { j[""] = 0.001; }, "\"\""},  // found by the fuzzer: a field is never unnamed
      {[](json& j) { j["samples"][2]["a\tb"] = 1; }, "samples[2].a?b"},
      {[](json& j) { j[std::string(300, 'k')] = 1; }, std::string(64, 'k') + "..."},
      {[](json& j) { j["label"] = std::string(129, 'x'); }, "label"},
      {[](json& j) { j["label"] = "a\nb"; }, "label"},
      {[](json& j) { j["map_version"] = -1; }, "map_version"},
      {[](json& j) { j["map_version"] = 1.5; }, "map_version"},
      {[](json& j) { j["pol"] = "xx"; }, "pol"},
      {[](json& j) { j["reference"] = "none"; }, "reference"},  // errors need a reference
      {[](json& j) { j["samples"] = json::array(); }, "samples"},
      {[](json& j) { j["samples"][4]["lat_deg"] = 86.0; }, "samples[4].lat_deg"},
      {[](json& j) { j["samples"][4]["lon_deg"] = "east"; }, "samples[4].lon_deg"},
      {[](json& j) { j["samples"][5]["yaw_enu_deg"] = -180.0; }, "samples[5].yaw_enu_deg"},
      {[](json& j) { j["samples"][6]["status"] = "happy"; }, "samples[6].status"},
      {[](json& j) { j["samples"][6].erase("t_s"); }, "samples[6].t_s"},
      {[](json& j) { j["samples"][6]["t_s"] = j["samples"][5]["t_s"]; }, "samples[6].t_s"},
      {[](json& j) { j["samples"][8]["cov_xx_m2"] = -0.1; }, "samples[8].cov_xx_m2"},
      {[](json& j) { j["samples"][8]["cov_xy_m2"] = 1.0; }, "samples[8].cov_xy_m2"},
      {[](json& j) { j["samples"][9].erase("err_lat_m"); }, "samples[9].err_long_m"},
      {[](json& j) { j["samples"][9]["err_rot_deg"] = 200.0; }, "samples[9].err_rot_deg"},
      {[](json& j) { j["samples"][9]["speed"] = 3; }, "samples[9].speed"},
      {[](json& j) { j["samples"][10]["lon_deg"] = 13.0; }, "samples[10]"},  // span
      {[](json& j) { j["samples"][3] = 7; }, "samples[3]"},
  };
  for (const auto& c : cases) {
    const LocalizationRunError e = refusal(c.edit);
    EXPECT_EQ(e.field, c.field) << e.what();
    EXPECT_EQ(e.http_status, 422) << e.what();
    EXPECT_NE(e.what().find(c.field), std::string::npos);
  }
}

TEST(LocalizationRun, RefusesWhatIsNotJsonOrTooLargeBeforeWork) {
  auto e = parse_localization_run("{\"format\": ");
  ASSERT_FALSE(e);
  EXPECT_EQ(e.error().http_status, 400);
  EXPECT_EQ(e.error().field, "body");

  e = parse_localization_run("[1, 2]");
  ASSERT_FALSE(e);
  EXPECT_EQ(e.error().http_status, 400);

  e = parse_localization_run(R"({"samples": [[[[[[1]]]]]]})");
  ASSERT_FALSE(e);
  EXPECT_EQ(e.error().http_status, 400);
  EXPECT_NE(e.error().message.find("nested"), std::string::npos);

  // 1e400 is not a double.
  e = parse_localization_run(R"({"format": "polmap-localization-run", "version": 1e400})");
  ASSERT_FALSE(e);
  EXPECT_EQ(e.error().http_status, 400);

  const std::string bytes = encode_localization_run(sample_run());
  LocalizationRunLimits small;
  small.max_bytes = bytes.size() - 1;
  e = parse_localization_run(bytes, small);
  ASSERT_FALSE(e);
  EXPECT_EQ(e.error().http_status, 413);

  LocalizationRunLimits few;
  few.max_samples = 5;
  e = parse_localization_run(bytes, few);
  ASSERT_FALSE(e);
  EXPECT_EQ(e.error().http_status, 413);
  EXPECT_EQ(e.error().field, "samples");
}

TEST(LocalizationRun, AcceptsARunWithoutErrorsOrOptionalFields) {
  LocalizationRun r = sample_run(3);
  for (auto& s : r.samples) s.error.reset();
  r.reference = RunReference::None;
  r.realtime_factor.reset();
  r.label.clear();
  const auto parsed = parse_localization_run(encode_localization_run(r));
  ASSERT_TRUE(parsed) << parsed.error().what();
  expect_same(r, *parsed);
}

}  // namespace
}  // namespace polmap
