#pragma once
/// @file scattering.hpp
/// Polarimetric scattering vectors in the LR circular basis, the same convention
/// as radar/polarimetry.hpp: Omega = (S_LL, S_LR, S_RL, S_RR) with
///   S_LL = (S_HH - S_VV + 2j S_HV) / 2,
///   S_RR = (S_VV - S_HH + 2j S_HV) / 2,
///   S_LR = S_RL = j (S_HH + S_VV) / 2.
/// Normalisation: span/2 = (|S_LL|^2+|S_LR|^2+|S_RL|^2+|S_RR|^2)/2 = 1, so the dominant
/// channel of a pure odd or even scatterer carries exactly the target's RCS.
#include <algorithm>
#include <cmath>
#include <complex>

#include "polmap/schema/polarimetry.hpp"
#include "polmap/sim/random.hpp"

namespace polmap::sim {

/// LR-basis vector of a linear-basis scattering matrix.
ScatteringVector lr_from_linear(cdouble s_hh, cdouble s_hv, cdouble s_vv);
/// (S_HH, S_HV, S_VV) of an LR-basis vector (inverse of lr_from_linear; uses (LR+RL)/2).
std::array<cdouble, 3> linear_from_lr(const ScatteringVector& omega);

/// Odd bounce (sphere, pole, plate): S_HH = S_VV = 1 -> (0, j, j, 0).
ScatteringVector odd_bounce();
/// Dihedral with fold orientation theta: S_HH = cos 2θ, S_VV = -cos 2θ, S_HV = sin 2θ
/// -> (e^{j2θ}, 0, 0, -e^{-j2θ}).
ScatteringVector dihedral(double theta_rad);
/// (|LL|^2 + |LR|^2 + |RL|^2 + |RR|^2) / 2.
double half_span(const ScatteringVector& omega);
/// omega scaled to half_span = 1 (zero stays zero).
ScatteringVector normalized(const ScatteringVector& omega);

/// Reflection-symmetric distributed scatterer in the linear basis: S_HH, S_VV
/// correlated with coefficient rho_hh_vv, S_HV uncorrelated with both. Samples
/// are complex Gaussian vectors with E[half_span] = 1.
struct DistributedModel {
  double var_hh = 1.0;
  double var_vv = 1.0;
  cdouble rho_hh_vv{0.0, 0.0};
  double var_hv = 0.0;

  /// Cloud of random dipoles (vegetation, fence mesh): diagonal LR covariance, equal powers.
  static DistributedModel volume() { return {1.0, 1.0, {1.0 / 3.0, 0.0}, 1.0 / 3.0}; }
  /// Rough surface (ground, diffuse facade): odd dominant (LR/RL), weak LL/RR.
  static DistributedModel surface() { return {1.0, 1.4, {0.85, 0.0}, 0.02}; }
  /// Mixed odd/even centres (guardrail beams, car bodies): all channels comparable.
  static DistributedModel mixed() { return {1.0, 1.0, {0.0, 0.0}, 0.15}; }

  /// Expected |S_c|^2 per LR channel for half_span normalised to 1.
  [[nodiscard]] std::array<double, 4> channel_power() const;
  /// One sample with E[half_span] = 1 (any generator with cnormal(): Rng, HashRng).
  template <typename Gen>
  ScatteringVector sample(Gen& rng) const {
    const double norm = 0.5 * (var_hh + var_vv + 2.0 * var_hv);
    const double k = 1.0 / std::sqrt(norm);
    const cdouble z1 = rng.cnormal(), z2 = rng.cnormal(), z3 = rng.cnormal();
    const double r = std::min(1.0, std::abs(rho_hh_vv));
    const cdouble hh = std::sqrt(var_hh) * z1;
    const cdouble vv = std::sqrt(var_vv) * (rho_hh_vv * z1 + std::sqrt(1.0 - r * r) * z2);
    const cdouble hv = std::sqrt(var_hv) * z3;
    return lr_from_linear(hh * k, hv * k, vv * k);
  }
};

}  // namespace polmap::sim
