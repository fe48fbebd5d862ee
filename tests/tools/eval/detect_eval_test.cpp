// Detection evaluation against a world truth: matching radius, structure hits,
// observability along the trajectory, class accuracy, line coverage and precision,
// repeatability, and the truth JSON reader's frame conversion and errors.
#include "polmap/eval/detect_eval.hpp"

#include <gtest/gtest.h>

#include "polmap/schema/errors.hpp"

namespace polmap::eval {
namespace {

WorldTruth toy_truth() {
  WorldTruth w;
  w.objects.push_back({1, "lamp_pole", "odd", true, {}, {{10.0, 5.0}}, {}});
  w.objects.push_back({2, "guardrail_post", "even", true, {}, {{20.0, 5.0}}, {}});
  w.objects.push_back({3, "lamp_pole", "odd", true, {}, {{200.0, 5.0}}, {}});  // far from the path
  w.objects.push_back({4, "parked_car", "mixed", false, {1}, {{30.0, -3.0}}, {}});  // drive 1 only
  w.objects.push_back({5, "curbstone", "even", true, {}, {{0.0, 4.0}, {40.0, 4.0}}, {}});
  return w;
}

std::vector<Eigen::Vector2d> path() {
  std::vector<Eigen::Vector2d> p;
  for (double x = 0.0; x <= 40.0; x += 0.5) p.push_back({x, 0.0});
  return p;
}

PointCandidate pc(double x, double y, ScatteringClass c = ScatteringClass::Odd) {
  PointCandidate p;
  p.position_m = {x, y};
  p.scattering = c;
  return p;
}

TEST(DetectEval, PointsPrecisionRecallAndClasses) {
  const std::vector<PointCandidate> pts{pc(10.2, 5.1), pc(20.0, 5.25, ScatteringClass::Odd),
                                        pc(15.0, 4.05), pc(30.5, -3.5), pc(5.0, -8.0)};
  const DetectEval e0 = evaluate_detections(pts, {}, toy_truth(), 0, path());
  EXPECT_EQ(e0.points.candidates, 5U);
  EXPECT_EQ(e0.points.candidates_on_points, 2U);
  EXPECT_EQ(e0.points.candidates_on_structure, 3U);  // + the one on the curb; car absent in drive 0
  EXPECT_EQ(e0.points.truth_observable, 2U);         // the far lamp is not expected
  EXPECT_EQ(e0.points.truth_found, 2U);
  EXPECT_DOUBLE_EQ(e0.points.recall, 1.0);
  EXPECT_EQ(e0.points.class_pairs, 2U);
  EXPECT_EQ(e0.points.class_correct, 1U);  // the even post was called odd
  EXPECT_NEAR(e0.points.rms_error_m, std::sqrt((0.05 + 0.0625) / 2.0), 1e-12);
  const DetectEval e1 = evaluate_detections(pts, {}, toy_truth(), 1, path());
  EXPECT_EQ(e1.points.candidates_on_structure, 4U);  // the parked car is there in drive 1
}

TEST(DetectEval, LineCoverageAndPrecision) {
  LineCandidate on, off;
  on.start_m = {0.0, 4.1};
  on.end_m = {20.0, 4.1};
  off.start_m = {0.0, -10.0};
  off.end_m = {10.0, -10.0};
  const DetectEval e = evaluate_detections({}, {on, off}, toy_truth(), 0, path());
  EXPECT_NEAR(e.lines.truth_length_m, 40.0, 1e-9);
  EXPECT_NEAR(e.lines.coverage, 0.5, 0.01);
  EXPECT_NEAR(e.lines.precision, 20.0 / 30.0, 0.01);
  EXPECT_NEAR(e.lines.coverage_by_class.at("curbstone").second, 20.0, 0.3);
}

TEST(DetectEval, RepeatabilityCountsMutualMatches) {
  const std::vector<PointCandidate> a{pc(10.0, 5.0), pc(20.0, 5.0), pc(25.0, 1.0), pc(300.0, 0.0)};
  const std::vector<PointCandidate> b{pc(10.1, 5.0), pc(20.0, 5.2), pc(33.0, 2.0)};
  // a: 2 of 3 in the common area matched; b: 2 of 3.
  EXPECT_NEAR(point_repeatability(a, path(), b, path()), 2.0 / 3.0, 1e-12);
}

TEST(DetectEval, TemporaryObjectsAreWhereTheyStoodInThatDrive) {
  // A parked car 1 m further along in drive 1 than in drive 0: its candidate counts as a
  // hit in each drive only at that drive's position (world.json "positions_by_drive").
  const std::string json = R"({"format": "polmap-sim-world-truth", "version": 1,
    "origin": {"lat_deg": 50.0, "lon_deg": 8.0, "alt_m": 0},
    "objects": [{"id": 4, "class": "parked_car", "mechanism": "mixed", "permanent": false,
                 "drives_present": [0, 1],
                 "position": {"lat_deg": 50.0, "lon_deg": 8.0, "x_m": 0, "y_m": 0},
                 "positions_by_drive": [{"lat_deg": 50.0, "lon_deg": 8.0},
                                        {"lat_deg": 50.0, "lon_deg": 8.000014}]}]})";
  const tiles::LocalFrame frame({50.0, 8.0, 0.0});
  const WorldTruth w = parse_world_truth(json, frame);
  ASSERT_EQ(w.objects.size(), 1U);
  const Eigen::Vector2d at0 = w.objects[0].geometry_in(0)[0];
  const Eigen::Vector2d at1 = w.objects[0].geometry_in(1)[0];
  EXPECT_NEAR(at0.norm(), 0.0, 1e-9);
  EXPECT_NEAR(at1.x(), frame.to_local(50.0, 8.000014).x(), 1e-9);
  EXPECT_NEAR(at1.x(), 1.0, 0.01);
  // A drive it was absent from: its nominal place.
  EXPECT_EQ(w.objects[0].geometry_in(5), w.objects[0].geometry_m);
  // A position list that does not match drives_present is rejected with the object named.
  std::string bad = json;
  bad.replace(bad.find("[0, 1]"), 6, "[0]");
  try {
    (void)parse_world_truth(bad, frame, "truth/world.json");
    FAIL() << "accepted";
  } catch (const FormatError& e) {
    EXPECT_NE(std::string(e.what()).find("truth/world.json: object 4"), std::string::npos);
  }
}

