// HD-map worlds: object counts against an independent count of the tagged
// line strings in the OSM files, routes along lanelets, error paths.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>

#include "polmap/schema/errors.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/world.hpp"
#include "test_dir.hpp"

namespace polmap::sim {
namespace {

const std::filesystem::path kMaps = std::filesystem::path(POLMAP_DATA_DIR) / "hdmaps";

/// Counts <way> elements by their type tag with plain text processing (no XML parser).
std::map<std::string, int> count_way_types(const std::filesystem::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  std::map<std::string, int> counts;
  std::size_t pos = 0;
  const std::regex type_re("<tag k=\"type\" v=\"([a-z_]+)\"");
  while ((pos = text.find("<way ", pos)) != std::string::npos) {
    const std::size_t end = text.find("</way>", pos);
    const std::string block = text.substr(pos, end - pos);
    std::smatch m;
    if (std::regex_search(block, m, type_re)) ++counts[m[1]];
    pos = end;
  }
  return counts;
}

std::map<std::string, int> count_osm_objects(const World& w) {
  std::map<std::string, int> c;
  for (const auto& o : w.objects) {
    if (o.source.rfind("osm way", 0) == 0) ++c[std::string(to_string(o.cls))];
  }
  return c;
}

TEST(HdMap, RoadShoulderObjectCountsMatchTheFile) {
  const auto file = kMaps / "autoware_road_shoulder.osm";
  const auto want = count_way_types(file);
  auto w = load_lanelet2_world(file);
  const auto got = count_osm_objects(*w);
  auto get = [](const std::map<std::string, int>& m, const std::string& k) {
    auto it = m.find(k);
    return it == m.end() ? 0 : it->second;
  };
  // curbstone (and the map's "curbestone" typo) -> curbstone; road_border, fence.
  EXPECT_EQ(get(got, "curbstone"), get(want, "curbstone") + get(want, "curbestone"));
  EXPECT_EQ(get(got, "road_border"), get(want, "road_border"));
  EXPECT_EQ(get(got, "fence_mesh"), get(want, "fence"));
  EXPECT_EQ(get(got, "wall"), get(want, "wall"));
  EXPECT_EQ(get(got, "guardrail_beam"), get(want, "guard_rail"));
  // Each traffic sign gives a plate and its pole; lights one object each.
  EXPECT_EQ(get(got, "sign_plate"), get(want, "traffic_sign"));
  EXPECT_EQ(get(got, "traffic_light"), get(want, "traffic_light"));
  EXPECT_GT(get(want, "curbstone"), 10);
  EXPECT_GT(get(want, "fence"), 0);
  // Implied objects: fence posts and lamps exist.
  int posts = 0, lamps = 0;
  for (const auto& o : w->objects) {
    posts += o.cls == ObjectClass::FencePost;
    lamps += o.cls == ObjectClass::LampPole;
  }
  EXPECT_GT(posts, 10);
  EXPECT_GT(lamps, 5);
  EXPECT_GT(w->route.length_m(), 100.0);
  // The world origin is inside the map (35.22 N 138.80 E).
  EXPECT_NEAR(w->origin().lat_deg, 35.22, 0.05);
  EXPECT_NEAR(w->origin().lon_deg, 138.80, 0.05);
}

TEST(HdMap, IntersectionHasLightsAndADrivableRoute) {
  const auto file = kMaps / "autoware_intersection.osm";
  const auto want = count_way_types(file);
  auto w = load_lanelet2_world(file);
  const auto got = count_osm_objects(*w);
  EXPECT_EQ(got.at("traffic_light"), want.at("traffic_light"));
  EXPECT_EQ(got.at("sign_plate"), want.at("traffic_sign"));
  EXPECT_EQ(got.at("curbstone"), want.at("curbstone"));
  EXPECT_GT(w->route.length_m(), 50.0);
  // The route follows lanelet centrelines: continuous, no jumps.
  const auto& pts = w->route.points();
  for (std::size_t i = 1; i < pts.size(); ++i) {
    ASSERT_LT(std::hypot(pts[i].x_m - pts[i - 1].x_m, pts[i].y_m - pts[i - 1].y_m), 0.2);
  }
  // A drive through it runs.
  SimConfig cfg;
  cfg.duration_s = 2.0;
  DriveSimulator sim(w, cfg, 0);
  int frames = 0;
  while (auto r = sim.next()) frames += std::holds_alternative<SensorFrame>(*r);
  EXPECT_EQ(frames, 61);  // t = 0 ... 2.0 s inclusive (sensor 0 triggers at 2.0 s)
}

TEST(HdMap, ErrorsNameTheFile) {
  try {
    load_world("/nonexistent/map.osm", 100, 1);
    FAIL();
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/map.osm"), std::string::npos);
  }
  const util::ScopedTempDir dir(polmap::test::unique_test_dir("sim-hdmap"));
  const auto bad = dir.path() / "bad_map.osm";
  {
    std::ofstream o(bad);
    o << "<osm><node id='1' lat='1' lon='2'></osm";
  }
  try {
    load_world(bad.string(), 100, 1);
    FAIL();
  } catch (const FormatError& e) {
    EXPECT_NE(std::string(e.what()).find(bad.string()), std::string::npos);
  }
  {
    std::ofstream o(bad);
    o << "<osm><node id='1' lat='1' lon='2'/></osm>";
  }
  EXPECT_THROW(load_world(bad.string(), 100, 1), FormatError);  // no lanelets
  std::filesystem::remove(bad);
  EXPECT_THROW(load_world("suburban", 100, 1), ValidationError);
}

}  // namespace
}  // namespace polmap::sim

namespace polmap::sim {
namespace {

int count_substr(const std::string& text, const std::string& what) {
  int n = 0;
  for (std::size_t p = text.find(what); p != std::string::npos; p = text.find(what, p + 1)) ++n;
  return n;
}

TEST(HdMap, OpenDriveStraightRoadWithPolesAndSigns) {
  const auto file = kMaps / "esmini_straight_500m_signs.xodr";
  std::ifstream in(file);
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  const int poles = count_substr(text, "<object type=\"pole\"");
  const int signals = count_substr(text, "<signal ");
  auto w = load_opendrive_world(file);
  int got_poles = 0, got_plates = 0;
  for (const auto& o : w->objects) {
    if (o.source.find("xodr") == std::string::npos) continue;
    got_poles += o.cls == ObjectClass::Pole;
    got_plates += o.cls == ObjectClass::SignPlate;
  }
  EXPECT_EQ(got_poles, poles);
  EXPECT_EQ(got_plates, signals);
  EXPECT_GT(poles, 10);
  EXPECT_NEAR(w->route.length_m(), 500.0, 1.0);
  // Route on the right driving lane centre (t = -3.07/2), heading +x.
  const PathPoint p = w->route.at(250.0);
  EXPECT_NEAR(p.y_m, -1.535, 0.02);
  EXPECT_NEAR(p.yaw_rad, 0.0, 1e-3);
  // Pole id 8 at s = 80, t = -3.57.
  bool found = false;
  for (const auto& o : w->objects) {
    if (o.cls == ObjectClass::Pole &&
        (o.geometry_m[0] - Eigen::Vector2d(80.0, -3.57)).norm() < 1e-6)
      found = true;
  }
  EXPECT_TRUE(found);
}

}  // namespace
}  // namespace polmap::sim
