#include "polmap/radar/polarimetry.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

#include "polmap/schema/errors.hpp"

namespace polmap::radar {
namespace {
constexpr double kInvSqrt2 = 0.70710678118654752440;
const cdouble kJ{0.0, 1.0};
}  // namespace

Eigen::VectorXcd level_vector(const ScatteringVector& omega, PolLevel level) {
  const cdouble ll = omega[0], lr = omega[1], rl = omega[2], rr = omega[3];
  Eigen::VectorXcd k(pol_dimension(level));
  switch (level) {
    case PolLevel::Full:
      k << ll, (lr + rl) * kInvSqrt2, rr;
      break;
    case PolLevel::DualLLLR:
      k << ll, lr;
      break;
    case PolLevel::DualHHVV:
      // HH = (LL − RR − j(LR+RL))/2, VV = (RR − LL − j(LR+RL))/2 (both reciprocal parts).
      k << 0.5 * (ll - rr - kJ * (lr + rl)), 0.5 * (rr - ll - kJ * (lr + rl));
      break;
    case PolLevel::SingleLR:
      k << lr;
      break;
    case PolLevel::SingleRR:
      k << rr;
      break;
    case PolLevel::SingleHH:
      k << 0.5 * (ll - rr - kJ * (lr + rl));
      break;
  }
  return k;
}

void level_vector(const std::array<cfloat, 4>& s, PolLevel level, cfloat* out) {
  const cfloat ll = s[0], lr = s[1], rl = s[2], rr = s[3];
  const cfloat j{0.0F, 1.0F};
  switch (level) {
    case PolLevel::Full:
      out[0] = ll;
      out[1] = (lr + rl) * static_cast<float>(kInvSqrt2);
      out[2] = rr;
      return;
    case PolLevel::DualLLLR:
      out[0] = ll;
      out[1] = lr;
      return;
    case PolLevel::DualHHVV:
      out[0] = 0.5F * (ll - rr - j * (lr + rl));
      out[1] = 0.5F * (rr - ll - j * (lr + rl));
      return;
    case PolLevel::SingleLR:
      out[0] = lr;
      return;
    case PolLevel::SingleRR:
      out[0] = rr;
      return;
    case PolLevel::SingleHH:
      out[0] = 0.5F * (ll - rr - j * (lr + rl));
      return;
  }
}

LinearScattering hv_from_lr(const ScatteringVector& o) {
  const cdouble ll = o[0], lr = 0.5 * (o[1] + o[2]), rr = o[3];
  return {0.5 * (ll - rr - 2.0 * kJ * lr), -0.5 * kJ * (ll + rr), 0.5 * (rr - ll - 2.0 * kJ * lr)};
}

ScatteringVector lr_from_hv(const LinearScattering& s) {
  const cdouble lr = 0.5 * kJ * (s.hh + s.vv);
  return {0.5 * (s.hh - s.vv + 2.0 * kJ * s.hv), lr, lr, 0.5 * (s.vv - s.hh + 2.0 * kJ * s.hv)};
}

Eigen::Matrix3cd pauli_lr_from_hv() {
  // Rows: S_LL, √2 S_LR, S_RR; columns: S_HH, √2 S_HV, S_VV (see header).
  Eigen::Matrix3cd u;
  u << 0.5, kJ * kInvSqrt2, -0.5,           //
      kJ * kInvSqrt2, 0.0, kJ * kInvSqrt2,  //
      -0.5, kJ * kInvSqrt2, 0.5;
  return u;
}

Eigen::Matrix3cd pauli_hv_from_lr() { return pauli_lr_from_hv().adjoint(); }

Eigen::MatrixXcd transform_covariance(const Eigen::MatrixXcd& c, const Eigen::MatrixXcd& a) {
  POLMAP_EXPECT(c.rows() == c.cols() && a.cols() == c.rows());
  return a * c * a.adjoint();
}

Eigen::MatrixXcd level_projection(PolLevel level) {
  const Eigen::Matrix3cd hv = pauli_hv_from_lr();  // rows HH, √2 HV, VV
  Eigen::MatrixXcd p = Eigen::MatrixXcd::Zero(pol_dimension(level), 3);
  switch (level) {
    case PolLevel::Full:
      p = Eigen::Matrix3cd::Identity();
      break;
    case PolLevel::DualLLLR:
      p(0, 0) = 1.0;
      p(1, 1) = kInvSqrt2;
      break;
    case PolLevel::DualHHVV:
      p.row(0) = hv.row(0);
      p.row(1) = hv.row(2);
      break;
    case PolLevel::SingleLR:
      p(0, 1) = kInvSqrt2;
      break;
    case PolLevel::SingleRR:
      p(0, 2) = 1.0;
      break;
    case PolLevel::SingleHH:
      p.row(0) = hv.row(0);
      break;
  }
  return p;
}

MechanismPowers mechanism_powers(const Eigen::MatrixXcd& c, PolLevel level, double noise_power) {
  POLMAP_EXPECT(c.rows() == pol_dimension(level) && c.cols() == c.rows());
  auto diag = [&](int i) { return std::max(0.0, c(i, i).real() - noise_power); };
  MechanismPowers p;
  switch (level) {
    case PolLevel::Full:
      p.odd = diag(1);
      p.even = diag(0) + diag(2);
      break;
    case PolLevel::DualLLLR:
      p.odd = diag(1);
      p.even = diag(0);
      break;
    case PolLevel::DualHHVV: {
      const double hh = diag(0), vv = diag(1);
      // Cross term of the noise-free part: noise is uncorrelated between channels.
      const double cross = c(0, 1).real();
      p.odd = std::max(0.0, 0.5 * (hh + vv + 2.0 * cross));
      p.even = std::max(0.0, 0.5 * (hh + vv - 2.0 * cross));
      break;
    }
    default:
      break;
  }
  return p;
}

ScatteringClass classify_scattering(const Eigen::MatrixXcd& c, PolLevel level,
                                    const ScatteringClassConfig& cfg, double noise_power) {
  if (pol_dimension(level) < 2) return ScatteringClass::Unknown;
  const MechanismPowers p = mechanism_powers(c, level, noise_power);
  if (!(p.odd + p.even > 0.0)) return ScatteringClass::Unknown;
  const double dominance = std::pow(10.0, cfg.dominance_db / 10.0);
  if (p.odd >= dominance * p.even) return ScatteringClass::Odd;
  if (p.even >= dominance * p.odd) return ScatteringClass::Even;
  return ScatteringClass::Mixed;
}

}  // namespace polmap::radar
