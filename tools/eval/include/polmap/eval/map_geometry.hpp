#pragma once
/// @file map_geometry.hpp
/// A map's point landmarks against the world's truth: the absolute offset, and the
/// relative geometry as maps from consumer-grade GNSS are judged (RMS landmark error after
/// the best rigid fit to truth within each window of the map, so a map that is shifted or
/// slightly rotated as a whole is not penalised there).
#include <Eigen/Core>
#include <span>
#include <vector>

#include "polmap/sim/world.hpp"

namespace polmap::eval {

/// The world's permanent point objects (poles, posts, signs, trunks, facade corners and
/// recesses, fence posts): what a point landmark should sit on.
std::vector<Eigen::Vector2d> truth_point_objects(const sim::World& world);

struct MapGeometryConfig {
  /// Windows are squares of this edge on the map frame's grid.
  double window_m = 200.0;
  /// Coarse start: the mode of the displacements truth - map within this radius.
  double vote_radius_m = 6.0;
  double vote_cell_m = 0.25;
  /// Nearest-truth matching gates of the rigid-fit rounds (coarse to fine).
  std::vector<double> gates_m = {1.0, 0.5, 0.3};
  /// Windows with fewer matches are left out of window_rms_m.
  int min_window_matches = 5;
};

struct MapGeometry {
  enum class Status { Ok, TooFewMatches };
  Status status = Status::TooFewMatches;
  int matched = 0;  ///< landmarks matched to truth in the final round
  /// The rigid fit over the whole map: truth ~ R map + t.
  Eigen::Matrix2d R_truth_map = Eigen::Matrix2d::Identity();
  Eigen::Vector2d t_truth_map_m = Eigen::Vector2d::Zero();
  double yaw_truth_map_rad = 0.0;
  /// |mean(truth - map)| over the matched landmarks: the absolute offset of the map.
  double offset_m = 0.0;
  double raw_rms_m = 0.0;     ///< RMS of truth - map (no fit)
  double global_rms_m = 0.0;  ///< after the one rigid fit
  double window_rms_m = 0.0;  ///< after a rigid fit per window
  int windows = 0;            ///< windows with at least min_window_matches matches
};

/// Matches the map's points to truth (voted start, then nearest neighbours within
/// shrinking gates, refitting each round) and measures the figures above.
MapGeometry map_geometry(std::span<const Eigen::Vector2d> map_m,
                         std::span<const Eigen::Vector2d> truth_m,
                         const MapGeometryConfig& cfg = {});

}  // namespace polmap::eval
