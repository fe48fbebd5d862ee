// HD-map comparisons and landmark details over HTTP, on loopback: a scene seen by six
// drives (version 1), then changed (a pole moved by 0.6 m) and seen by six more (version 2);
// an HD map of the scene with two signs the radar never saw and a wall longer than the
// radar's is compared with version 2 and stored as `polmap compare-hdmap --store` does.
// GET /v1/maps/{v}/hdmap-comparison[/{name}] serves it (the GeoJSON agreeing with the core's
// counts), GET /v1/maps/{v}/landmarks/{key} a landmark's support times and its history
// (moved in 2, there since 1); bad requests name the parameter.
#include <nlohmann/json.hpp>
#include <set>

#include "mapping_service/server_fixture.hpp"
#include "polmap/mapping_service/hdmap_compare.hpp"

namespace polmap::mapping::testing {
namespace {

using nlohmann::json;

constexpr double kT0 = 1.7e9;  // drive times on a UTC clock (2023-11-14)

std::vector<Eigen::Vector2d> poles(bool moved) {
  std::vector<Eigen::Vector2d> p;
  for (int i = 0; i < 6; ++i) p.emplace_back(-12.0 + 5.0 * i, i % 2 ? 6.0 : -6.0);
  if (moved) p[3].x() += 0.6;
  return p;
}

/// A landmarks-only package of one pass along the x axis seeing the poles and the wall
/// (-15, 9) -> (-3, 9), ±2 cm noise.
std::string package(const std::string& id, double start_time_s, bool moved, unsigned seed) {
  SyntheticDrive d = pass_along_x(id, "veh_" + std::to_string(seed % 3), start_time_s, seed);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> j(-0.02, 0.02);
  for (const auto& p : poles(moved)) {
    PointCandidate c;
    c.position_m = p + Eigen::Vector2d(j(rng), j(rng));
    c.strength = 12.0;
    c.scattering = ScatteringClass::Odd;
    d.pkg.points.push_back(c);
  }
  LineCandidate l;
  l.start_m = Eigen::Vector2d(-15.0, 9.0) + Eigen::Vector2d(j(rng), j(rng));
  l.end_m = Eigen::Vector2d(-3.0, 9.0) + Eigen::Vector2d(j(rng), j(rng));
  l.strength = 1.0;
  d.pkg.lines.push_back(l);
  const util::ScopedTempDir base(polmap::test::unique_test_dir("hdmap-pkgs"));
  PackageWriteOptions wo;
  wo.format_version = 2;
  wo.landmarks_only = true;
  write_drive_package(d.pkg, d.raster, base.path() / id, wo);
  return pack_drive_package(base.path() / id);
}

/// The HD map: signs at poles 0..2 (3 cm off), two signs nobody saw, the wall from -15 to
/// 5 m (the radar saw 12 of its 20 m).
HdMap hd_map() {
  const tiles::LocalFrame f = scene_frame();
  HdMap hd;
  const auto p = poles(true);
  for (int i = 0; i < 3; ++i) {
    hd.points.push_back(
        {100 + i, "traffic_sign", "de206", f.to_geo(p[i] + Eigen::Vector2d(0.03, 0.0))});
  }
  hd.points.push_back({200, "traffic_sign", "de101", f.to_geo(Eigen::Vector2d(0.0, -9.0))});
  hd.points.push_back({201, "pole", "", f.to_geo(Eigen::Vector2d(8.0, 9.0))});
  hd.lines.push_back({300, "wall", "", {f.to_geo({-15.0, 9.0}), f.to_geo({5.0, 9.0})}});
  return hd;
}

class HdMapComparisonTest : public ServerFixture {
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
  json get_json(const std::string& path, int expect_status = 200, const httplib::Headers& h = {}) {
    auto r = client().Get(path, h);
    EXPECT_TRUE(r);
    EXPECT_EQ(r->status, expect_status) << path << ": " << r->body;
    return json::parse(r->body);
  }
  void SetUp() override {
    ServerFixture::SetUp();
    for (int k = 0; k < 6; ++k)
      upload(package("before_" + std::to_string(k), kT0 + 100.0 * k, false, 10 + k));
    v1_ = build();
    for (int k = 0; k < 6; ++k)
      upload(package("after_" + std::to_string(k), kT0 + 9000.0 + 100.0 * k, true, 20 + k));
    v2_ = build();
    ASSERT_EQ(v2_, v1_ + 1);
  }
  std::int64_t v1_ = 0, v2_ = 0;
};

TEST_F(HdMapComparisonTest, TheStoredComparisonIsServedAsGeoJsonAgreeingWithTheCore) {
  const HdMap hd = hd_map();
  const LandmarkSet lm = store_->landmarks_in(v2_, std::nullopt, false);
  ASSERT_EQ(lm.points.size(), 6U);
  ASSERT_EQ(lm.lines.size(), 1U);
  const HdMapComparison c = compare_with_hdmap(lm, hd);
  EXPECT_EQ(c.matched_points, 3U);
  EXPECT_EQ(c.hd_points, 5U);
  ASSERT_TRUE(c.line_coverage);
  EXPECT_NEAR(*c.line_coverage, 0.6, 0.06);
  HdMapComparisonRecord rec{v2_, "scene-hd", "/maps/scene.osm",
                            "",  to_json(c), hdmap_comparison_geojson(lm, hd, c)};
  store_->put_hdmap_comparison(rec);

  // The list of a version, "current" included; version 1 has none.
  const json list = get_json("/v1/maps/current/hdmap-comparison");
  EXPECT_EQ(list["version"], v2_);
  ASSERT_EQ(list["comparisons"].size(), 1U);
  EXPECT_EQ(list["comparisons"][0]["name"], "scene-hd");
  EXPECT_EQ(list["comparisons"][0]["hdmap_file"], "/maps/scene.osm");
  EXPECT_EQ(list["comparisons"][0]["summary"]["matched_points"], 3);
  EXPECT_EQ(list["comparisons"][0]["href"],
            "/v1/maps/" + std::to_string(v2_) + "/hdmap-comparison/scene-hd");
  EXPECT_TRUE(
      get_json("/v1/maps/" + std::to_string(v1_) + "/hdmap-comparison")["comparisons"].empty());

  const std::string url = "/v1/maps/" + std::to_string(v2_) + "/hdmap-comparison/scene-hd";
  auto r = client().Get(url);
  ASSERT_EQ(r->status, 200) << r->body;
  EXPECT_EQ(r->get_header_value("Content-Type"), "application/geo+json");
  EXPECT_EQ(r->get_header_value("Cache-Control"), "no-cache");
  const std::string etag = r->get_header_value("ETag");
  ASSERT_FALSE(etag.empty());
  const json g = json::parse(r->body);
  EXPECT_EQ(g["type"], "FeatureCollection");
  EXPECT_EQ(g["properties"]["name"], "scene-hd");
  EXPECT_EQ(g["properties"]["version"], v2_);
  EXPECT_EQ(g["properties"]["summary"]["hd_points"], 5);
  // Per-feature flags add up to the core's counts.
  std::size_t hd_pts = 0, hd_matched = 0, map_pts = 0, map_matched = 0;
  double covered_m = 0, hd_len_m = 0;
  std::set<std::string> matched_keys;
  for (const json& f : g["features"]) {
    const json& p = f["properties"];
    const std::string geom = f["geometry"]["type"];
    if (p["role"] == "hd" && geom == "Point") {
      ++hd_pts;
      EXPECT_TRUE(p["in_area"].get<bool>());
      if (p["matched"].get<bool>()) {
        ++hd_matched;
        EXPECT_GE(p["hd_id"].get<int>(), 100);
        EXPECT_LE(p["hd_id"].get<int>(), 102);
        EXPECT_NEAR(p["distance_m"].get<double>(), 0.03, 0.05);
        matched_keys.insert(p["landmark_key"].get<std::string>());
      } else {
        EXPECT_GE(p["hd_id"].get<int>(), 200);
      }
    } else if (p["role"] == "map" && geom == "Point") {
      ++map_pts;
      EXPECT_EQ(p["type"], "point_landmark");
      if (p["matched"].get<bool>()) {
        ++map_matched;
        EXPECT_TRUE(matched_keys.count(p["key"].get<std::string>())) << p.dump();
        EXPECT_EQ(p["hd_type"], "traffic_sign");
      }
    } else if (p["role"] == "hd") {
      EXPECT_EQ(geom, "LineString");
      EXPECT_EQ(p["type"], "wall");
      EXPECT_NEAR(p["line_coverage"].get<double>(), *c.line_coverage, 1e-9);
      hd_len_m += p["length_m"].get<double>();
      if (p["matched"].get<bool>()) covered_m += p["length_m"].get<double>();
    } else {
      EXPECT_EQ(p["type"], "line_landmark");
      EXPECT_TRUE(p["matched"].get<bool>()) << "the radar's wall lies on the HD wall";
      EXPECT_LT(p["median_offset_m"].get<double>(), 0.1);
    }
  }
  EXPECT_EQ(hd_pts, hd.points.size());
  EXPECT_EQ(hd_matched, c.matched_points);
  EXPECT_EQ(map_pts, lm.points.size());
  EXPECT_EQ(map_matched, c.matched_points);
  EXPECT_NEAR(covered_m, c.line_covered_length_m, 1e-6);
  EXPECT_NEAR(hd_len_m, c.line_total_length_m, 1e-6);
  EXPECT_NEAR(hd_len_m, 20.0, 0.01);

  // Revalidation; the JSON format is the summary alone.
  r = client().Get(url, {{"If-None-Match", etag}});
  EXPECT_EQ(r->status, 304);
  const json j = get_json(url + "?format=json");
  EXPECT_EQ(j["summary"], to_json(c));
  EXPECT_FALSE(j.contains("features"));

  // Bad requests name the parameter; what is missing is named too.
  EXPECT_EQ(get_json("/v1/maps/x/hdmap-comparison", 400)["field"], "version");
  EXPECT_EQ(get_json("/v1/maps/0/hdmap-comparison/scene-hd", 400)["field"], "version");
  EXPECT_EQ(get_json("/v1/maps/99/hdmap-comparison", 404)["field"], "version");
  EXPECT_EQ(get_json(url + "?format=xml", 400)["field"], "format");
  EXPECT_EQ(get_json("/v1/maps/current/hdmap-comparison/.hidden", 400)["field"], "name");
  EXPECT_EQ(get_json("/v1/maps/current/hdmap-comparison/a%20b", 400)["field"], "name");
  const json missing =
      get_json("/v1/maps/" + std::to_string(v1_) + "/hdmap-comparison/scene-hd", 404);
  EXPECT_EQ(missing["field"], "name");
  EXPECT_NE(missing["error"].get<std::string>().find("scene-hd"), std::string::npos);

  // Deleting the version takes its comparison with it.
  store_->set_current_map_version(v1_);
  ASSERT_TRUE(store_->delete_map_version(v2_));
  EXPECT_EQ(get_json(url, 404)["field"], "version");
}

TEST_F(HdMapComparisonTest, ALandmarkShowsItsSupportTimesAndHistory) {
  const json d = get_json("/v1/maps/" + std::to_string(v2_) + "/diff?from=" + std::to_string(v1_));
  ASSERT_EQ(d["counts"]["moved"], 1) << d.dump();
  std::int64_t key = 0, previous = 0;
  for (const json& c : d["changes"]) {
    if (c["change"] == "moved") {
      key = std::stoll(c["key"].get<std::string>());  // decimal strings: 63-bit keys
      previous = std::stoll(c["previous_key"].get<std::string>());
    }
  }
  ASSERT_GT(key, 0);
  const std::string url = "/v1/maps/" + std::to_string(v2_) + "/landmarks/" + std::to_string(key);
  const json l = get_json(url);
  EXPECT_EQ(l["key"], std::to_string(key));  // a string: 63-bit keys
  EXPECT_EQ(l["version"], v2_);
  EXPECT_EQ(l["kind"], "point");
  EXPECT_EQ(l["class"], "odd");
  EXPECT_EQ(l["geometry"]["type"], "Point");
  EXPECT_EQ(l["support_drives"], 6);
  EXPECT_EQ(l["supporting_drives"], 6);
  // Without a key: when vehicles passed is trajectory data, so UTC days only.
  EXPECT_EQ(l["times"], "day");
  EXPECT_EQ(l["first_seen"], "2023-11-15");  // 1700009000 s
  EXPECT_EQ(l["last_seen"], "2023-11-15");
  EXPECT_TRUE(l["first_seen_s"].is_null());
  EXPECT_TRUE(l["last_seen_s"].is_null());
  EXPECT_EQ(l["first_ingested_at"].get<std::string>().size(), 10U);
  EXPECT_FALSE(l.contains("drives")) << "drive ids need a key";
  ASSERT_EQ(l["history"].size(), 2U) << l.dump();
  EXPECT_EQ(l["history"][0]["version"], v2_);
  EXPECT_EQ(l["history"][0]["change"], "moved");
  EXPECT_NEAR(l["history"][0]["distance_m"].get<double>(), 0.6, 0.05);
  EXPECT_EQ(l["history"][0]["previous_key"], std::to_string(previous));
  EXPECT_FALSE(l["history"][0]["reason"].is_null());
  EXPECT_FALSE(l["history"][0]["inferred"].get<bool>());
  EXPECT_EQ(l["history"][1]["version"], v1_);
  EXPECT_EQ(l["history"][1]["change"], "added");
  EXPECT_EQ(l["history"][1]["key"], std::to_string(previous));
  EXPECT_TRUE(l["history"][1]["inferred"].get<bool>());

  // With an operator key: the drives.
  const json lk = get_json(url, 200, auth());
  EXPECT_EQ(lk["times"], "exact");
  EXPECT_DOUBLE_EQ(lk["first_seen_s"].get<double>(), kT0 + 9000.0);
  EXPECT_DOUBLE_EQ(lk["last_seen_s"].get<double>(), kT0 + 9000.0 + 500.0 + 4.0);
  EXPECT_EQ(lk["first_seen"], "2023-11-15T00:43:20Z");
  EXPECT_EQ(lk["last_seen"], "2023-11-15T00:51:44Z");
  EXPECT_EQ(lk["first_ingested_at"].get<std::string>().size(), 20U);
  ASSERT_EQ(lk["drives"].size(), 6U);
  EXPECT_EQ(lk["drives"][0]["drive_id"], "after_0");  // by start time
  EXPECT_EQ(lk["drives"][0]["candidates"], 1);

  // The old key in version 1: the first version, no changes recorded.
  const json old =
      get_json("/v1/maps/" + std::to_string(v1_) + "/landmarks/" + std::to_string(previous));
  ASSERT_EQ(old["history"].size(), 1U);
  EXPECT_TRUE(old["history"][0]["inferred"].get<bool>());
  EXPECT_EQ(old["supporting_drives"], 6);
  EXPECT_EQ(old["first_seen"], "2023-11-14");

  EXPECT_EQ(get_json("/v1/maps/" + std::to_string(v2_) + "/landmarks/abc", 400)["field"], "key");
  EXPECT_EQ(get_json("/v1/maps/" + std::to_string(v2_) + "/landmarks/-5", 400)["field"], "key");
  EXPECT_EQ(get_json("/v1/maps/" + std::to_string(v2_) + "/landmarks/12345", 404)["field"], "key");
  EXPECT_EQ(get_json("/v1/maps/99/landmarks/" + std::to_string(key), 404)["field"], "version");
  // The new key did not exist in version 1.
  EXPECT_EQ(get_json("/v1/maps/" + std::to_string(v1_) + "/landmarks/" + std::to_string(key),
                     404)["field"],
            "key");
}

}  // namespace
}  // namespace polmap::mapping::testing
