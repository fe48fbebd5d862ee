// Factor residuals: zero at the true state, and Ceres' automatic Jacobians
// equal central differences of the same residual functions evaluated in double.
#include "polmap/localization_client/graph_factors.hpp"

#include <ceres/ceres.h>
#include <gtest/gtest.h>

#include <random>

namespace polmap::loc {
namespace {

/// Compares the autodiff Jacobians of cost with central differences of
/// residual_fn (the functor called with doubles) at the given blocks.
template <class Functor>
void expect_jacobians_match(const Functor& f, ceres::CostFunction& cost,
                            std::vector<std::vector<double>> blocks, double tol) {
  const int nres = cost.num_residuals();
  const auto& sizes = cost.parameter_block_sizes();
  ASSERT_EQ(sizes.size(), blocks.size());
  std::vector<double*> params;
  for (auto& b : blocks) params.push_back(b.data());
  std::vector<std::vector<double>> jac(blocks.size());
  std::vector<double*> jac_ptrs;
  for (std::size_t i = 0; i < blocks.size(); ++i) {
    jac[i].resize(nres * sizes[i]);
    jac_ptrs.push_back(jac[i].data());
  }
  std::vector<double> r(nres);
  ASSERT_TRUE(cost.Evaluate(params.data(), r.data(), jac_ptrs.data()));

  auto eval = [&](std::vector<double>& out) {
    out.resize(nres);
    if constexpr (requires { f(params[0], params[1], params[2], params[3], out.data()); }) {
      f(params[0], params[1], params[2], params[3], out.data());
    } else if constexpr (requires { f(params[0], params[1], params[2], out.data()); }) {
      f(params[0], params[1], params[2], out.data());
    } else if constexpr (requires { f(params[0], params[1], out.data()); }) {
      f(params[0], params[1], out.data());
    } else {
      f(params[0], out.data());
    }
  };
  std::vector<double> r0;
  eval(r0);
  for (int k = 0; k < nres; ++k) EXPECT_NEAR(r0[k], r[k], 1e-12) << "residual " << k;
  const double h = 1e-6;
  for (std::size_t b = 0; b < blocks.size(); ++b) {
    for (int j = 0; j < sizes[b]; ++j) {
      const double x0 = blocks[b][j];
      std::vector<double> rp, rm;
      blocks[b][j] = x0 + h;
      eval(rp);
      blocks[b][j] = x0 - h;
      eval(rm);
      blocks[b][j] = x0;
      for (int k = 0; k < nres; ++k) {
        const double numeric = (rp[k] - rm[k]) / (2.0 * h);
        // Ceres Jacobians are row-major: residual k, parameter j.
        EXPECT_NEAR(jac[b][k * sizes[b] + j], numeric, tol * (1.0 + std::abs(numeric)))
            << "block " << b << " param " << j << " residual " << k;
      }
    }
  }
}

class FactorTest : public ::testing::Test {
 protected:
  std::mt19937 rng{42};
  double uni(double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng); }
};

TEST_F(FactorTest, OdometryZeroAtTruthAndJacobians) {
  for (int trial = 0; trial < 20; ++trial) {
    std::vector<double> pa{uni(-50, 50), uni(-50, 50)}, ya{uni(-3.0, 3.0)};
    // Truth: b = a * delta.
    const double dx = uni(-3, 3), dy = uni(-1, 1), dyaw = uni(-0.3, 0.3);
    const Eigen::Vector2d pb =
        Eigen::Vector2d(pa[0], pa[1]) + rotation_2d(ya[0]) * Eigen::Vector2d(dx, dy);
    std::vector<double> pbv{pb.x(), pb.y()}, yb{normalize_angle(ya[0] + dyaw)};
    Eigen::Matrix3d sqrt_info = Eigen::Vector3d(20.0, 20.0, 100.0).asDiagonal();
    OdometryResidual f(dx, dy, dyaw, sqrt_info);
    double r[3];
    f(pa.data(), ya.data(), pbv.data(), yb.data(), r);
    for (double v : r) EXPECT_NEAR(v, 0.0, 1e-9);
    // Jacobians away from the truth.
    pa[0] += uni(-1, 1);
    yb[0] += uni(-0.2, 0.2);
    ceres::AutoDiffCostFunction<OdometryResidual, 3, 2, 1, 2, 1> cost(new OdometryResidual(f));
    expect_jacobians_match(f, cost, {pa, ya, pbv, yb}, 1e-6);
  }
}

TEST_F(FactorTest, OdometryWrapsAngleAcrossPi) {
  // yaw_a = pi - 0.01, yaw_b = -pi + 0.01: the true difference is +0.02.
  const double pa[2] = {0, 0}, ya[1] = {std::numbers::pi - 0.01};
  const double pb[2] = {0, 0}, yb[1] = {-std::numbers::pi + 0.01};
  OdometryResidual f(0.0, 0.0, 0.02, Eigen::Matrix3d::Identity());
  double r[3];
  f(pa, ya, pb, yb, r);
  EXPECT_NEAR(r[2], 0.0, 1e-12);
}

TEST_F(FactorTest, BearingRangeZeroAtTruthAndJacobians) {
  for (int trial = 0; trial < 20; ++trial) {
    std::vector<double> p{uni(-50, 50), uni(-50, 50)}, yaw{uni(-3.1, 3.1)};
    const double bearing = uni(-1.2, 1.2), range = uni(2.0, 70.0);
    const Eigen::Vector2d l =
        Eigen::Vector2d(p[0], p[1]) +
        rotation_2d(yaw[0]) * (range * Eigen::Vector2d(std::cos(bearing), std::sin(bearing)));
    std::vector<double> lv{l.x(), l.y()};
    BearingRangeResidual f(bearing, range, 0.03, 0.5);
    double r[2];
    f(p.data(), yaw.data(), lv.data(), r);
    EXPECT_NEAR(r[0], 0.0, 1e-9);
    EXPECT_NEAR(r[1], 0.0, 1e-9);
    lv[0] += uni(-2, 2);
    yaw[0] += uni(-0.1, 0.1);
    ceres::AutoDiffCostFunction<BearingRangeResidual, 2, 2, 1, 2> cost(new BearingRangeResidual(f));
    expect_jacobians_match(f, cost, {p, yaw, lv}, 1e-6);
  }
}

TEST_F(FactorTest, BearingResidualWrapsBehindTheVehicle) {
  // Observed bearing pi - 0.01, predicted -pi + 0.01 -> residual +0.02 / sigma.
  const double p[2] = {0, 0}, yaw[1] = {0};
  const double l[2] = {-10.0 * std::cos(0.01), -10.0 * std::sin(0.01)};
  BearingRangeResidual f(std::numbers::pi - 0.01, 10.0, 0.01, 1.0);
  double r[2];
  f(p, yaw, l, r);
  EXPECT_NEAR(r[0], 2.0, 1e-6);
}

TEST_F(FactorTest, PointPriorAndLinePrior) {
  const Eigen::Vector2d prior(3.0, -4.0);
  PointPriorResidual f(prior, Eigen::Matrix2d::Identity() / 0.1);
  std::vector<double> l{3.0, -4.0};
  double r[2];
  f(l.data(), r);
  EXPECT_NEAR(r[0], 0.0, 1e-12);
  EXPECT_NEAR(r[1], 0.0, 1e-12);
  l = {3.5, -3.2};
  ceres::AutoDiffCostFunction<PointPriorResidual, 2, 2> cost(new PointPriorResidual(f));
  expect_jacobians_match(f, cost, {l}, 1e-7);

  // Line prior: information strong across the line, weak (10 sigma) along it.
  const Eigen::Vector2d along = Eigen::Vector2d(1.0, 1.0).normalized();
  const Eigen::Matrix2d S = line_prior_sqrt_information(along, 0.1, 10.0);
  const Eigen::Matrix2d info = S.transpose() * S;
  const Eigen::Matrix2d cov = info.inverse();
  EXPECT_NEAR(along.dot(cov * along), 1.0, 1e-12);  // (10 * 0.1)^2
  const Eigen::Vector2d across(-along.y(), along.x());
  EXPECT_NEAR(across.dot(cov * across), 0.01, 1e-12);
  PointPriorResidual g(prior, S);
  const Eigen::Vector2d moved_along = prior + 0.5 * along, moved_across = prior + 0.5 * across;
  double ra[2], rc[2];
  g(moved_along.data(), ra);
  g(moved_across.data(), rc);
  EXPECT_NEAR(Eigen::Vector2d(ra[0], ra[1]).norm(), 0.5, 1e-12);
  EXPECT_NEAR(Eigen::Vector2d(rc[0], rc[1]).norm(), 5.0, 1e-12);
}

TEST_F(FactorTest, PosePriorZeroAtTruthAndJacobians) {
  Eigen::Matrix3d cov;
  cov << 0.04, 0.01, 0.0, 0.01, 0.09, 0.001, 0.0, 0.001, 0.0004;
  const Eigen::Matrix3d S = sqrt_information_from_covariance(cov);
  EXPECT_TRUE((S.transpose() * S).isApprox(cov.inverse(), 1e-9));
  PosePriorResidual f(10.0, -2.0, 3.1, S);
  std::vector<double> p{10.0, -2.0}, yaw{3.1};
  double r[3];
  f(p.data(), yaw.data(), r);
  for (double v : r) EXPECT_NEAR(v, 0.0, 1e-12);
  p = {10.3, -2.2};
  yaw = {3.0};
  ceres::AutoDiffCostFunction<PosePriorResidual, 3, 2, 1> cost(new PosePriorResidual(f));
  expect_jacobians_match(f, cost, {p, yaw}, 1e-6);
}

}  // namespace
}  // namespace polmap::loc
