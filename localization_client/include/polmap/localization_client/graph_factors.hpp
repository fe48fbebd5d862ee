#pragma once
/// @file graph_factors.hpp
/// Residual functors of the sliding-window factor graph (paper §III-F,
/// Table II), written in the style of Ceres' pose_graph_2d example: templated
/// on the scalar so ceres::AutoDiffCostFunction can differentiate them, poses
/// as a position block (x_m, y_m) plus a yaw block (yaw_rad, kept normalized by
/// an angle manifold), residuals already whitened by the square-root
/// information. This header has no Ceres dependency: the same functors are
/// evaluated with doubles by the tests (central differences) and with Jets by
/// the solver.
///
/// Frames: a pose block is T_map_vehicle (vehicle = rear-axle centre, x
/// forward, y left). Landmark observations are bearing/range in the VEHICLE
/// frame: candidates come from a gridmap fused over all sensors, so they are
/// no longer tied to one sensor's origin; the paper's σ_φ = 0.03 rad and
/// σ_r = 0.5 m are applied there.
#include <Eigen/Dense>
#include <cmath>
#include <numbers>

namespace polmap::loc {

/// Wraps an angle into [-pi, pi) for doubles and Ceres Jets alike
/// (floor is found by ADL for Jets).
template <typename T>
T normalize_angle(const T& angle_rad) {
  using std::floor;
  const T two_pi(2.0 * std::numbers::pi);
  return angle_rad - two_pi * floor((angle_rad + T(std::numbers::pi)) / two_pi);
}

template <typename T>
Eigen::Matrix<T, 2, 2> rotation_2d(const T& yaw_rad) {
  using std::cos;
  using std::sin;
  const T c = cos(yaw_rad), s = sin(yaw_rad);
  Eigen::Matrix<T, 2, 2> r;
  r << c, -s, s, c;
  return r;
}

/// Odometry between-factor (BetweenFactorPose2). Measurement: T_a_b (vehicle
/// frames of two consecutive poses), from integrated ego-motion.
///   r = sqrt_info * [ R_a^T (p_b - p_a) - t_ab ; normalize(yaw_b - yaw_a - yaw_ab) ]
struct OdometryResidual {
  OdometryResidual(double x_ab_m, double y_ab_m, double yaw_ab_rad,
                   const Eigen::Matrix3d& sqrt_information)
      : t_ab_m(x_ab_m, y_ab_m), yaw_ab_rad(yaw_ab_rad), sqrt_information(sqrt_information) {}

  template <typename T>
  bool operator()(const T* const p_a, const T* const yaw_a, const T* const p_b,
                  const T* const yaw_b, T* residual) const {
    const Eigen::Matrix<T, 2, 1> pa(p_a[0], p_a[1]), pb(p_b[0], p_b[1]);
    Eigen::Matrix<T, 3, 1> e;
    e.template head<2>() = rotation_2d(yaw_a[0]).transpose() * (pb - pa) - t_ab_m.cast<T>();
    e(2) = normalize_angle(yaw_b[0] - yaw_a[0] - T(yaw_ab_rad));
    Eigen::Map<Eigen::Matrix<T, 3, 1>> r(residual);
    r = sqrt_information.cast<T>() * e;
    return true;
  }

  Eigen::Vector2d t_ab_m;
  double yaw_ab_rad;
  Eigen::Matrix3d sqrt_information;
};

/// Bearing-range observation of a 2-D landmark from a pose
/// (BearingRangeFactor2D). Measurement: bearing (vehicle frame, +left) and
/// range of the observed candidate.
///   d = R^T (l - p);  r = [ normalize(atan2(d_y, d_x) - bearing) / σ_φ ; (|d| - range) / σ_r ]
struct BearingRangeResidual {
  BearingRangeResidual(double bearing_rad, double range_m, double sigma_bearing_rad,
                       double sigma_range_m)
      : bearing_rad(bearing_rad),
        range_m(range_m),
        inv_sigma_bearing(1.0 / sigma_bearing_rad),
        inv_sigma_range(1.0 / sigma_range_m) {}

