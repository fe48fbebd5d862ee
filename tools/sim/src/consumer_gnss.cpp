#include "polmap/sim/consumer_gnss.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

#include "polmap/sim/random.hpp"
#include "polmap/sim/world.hpp"

namespace polmap::sim {

namespace {

// A standard normal pair from a lattice node's hash (Box-Muller on two hashed uniforms).
Eigen::Vector2d node_normal(std::uint64_t seed, std::int64_t ix, std::int64_t iy) {
  const std::uint64_t h =
      seed_of(seed, static_cast<std::uint64_t>(ix), static_cast<std::uint64_t>(iy));
  const double u1 = std::max(hash_uniform(h), 1e-300);
  const double u2 = hash_uniform(h ^ 0x5bd1e995ULL);
  const double r = std::sqrt(-2.0 * std::log(u1));
  const double a = 2.0 * std::numbers::pi * u2;
  return {r * std::cos(a), r * std::sin(a)};
}

bool is_building(ObjectClass c) {
  return c == ObjectClass::Facade || c == ObjectClass::FacadeRecess ||
         c == ObjectClass::FacadeCorner || c == ObjectClass::Wall;
}

}  // namespace

CanyonMultipathField::CanyonMultipathField(const World& world, const ConsumerGnssConfig& cfg,
                                           std::uint64_t seed)
    : world_(world), cfg_(cfg), seed_(seed_of(seed, 0x6d756c7469ULL)) {}

Eigen::Vector2d CanyonMultipathField::unit_field(const Eigen::Vector2d& p_m) const {
  const double L = std::max(cfg_.multipath_correlation_m, 1.0);
  const double gx = p_m.x() / L, gy = p_m.y() / L;
  const double fx = std::floor(gx), fy = std::floor(gy);
  const auto ix = static_cast<std::int64_t>(fx), iy = static_cast<std::int64_t>(fy);
  auto smooth = [](double t) { return t * t * (3.0 - 2.0 * t); };
  const double wx = smooth(gx - fx), wy = smooth(gy - fy);
  const double w[4] = {(1 - wx) * (1 - wy), wx * (1 - wy), (1 - wx) * wy, wx * wy};
  const Eigen::Vector2d n[4] = {node_normal(seed_, ix, iy), node_normal(seed_, ix + 1, iy),
                                node_normal(seed_, ix, iy + 1), node_normal(seed_, ix + 1, iy + 1)};
  Eigen::Vector2d v = Eigen::Vector2d::Zero();
  double w2 = 0.0;
  for (int k = 0; k < 4; ++k) {
    v += w[k] * n[k];
    w2 += w[k] * w[k];
  }
  // Independent unit-variance nodes: the weighted sum has variance sum w^2; rescale so the
  // field has unit variance everywhere, not only at the nodes.
  return v / std::sqrt(w2);
}

double CanyonMultipathField::canyon_factor(const Eigen::Vector2d& p_m, double yaw_rad) const {
  std::vector<std::uint32_t> pts, lines, occ;
  world_.query(p_m, cfg_.canyon_radius_m, pts, lines, occ);
  const Eigen::Vector2d heading(std::cos(yaw_rad), std::sin(yaw_rad));
  double left_m = 0.0, right_m = 0.0;
  for (const std::uint32_t i : lines) {
    const LineScatterer& l = world_.lines[i];
    if (l.object >= world_.objects.size() || !is_building(world_.objects[l.object].cls)) continue;
    const Eigen::Vector2d d = l.p1_m - l.p0_m;
    const double len = d.norm();
    if (len <= 0.0) continue;
    const double t = std::clamp((p_m - l.p0_m).dot(d) / (len * len), 0.0, 1.0);
    const Eigen::Vector2d q = l.p0_m + t * d - p_m;
    const double r = q.norm() / std::max(cfg_.canyon_radius_m, 1e-6);
    if (r >= 1.0) continue;
    // Tapered with distance so the error does not jump as facades enter the radius.
    const double side = heading.x() * q.y() - heading.y() * q.x();  // > 0: left
    (side > 0.0 ? left_m : right_m) += len * (1.0 - r * r);
  }
  const double fl = std::min(1.0, left_m / 15.0), fr = std::min(1.0, right_m / 15.0);
  return 0.25 * (fl + fr) + 0.5 * fl * fr;  // 1 between facades, 0.25 beside one
}

Eigen::Vector2d CanyonMultipathField::error_m(const Eigen::Vector2d& p_m, double yaw_rad) const {
  const double f = canyon_factor(p_m, yaw_rad);
  if (f <= 0.0 || cfg_.canyon_multipath_m <= 0.0) return Eigen::Vector2d::Zero();
  return cfg_.canyon_multipath_m * f * unit_field(p_m);
}

}  // namespace polmap::sim
