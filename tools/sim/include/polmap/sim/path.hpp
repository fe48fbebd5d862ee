#pragma once
/// @file path.hpp
/// A planar path sampled uniformly in arc length (world frame, metres): the
/// route of a world and the exact path of one drive.
#include <Eigen/Core>
#include <functional>
#include <vector>

namespace polmap::sim {

struct PathPoint {
  double s_m = 0.0;
  double x_m = 0.0;
  double y_m = 0.0;
  double yaw_rad = 0.0;    ///< frame yaw of the tangent (x east, y north, CCW from x)
  double kappa_1pm = 0.0;  ///< curvature, positive = left turn
};

class Path {
 public:
  Path() = default;
  /// Integrates heading and position from a curvature profile kappa(s), s in [0, length].
  static Path from_curvature(const Eigen::Vector2d& start, double yaw0_rad, double length_m,
                             const std::function<double(double)>& kappa_of_s, double step_m = 0.1);
  /// Resamples a polyline at step_m; heading and curvature from a smoothed tangent
  /// (smoothing window smooth_m), so corners of the input become short arcs.
  static Path from_polyline(const std::vector<Eigen::Vector2d>& pts, double step_m = 0.1,
                            double smooth_m = 4.0);

  [[nodiscard]] double length_m() const { return pts_.empty() ? 0.0 : pts_.back().s_m; }
  [[nodiscard]] bool empty() const { return pts_.size() < 2; }
  [[nodiscard]] double step_m() const { return step_; }
  [[nodiscard]] const std::vector<PathPoint>& points() const { return pts_; }
  /// Pose at station s (clamped to the path), linearly interpolated.
  [[nodiscard]] PathPoint at(double s_m) const;
  /// Point at station s shifted by lateral_m to the left of the tangent.
  [[nodiscard]] Eigen::Vector2d offset_point(double s_m, double lateral_m) const;
  /// Polyline parallel to the path over [s0, s1] at lateral_m (left positive), vertices
  /// every max_step_m (closer on curves).
  [[nodiscard]] std::vector<Eigen::Vector2d> offset_polyline(double s0_m, double s1_m,
                                                             double lateral_m,
                                                             double max_step_m = 4.0) const;
  /// A new path displaced laterally by d(s) (lane wander), re-parameterised by arc length.
  [[nodiscard]] Path displaced(const std::function<double(double)>& lateral_of_s) const;
  /// Station of the point of the path nearest to p (coarse search over samples).
  [[nodiscard]] double project(const Eigen::Vector2d& p) const;

 private:
  double step_ = 0.1;
  std::vector<PathPoint> pts_;
};

}  // namespace polmap::sim
