#include "polmap/sim/scattering.hpp"

#include <cmath>

namespace polmap::sim {

namespace {
constexpr cdouble kJ{0.0, 1.0};
}

ScatteringVector lr_from_linear(cdouble s_hh, cdouble s_hv, cdouble s_vv) {
  const cdouble ll = (s_hh - s_vv + 2.0 * kJ * s_hv) / 2.0;
  const cdouble rr = (s_vv - s_hh + 2.0 * kJ * s_hv) / 2.0;
  const cdouble lr = kJ * (s_hh + s_vv) / 2.0;
  return {ll, lr, lr, rr};
}

std::array<cdouble, 3> linear_from_lr(const ScatteringVector& o) {
  const cdouble ll = o[0], rr = o[3];
  const cdouble lr = 0.5 * (o[1] + o[2]);
  // LL - RR = HH - VV; LL + RR = 2j HV; LR = j(HH + VV)/2 -> HH + VV = -2j LR.
  const cdouble sum = -2.0 * kJ * lr;
  const cdouble diff = ll - rr;
  const cdouble hv = (ll + rr) / (2.0 * kJ);
  return {(sum + diff) / 2.0, hv, (sum - diff) / 2.0};
}

ScatteringVector odd_bounce() { return lr_from_linear(1.0, 0.0, 1.0); }

ScatteringVector dihedral(double theta_rad) {
  const double c = std::cos(2.0 * theta_rad), s = std::sin(2.0 * theta_rad);
  return lr_from_linear(c, s, -c);
}

double half_span(const ScatteringVector& o) {
  return 0.5 * (std::norm(o[0]) + std::norm(o[1]) + std::norm(o[2]) + std::norm(o[3]));
}

ScatteringVector normalized(const ScatteringVector& o) {
  const double h = half_span(o);
  if (h <= 0) return o;
  const double k = 1.0 / std::sqrt(h);
  return {o[0] * k, o[1] * k, o[2] * k, o[3] * k};
}

std::array<double, 4> DistributedModel::channel_power() const {
  // E|LL|^2 = E|HH - VV + 2j HV|^2 / 4 (HV uncorrelated), E|LR|^2 = E|HH + VV|^2 / 4.
  const double cross = 2.0 * std::real(rho_hh_vv) * std::sqrt(var_hh * var_vv);
  const double ll = (var_hh + var_vv - cross + 4.0 * var_hv) / 4.0;
  const double lr = (var_hh + var_vv + cross) / 4.0;
  const double norm = 0.5 * (var_hh + var_vv + 2.0 * var_hv);  // E[half_span]
  return {ll / norm, lr / norm, lr / norm, ll / norm};
}

}  // namespace polmap::sim
