// JSON conversions of schema value types: exact round trips, lenient about
// missing keys, strict about types with the full field path in the error.
#include "polmap/schema/json.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace polmap {
namespace {

using nlohmann::json;

template <typename T>
T round_trip(const T& v) {
  // Through text, as in files: doubles must survive exactly.
  return json::parse(json(v).dump()).get<T>();
}

RecordingHeader sample_header() {
  RecordingHeader h;
  h.drive_id = "drive_7";
  h.vehicle_id = "veh-1";
  h.world = "rural";
  h.origin = {48.39841234567891, 9.99155512345678, 478.123};
  h.sensors = default_front_mounts();
  h.sensors[1].spec.v_unambiguous_mps = 4.75;
  h.sensors[2].spec.polarization_basis = "HV";
  h.start_time_s = 1.7e9 + 0.123456789;
  h.has_cube = true;
  h.producer = "polmap simulate 0.1.0 seed=3";
  return h;
}

TEST(Json, GeoPointAndPoseRoundTripExactly) {
  const GeoPoint p{48.123456789012345, -122.98765432109876, -12.5};
  const GeoPoint q = round_trip(p);
  EXPECT_EQ(q.lat_deg, p.lat_deg);
  EXPECT_EQ(q.lon_deg, p.lon_deg);
  EXPECT_EQ(q.alt_m, p.alt_m);

  const Pose2 t{3.5, -0.75, -0.6981317007977318};
  const Pose2 u = round_trip(t);
  EXPECT_EQ(u.x_m, t.x_m);
  EXPECT_EQ(u.y_m, t.y_m);
  EXPECT_EQ(u.yaw_rad, t.yaw_rad);

  const GeoPose g{p, 1.25};
  const GeoPose h = round_trip(g);
  EXPECT_EQ(h.position.lat_deg, p.lat_deg);
  EXPECT_EQ(h.yaw_enu_rad, 1.25);
}

TEST(Json, HeaderRoundTripsAllFields) {
  const RecordingHeader h = sample_header();
  const RecordingHeader r = round_trip(h);
  EXPECT_EQ(r.format_version, h.format_version);
  EXPECT_EQ(r.drive_id, h.drive_id);
  EXPECT_EQ(r.vehicle_id, h.vehicle_id);
  EXPECT_EQ(r.world, h.world);
  EXPECT_EQ(r.origin.lat_deg, h.origin.lat_deg);
  EXPECT_EQ(r.origin.lon_deg, h.origin.lon_deg);
  EXPECT_EQ(r.origin.alt_m, h.origin.alt_m);
  EXPECT_EQ(r.start_time_s, h.start_time_s);
  EXPECT_EQ(r.has_cube, h.has_cube);
  EXPECT_EQ(r.producer, h.producer);
  ASSERT_EQ(r.sensors.size(), 3u);
  for (std::size_t i = 0; i < 3; ++i) {
    const SensorMount& a = h.sensors[i];
    const SensorMount& b = r.sensors[i];
    EXPECT_EQ(a.sensor_id, b.sensor_id);
    EXPECT_EQ(a.name, b.name);
    EXPECT_EQ(a.T_vehicle_sensor.x_m, b.T_vehicle_sensor.x_m);
    EXPECT_EQ(a.T_vehicle_sensor.y_m, b.T_vehicle_sensor.y_m);
    EXPECT_EQ(a.T_vehicle_sensor.yaw_rad, b.T_vehicle_sensor.yaw_rad);
    EXPECT_EQ(a.trigger_offset_s, b.trigger_offset_s);
    EXPECT_EQ(a.spec.center_frequency_hz, b.spec.center_frequency_hz);
    EXPECT_EQ(a.spec.bandwidth_hz, b.spec.bandwidth_hz);
    EXPECT_EQ(a.spec.range_resolution_m, b.spec.range_resolution_m);
    EXPECT_EQ(a.spec.max_range_m, b.spec.max_range_m);
    EXPECT_EQ(a.spec.fov_half_rad, b.spec.fov_half_rad);
    EXPECT_EQ(a.spec.azimuth_resolution_rad, b.spec.azimuth_resolution_rad);
    EXPECT_EQ(a.spec.virtual_elements, b.spec.virtual_elements);
    EXPECT_EQ(a.spec.frame_rate_hz, b.spec.frame_rate_hz);
    EXPECT_EQ(a.spec.v_unambiguous_mps, b.spec.v_unambiguous_mps);
    EXPECT_EQ(a.spec.velocity_resolution_mps, b.spec.velocity_resolution_mps);
    EXPECT_EQ(a.spec.polarization_basis, b.spec.polarization_basis);
    EXPECT_EQ(a.spec.mimo_scheme, b.spec.mimo_scheme);
  }
  // Serialization is deterministic (sorted keys): same value, same text.
  EXPECT_EQ(json(h).dump(), json(r).dump());
}

TEST(Json, TrajectorySampleAndDetectionRoundTrip) {
  TrajectorySample s;
  s.time_s = 12.34;
  s.lat_deg = 50.1;
  s.lon_deg = 8.6;
  s.yaw_enu_rad = -2.5;
  s.speed_mps = 13.9;
  s.yaw_rate_rps = 0.05;
  s.std_east_m = 0.086F;
  s.std_north_m = 0.014F;
  s.std_yaw_rad = 1e-3F;
  s.solution = GnssSolution::CarrierPhaseFloat;
  const json j = s;
  EXPECT_EQ(j.at("solution"), "carrier_phase_float");
  const auto t = round_trip(s);
  EXPECT_EQ(json(t), j);
  EXPECT_EQ(t.std_east_m, s.std_east_m);
  EXPECT_EQ(t.solution, s.solution);

  const Detection d{42.125F, -0.5F, -4.99F, 23.5F};
  const Detection e = round_trip(d);
  EXPECT_EQ(e.range_m, d.range_m);
  EXPECT_EQ(e.azimuth_rad, d.azimuth_rad);
  EXPECT_EQ(e.radial_velocity_mps, d.radial_velocity_mps);
  EXPECT_EQ(e.snr_db, d.snr_db);
}

TEST(Json, MissingKeysKeepDefaultsUnknownKeysIgnored) {
  const auto spec = json{{"bandwidth_hz", 1e9}, {"future_key", "x"}}.get<RadarSpec>();
  EXPECT_EQ(spec.bandwidth_hz, 1e9);
  EXPECT_EQ(spec.center_frequency_hz, RadarSpec{}.center_frequency_hz);
  EXPECT_EQ(spec.virtual_elements, 31);
  const auto h = json::object().get<RecordingHeader>();
  EXPECT_EQ(h.format_version, kRecordingFormatVersion);
  EXPECT_TRUE(h.sensors.empty());
}

TEST(Json, NonFiniteNumbersBecomeNullAndNaN) {
  Detection d;
  d.snr_db = std::numeric_limits<float>::quiet_NaN();
  const std::string text = json(d).dump();
  EXPECT_NE(text.find("\"snr_db\":null"), std::string::npos) << text;
  EXPECT_TRUE(std::isnan(round_trip(d).snr_db));
}

TEST(Json, WrongTypesNameTheFieldPath) {
  json j = sample_header();
  j["sensors"][1]["spec"]["bandwidth_hz"] = "2 GHz";
  try {
    (void)j.get<RecordingHeader>();
    FAIL();
  } catch (const JsonFieldError& e) {
    EXPECT_EQ(e.path(), "sensors[1].spec.bandwidth_hz");
    EXPECT_NE(std::string(e.what()).find("expected number, got string"), std::string::npos)
        << e.what();
  }

  json k = sample_header();
  k["origin"] = 5;
  try {
    (void)k.get<RecordingHeader>();
    FAIL();
  } catch (const JsonFieldError& e) {
    EXPECT_EQ(e.path(), "origin");
  }

  json s = sample_header();
  s["sensors"][0]["sensor_id"] = 300;  // does not fit std::uint8_t
  try {
    (void)s.get<RecordingHeader>();
    FAIL();
  } catch (const JsonFieldError& e) {
    EXPECT_EQ(e.path(), "sensors[0].sensor_id");
    EXPECT_NE(std::string(e.what()).find("out of range"), std::string::npos);
  }

  json t = TrajectorySample{};
  t["solution"] = "rtk";
  try {
    (void)t.get<TrajectorySample>();
    FAIL();
  } catch (const JsonFieldError& e) {
    EXPECT_EQ(e.path(), "solution");
    EXPECT_NE(std::string(e.what()).find("unknown GNSS solution 'rtk'"), std::string::npos);
  }

  EXPECT_THROW((void)json::array().get<Pose2>(), JsonFieldError);
  json v = sample_header();
  v["sensors"] = json::object();
  EXPECT_THROW((void)v.get<RecordingHeader>(), FormatError);  // JsonFieldError is a FormatError
}

}  // namespace
}  // namespace polmap
