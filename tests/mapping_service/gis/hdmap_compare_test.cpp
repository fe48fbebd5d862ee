// HD-map comparison on real Lanelet2 maps with synthetic radar landmarks placed at the
// HD-map features (known offsets, gaps and outliers), checked against brute force.
#include "polmap/mapping_service/hdmap_compare.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <random>

#include "polmap/tiles/local_frame.hpp"
#include "test_dir.hpp"

namespace polmap::mapping {
namespace {

namespace fs = std::filesystem;
using Vec = Eigen::Vector2d;

const fs::path kShoulder = fs::path(POLMAP_DATA_DIR) / "hdmaps" / "autoware_road_shoulder.osm";
const fs::path kIntersection = fs::path(POLMAP_DATA_DIR) / "hdmaps" / "autoware_intersection.osm";

tiles::LocalFrame frame_of(const HdMap& hd) {
  const auto b = hdmap_bounds(hd);
  return tiles::LocalFrame(
      {0.5 * (b->min_lat_deg + b->max_lat_deg), 0.5 * (b->min_lon_deg + b->max_lon_deg), 0.0});
}

std::vector<std::vector<Vec>> hd_lines_local(const HdMap& hd, const tiles::LocalFrame& f) {
  std::vector<std::vector<Vec>> out;
  for (const auto& l : hd.lines) {
    auto& v = out.emplace_back();
    for (const auto& p : l.polyline) v.push_back(f.to_local(p));
  }
  return out;
}

double seg_dist(const Vec& p, const Vec& a, const Vec& b) {
  const Vec d = b - a;
  const double t =
      d.squaredNorm() > 0 ? std::clamp((p - a).dot(d) / d.squaredNorm(), 0.0, 1.0) : 0.0;
  return (p - (a + t * d)).norm();
}

/// Brute-force reference of coverage: fine pieces, distance to every map segment.
double brute_coverage(const std::vector<std::vector<Vec>>& hd,
                      const std::vector<std::vector<Vec>>& map, double band, double step) {
  double covered = 0, total = 0;
  for (const auto& l : hd) {
    for (std::size_t i = 1; i < l.size(); ++i) {
      const Vec d = l[i] - l[i - 1];
      const int n = std::max(1, static_cast<int>(std::ceil(d.norm() / step)));
      for (int k = 0; k < n; ++k) {
        const Vec mid = l[i - 1] + d * ((k + 0.5) / n);
        const double len = d.norm() / n;
        total += len;
        double best = 1e300;
        for (const auto& m : map)
          for (std::size_t j = 1; j < m.size(); ++j)
            best = std::min(best, seg_dist(mid, m[j - 1], m[j]));
        if (best <= band) covered += len;
      }
    }
  }
  return covered / total;
}

/// Segment-wise copies of the HD lines shifted `offset_m` to the left of their direction.
std::vector<std::vector<Vec>> shifted(const std::vector<std::vector<Vec>>& lines, double offset_m) {
  std::vector<std::vector<Vec>> out;
  for (const auto& l : lines) {
    for (std::size_t i = 1; i < l.size(); ++i) {
      const Vec d = (l[i] - l[i - 1]).normalized();
      const Vec n(-d.y(), d.x());
      out.push_back({l[i - 1] + offset_m * n, l[i] + offset_m * n});
    }
  }
  return out;
}

TEST(HdMapRead, RoadShoulderLinearFeatures) {
  const HdMap hd = read_lanelet2_osm(kShoulder);
  EXPECT_EQ(hd.num_ways, 1199U);
  EXPECT_TRUE(hd.points.empty());  // no signs, lights or poles in this map
  int curb = 0, border = 0, fence = 0;
  for (const auto& l : hd.lines) {
    EXPECT_GE(l.polyline.size(), 2U);
    curb += l.type == "curbstone";  // includes the map's "curbestone" spelling
    border += l.type == "road_border";
    fence += l.type == "fence";
  }
  EXPECT_EQ(curb, 27);
  EXPECT_EQ(border, 24);
  EXPECT_EQ(fence, 5);
  EXPECT_EQ(hd.lines.size(), 56U);
  const auto b = hdmap_bounds(hd);
  ASSERT_TRUE(b.has_value());
  EXPECT_NEAR(b->min_lat_deg, 35.22, 0.02);
  EXPECT_NEAR(b->min_lon_deg, 138.80, 0.02);
}

TEST(HdMapRead, IntersectionPointFeaturesAreCentroids) {
  const HdMap hd = read_lanelet2_osm(kIntersection);
  int lights = 0, signs = 0;
  for (const auto& p : hd.points) {
    lights += p.type == "traffic_light";
    signs += p.type == "traffic_sign";
  }
  EXPECT_EQ(lights, 11);
  EXPECT_EQ(signs, 1);
}

TEST(HdMapRead, Errors) {
  EXPECT_THROW((void)read_lanelet2_osm("/nonexistent/map.osm"), IoError);
  const util::ScopedTempDir dir(polmap::test::unique_test_dir("hdmap"));
  const fs::path bad = dir.path() / "bad.osm";
  std::ofstream(bad) << "<osm><node id='1' lat='x' lon='2'/></osm>";
  try {
    (void)read_lanelet2_osm(bad);
    ADD_FAILURE();
  } catch (const FormatError& e) {
    EXPECT_NE(std::string(e.what()).find("node 1"), std::string::npos) << e.what();
  }
  std::ofstream(bad) << "<osm><node id='1' lat='1' lon='2'></osm>";
  EXPECT_THROW((void)read_lanelet2_osm(bad), FormatError);
  fs::remove(bad);
}

TEST(HdMapCompare, LinesShiftedLaterallyOnRealMap) {
  const HdMap hd = read_lanelet2_osm(kShoulder);
  const auto f = frame_of(hd);
  const auto hl = hd_lines_local(hd, f);
  auto ml = shifted(hl, 0.2);
  const auto r = compare_hdmap_metric({}, ml, {}, hl);
  ASSERT_TRUE(r.line_median_lateral_offset_m.has_value());
  EXPECT_NEAR(*r.line_median_lateral_offset_m, 0.2, 0.005);
  ASSERT_TRUE(r.line_coverage.has_value());
  EXPECT_GT(*r.line_coverage, 0.995);
  EXPECT_GT(r.line_total_length_m, 1000.0);
  EXPECT_NEAR(r.line_covered_length_m, *r.line_coverage * r.line_total_length_m, 1e-6);
  EXPECT_EQ(r.matched_line_samples, r.map_line_samples);
  // Outliers: radar lines with no HD counterpart (15 m away) do not move the median,
  // and 20 % of the lines with a 0.6 m offset shift it only slightly.
  std::vector<std::vector<Vec>> noisy = ml;
  const std::size_t n = noisy.size();
  for (std::size_t i = 0; i < n; i += 5) {
    const Vec d = (noisy[i][1] - noisy[i][0]).normalized();
    const Vec nrm(-d.y(), d.x());
    noisy[i][0] += 0.4 * nrm;
    noisy[i][1] += 0.4 * nrm;
  }
  for (std::size_t i = 0; i < 30; ++i)
    noisy.push_back({hl[i % hl.size()][0] + Vec(15, 15), hl[i % hl.size()][0] + Vec(25, 15)});
  const auto r2 = compare_hdmap_metric({}, noisy, {}, hl);
  EXPECT_LT(r2.matched_line_samples, r2.map_line_samples);
  EXPECT_NEAR(*r2.line_median_lateral_offset_m, 0.2, 0.02);
}

TEST(HdMapCompare, CoverageOfPartialMapMatchesBruteForce) {
  const HdMap hd = read_lanelet2_osm(kShoulder);
  const auto f = frame_of(hd);
  const auto hl = hd_lines_local(hd, f);
  // Keep the first 60 % of every shifted segment, drop every third line entirely.
  std::vector<std::vector<Vec>> ml;
  for (std::size_t i = 0; i < hl.size(); ++i) {
    if (i % 3 == 0) continue;
    for (auto s : shifted({hl[i]}, 0.3)) {
      s[1] = s[0] + 0.6 * (s[1] - s[0]);
      ml.push_back(s);
    }
  }
  HdMapCompareConfig cfg;
  cfg.restrict_to_overlap = false;
  const auto r = compare_hdmap_metric({}, ml, {}, hl, cfg);
  const double want = brute_coverage(hl, ml, cfg.line_band_m, cfg.line_sample_step_m);
  ASSERT_TRUE(r.line_coverage.has_value());
  EXPECT_NEAR(*r.line_coverage, want, 1e-9);
  EXPECT_GT(want, 0.3);
  EXPECT_LT(want, 0.8);
  EXPECT_NEAR(*r.line_median_lateral_offset_m, 0.3, 0.005);
}

TEST(HdMapCompare, PointsOnRealIntersectionWithOffsetsGapsAndOutliers) {
  const HdMap hd = read_lanelet2_osm(kIntersection);
  const auto f = frame_of(hd);
  std::vector<Vec> hp;
  for (const auto& p : hd.points) hp.push_back(f.to_local(p.position));
  ASSERT_EQ(hp.size(), 12U);
  // The features stand far enough apart for unambiguous 1 m matching.
  double min_sep = 1e9;
  for (std::size_t i = 0; i < hp.size(); ++i)
    for (std::size_t j = i + 1; j < hp.size(); ++j)
      min_sep = std::min(min_sep, (hp[i] - hp[j]).norm());
  ASSERT_GT(min_sep, 2.0) << "test assumes separated features";
  std::vector<Vec> mp;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> ang(0.0, 2 * std::numbers::pi);
  // 10 of 12 found with a 0.3 m offset in random directions; 2 missed.
  for (std::size_t i = 0; i < 10; ++i) {
    const double a = ang(rng);
    mp.push_back(hp[i] + 0.3 * Vec(std::cos(a), std::sin(a)));
  }
  // One 1.5 m off (outside the radius): a false positive, its feature stays unmatched.
  mp.push_back(hp[10] + Vec(1.5, 0.0));
  // Three outliers: radar point landmarks where the HD map has nothing.
  mp.push_back(hp[0] + Vec(8.0, 0.0));
  mp.push_back(hp[1] + Vec(0.0, -9.0));
  mp.push_back(hp[2] + Vec(-7.0, 7.0));
  const auto r = compare_hdmap_metric(mp, {}, hp, {});
  EXPECT_EQ(r.map_points, 14U);
  EXPECT_EQ(r.hd_points, 12U);
  EXPECT_EQ(r.matched_points, 10U);
  EXPECT_NEAR(*r.point_precision, 10.0 / 14.0, 1e-12);
  EXPECT_NEAR(*r.point_recall, 10.0 / 12.0, 1e-12);
  EXPECT_NEAR(*r.point_median_offset_m, 0.3, 1e-9);
  for (const auto& m : r.point_matches) EXPECT_EQ(m.map_index, m.hd_index);
  // No lines in either map: line metrics undefined, not zero.
  EXPECT_FALSE(r.line_coverage.has_value());
  EXPECT_FALSE(r.line_median_lateral_offset_m.has_value());
}

TEST(HdMapCompare, GreedyMatchingIsOneToOneAndPrefersClosest) {
  // Two map points compete for one HD point; the closer wins, the other is unmatched.
  const auto r = compare_hdmap_metric({Vec(0.2, 0), Vec(-0.5, 0)}, {}, {Vec(0, 0)}, {});
  ASSERT_EQ(r.point_matches.size(), 1U);
  EXPECT_EQ(r.point_matches[0].map_index, 0U);
  EXPECT_NEAR(*r.point_precision, 0.5, 1e-12);
  EXPECT_NEAR(*r.point_recall, 1.0, 1e-12);
  // Boundary of the radius is inclusive.
  EXPECT_EQ(compare_hdmap_metric({Vec(1.0, 0)}, {}, {Vec(0, 0)}, {}).matched_points, 1U);
  EXPECT_EQ(compare_hdmap_metric({Vec(1.0001, 0)}, {}, {Vec(0, 0)}, {}).matched_points, 0U);
}

TEST(HdMapCompare, EvaluationAreaIsTheOverlap) {
  // HD map covers x in [0, 100]; radar map drove x in [0, 50] only: HD points beyond
  // 60 m (50 + 10 m margin) do not count against recall.
  std::vector<Vec> hp, mp;
  for (int x = 0; x <= 100; x += 10) hp.push_back(Vec(x, 0));
  for (int x = 0; x <= 50; x += 10) mp.push_back(Vec(x + 0.1, 0));
  const auto r = compare_hdmap_metric(mp, {}, hp, {});
  EXPECT_EQ(r.hd_points, 7U);  // 0..60
  EXPECT_NEAR(*r.point_recall, 6.0 / 7.0, 1e-12);
  HdMapCompareConfig all;
  all.restrict_to_overlap = false;
  EXPECT_NEAR(*compare_hdmap_metric(mp, {}, hp, {}, all).point_recall, 6.0 / 11.0, 1e-12);
}

TEST(HdMapCompare, GeodeticEntryPointAndJson) {
  const HdMap hd = read_lanelet2_osm(kShoulder);
  const auto f = frame_of(hd);
  const auto hl = hd_lines_local(hd, f);
  LandmarkSet lm;
  for (const auto& s : shifted(hl, 0.25)) {
    StoredLineLandmark l;
    l.polyline = {f.to_geo(s[0]), f.to_geo(s[1])};
    lm.lines.push_back(l);
  }
  const auto r = compare_with_hdmap(lm, hd);
  EXPECT_NEAR(*r.line_median_lateral_offset_m, 0.25, 0.005);
  const auto j = to_json(r);
  for (const char* k :
       {"point_precision", "point_recall", "point_median_offset_m", "line_median_lateral_offset_m",
        "line_covered_length_m", "line_total_length_m", "line_coverage"}) {
    EXPECT_TRUE(j.contains(k)) << k;
  }
  EXPECT_TRUE(j["point_precision"].is_null());
  // Radar points but no HD point features: precision undefined, not 0.
  StoredPointLandmark p;
  p.position = f.to_geo(Vec(1.0, 2.0));
  lm.points.push_back(p);
  const auto r2 = compare_with_hdmap(lm, hd);
  EXPECT_EQ(r2.map_points, 1U);
  EXPECT_FALSE(r2.point_precision.has_value());
  EXPECT_FALSE(r2.point_recall.has_value());
  EXPECT_GT(j["line_coverage"].get<double>(), 0.99);
}

TEST(HdMapCompare, RunsSplitLinesByVerdictAndAddUpToTheCounts) {
  // HD wall 0..20 m along y = 0; the radar saw 0..12 m, 0.3 m off, and a wall at y = 5
  // from 2 to 6 m that the HD map lacks; a second radar line starts on the HD wall and
  // leaves it (x = 14 -> 14, 4).
  const std::vector<std::vector<Vec>> hd{{Vec(0, 0), Vec(10, 0), Vec(20, 0)}};
  const std::vector<std::vector<Vec>> map{
      {Vec(0, 0.3), Vec(12, 0.3)}, {Vec(2, 5), Vec(6, 5)}, {Vec(14, 0.2), Vec(14, 4)}};
  const auto r = compare_hdmap_metric({}, map, {}, hd);
  // HD runs: covered 0..~12 (and around x = 14), uncovered elsewhere; without gaps.
  ASSERT_GE(r.hd_line_runs.size(), 2U);
  double len = 0, covered = 0;
  for (std::size_t i = 0; i < r.hd_line_runs.size(); ++i) {
    const auto& run = r.hd_line_runs[i];
    EXPECT_EQ(run.line, 0U);
    EXPECT_TRUE(run.in_area);
    if (i > 0) {
      const auto& prev = r.hd_line_runs[i - 1];
      EXPECT_NE(prev.matched, run.matched) << "consecutive runs differ";
      const bool joined =
          (prev.end.segment == run.begin.segment && prev.end.t == run.begin.t) ||
          (prev.end.t == 1.0 && run.begin.segment == prev.end.segment + 1 && run.begin.t == 0.0);
      EXPECT_TRUE(joined) << "no gap between runs " << i - 1 << " and " << i;
    }
    len += run.length_m;
    if (run.matched) covered += run.length_m;
  }
  EXPECT_NEAR(len, r.line_total_length_m, 1e-9);
  EXPECT_NEAR(covered, r.line_covered_length_m, 1e-9);
  EXPECT_TRUE(r.hd_line_runs.front().matched);
  EXPECT_EQ(r.hd_line_runs.front().begin.segment, 0U);
  EXPECT_EQ(r.hd_line_runs.back().end.segment, 1U);
  EXPECT_EQ(r.hd_line_runs.back().end.t, 1.0);
  // Map runs: line 0 all on (one run), line 1 all off, line 2 on then off.
  std::size_t samples = 0, on = 0;
  std::vector<int> runs_per_line(3, 0);
  for (const auto& run : r.map_line_runs) {
    ++runs_per_line[run.line];
    samples += run.samples;
    if (run.matched) {
      on += run.samples;
      ASSERT_TRUE(run.median_offset_m.has_value());
    } else {
      EXPECT_FALSE(run.median_offset_m.has_value());
    }
  }
  EXPECT_EQ(samples, r.map_line_samples);
  EXPECT_EQ(on, r.matched_line_samples);
  EXPECT_EQ(runs_per_line, (std::vector<int>{1, 1, 2}));
  EXPECT_NEAR(*r.map_line_runs.front().median_offset_m, 0.3, 1e-9);
  EXPECT_NEAR(r.map_line_runs.front().length_m, 12.0, 1e-9);
  EXPECT_FALSE(r.map_line_runs[1].matched);
  EXPECT_NEAR(r.map_line_runs[1].length_m, 4.0, 1e-9);
}

TEST(HdMapCompare, GeoJsonHasOneFeaturePerPointAndRunWithTheVerdicts) {
  const tiles::LocalFrame f(GeoPoint{48.0, 9.0, 0.0});
  HdMap hd;
  hd.points.push_back({7, "traffic_sign", "de206", f.to_geo(Vec(0, 0))});
  hd.points.push_back({8, "pole", "", f.to_geo(Vec(30, 0))});
  hd.lines.push_back({9, "curbstone", "high", {f.to_geo(Vec(0, 3)), f.to_geo(Vec(20, 3))}});
  LandmarkSet lm;
  StoredPointLandmark p;
  p.key = 4611686018427387905;  // > 2^53: kept exact as a string
  p.position = f.to_geo(Vec(0.4, 0));
  p.scattering = ScatteringClass::Even;
  p.support_drives = 3;
  lm.points.push_back(p);
  p.key = 5;
  p.position = f.to_geo(Vec(10, -3));
  lm.points.push_back(p);
  StoredLineLandmark l;
  l.key = 6;
  l.polyline = {f.to_geo(Vec(0, 3.1)), f.to_geo(Vec(10, 3.1))};
  lm.lines.push_back(l);
  const auto c = compare_with_hdmap(lm, hd);
  ASSERT_EQ(c.matched_points, 1U);
  const auto g = hdmap_comparison_geojson(lm, hd, c);
  EXPECT_EQ(g["type"], "FeatureCollection");
  EXPECT_EQ(g["properties"]["summary"], to_json(c));
  int hd_points = 0, map_points = 0, hd_runs = 0, map_runs = 0;
  for (const auto& feat : g["features"]) {
    const auto& pr = feat["properties"];
    const auto& geom = feat["geometry"];
    if (geom["type"] == "Point") {
      const auto& xy = geom["coordinates"];
      EXPECT_NEAR(xy[0].get<double>(), 9.0, 0.01);  // lon first
      EXPECT_NEAR(xy[1].get<double>(), 48.0, 0.01);
    }
    if (pr["role"] == "hd" && geom["type"] == "Point") {
      ++hd_points;
      if (pr["hd_id"] == 7) {
        EXPECT_TRUE(pr["matched"].get<bool>());
        EXPECT_EQ(pr["landmark_key"], "4611686018427387905");
        EXPECT_NEAR(pr["distance_m"].get<double>(), 0.4, 1e-3);
        EXPECT_EQ(pr["subtype"], "de206");
      } else {
        EXPECT_FALSE(pr["matched"].get<bool>());
        EXPECT_FALSE(pr.contains("landmark_key"));
      }
    } else if (pr["role"] == "map" && geom["type"] == "Point") {
      ++map_points;
      EXPECT_EQ(pr["type"], "point_landmark");
      EXPECT_EQ(pr["class"], "even");
      EXPECT_EQ(pr["support_drives"], 3);
      EXPECT_EQ(pr["matched"].get<bool>(), pr["key"] == "4611686018427387905");
      if (pr["matched"].get<bool>()) {
        EXPECT_EQ(pr["hd_id"], 7);
      }
    } else if (pr["role"] == "hd") {
      ++hd_runs;
      EXPECT_EQ(pr["type"], "curbstone");
      EXPECT_NEAR(pr["line_coverage"].get<double>(), *c.line_coverage, 1e-12);
      EXPECT_GE(geom["coordinates"].size(), 2U);
    } else {
      ++map_runs;
      EXPECT_EQ(pr["key"], "6");
      EXPECT_TRUE(pr["matched"].get<bool>());
      EXPECT_NEAR(pr["median_offset_m"].get<double>(), 0.1, 1e-3);
      // The run redraws the whole landmark line.
      const auto& cs = geom["coordinates"];
      ASSERT_EQ(cs.size(), 2U);
      EXPECT_NEAR(cs[1][0].get<double>(), l.polyline[1].lon_deg, 1e-12);
    }
  }
  EXPECT_EQ(hd_points, 2);
  EXPECT_EQ(map_points, 2);
  EXPECT_EQ(hd_runs, 2);  // covered 0..10, uncovered 10..20
  EXPECT_EQ(map_runs, 1);
  EXPECT_NEAR(*c.line_coverage, 0.55, 0.03);  // 0..11 m of 20 (1 m band beyond the end)
  for (const auto& feat : g["features"]) EXPECT_TRUE(feat["properties"]["judged"].get<bool>());

  // Without HD point features the landmarks' points are not judged (precision undefined);
  // the lines still are.
  hd.points.clear();
  const auto c2 = compare_with_hdmap(lm, hd);
  const auto g2 = hdmap_comparison_geojson(lm, hd, c2);  // kept: the loop reads into it
  for (const auto& feat : g2["features"]) {
    const auto& pr = feat["properties"];
    EXPECT_EQ(pr["judged"].get<bool>(), feat["geometry"]["type"] != "Point") << pr.dump();
  }
}

}  // namespace
}  // namespace polmap::mapping
