// A map that follows the world, end to end on loopback: six drives of three vehicles see
// a scene; the world changes (a pole removed, one moved by 0.6 m, one added, a wall
// taken down); six later drives see the new state and are uploaded in an order unlike
// their drive times. The map after the second set holds the new state, and
// GET /v1/maps/{v}/diff?from=U names the changes with the builder's reasons (JSON and
// GeoJSON).
#include <nlohmann/json.hpp>

#include "mapping_service/server_fixture.hpp"

namespace polmap::mapping::testing {
namespace {

using nlohmann::json;

struct Scene {
  std::vector<Eigen::Vector2d> points;
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> walls;
};

Scene before() {
  Scene s;
  for (int i = 0; i < 8; ++i) s.points.emplace_back(-14.0 + 4.0 * i, i % 2 ? 6.0 : -6.0);
  s.walls = {{{-15.0, 9.0}, {-3.0, 9.0}}, {{3.0, -9.0}, {15.0, -9.0}}};
  return s;
}

/// points[5] removed, points[6] moved 0.6 m along x, a new pole at (0, 4), wall 1 gone.
Scene after() {
  Scene s = before();
  s.points[6].x() += 0.6;
  s.points.erase(s.points.begin() + 5);
  s.points.emplace_back(0.0, 4.0);
  s.walls.pop_back();
  return s;
}

/// A landmarks-only package of one pass along the x axis seeing `scene` (±2 cm noise).
std::string package(const std::string& id, const std::string& vehicle, double start_time_s,
                    const Scene& scene, unsigned seed) {
  SyntheticDrive d = pass_along_x(id, vehicle, start_time_s, seed);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> j(-0.02, 0.02);
  for (const auto& p : scene.points) {
    PointCandidate c;
    c.position_m = p + Eigen::Vector2d(j(rng), j(rng));
    c.strength = 12.0;
    c.scattering = ScatteringClass::Odd;
    d.pkg.points.push_back(c);
  }
  for (const auto& [a, b] : scene.walls) {
    LineCandidate l;
    l.start_m = a + Eigen::Vector2d(j(rng), j(rng));
    l.end_m = b + Eigen::Vector2d(j(rng), j(rng));
    l.strength = 1.0;
    d.pkg.lines.push_back(l);
  }
  const util::ScopedTempDir base(polmap::test::unique_test_dir("diff-pkgs"));
  PackageWriteOptions wo;
  wo.format_version = 2;
  wo.landmarks_only = true;
  write_drive_package(d.pkg, d.raster, base.path() / id, wo);
  return pack_drive_package(base.path() / id);
}

class MapDiffTest : public ServerFixture {
 protected:
  void upload(const std::string& tar) {
    auto r = client().Post("/v1/drives", auth(), tar, "application/x-tar");
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 201) << r->body;
  }
  std::int64_t build() {
    auto r = client().Post("/v1/maps", auth(), "{}", "application/json");
    EXPECT_EQ(r->status, 202) << r->body;
    server_->wait_for_builds();
    return json::parse(r->body)["version"].get<std::int64_t>();
  }
  json get_json(const std::string& path, int expect_status = 200) {
    auto r = client().Get(path);
    EXPECT_TRUE(r);
    EXPECT_EQ(r->status, expect_status) << path << ": " << r->body;
    return json::parse(r->body);
  }
  /// Drive-frame position of a change's (first) geometry vertex.
  static Eigen::Vector2d at(const json& geometry) {
    return scene_frame().to_local(
        GeoPoint{geometry[0]["lat_deg"].get<double>(), geometry[0]["lon_deg"].get<double>(), 0.0});
  }
};

TEST_F(MapDiffTest, TheMapFollowsAWorldChangeAndTheDiffNamesIt) {
  const char* vehicles[] = {"veh_a", "veh_b", "veh_c"};
  for (int k = 0; k < 6; ++k) {
    upload(package("before_" + std::to_string(k), vehicles[k % 3], 1000.0 + 100.0 * k, before(),
                   100 + k));
  }
  const std::int64_t v1 = build();
  // The later drives arrive in reverse order of their drive times.
  for (int k = 5; k >= 0; --k) {
    upload(package("after_" + std::to_string(k), vehicles[k % 3], 9000.0 + 100.0 * k, after(),
                   200 + k));
  }
  const std::int64_t v2 = build();
  ASSERT_GT(v2, v1);

  const json stats = get_json("/v1/maps/" + std::to_string(v2))["statistics"];
  EXPECT_EQ(stats["point_landmarks"], 8);  // 8 before: one removed, one added, one moved
  EXPECT_EQ(stats["line_landmarks"], 1);
  EXPECT_EQ(stats["changes"]["against_version"], v1);

  const json d = get_json("/v1/maps/" + std::to_string(v2) + "/diff?from=" + std::to_string(v1));
  EXPECT_EQ(d["from"], v1);
  EXPECT_EQ(d["to"], v2);
  EXPECT_EQ(d["counts"]["added"], 1);
  EXPECT_EQ(d["counts"]["moved"], 1);
  EXPECT_EQ(d["counts"]["retired"], 2);  // the pole and the wall
  EXPECT_EQ(d["counts"]["unchanged"].get<int>() + d["counts"]["refined"].get<int>(), 7 - 1 + 1);
  const Scene b = before(), a = after();
  int seen = 0;
  for (const json& c : d["changes"]) {
    const std::string change = c["change"];
    const Eigen::Vector2d p = at(c["geometry"]);
    EXPECT_EQ(c["reason_version"], v2) << c.dump();
    if (change == "added") {
      EXPECT_EQ(c["kind"], "point");
      EXPECT_LT((p - a.points.back()).norm(), 0.05) << c.dump();
      EXPECT_EQ(c["reason"]["rule"], "support");
      EXPECT_EQ(c["reason"]["support_drives"], 6);
      EXPECT_EQ(c["reason"]["drives_in_view"], 12);
      ++seen;
    } else if (change == "moved") {
      EXPECT_LT((p - a.points[5]).norm(), 0.05) << c.dump();  // after() erased index 5
      EXPECT_LT((at(c["previous_geometry"]) - b.points[6]).norm(), 0.05);
      EXPECT_NEAR(c["distance_m"].get<double>(), 0.6, 0.05);
      EXPECT_NE(c["previous_key"], c["key"]);
      ++seen;
    } else if (change == "retired") {
      EXPECT_EQ(c["reason"]["rule"], "missed") << c.dump();
      EXPECT_EQ(c["reason"]["miss_streak"], 6);
      EXPECT_EQ(c["reason"]["miss_streak_vehicles"], 3);
      EXPECT_EQ(c["reason"]["last_support_day"], "1970-01-01");  // the day only
      EXPECT_FALSE(c["reason"].contains("last_support_time_s"));
      if (c["kind"] == "point") {
        EXPECT_LT((p - b.points[5]).norm(), 0.05) << c.dump();
      } else {
        EXPECT_LT((p - b.walls[1].first).norm(), 0.1) << c.dump();
      }
      ++seen;
    }
  }
  EXPECT_EQ(seen, 4);

  // GeoJSON: one feature per change, lon/lat order, the same properties.
  auto r = client().Get("/v1/maps/" + std::to_string(v2) + "/diff?from=" + std::to_string(v1) +
                        "&format=geojson");
  ASSERT_EQ(r->status, 200);
  EXPECT_EQ(r->get_header_value("Content-Type"), "application/geo+json");
  const json g = json::parse(r->body);
  EXPECT_EQ(g["type"], "FeatureCollection");
  ASSERT_EQ(g["features"].size(), 4U);
  for (const json& f : g["features"]) {
    const json& geom = f["geometry"];
    EXPECT_EQ(geom["type"], f["properties"]["kind"] == "line" ? "LineString" : "Point");
    const json& c = geom["type"] == "Point" ? geom["coordinates"] : geom["coordinates"][0];
    EXPECT_NEAR(c[0].get<double>(), 138.8045, 0.01);  // longitude first
    EXPECT_NEAR(c[1].get<double>(), 35.2240, 0.01);
  }

  // Backwards: the same objects, roles swapped; no reasons (no version recorded them).
  const json back = get_json("/v1/maps/" + std::to_string(v1) + "/diff?from=" + std::to_string(v2));
  EXPECT_EQ(back["counts"]["added"], 2);
  EXPECT_EQ(back["counts"]["retired"], 1);
  EXPECT_EQ(back["counts"]["moved"], 1);
}

TEST_F(MapDiffTest, BadRequestsNameTheParameter) {
  upload(package("only_0", "veh_a", 1000.0, before(), 1));
  upload(package("only_1", "veh_b", 1100.0, before(), 2));
  const std::int64_t v = build();
  const std::string base = "/v1/maps/" + std::to_string(v) + "/diff";
  EXPECT_EQ(get_json(base, 400)["field"], "from");
  EXPECT_EQ(get_json(base + "?from=x", 400)["field"], "from");
  EXPECT_EQ(get_json(base + "?from=" + std::to_string(v + 5), 404)["field"], "from");
  EXPECT_EQ(get_json("/v1/maps/0/diff?from=1", 400)["field"], "version");
  EXPECT_EQ(get_json(base + "?from=current&format=xml", 400)["field"], "format");
  EXPECT_EQ(get_json(base + "?from=current&bbox=1,2,3", 400)["field"], "bbox");
  // A version against itself: nothing changed.
  const json same = get_json(base + "?from=current");
  EXPECT_TRUE(same["changes"].empty());
  EXPECT_EQ(same["counts"]["unchanged"], 10);
}

}  // namespace
}  // namespace polmap::mapping::testing
