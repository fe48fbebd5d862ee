#pragma once
/// @file map_geometry.hpp
/// A map's point landmarks against the world's truth: the absolute offset, and the
/// relative geometry as maps from consumer-grade GNSS are judged (RMS landmark error after
/// the best rigid fit to truth within each window of the map, so a map that is shifted or
/// slightly rotated as a whole is not penalised there). Each window is matched afresh from
/// the global fit, and the share of its landmarks that find truth is reported next to the
/// RMS: a section that broke apart shows as a low share instead of dropping out of the RMS.
#include <Eigen/Core>
#include <optional>
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
  /// Windows with fewer near landmarks (MapWindowFit) are left out of the window figures.
  int min_window_landmarks = 5;
  /// Each window's own start: the mode of truth - (global fit of map) within this radius,
  /// so a window that the global fit leaves metres off (a bent map, or a global fit that
  /// followed one section) is still fitted on its own.
  double window_vote_radius_m = 6.0;
  /// The window fit's gates after its vote (which starts it within a vote cell or two): a
  /// window whose landmarks split into two offsets is fitted to one of them, not averaged
  /// between them and then lost.
  std::vector<double> window_gates_m = {0.5, 0.3};
};

/// One window of the map fitted to truth on its own.
struct MapWindowFit {
  long ix = 0, iy = 0;  ///< grid index: the window covers [ix, ix + 1) * window_m in x (map frame)
  int landmarks = 0;    ///< map point landmarks in the window
  /// Of them within the first (widest) gate of truth after the window fit: the landmarks
  /// that belong to a real object. Ghosts and clutter, metres from any object, are not
  /// counted, so share() measures geometry, not the map's precision.
  int near = 0;
  int matched = 0;       ///< of them matched to truth within the last gate of the window fit
  double rms_m = 0.0;    ///< RMS of the matched pairs after the window's rigid fit
  double yaw_rad = 0.0;  ///< the window fit's rotation relative to the global fit
  double shift_m = 0.0;  ///< the window fit's displacement of the window centre vs. the global fit
  /// The window's own fit: truth ~ R map + t.
  Eigen::Matrix2d R_truth_map = Eigen::Matrix2d::Identity();
  Eigen::Vector2d t_truth_map_m = Eigen::Vector2d::Zero();
  [[nodiscard]] double share() const {
    return near > 0 ? static_cast<double>(matched) / near : 0.0;
  }
};

/// A map landmark and the truth object it was matched to.
struct MapTruthPair {
  Eigen::Vector2d map_m = Eigen::Vector2d::Zero();
  Eigen::Vector2d truth_m = Eigen::Vector2d::Zero();
};

/// A rigid transform truth ~ R map + t and the pairs it was fitted to.
struct RigidFit2 {
  Eigen::Matrix2d R_truth_map = Eigen::Matrix2d::Identity();
  Eigen::Vector2d t_truth_map_m = Eigen::Vector2d::Zero();
  int pairs = 0;
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
  double window_rms_m = 0.0;  ///< after a rigid fit per window, over the windows' own matches
  int windows = 0;            ///< windows with at least min_window_landmarks near landmarks
  /// Matched landmarks / near landmarks (MapWindowFit), pooled over those windows: the share
  /// of the map's real landmarks that sit within the last gate of truth after their
  /// window's fit.
  double window_matched_share = 0.0;
  double worst_window_share = 0.0;  ///< the lowest share of a single window
  /// The largest displacement of a window's own fit against the whole map's (at the window
  /// centre): how far the map bends between its sections. The whole-map figures count only
  /// the landmarks within the last gate, so a section a metre off drops out of them, but a
  /// vehicle localizing there is a metre off in the map's frame.
  double max_window_shift_m = 0.0;
  /// Windows with min_window_landmarks landmarks but fewer near ones: clutter and ghosts
  /// only, or a section so broken that its own fit finds no real object within a metre.
  int windows_unfitted = 0;
  std::vector<MapWindowFit> window_fits;  ///< those windows, in grid order
  /// Every fitted window's final matches (its own vote and gates): correspondences that
  /// hold in a bent map too, for local fits (local_rigid_fit).
  std::vector<MapTruthPair> window_pairs;
};

/// Least-squares rigid transform truth ~ R map + t of the pairs (closed form in 2-D).
/// Expects at least two pairs.
RigidFit2 fit_rigid(std::span<const MapTruthPair> pairs);

/// The map's own frame around a place: the rigid fit of the pairs whose truth object lies
/// in the square of edge window_m centred at centre_m (truth frame), as the map geometry's
/// windows are judged, but centred where it is asked. A vehicle localizing there sees the
/// map's local frame: a section shifted by a bend of the map is that section's frame.
/// Nullopt with fewer than min_pairs pairs.
std::optional<RigidFit2> local_rigid_fit(std::span<const MapTruthPair> pairs,
                                         const Eigen::Vector2d& centre_m, double window_m,
                                         int min_pairs);

/// Matches the map's points to truth (voted start, then nearest neighbours within
/// shrinking gates, refitting each round) and measures the figures above.
MapGeometry map_geometry(std::span<const Eigen::Vector2d> map_m,
                         std::span<const Eigen::Vector2d> truth_m,
                         const MapGeometryConfig& cfg = {});

}  // namespace polmap::eval
