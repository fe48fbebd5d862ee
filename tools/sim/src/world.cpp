#include "polmap/sim/world.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "polmap/schema/errors.hpp"
#include "polmap/sim/random.hpp"
#include "world_builder.hpp"

namespace polmap::sim {

std::string_view to_string(ObjectClass c) {
  switch (c) {
    case ObjectClass::LampPole:
      return "lamp_pole";
    case ObjectClass::SignPole:
      return "sign_pole";
    case ObjectClass::SignPlate:
      return "sign_plate";
    case ObjectClass::TrafficLight:
      return "traffic_light";
    case ObjectClass::Pole:
      return "pole";
    case ObjectClass::GuardrailPost:
      return "guardrail_post";
    case ObjectClass::GuidePost:
      return "guide_post";
    case ObjectClass::TreeTrunk:
      return "tree_trunk";
    case ObjectClass::GuardrailBeam:
      return "guardrail_beam";
    case ObjectClass::Curbstone:
      return "curbstone";
    case ObjectClass::RoadBorder:
      return "road_border";
    case ObjectClass::Wall:
      return "wall";
    case ObjectClass::Facade:
      return "facade";
    case ObjectClass::FacadeRecess:
      return "facade_recess";
    case ObjectClass::FacadeCorner:
      return "facade_corner";
    case ObjectClass::FenceMesh:
      return "fence_mesh";
    case ObjectClass::FencePost:
      return "fence_post";
    case ObjectClass::Vegetation:
      return "vegetation";
    case ObjectClass::ParkedCar:
      return "parked_car";
    case ObjectClass::Bin:
      return "bin";
  }
  return "unknown";
}

std::string_view to_string(Mechanism m) {
  switch (m) {
    case Mechanism::Odd:
      return "odd";
    case Mechanism::Even:
      return "even";
    case Mechanism::Mixed:
      return "mixed";
    case Mechanism::Diffuse:
      return "diffuse";
    case Mechanism::Volume:
      return "volume";
  }
  return "unknown";
}

World::World(std::string world_name, const GeoPoint& origin)
    : name(std::move(world_name)), frame(origin) {}

std::uint32_t World::add_object(WorldObject obj) {
  obj.id = static_cast<std::uint32_t>(objects.size());
  objects.push_back(std::move(obj));
  return objects.back().id;
}

void World::add_line_pieces(const std::vector<Eigen::Vector2d>& poly, const LineScatterer& proto) {
  constexpr double kMaxPiece = 8.0;
  for (std::size_t i = 0; i + 1 < poly.size(); ++i) {
    const Eigen::Vector2d a = poly[i], b = poly[i + 1];
    const double len = (b - a).norm();
    if (len < 1e-3) continue;
    const int n = std::max(1, static_cast<int>(std::ceil(len / kMaxPiece)));
    for (int k = 0; k < n; ++k) {
      LineScatterer l = proto;
      l.p0_m = a + (b - a) * (static_cast<double>(k) / n);
      l.p1_m = a + (b - a) * (static_cast<double>(k + 1) / n);
      lines.push_back(l);
    }
  }
}

void World::build_index() {
  grid_.clear();
  auto cell_of = [](const Eigen::Vector2d& p) {
    return std::pair<int, int>{static_cast<int>(std::floor(p.x() / kCell)),
                               static_cast<int>(std::floor(p.y() / kCell))};
  };
  for (std::uint32_t i = 0; i < points.size(); ++i) {
    auto [ix, iy] = cell_of(points[i].pos_m);
    grid_[key(ix, iy)].points.push_back(i);
  }
  // Pieces are <= 8 m: indexing by midpoint and querying with a 4 m margin finds them.
  for (std::uint32_t i = 0; i < lines.size(); ++i) {
    auto [ix, iy] = cell_of(0.5 * (lines[i].p0_m + lines[i].p1_m));
    grid_[key(ix, iy)].lines.push_back(i);
  }
  for (std::uint32_t i = 0; i < occluders.size(); ++i) {
    auto [ix, iy] = cell_of(0.5 * (occluders[i].p0_m + occluders[i].p1_m));
    grid_[key(ix, iy)].occluders.push_back(i);
  }
}

void World::query(const Eigen::Vector2d& c, double radius, std::vector<std::uint32_t>& pts,
                  std::vector<std::uint32_t>& lns, std::vector<std::uint32_t>& occ) const {
  pts.clear();
  lns.clear();
  occ.clear();
  const double r = radius + 4.5;
  const int x0 = static_cast<int>(std::floor((c.x() - r) / kCell));
  const int x1 = static_cast<int>(std::floor((c.x() + r) / kCell));
  const int y0 = static_cast<int>(std::floor((c.y() - r) / kCell));
  const int y1 = static_cast<int>(std::floor((c.y() + r) / kCell));
  for (int ix = x0; ix <= x1; ++ix) {
    for (int iy = y0; iy <= y1; ++iy) {
      // Skip cells entirely outside the disc.
      const double cx = std::clamp(c.x(), ix * kCell, (ix + 1) * kCell);
      const double cy = std::clamp(c.y(), iy * kCell, (iy + 1) * kCell);
      if ((cx - c.x()) * (cx - c.x()) + (cy - c.y()) * (cy - c.y()) > r * r) continue;
      auto it = grid_.find(key(ix, iy));
      if (it == grid_.end()) continue;
      pts.insert(pts.end(), it->second.points.begin(), it->second.points.end());
      lns.insert(lns.end(), it->second.lines.begin(), it->second.lines.end());
      occ.insert(occ.end(), it->second.occluders.begin(), it->second.occluders.end());
    }
  }
}

bool World::present(std::uint32_t id, int drive, std::uint64_t seed) const {
  const WorldObject& o = objects[id];
  if (o.permanent) return true;
  return hash_uniform(seed_of(seed, 0x7072657365ULL, id, static_cast<std::uint64_t>(drive))) <
         o.presence_probability;
}

Eigen::Vector2d World::drive_shift_m(std::uint32_t id, int drive, std::uint64_t seed) const {
  const WorldObject& o = objects[id];
  if (o.permanent || o.drive_shift_max_m <= 0.0) return Eigen::Vector2d::Zero();
  const double u =
      hash_uniform(seed_of(seed, 0x7368696674ULL, id, static_cast<std::uint64_t>(drive)));
  return (2.0 * u - 1.0) * o.drive_shift_max_m * o.drive_shift_axis;
}

// ---------------------------------------------------------------------------
// Procedural presets
// ---------------------------------------------------------------------------
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;
constexpr double kPi = std::numbers::pi;

/// Curvature profile as piecewise-linear knots.
struct KappaProfile {
  std::vector<double> s, k;
  void add(double s_m, double k_1pm) {
    s.push_back(s_m);
    k.push_back(k_1pm);
  }
  [[nodiscard]] double operator()(double q) const {
    if (s.empty() || q <= s.front()) return k.empty() ? 0.0 : k.front();
    if (q >= s.back()) return k.back();
    const auto it = std::upper_bound(s.begin(), s.end(), q);
    const std::size_t i = static_cast<std::size_t>(it - s.begin());
    const double t = (q - s[i - 1]) / std::max(1e-9, s[i] - s[i - 1]);
    return k[i - 1] + t * (k[i] - k[i - 1]);
  }
};

/// Station intervals [a, b] of the route minus intersection gaps.
std::vector<std::pair<double, double>> free_intervals(double length,
                                                      std::vector<std::pair<double, double>> gaps) {
  std::sort(gaps.begin(), gaps.end());
  std::vector<std::pair<double, double>> out;
  double cur = 0.0;
  for (const auto& [a, b] : gaps) {
    if (a > cur + 1.0) out.emplace_back(cur, std::min(a, length));
    cur = std::max(cur, b);
  }
  if (cur < length - 1.0) out.emplace_back(cur, length);
  return out;
}

/// Staircase route (alternating 90 deg turns) with crossings: urban / industrial.
struct GridRoute {
  KappaProfile kappa;
  std::vector<std::pair<double, double>> gaps;  // intersections (no buildings/curbs)
  std::vector<double> lights;                   // traffic light stations
};

GridRoute make_grid_route(Rng& rng, double length, double straight_min, double straight_max,
                          double radius_min, double radius_max, double crossing_min,
                          double crossing_max, double light_probability, double gap_half) {
  GridRoute r;
  double s = 0.0;
  int dir = rng.bernoulli(0.5) ? 1 : -1;
  r.kappa.add(0.0, 0.0);
  while (s < length) {
    const double straight = rng.uniform(straight_min, straight_max);
    // Crossings along the straight (gaps, maybe lights).
    double c = s + rng.uniform(crossing_min, crossing_max);
    while (c < s + straight - 40.0 && c < length) {
      r.gaps.emplace_back(c - gap_half, c + gap_half);
      if (rng.bernoulli(light_probability)) r.lights.push_back(c - gap_half);
      c += rng.uniform(crossing_min, crossing_max);
    }
    s += straight;
    if (s >= length) break;
    const double radius = rng.uniform(radius_min, radius_max);
    const double ramp = 6.0;
    const double arc = std::max(0.0, 0.5 * kPi * radius - ramp);
    const double k = dir / radius;
    const double turn_mid = s + ramp + 0.5 * arc;
    r.kappa.add(s, 0.0);
    r.kappa.add(s + ramp, k);
    r.kappa.add(s + ramp + arc, k);
    r.kappa.add(s + 2 * ramp + arc, 0.0);
    const double half = 0.5 * arc + ramp + gap_half;
    r.gaps.emplace_back(turn_mid - half, turn_mid + half);
    if (rng.bernoulli(light_probability)) r.lights.push_back(turn_mid - half);
    s += 2 * ramp + arc;
    dir = -dir;  // staircase: never self-intersects
  }
  return r;
}

void finish_route(World& w, const KappaProfile& kappa, double length, double step) {
  w.route = Path::from_curvature(
      {0.0, 0.0}, 0.0, length, [&](double s) { return kappa(s); }, step);
}

/// Lays gr out as w's route with the given road, puts traffic lights at both curbs of each
/// light station, and curbs both sides of each stretch between intersections (driveways
/// interrupt the curbs now and then) before furnish(a, e) furnishes the stretch [a, e].
template <class Furnish>
void build_grid_streets(World& w, WorldBuilder& b, const GridRoute& gr, double length,
                        const SimConfig& cfg, const RoadLayout& road, double curb_r, double curb_l,
                        Furnish&& furnish) {
  finish_route(w, gr.kappa, length, cfg.drive.trajectory_step_m);
  w.light_stations_m = gr.lights;
  w.road = road;
  for (double ls : gr.lights) {
    b.traffic_light(ls, curb_r - 0.6);
    b.traffic_light(ls, curb_l + 0.6);
  }
  for (const auto& [a, e] : free_intervals(length, gr.gaps)) {
    b.curb_with_driveways(a, e, curb_r);
    b.curb_with_driveways(a, e, curb_l);
    furnish(a, e);
  }
}

void build_urban(World& w, WorldBuilder& b, Rng& rng, double length, const SimConfig& cfg) {
  const GridRoute gr = make_grid_route(rng, length, 90, 220, 18, 26, 70, 150, 0.6, 9.0);
  const RoadLayout road = oncoming_lane_road(cfg, 3.3, cfg.traffic.oncoming_per_km_urban);
  const double curb_r = -3.6, curb_l = 5.0;
  build_grid_streets(w, b, gr, length, cfg, road, curb_r, curb_l, [&](double a, double e) {
    for (int side : {-1, 1}) {
      const double curb = side < 0 ? curb_r : curb_l;
      double s = a + rng.uniform(0.0, 4.0);
      while (s < e - 6.0) {
        const double len = std::min(rng.uniform(12.0, 40.0), e - s);
        const double setback = rng.uniform(2.5, 4.5);
        b.facade(s, s + len, curb + side * setback, side);
        s += len + rng.uniform(1.0, 6.0);
      }
      // Street trees on some sides.
      if (rng.bernoulli(0.35)) {
        for (double t = a + rng.uniform(2, 8); t < e - 2; t += rng.uniform(8, 12)) {
          b.tree(t, curb + side * 1.4);
        }
      }
    }
    // Lamps staggered both sides.
    for (double s = a + rng.uniform(3, 15); s < e; s += 30.0)
      b.pole(ObjectClass::LampPole, s, curb_r - 0.5);
    for (double s = a + rng.uniform(15, 30); s < e; s += 30.0)
      b.pole(ObjectClass::LampPole, s, curb_l + 0.5);
    // Signs.
    for (double s = a + rng.uniform(10, 40); s < e; s += rng.uniform(30, 70)) {
      if (rng.bernoulli(0.7)) {
        b.sign(s, curb_r - 0.4, +1);
      } else {
        b.sign(s, curb_l + 0.4, +1);
      }
    }
    // Parked cars in parking zones (temporary), bins near the curb.
    double s = a + 3.0;
    while (s < e - 8.0) {
      const double zone = std::min(rng.uniform(20.0, 60.0), e - s);
      if (rng.bernoulli(0.6)) {
        for (double c = s + 3.0; c < s + zone - 3.0; c += rng.uniform(5.6, 7.0)) {
          b.parked_car(c, -2.65, cfg.traffic.parked_presence, cfg.traffic.parked_shift_m);
        }
      }
      s += zone + rng.uniform(5.0, 15.0);
    }
    for (double t = a + rng.uniform(5, 30); t < e; t += rng.uniform(20, 60)) {
      b.bin(t, curb_r - 0.7, cfg.traffic.bin_presence, cfg.traffic.bin_shift_m);
    }
  });
}

void build_industrial(World& w, WorldBuilder& b, Rng& rng, double length, const SimConfig& cfg) {
  const GridRoute gr = make_grid_route(rng, length, 150, 400, 25, 35, 150, 300, 0.3, 12.0);
  RoadLayout road = oncoming_lane_road(cfg, 7.5, cfg.traffic.oncoming_per_km_industrial);
  road.has_same_dir_lane = true;
  road.same_dir_lane_m = 3.75;
  road.same_dir_per_km = cfg.traffic.same_dir_per_km_industrial;
  const double curb_r = -2.0, curb_l = 9.4;
  build_grid_streets(w, b, gr, length, cfg, road, curb_r, curb_l, [&](double a, double e) {
    for (int side : {-1, 1}) {
      const double curb = side < 0 ? curb_r : curb_l;
      double s = a + rng.uniform(0.0, 5.0);
      while (s < e - 10.0) {
        const double len = std::min(rng.uniform(40.0, 150.0), e - s);
        const double u = rng.uniform();
        if (u < 0.55) {
          b.fence(s, s + len, curb + side * rng.uniform(2.5, 6.0), side);
        } else if (u < 0.8) {
          b.wall(s, s + len, curb + side * rng.uniform(2.5, 6.0), side);
        } else {
          // Warehouse set back behind a fence.
          b.fence(s, s + len, curb + side * 3.0, side);
          b.wall(s + 5, s + len - 5, curb + side * rng.uniform(10.0, 20.0), side);
        }
        s += len + rng.uniform(6.0, 20.0);  // gates, plot entries
      }
    }
    for (double s = a + rng.uniform(3, 20); s < e; s += rng.uniform(35, 40)) {
      b.pole(ObjectClass::LampPole, s, curb_r - 0.6);
    }
    for (double s = a + rng.uniform(20, 80); s < e; s += rng.uniform(60, 140)) {
      b.sign(s, curb_r - 0.5, +1);
    }
    for (double s = a + rng.uniform(10, 60); s < e; s += rng.uniform(40, 120)) {
      b.parked_car(s, curb_r - 1.2, cfg.traffic.parked_presence * 0.8, cfg.traffic.parked_shift_m);
    }
  });
}

void build_rural(World& w, WorldBuilder& b, Rng& rng, double length, const SimConfig& cfg) {
  KappaProfile kappa;
  double s = 0.0, heading = 0.0;
  kappa.add(0.0, 0.0);
  while (s < length) {
    const double straight = rng.uniform(60.0, 300.0);
    s += straight;
    kappa.add(s, 0.0);
    const double radius = rng.uniform(180.0, 700.0);
    const double arc = std::min(rng.uniform(60.0, 250.0), 0.6 * radius - 20.0);
    // Curve towards the mean direction so the road never loops back.
    const double sign = heading > 0.3    ? -1.0
                        : heading < -0.3 ? 1.0
                                         : (rng.bernoulli(0.5) ? 1.0 : -1.0);
    const double ramp = 20.0;
    kappa.add(s + ramp, sign / radius);
    kappa.add(s + ramp + arc, sign / radius);
    kappa.add(s + 2 * ramp + arc, 0.0);
    heading += sign * (arc + ramp) / radius;
    s += 2 * ramp + arc;
  }
  finish_route(w, kappa, length, cfg.drive.trajectory_step_m);
  w.road = oncoming_lane_road(cfg, 3.5, cfg.traffic.oncoming_per_km_rural);
  w.road.traffic_max_speed_mps = cfg.traffic.max_speed_mps + 5.0;
  w.road.default_max_speed_mps = 20.0;
  const double edge_r = -1.9, edge_l = 5.4;
  // Villages: short sections with curbs and lamps.
  std::vector<std::pair<double, double>> villages;
  for (double v = rng.uniform(300, 1200); v < length; v += rng.uniform(1200, 2500)) {
    villages.emplace_back(v, std::min(length, v + rng.uniform(150, 350)));
  }
  for (const auto& [a, e] : villages) {
    b.curb(a, e, edge_r - 0.3);
    b.curb(a, e, edge_l + 0.3);
    for (double q = a + 5; q < e; q += 30) b.pole(ObjectClass::LampPole, q, edge_r - 0.9);
    b.sign(a + 2, edge_r - 0.8, +1);
  }
  // Guide posts every 50 m both sides; low vegetation in front of some in some drives.
  for (double q = 25.0; q < length; q += 50.0) {
    for (int side : {-1, 1}) {
      const double d = side < 0 ? edge_r - 1.0 : edge_l + 1.0;
      b.guide_post(q, d);
      if (rng.bernoulli(0.6)) {
        const double len = rng.uniform(2.0, 5.0);
        const double dv = d - side * 0.45;  // between road and post
        b.vegetation(q - 0.6 * len, q + 0.4 * len, dv, false, cfg.traffic.vegetation_presence);
      }
    }
  }
  // Guardrail sections with posts every 2-4 m.
  for (double q = rng.uniform(50, 300); q < length - 50; q += rng.uniform(250, 700)) {
    const double len = std::min(rng.uniform(100.0, 400.0), length - q);
    const int side = rng.bernoulli(0.6) ? -1 : 1;
    const double d = side < 0 ? edge_r - 0.7 : edge_l + 0.7;
    b.guardrail(q, q + len, d, side, rng.uniform(2.0, 4.0));
    q += len;
  }
  // Tree alleys and hedges.
  for (double q = rng.uniform(0, 400); q < length; q += rng.uniform(300, 900)) {
    const double len = std::min(rng.uniform(150.0, 500.0), length - q);
    for (int side : {-1, 1}) {
      if (!rng.bernoulli(0.6)) continue;
      const double d = side < 0 ? edge_r - rng.uniform(2.5, 5.0) : edge_l + rng.uniform(2.5, 5.0);
      for (double t = q + rng.uniform(0, 8); t < q + len; t += rng.uniform(8, 15)) {
        b.tree(t, d + rng.uniform(-0.3, 0.3));
      }
    }
    q += len;
  }
  for (double q = rng.uniform(50, 300); q < length; q += rng.uniform(150, 400)) {
    const double len = std::min(rng.uniform(20.0, 80.0), length - q);
    const int side = rng.bernoulli(0.5) ? -1 : 1;
    const double d = side < 0 ? edge_r - rng.uniform(3.0, 6.0) : edge_l + rng.uniform(3.0, 6.0);
    b.vegetation(q, q + len, d, true, 1.0);
  }
  for (double q = rng.uniform(100, 600); q < length; q += rng.uniform(400, 1000)) {
    b.sign(q, edge_r - 1.2, +1);
  }
}

}  // namespace