  template <typename T>
  bool operator()(const T* const p, const T* const yaw, const T* const l, T* residual) const {
    using std::atan2;
    using std::sqrt;
    const Eigen::Matrix<T, 2, 1> d =
        rotation_2d(yaw[0]).transpose() * Eigen::Matrix<T, 2, 1>(l[0] - p[0], l[1] - p[1]);
    // sqrt at exactly 0 has an infinite derivative; a landmark at the vehicle
    // origin is impossible for a radar (minimum range), so a tiny floor is safe.
    const T r = sqrt(d.squaredNorm() + T(1e-12));
    residual[0] = normalize_angle(atan2(d.y(), d.x()) - T(bearing_rad)) * T(inv_sigma_bearing);
    residual[1] = (r - T(range_m)) * T(inv_sigma_range);
    return true;
  }

  double bearing_rad;
  double range_m;
  double inv_sigma_bearing;
  double inv_sigma_range;
};

/// Unary prior on a 2-D landmark node (PriorFactorPoint2). Points: isotropic
/// σ = 0.1 m. Line end points: anisotropic, see line_prior_sqrt_information().
///   r = sqrt_info * (l - prior)
struct PointPriorResidual {
  PointPriorResidual(const Eigen::Vector2d& prior_m, const Eigen::Matrix2d& sqrt_information)
      : prior_m(prior_m), sqrt_information(sqrt_information) {}

  template <typename T>
  bool operator()(const T* const l, T* residual) const {
    const Eigen::Matrix<T, 2, 1> e(l[0] - T(prior_m.x()), l[1] - T(prior_m.y()));
    Eigen::Map<Eigen::Matrix<T, 2, 1>> r(residual);
    r = sqrt_information.cast<T>() * e;
    return true;
  }

  Eigen::Vector2d prior_m;
  Eigen::Matrix2d sqrt_information;
};

/// Unary prior on a pose (PriorFactorPose2), used on the last pose when the
/// window is under-constrained and to anchor the first pose after
/// initialization.   r = sqrt_info * [ p - p0 ; normalize(yaw - yaw0) ]
struct PosePriorResidual {
  PosePriorResidual(double x_m, double y_m, double yaw_rad, const Eigen::Matrix3d& sqrt_information)
      : p0_m(x_m, y_m), yaw0_rad(yaw_rad), sqrt_information(sqrt_information) {}

  template <typename T>
  bool operator()(const T* const p, const T* const yaw, T* residual) const {
    Eigen::Matrix<T, 3, 1> e;
    e(0) = p[0] - T(p0_m.x());
    e(1) = p[1] - T(p0_m.y());
    e(2) = normalize_angle(yaw[0] - T(yaw0_rad));
    Eigen::Map<Eigen::Matrix<T, 3, 1>> r(residual);
    r = sqrt_information.cast<T>() * e;
    return true;
  }

  Eigen::Vector2d p0_m;
  double yaw0_rad;
  Eigen::Matrix3d sqrt_information;
};

/// Square-root information of the line end-point prior (paper Table II):
/// Ω = (U diag((10σ)², σ²) Uᵀ)⁻¹ with U = [along, across]; the square root
/// returned is diag(1/(along_factor σ), 1/σ) Uᵀ, so the residual's first
/// component is the along-line error and the second the across-line error.
inline Eigen::Matrix2d line_prior_sqrt_information(const Eigen::Vector2d& along_unit,
                                                   double sigma_m, double along_factor = 10.0) {
  Eigen::Matrix2d ut;
  ut.row(0) = along_unit.transpose() / (along_factor * sigma_m);
  ut.row(1) = Eigen::Vector2d(-along_unit.y(), along_unit.x()).transpose() / sigma_m;
  return ut;
}

/// Square root of a symmetric positive-definite information matrix such that
/// Sᵀ S = Ω (upper Cholesky factor), used for covariance-given priors.
inline Eigen::Matrix3d sqrt_information_from_covariance(const Eigen::Matrix3d& covariance) {
  const Eigen::Matrix3d info = covariance.inverse();
  const Eigen::Matrix3d l = info.llt().matrixL();
  return l.transpose();
}

}  // namespace polmap::loc