TEST(DetectEval, TruthJsonIsReprojectedAndValidated) {
  const std::string json = R"({"format": "polmap-sim-world-truth", "version": 1,
    "origin": {"lat_deg": 50.0, "lon_deg": 8.0, "alt_m": 0},
    "route": {"xy": [[0, 0], [1, 0]]},
    "objects": [{"id": 7, "class": "lamp_pole", "mechanism": "odd", "permanent": true,
                 "position": {"lat_deg": 50.0, "lon_deg": 8.001, "x_m": 71.6, "y_m": 0}}]})";
  const tiles::LocalFrame same({50.0, 8.0, 0.0});
  const WorldTruth w = parse_world_truth(json, same);
  ASSERT_EQ(w.objects.size(), 1U);
  EXPECT_NEAR(w.objects[0].geometry_m[0].x(), same.to_local(50.0, 8.001).x(), 1e-9);
  // Another drive frame: positions follow the lat/lon, not the world x/y.
  const tiles::LocalFrame other({50.0, 8.001, 0.0});
  EXPECT_NEAR(parse_world_truth(json, other).objects[0].geometry_m[0].norm(), 0.0, 1e-6);
  EXPECT_THROW(parse_world_truth("{", same), FormatError);
  EXPECT_THROW(parse_world_truth(R"({"format": "other"})", same), FormatError);
  EXPECT_THROW(parse_world_truth(R"({"format": "polmap-sim-world-truth", "origin": {}})", same),
               FormatError);
}

}  // namespace
}  // namespace polmap::eval
