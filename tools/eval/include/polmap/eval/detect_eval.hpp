#pragma once
/// @file detect_eval.hpp
/// Evaluation of landmark candidates of processed drives against the simulator's
/// world truth (DIR/truth/world.json, tools/sim/include/polmap/sim/truth.hpp):
/// point precision/recall within a radius, mechanism-class accuracy, line coverage
/// of true curbs, walls, facades, guardrails and fences, and repeatability between
/// drives. Evaluation only: the processing never reads truth.
///
/// Definitions (all distances in the drive frame, metres):
/// - Observable truth: objects present in the evaluated drive within
///   max_distance_from_path_m of a trajectory position, at a bearing of at most
///   max_bearing_deg from its heading (the front sensors' field of view).
/// - Point precision: share of point candidates within point_radius_m of a present
///   point-like truth object (any distance from the path). "Structure" precision
///   also accepts candidates within point_radius_m of a present extended object or
///   temporary object (object_radius_m around cars and bins): a real static
///   reflector, but not a point landmark.
/// - Point recall: share of observable point-like truth objects with a candidate
///   within point_radius_m. Class accuracy: among matched pairs whose truth
///   mechanism is odd or even, the share classified the same.
/// - Line coverage: share of the observable length of line truth (sampled every
///   sample_step_m) within line_radius_m of a line candidate. Line precision: share
///   of candidate length (sampled alike) within line_radius_m of any present
///   extended object.
/// - Repeatability (points): mean over both directions of the share of one drive's
///   candidates with a candidate of the other drive within point_radius_m,
///   restricted to the region both drives observed (near both trajectories).
#include <Eigen/Core>
#include <filesystem>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "polmap/schema/geo.hpp"
#include "polmap/schema/landmark.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::eval {

/// One object of the world truth, in some local frame.
struct TruthObject {
  std::uint32_t id = 0;
  std::string cls;        ///< "lamp_pole", "curbstone", ...
  std::string mechanism;  ///< "odd", "even", "mixed", "diffuse", "volume"
  bool permanent = true;
  std::vector<int> drives_present;
  std::vector<Eigen::Vector2d> geometry_m;  ///< one point or a polyline
  /// A temporary point object that stands elsewhere in each drive: its position in each
  /// drive of drives_present (same order); empty when it does not move.
  std::vector<Eigen::Vector2d> positions_by_drive_m;
  [[nodiscard]] bool present_in(int drive) const;
  /// The geometry as it was in `drive` (geometry_m, or that drive's position).
  [[nodiscard]] std::vector<Eigen::Vector2d> geometry_in(int drive) const;
  [[nodiscard]] bool is_point() const { return geometry_m.size() == 1; }
};

struct WorldTruth {
  GeoPoint origin;
  std::vector<TruthObject> objects;
  std::vector<Eigen::Vector2d> route_m;
};

/// Reads DIR/truth/world.json; positions are converted from lat/lon into `frame`
/// (the drive frame of the recordings). Throws IoError / FormatError naming the file.
WorldTruth read_world_truth(const std::filesystem::path& world_json,
                            const tiles::LocalFrame& frame);
/// Parses the JSON text (same conversion).
WorldTruth parse_world_truth(const std::string& json_text, const tiles::LocalFrame& frame,
                             const std::string& source_name = "world.json");

struct DetectEvalConfig {
  double point_radius_m = 0.3;  ///< = consensus radius d_p (paper §IV-B)
  double line_radius_m = 0.3;
  double sample_step_m = 0.25;
  /// Truth farther than this from the trajectory is not expected to be seen.
  double max_distance_from_path_m = 30.0;
  /// ... and truth only behind the vehicle neither: bearing from the heading at most
  /// this (the default front mounts at ±40° with ±60° FoV see ±100°).
  double max_bearing_deg = 100.0;
  /// Point landmark classes (truth objects with one position).
  std::set<std::string> point_classes{
      "lamp_pole",  "sign_pole",  "sign_plate",    "traffic_light", "pole",      "guardrail_post",
      "guide_post", "tree_trunk", "facade_recess", "facade_corner", "fence_post"};
  /// Objects the truth gives as one position but that extend around it (the
  /// simulator's parked cars are 4–4.9 m × 1.8 m with centres at the corners; bins
  /// 0.7 m): candidates within this radius (+ the match radius) count as structure.
  std::map<std::string, double> object_radius_m{{"parked_car", 2.6}, {"bin", 0.5}};
  /// Line landmark classes (truth polylines).
  std::set<std::string> line_classes{"curbstone", "road_border",    "wall",
                                     "facade",    "guardrail_beam", "fence_mesh"};
};

struct PointEval {
  std::size_t candidates = 0;
  std::size_t candidates_on_points = 0;     ///< within radius of a point-like truth
  std::size_t candidates_on_structure = 0;  ///< ... or of any present object
  std::size_t truth_observable = 0;
  std::size_t truth_found = 0;
  double precision = 0.0;            ///< candidates_on_points / candidates
  double structure_precision = 0.0;  ///< candidates_on_structure / candidates
  double recall = 0.0;               ///< truth_found / truth_observable
  double rms_error_m = 0.0;          ///< of matched candidates (nearest truth)
  std::size_t class_pairs = 0;       ///< matched with odd/even truth
  std::size_t class_correct = 0;
  double class_accuracy = 0.0;
  /// Per truth class: observable, found.
  std::map<std::string, std::pair<std::size_t, std::size_t>> recall_by_class;
};

struct LineEval {
  std::size_t candidates = 0;
  double candidate_length_m = 0.0;
  double candidate_length_on_truth_m = 0.0;
  double truth_length_m = 0.0;  ///< observable
  double truth_covered_m = 0.0;
  double precision = 0.0;
  double coverage = 0.0;
  /// Per truth class: observable length, covered length.
  std::map<std::string, std::pair<double, double>> coverage_by_class;
};

struct DetectEval {
  PointEval points;
  LineEval lines;
};

/// Evaluates one drive's candidates. trajectory_m: driven positions in the same frame.
DetectEval evaluate_detections(const std::vector<PointCandidate>& points,
                               const std::vector<LineCandidate>& lines, const WorldTruth& truth,
                               int drive_index, const std::vector<Eigen::Vector2d>& trajectory_m,
                               const DetectEvalConfig& cfg = {});

/// Point repeatability between two drives of the same frame (see file comment).
double point_repeatability(const std::vector<PointCandidate>& a,
                           const std::vector<Eigen::Vector2d>& trajectory_a_m,
                           const std::vector<PointCandidate>& b,
                           const std::vector<Eigen::Vector2d>& trajectory_b_m,
                           const DetectEvalConfig& cfg = {});

}  // namespace polmap::eval
