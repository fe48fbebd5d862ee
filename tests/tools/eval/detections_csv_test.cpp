// Detections CSV and sensor mounts JSON: round trips and error messages.
#include "polmap/eval/detections_csv.hpp"

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <random>

#include "polmap/schema/errors.hpp"
#include "test_dir.hpp"

namespace polmap::eval {
namespace {

std::vector<SensorFrame> sample_frames() {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1.0F, 1.0F);
  std::vector<SensorFrame> frames;
  for (int cycle = 0; cycle < 3; ++cycle) {
    for (int s = 0; s < 3; ++s) {
      SensorFrame f;
      f.sensor_id = static_cast<std::uint8_t>(s);
      f.time_s = 100.0 + 0.1 * cycle + 0.033 * s;
      f.cycle_index = static_cast<std::uint32_t>(cycle);
      for (int k = 0; k < 5 + s; ++k) {
        f.detections.push_back(
            {40.0F + 30.0F * u(rng), 1.0F * u(rng), 5.0F * u(rng), 20.0F + 10.0F * u(rng)});
      }
      frames.push_back(f);
    }
  }
  return frames;
}

/// Expects `fn` to throw FormatError whose message contains every fragment.
template <typename Fn>
void expect_format_error(Fn fn, std::initializer_list<std::string> fragments) {
  try {
    fn();
    FAIL() << "no FormatError";
  } catch (const FormatError& e) {
    const std::string msg = e.what();
    for (const auto& frag : fragments) {
      EXPECT_NE(msg.find(frag), std::string::npos) << "'" << frag << "' not in: " << msg;
    }
  }
}

TEST(DetectionsCsv, RoundTripIsExact) {
  const auto frames = sample_frames();
  const std::string text = format_detections_csv(frames);
  const auto back = parse_detections_csv(text, "x.csv");
  ASSERT_EQ(back.size(), frames.size());
  for (std::size_t i = 0; i < frames.size(); ++i) {
    EXPECT_EQ(back[i].sensor_id, frames[i].sensor_id);
    EXPECT_EQ(back[i].time_s, frames[i].time_s);
    EXPECT_EQ(back[i].cycle_index, frames[i].cycle_index);
    ASSERT_EQ(back[i].detections.size(), frames[i].detections.size());
    for (std::size_t k = 0; k < frames[i].detections.size(); ++k) {
      const auto& a = back[i].detections[k];
      const auto& b = frames[i].detections[k];
      EXPECT_EQ(a.range_m, b.range_m);
      EXPECT_EQ(a.azimuth_rad, b.azimuth_rad);
      EXPECT_EQ(a.radial_velocity_mps, b.radial_velocity_mps);
      EXPECT_EQ(a.snr_db, b.snr_db);
    }
  }
  // Through a file, streaming.
  const util::ScopedTempDir owned(polmap::test::unique_test_dir("detections-csv"));
  const auto path = owned.path() / "detections.csv";
  write_detections_csv(path, frames);
  DetectionsCsvReader reader(path);
  int n = 0;
  while (auto f = reader.next()) {
    EXPECT_EQ(f->detections.size(), frames[n].detections.size());
    ++n;
  }
  EXPECT_EQ(n, static_cast<int>(frames.size()));
  std::filesystem::remove(path);
}

TEST(DetectionsCsv, ColumnOrderCommentsExtraColumnsAndCrlf) {
  const std::string text =
      "# exported by some radar\r\n"
      "sensor_id, timestamp_s, elevation_rad, azimuth_rad, range_m, radial_velocity_mps, "
      "amplitude_db\r\n"
      "2,0.5,0.01,0.1,10,-3.5,12\r\n"
      "2,0.5,0.02,-0.2,20,-4.0,13\r\n"
      "\r\n"
      "0,0.6,0.0,0.0,5,1.0,9\r\n";
  const auto frames = parse_detections_csv(text);
  ASSERT_EQ(frames.size(), 2u);
  EXPECT_EQ(frames[0].sensor_id, 2);
  EXPECT_DOUBLE_EQ(frames[0].time_s, 0.5);
  ASSERT_EQ(frames[0].detections.size(), 2u);
  EXPECT_FLOAT_EQ(frames[0].detections[1].azimuth_rad, -0.2F);
  EXPECT_FLOAT_EQ(frames[0].detections[1].range_m, 20.0F);
  EXPECT_FLOAT_EQ(frames[0].detections[1].radial_velocity_mps, -4.0F);
  EXPECT_FLOAT_EQ(frames[0].detections[1].snr_db, 13.0F);
  EXPECT_EQ(frames[1].sensor_id, 0);
  EXPECT_EQ(frames[1].cycle_index, 0u);
}

TEST(DetectionsCsv, BadRowsNameLineAndColumn) {
  const std::string header =
      "timestamp_s,sensor_id,range_m,azimuth_rad,radial_velocity_mps,amplitude_db\n";
  expect_format_error(
      [&] { parse_detections_csv(header + "0.1,0,10,0.1,-2,10\n0.1,0,10,0.1,abc,10\n", "d.csv"); },
      {"d.csv", "line 3", "column 5", "radial_velocity_mps", "abc"});
  expect_format_error([&] { parse_detections_csv(header + "0.1,300,10,0.1,-2,10\n", "d.csv"); },
                      {"line 2", "column 2", "sensor_id"});
  expect_format_error([&] { parse_detections_csv(header + "0.1,0,10,0.1\n", "d.csv"); },
                      {"line 2", "4 fields"});
  expect_format_error([&] { parse_detections_csv(header + "0.1,0,-1,0.1,1,1\n", "d.csv"); },
                      {"line 2", "column 3", "range_m", "negative"});
  expect_format_error([&] { parse_detections_csv(header + "0.1,0,1,45,1,1\n", "d.csv"); },
                      {"line 2", "column 4", "azimuth_rad", "radians"});
  expect_format_error(
      [&] { parse_detections_csv(header + "0.2,0,1,0,1,1\n0.1,1,1,0,1,1\n", "d.csv"); },
      {"line 3", "column 1", "time order"});
  expect_format_error(
      [&] {
        parse_detections_csv(header + "0.2,0,1,0,1,1\n0.2,1,1,0,1,1\n0.2,0,1,0,1,1\n", "d.csv");
      },
      {"line 4", "consecutive"});
  expect_format_error(
      [&] { parse_detections_csv("timestamp_s,sensor_id,range_m\n0,0,1\n", "d.csv"); },
      {"d.csv", "line 1", "azimuth_rad"});
  expect_format_error([&] { parse_detections_csv("", "e.csv"); }, {"e.csv", "empty"});
  expect_format_error([&] { parse_detections_csv(header + "nan,0,1,0,1,1\n", "d.csv"); },
                      {"line 2", "column 1", "not finite"});
  EXPECT_THROW(read_detections_csv("/nonexistent/polmap.csv"), IoError);
}

TEST(SensorMountsJson, RoundTrip) {
  auto mounts = default_front_mounts();
  mounts[1].spec.v_unambiguous_mps = 7.5;
  const auto back = parse_sensor_mounts_json(format_sensor_mounts_json(mounts), "m.json");
  ASSERT_EQ(back.size(), mounts.size());
  for (std::size_t i = 0; i < mounts.size(); ++i) {
    EXPECT_EQ(back[i].sensor_id, mounts[i].sensor_id);
    EXPECT_EQ(back[i].name, mounts[i].name);
    EXPECT_EQ(back[i].T_vehicle_sensor.x_m, mounts[i].T_vehicle_sensor.x_m);
    EXPECT_EQ(back[i].T_vehicle_sensor.y_m, mounts[i].T_vehicle_sensor.y_m);
    EXPECT_EQ(back[i].T_vehicle_sensor.yaw_rad, mounts[i].T_vehicle_sensor.yaw_rad);
    EXPECT_EQ(back[i].trigger_offset_s, mounts[i].trigger_offset_s);
    EXPECT_EQ(back[i].spec.v_unambiguous_mps, mounts[i].spec.v_unambiguous_mps);
  }
  // The minimal documented form.
  const auto minimal = parse_sensor_mounts_json(
      R"([{"sensor_id":0,"x_m":3.7,"y_m":0,"yaw_rad":0,"v_unambiguous_mps":5.0}])");
  ASSERT_EQ(minimal.size(), 1u);
  EXPECT_EQ(minimal[0].name, "sensor_0");
  EXPECT_EQ(minimal[0].trigger_offset_s, 0.0);
}

TEST(SensorMountsJson, ErrorsNameLocation) {
  expect_format_error(
      [] { parse_sensor_mounts_json("[\n  {\"sensor_id\": 0,\n   \"x_m\": 3.7,,\n}]", "m.json"); },
      {"m.json", "line 3", "column", "syntax"});
  expect_format_error(
      [] {
        parse_sensor_mounts_json(
            R"([{"sensor_id":0,"x_m":3.7,"y_m":0,"yaw_rad":0,"v_unambiguous_mps":5},
                {"sensor_id":1,"x_m":3.5,"yaw_rad":0.7,"v_unambiguous_mps":5}])",
            "m.json");
      },
      {"m.json", "[1].y_m", "missing"});
  expect_format_error(
      [] {
        parse_sensor_mounts_json(
            R"([{"sensor_id":0,"x_m":"3.7","y_m":0,"yaw_rad":0,"v_unambiguous_mps":5}])", "m.json");
      },
      {"[0].x_m", "expected a number"});
  expect_format_error(
      [] {
        parse_sensor_mounts_json(
            R"([{"sensor_id":0,"x_m":3.7,"y_m":0,"yaw_deg":0,"v_unambiguous_mps":5}])", "m.json");
      },
      {"[0].yaw_deg", "unknown field"});
  expect_format_error(
      [] {
        parse_sensor_mounts_json(
            R"([{"sensor_id":0,"x_m":3.7,"y_m":0,"yaw_rad":0,"v_unambiguous_mps":5},
                {"sensor_id":0,"x_m":3.7,"y_m":0,"yaw_rad":0,"v_unambiguous_mps":5}])",
            "m.json");
      },
      {"[1].sensor_id", "duplicate"});
  expect_format_error([] { parse_sensor_mounts_json(R"({"sensor_id":0})", "m.json"); },
                      {"m.json", "array"});
}

}  // namespace
}  // namespace polmap::eval