std::shared_ptr<World> make_world(const WorldSpec& spec, const SimConfig& cfg) {
  if (!(spec.length_m >= 50.0 && spec.length_m <= 100000.0)) {
    throw ValidationError("world length must be within [50, 100000] m, got " +
                          std::to_string(spec.length_m));
  }
  auto w = std::make_shared<World>(spec.preset, spec.origin);
  Rng rng(seed_of(spec.seed, 0x776f726c64ULL));
  WorldBuilder b(*w, rng, spec.seed);
  if (spec.preset == "urban") {
    build_urban(*w, b, rng, spec.length_m, cfg);
  } else if (spec.preset == "industrial") {
    build_industrial(*w, b, rng, spec.length_m, cfg);
  } else if (spec.preset == "rural") {
    build_rural(*w, b, rng, spec.length_m, cfg);
  } else {
    throw ValidationError("unknown world preset '" + spec.preset +
                          "' (expected urban, industrial, rural, FILE.osm or FILE.xodr)");
  }
  w->build_index();
  return w;
}

std::shared_ptr<World> load_world(const std::string& world, double length_m, std::uint64_t seed,
                                  const SimConfig& cfg) {
  auto ends_with = [&](std::string_view suf) {
    return world.size() >= suf.size() &&
           world.compare(world.size() - suf.size(), suf.size(), suf) == 0;
  };
  if (ends_with(".osm")) return load_lanelet2_world(world, cfg, seed, length_m);
  if (ends_with(".xodr")) return load_opendrive_world(world, cfg, seed, length_m);
  WorldSpec spec;
  spec.preset = world;
  spec.length_m = length_m;
  spec.seed = seed;
  if (world == "industrial") spec.origin = {48.7665, 11.4258, 370.0};  // Ingolstadt
  if (world == "rural") spec.origin = {48.4011, 9.9876, 480.0};        // Ulm
  return make_world(spec, cfg);
}

}  // namespace polmap::sim
