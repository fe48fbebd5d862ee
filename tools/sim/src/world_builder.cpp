#include "world_builder.hpp"

#include <cmath>
#include <numbers>

namespace polmap::sim {

namespace {
constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180.0;

double polyline_length(const std::vector<Eigen::Vector2d>& p) {
  double l = 0;
  for (std::size_t i = 1; i < p.size(); ++i) l += (p[i] - p[i - 1]).norm();
  return l;
}

/// Source of the objects implied by one from `source` (posts of a mapped fence, ...).
std::string implied_by(const std::string& source) {
  return source == "procedural" ? source : "implied";
}

/// Calls at(p) for the points `first`, first + spacing, ... metres along poly; a point
/// still falls on a segment up to `slack` metres past the segment's end.
template <class At>
void every_along(const std::vector<Eigen::Vector2d>& poly, double first, double spacing,
                 double slack, At&& at) {
  double next = first, acc = 0.0;
  for (std::size_t i = 0; i + 1 < poly.size(); ++i) {
    const Eigen::Vector2d a = poly[i], b = poly[i + 1];
    const double len = (b - a).norm();
    while (next <= acc + len + slack) {
      const Eigen::Vector2d p = a + (b - a) * ((next - acc) / std::max(len, 1e-9));
      at(p);
      next += spacing;
    }
    acc += len;
  }
}
}  // namespace

std::uint32_t WorldBuilder::object(ObjectClass cls, Mechanism m, std::vector<Eigen::Vector2d> geom,
                                   double rcs_dbsm, bool permanent, double presence,
                                   std::string source) {
  WorldObject o;
  o.cls = cls;
  o.mechanism = m;
  o.permanent = permanent;
  o.presence_probability = permanent ? 1.0 : presence;
  o.geometry_m = std::move(geom);
  o.rcs_dbsm = rcs_dbsm;
  o.source = std::move(source);
  return w_.add_object(std::move(o));
}

double WorldBuilder::toward_route(const Eigen::Vector2d& p) const {
  if (w_.route.empty()) return 0.0;
  const PathPoint q = w_.route.at(w_.route.project(p));
  return std::atan2(q.y_m - p.y(), q.x_m - p.x());
}

ScatteringVector WorldBuilder::mixed_omega() {
  const double u = rng_.uniform();
  if (u < 0.4) return odd_bounce();
  if (u < 0.7) return dihedral(rng_.uniform(0.0, kPi));
  ScatteringVector o{};
  const ScatteringVector a = odd_bounce(), b = dihedral(rng_.uniform(0.0, kPi));
  const cdouble ca = rng_.cnormal(), cb = rng_.cnormal();
  for (int c = 0; c < 4; ++c) o[c] = ca * a[c] + cb * b[c];
  return normalized(o);
}

float WorldBuilder::random_phase() { return static_cast<float>(rng_.uniform(0, 2 * kPi)); }

void WorldBuilder::surface_lines(const std::vector<Eigen::Vector2d>& poly, double rcs_per_m_dbsm,
                                 std::uint32_t object) {
  LineScatterer l = line_scatterer(ExtendedModel::Surface, rcs_per_m_dbsm, 1.0F, object);
  l.specular_gain_db = 20.0F;
  l.specular_width_rad = static_cast<float>(1.5 * kDeg);
  l.opaque = true;
  w_.add_line_pieces(poly, l);
}

void WorldBuilder::end_corners(const std::vector<Eigen::Vector2d>& poly, const std::string& source,
                               bool with_phase) {
  for (const Eigen::Vector2d& c : {poly.front(), poly.back()}) {
    const double r = rng_.uniform(0.0, 8.0);
    PointScatterer p = point_scatterer(
        c, odd_bounce(), r,
        object(ObjectClass::FacadeCorner, Mechanism::Odd, {c}, r, true, 1.0, source));
    if (with_phase) p.phase_rad = random_phase();
    point(p);
  }
}

// --- route-relative --------------------------------------------------------

void WorldBuilder::pole(ObjectClass cls, double s, double d) {
  pole_at(cls, at(s, d), "procedural");
}

std::uint32_t WorldBuilder::pole_at(ObjectClass cls, const Eigen::Vector2d& xy,
                                    const std::string& source) {
  double lo = 0.0, hi = 5.0;  // lamp / sign pole, 0..5 dBsm
  if (cls == ObjectClass::TrafficLight) lo = 3.0, hi = 8.0;
  const double rcs = rng_.uniform(lo, hi);
  const std::uint32_t id = object(cls, Mechanism::Odd, {xy}, rcs, true, 1.0, source);
  PointScatterer p = point_scatterer(xy, odd_bounce(), rcs, id);
  p.phase_rad = random_phase();
  point(p);
  return id;
}

void WorldBuilder::sign(double s, double d, int facing) {
  const double normal = yaw(s) + (facing > 0 ? kPi : 0.0) + rng_.uniform(-8.0, 8.0) * kDeg;
  sign_at(at(s, d), normal, "procedural");
}

void WorldBuilder::sign_at(const Eigen::Vector2d& xy, double normal_rad,
                           const std::string& source) {
  pole_at(ObjectClass::SignPole, xy, source);
  const double rcs = rng_.uniform(10.0, 20.0);
  const Eigen::Vector2d pp =
      xy + 0.04 * Eigen::Vector2d(std::cos(normal_rad), std::sin(normal_rad));
  const std::uint32_t id =
      object(ObjectClass::SignPlate, Mechanism::Odd, {pp}, rcs, true, 1.0, source);
  PointScatterer p = point_scatterer(pp, odd_bounce(), rcs, id);
  p.aspect = Aspect::Specular;
  p.normal_rad = static_cast<float>(normal_rad);
  p.lobe_rad = static_cast<float>(3.3 * kDeg);  // -20 dB at +-10 deg
  p.back_gain_db = -20.0F;
  p.two_sided = true;
  p.phase_rad = random_phase();
  point(p);
}

void WorldBuilder::traffic_light(double s, double d) { pole(ObjectClass::TrafficLight, s, d); }

void WorldBuilder::curb(double s0, double s1, double d) {
  curb_line(ObjectClass::Curbstone, w_.route.offset_polyline(s0, s1, d), "procedural");
}

void WorldBuilder::curb_with_driveways(double s0, double s1, double d) {
  double s = s0;
  while (s < s1 - 2.0) {
    const double len = std::min(rng_.uniform(25.0, 90.0), s1 - s);
    curb(s, s + len, d);
    s += len + rng_.uniform(3.0, 6.0);
  }
}

void WorldBuilder::facade(double s0, double s1, double d, int side) {
  const auto poly = w_.route.offset_polyline(s0, s1, d);
  if (poly.size() < 2) return;
  const double rcs = -10.0 + 10.0 * std::log10(3.0);  // -10 dBsm/m^2 over ~3 m seen height
  surface_lines(poly, rcs, object(ObjectClass::Facade, Mechanism::Diffuse, poly, rcs));
  // Door/window recesses (even, vertical inner corners) and the outer corners (odd).
  for (double s = s0 + rng_.uniform(2.0, 6.0); s < s1 - 1.5; s += rng_.uniform(4.0, 10.0)) {
    const double n = yaw(s) - side * 0.5 * kPi;  // facade normal towards the road
    const Eigen::Vector2d xy = at(s, d + side * 0.25);
    const double r = rng_.uniform(0.0, 10.0);
    PointScatterer p = point_scatterer(xy, dihedral(0.5 * kPi), r,
                                       object(ObjectClass::FacadeRecess, Mechanism::Even, {xy}, r));
    p.aspect = Aspect::FrontLobe;
    p.normal_rad = static_cast<float>(n);
    p.lobe_rad = static_cast<float>(45.0 * kDeg);
    p.back_gain_db = -25.0F;
    p.phase_rad = random_phase();
    point(p);
  }
  end_corners(poly, "procedural", /*with_phase=*/true);
}

void WorldBuilder::wall(double s0, double s1, double d, int /*side*/) {
  const auto poly = w_.route.offset_polyline(s0, s1, d);
  if (poly.size() < 2) return;
  wall_line(poly, "procedural");
}

std::uint32_t WorldBuilder::wall_line(const std::vector<Eigen::Vector2d>& poly,
                                      const std::string& source) {
  const double rcs = -10.0 + 10.0 * std::log10(3.0);
  const std::uint32_t id =
      object(ObjectClass::Wall, Mechanism::Diffuse, poly, rcs, true, 1.0, source);
  surface_lines(poly, rcs, id);
  end_corners(poly, implied_by(source), /*with_phase=*/false);
  return id;
}

void WorldBuilder::fence(double s0, double s1, double d, int /*side*/) {
  const auto poly = w_.route.offset_polyline(s0, s1, d);
  if (poly.size() < 2) return;
  fence_line(poly, rng_.uniform(2.5, 3.0), "procedural");
}

std::uint32_t WorldBuilder::fence_line(const std::vector<Eigen::Vector2d>& poly, double spacing,
                                       const std::string& source) {
  const double rcs = -15.0;
  const std::uint32_t id =
      object(ObjectClass::FenceMesh, Mechanism::Volume, poly, rcs, true, 1.0, source);
  w_.add_line_pieces(poly, line_scatterer(ExtendedModel::Volume, rcs, 0.5F, id));
  posts_along(poly, spacing, ObjectClass::FencePost, 0.0, implied_by(source));
  return id;
}

void WorldBuilder::posts_along(const std::vector<Eigen::Vector2d>& poly, double spacing,
                               ObjectClass cls, double behind_m, const std::string& source) {
  const double total = polyline_length(poly);
  if (total <= 0) return;
  every_along(poly, 0.0, spacing, 1e-9, [&](const Eigen::Vector2d& p) {
    const double to_road = toward_route(p);
    const Eigen::Vector2d xy = p - behind_m * Eigen::Vector2d(std::cos(to_road), std::sin(to_road));
    PointScatterer s;
    s.pos_m = xy;
    s.phase_rad = random_phase();
    if (cls == ObjectClass::GuardrailPost) {
      const double r = rng_.uniform(0.0, 8.0);
      const double theta = rng_.uniform(0.0, kPi);
      s.object = object(cls, Mechanism::Even, {xy}, r, true, 1.0, source);
      s.omega = dihedral(theta);
      s.rcs_dbsm = static_cast<float>(r);
      s.aspect = Aspect::FrontLobe;  // C/U profile: open side towards the road (+-30 deg)
      s.normal_rad = static_cast<float>(to_road + rng_.uniform(-30.0, 30.0) * kDeg);
      s.lobe_rad = static_cast<float>(60.0 * kDeg);
      s.back_gain_db = -15.0F;
    } else {  // fence post: round (odd) or angle profile (even)
      const double r = rng_.uniform(-3.0, 3.0);
      const bool even = rng_.bernoulli(0.3);
      s.object = object(cls, even ? Mechanism::Even : Mechanism::Odd, {xy}, r, true, 1.0, source);
      s.omega = even ? dihedral(0.5 * kPi) : odd_bounce();
      s.rcs_dbsm = static_cast<float>(r);
      if (even) {
        s.aspect = Aspect::FrontLobe;
        s.normal_rad = static_cast<float>(to_road);
        s.lobe_rad = static_cast<float>(60.0 * kDeg);
        s.back_gain_db = -10.0F;
      }
    }
    point(s);
  });
}

void WorldBuilder::guardrail(double s0, double s1, double d, int side, double spacing) {
  const auto poly = w_.route.offset_polyline(s0, s1, d);
  if (poly.size() < 2) return;
  guardrail_line(poly, spacing, "procedural");
  (void)side;
}

std::uint32_t WorldBuilder::guardrail_line(const std::vector<Eigen::Vector2d>& poly, double spacing,
                                           const std::string& source) {
  const double rcs = -5.0;
  const std::uint32_t id =
      object(ObjectClass::GuardrailBeam, Mechanism::Mixed, poly, rcs, true, 1.0, source);
  LineScatterer l = line_scatterer(ExtendedModel::MixedRandom, rcs, 1.0F, id);
  l.specular_gain_db = 20.0F;
  l.specular_width_rad = static_cast<float>(1.5 * kDeg);
  w_.add_line_pieces(poly, l);
  posts_along(poly, spacing, ObjectClass::GuardrailPost, 0.15, implied_by(source));
  return id;
}

std::uint32_t WorldBuilder::curb_line(ObjectClass cls, const std::vector<Eigen::Vector2d>& poly,
                                      const std::string& source) {
  const double rcs = rng_.uniform(-20.0, -12.0);
  const std::uint32_t id = object(cls, Mechanism::Even, poly, rcs, true, 1.0, source);
  LineScatterer l = line_scatterer(ExtendedModel::EvenDihedral, rcs, 1.0F, id);
  l.theta_rad = 0.0F;  // horizontal fold (curb face + road surface)
  w_.add_line_pieces(poly, l);
  return id;
}

void WorldBuilder::guide_post(double s, double d) {
  const Eigen::Vector2d xy = at(s, d);
  const double r = rng_.uniform(-10.0, 0.0);
  PointScatterer p =
      point_scatterer(xy, odd_bounce(), r, object(ObjectClass::GuidePost, Mechanism::Odd, {xy}, r));
  p.aspect = Aspect::FrontLobe;  // reflector towards approaching traffic
  p.normal_rad = static_cast<float>(yaw(s) + kPi);
  p.lobe_rad = static_cast<float>(60.0 * kDeg);
  p.back_gain_db = -6.0F;
  p.phase_rad = random_phase();
  point(p);
}

void WorldBuilder::tree(double s, double d) {
  const Eigen::Vector2d xy = at(s, d);
  const double r = rng_.uniform(-5.0, 5.0);
  PointScatterer p =
      point_scatterer(xy, odd_bounce(), r, object(ObjectClass::TreeTrunk, Mechanism::Odd, {xy}, r));
  p.diffuse_fraction = 0.3F;  // bark roughness: part of the power re-drawn per frame
  p.phase_rad = random_phase();
  point(p);
  const double rad = 0.5 * rng_.uniform(0.25, 0.5);
  w_.occluders.push_back(
      {xy - Eigen::Vector2d(rad, 0), xy + Eigen::Vector2d(rad, 0), false, p.object});
  w_.occluders.push_back(
      {xy - Eigen::Vector2d(0, rad), xy + Eigen::Vector2d(0, rad), false, p.object});
}

void WorldBuilder::vegetation(double s0, double s1, double d, bool permanent, double presence) {
  const auto poly = w_.route.offset_polyline(std::max(0.0, s0), s1, d, 2.0);
  if (poly.size() < 2) return;
  const double rcs = -15.0;  // -15 dBsm/m^2 over ~1 m depth
  const std::uint32_t id =
      object(ObjectClass::Vegetation, Mechanism::Volume, poly, rcs, permanent, presence);
  LineScatterer l = line_scatterer(ExtendedModel::Volume, rcs, 0.3F, id);
  l.vegetation = true;
  w_.add_line_pieces(poly, l);
}

void WorldBuilder::car_like(ObjectClass cls, const Eigen::Vector2d& c, double yaw_rad,
                            double length, double width, double rcs_min, double rcs_max,
                            int centres, double presence, double shift_m) {
  const double total = rng_.uniform(rcs_min, rcs_max);
  const std::uint32_t id = object(cls, Mechanism::Mixed, {c}, total, false, presence);
  const Eigen::Vector2d ex(std::cos(yaw_rad), std::sin(yaw_rad)), ey(-ex.y(), ex.x());
  w_.objects[id].drive_shift_axis = ex;
  w_.objects[id].drive_shift_max_m = shift_m;
  const double hl = 0.5 * length, hw = 0.5 * width;
  std::vector<Eigen::Vector2d> local = {{hl, hw}, {hl, -hw}, {-hl, hw}, {-hl, -hw}};
  if (centres > 4) {
    local.push_back({0.3 * length, hw});
    local.push_back({0.3 * length, -hw});
    local.push_back({-0.3 * length, hw});
    local.push_back({-0.3 * length, -hw});
  }
  const double each = total - 10.0 * std::log10(static_cast<double>(local.size()));
  for (const auto& l : local) {
    PointScatterer p;
    p.pos_m = c + l.x() * ex + l.y() * ey;
    p.omega = mixed_omega();
    p.rcs_dbsm = static_cast<float>(each + rng_.uniform(-3.0, 3.0));
    p.object = id;
    p.phase_rad = random_phase();
    point(p);
  }
  const Eigen::Vector2d corners[4] = {c + hl * ex + hw * ey, c - hl * ex + hw * ey,
                                      c - hl * ex - hw * ey, c + hl * ex - hw * ey};
  for (int i = 0; i < 4; ++i) w_.occluders.push_back({corners[i], corners[(i + 1) % 4], false, id});
}

void WorldBuilder::parked_car(double s, double d, double presence, double shift_m) {
  car_like(ObjectClass::ParkedCar, at(s, d), yaw(s), rng_.uniform(4.0, 4.9), rng_.uniform(1.7, 1.9),
           5.0, 20.0, 8, presence, shift_m);
}

void WorldBuilder::bin(double s, double d, double presence, double shift_m) {
  car_like(ObjectClass::Bin, at(s, d), yaw(s) + rng_.uniform(-0.3, 0.3), 0.7, 0.6, 0.0, 8.0, 4,
           presence, shift_m);
}

void WorldBuilder::lamps_along(const std::vector<Eigen::Vector2d>& poly, double spacing,
                               double offset) {
  const double total = polyline_length(poly);
  if (total < 0.5 * spacing) return;
  every_along(poly, 0.5 * spacing, spacing, 0.0, [&](const Eigen::Vector2d& p) {
    const double to_road = toward_route(p);
    pole_at(ObjectClass::LampPole,
            p - offset * Eigen::Vector2d(std::cos(to_road), std::sin(to_road)), "implied");
  });
}

}  // namespace polmap::sim
