// Lanelet2 OSM worlds: geometry from the map (nodes' lat/lon), a route along
// the longest chain of connected road lanelets, and what the map implies
// (posts along guard rails and fences, lamps along borders).
#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <numbers>
#include <unordered_map>

#include "polmap/hdmap/lanelet2_osm.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/sim/world.hpp"
#include "world_builder.hpp"

namespace polmap::sim {

namespace {

struct OsmWay {
  std::vector<std::int64_t> nodes;
  std::string type, subtype;
};

struct Lanelet {
  std::int64_t id = 0;
  std::vector<Eigen::Vector2d> centre;
  double length = 0;
};

std::vector<Eigen::Vector2d> resample(const std::vector<Eigen::Vector2d>& p, int n) {
  std::vector<double> cum(p.size(), 0.0);
  for (std::size_t i = 1; i < p.size(); ++i) cum[i] = cum[i - 1] + (p[i] - p[i - 1]).norm();
  std::vector<Eigen::Vector2d> out;
  std::size_t seg = 0;
  for (int k = 0; k < n; ++k) {
    const double s = cum.back() * k / (n - 1);
    while (seg + 2 < p.size() && cum[seg + 1] < s) ++seg;
    const double len = cum[seg + 1] - cum[seg];
    const double t = len > 0 ? std::clamp((s - cum[seg]) / len, 0.0, 1.0) : 0.0;
    out.push_back(p[seg] + t * (p[seg + 1] - p[seg]));
  }
  return out;
}

double poly_length(const std::vector<Eigen::Vector2d>& p) {
  double l = 0;
  for (std::size_t i = 1; i < p.size(); ++i) l += (p[i] - p[i - 1]).norm();
  return l;
}

double heading(const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return std::atan2(b.y() - a.y(), b.x() - a.x());
}

}  // namespace

std::shared_ptr<World> load_lanelet2_world(const std::filesystem::path& path, const SimConfig& cfg,
                                           std::uint64_t seed, double max_length_m) {
  const std::string name = path.string();
  const hdmap::Lanelet2Osm osm = hdmap::read_lanelet2_osm_file(path);

  // Nodes (lat/lon are authoritative; local_x/local_y ignored).
  double lat_min = 90, lat_max = -90, lon_min = 180, lon_max = -180;
  for (const auto& n : osm.nodes) {
    lat_min = std::min(lat_min, n.position.lat_deg);
    lat_max = std::max(lat_max, n.position.lat_deg);
    lon_min = std::min(lon_min, n.position.lon_deg);
    lon_max = std::max(lon_max, n.position.lon_deg);
  }
  if (osm.nodes.empty()) throw FormatError(name, 0, "no nodes");
  const GeoPoint origin{0.5 * (lat_min + lat_max), 0.5 * (lon_min + lon_max), 0.0};
  auto world = std::make_shared<World>(path.filename().string(), origin);
  World& w = *world;
  std::unordered_map<std::int64_t, Eigen::Vector2d> xy;
  xy.reserve(osm.node_index.size());
  for (const auto& [id, index] : osm.node_index) {
    GeoPoint g = osm.nodes[index].position;
    g.alt_m = osm.nodes[index].ele_m;
    xy[id] = w.frame.to_local(g);
  }

  std::unordered_map<std::int64_t, OsmWay> ways;
  std::vector<std::int64_t> way_order;
  for (const auto& ow : osm.ways) {
    for (const std::int64_t ref : ow.node_refs) {
      if (!xy.count(ref)) {
        throw FormatError(
            name, 0,
            "way " + std::to_string(ow.id) + " references missing node " + std::to_string(ref));
      }
    }
    ways[ow.id] = OsmWay{ow.node_refs, ow.type, ow.subtype};
    way_order.push_back(ow.id);
  }
  auto way_xy = [&](const OsmWay& way) {
    std::vector<Eigen::Vector2d> p;
    for (std::int64_t n : way.nodes) p.push_back(xy[n]);
    return p;
  };

  // Road lanelets with their centrelines.
  std::vector<Lanelet> lanelets;
  for (const auto& r : osm.relations) {
    if (r.type != "lanelet") continue;
    if (!(r.subtype.empty() || r.subtype == "road" || r.subtype == "highway" ||
          r.subtype == "play_street")) {
      continue;
    }
    std::int64_t left = 0, right = 0;
    for (const auto& m : r.members) {
      if (m.role == "left") left = m.ref;
      if (m.role == "right") right = m.ref;
    }
    if (!ways.count(left) || !ways.count(right)) continue;
    std::vector<Eigen::Vector2d> l = way_xy(ways[left]), rt = way_xy(ways[right]);
    if (l.size() < 2 || rt.size() < 2) continue;
    if ((l.front() - rt.front()).norm() + (l.back() - rt.back()).norm() >
        (l.front() - rt.back()).norm() + (l.back() - rt.front()).norm()) {
      std::reverse(rt.begin(), rt.end());
    }
    const int n =
        std::max(2, static_cast<int>(std::ceil(std::max(poly_length(l), poly_length(rt)))) + 1);
    const auto lr = resample(l, n), rr = resample(rt, n);
    Lanelet ll;
    ll.id = r.id;
    for (int k = 0; k < n; ++k) ll.centre.push_back(0.5 * (lr[k] + rr[k]));
    // Driving direction: the right bound lies to the right of the centreline.
    const Eigen::Vector2d d = ll.centre.back() - ll.centre.front();
    const Eigen::Vector2d side = rr[n / 2] - lr[n / 2];
    if (d.x() * side.y() - d.y() * side.x() > 0) std::reverse(ll.centre.begin(), ll.centre.end());
    ll.length = poly_length(ll.centre);
    if (ll.length > 0.5) lanelets.push_back(std::move(ll));
  }
  if (lanelets.empty()) throw FormatError(name, 0, "no road lanelets (type=lanelet, subtype=road)");

  // Successor graph: end of A meets start of B with a similar heading.
  const std::size_t nl = lanelets.size();
  std::vector<std::vector<std::size_t>> succ(nl);
  for (std::size_t a = 0; a < nl; ++a) {
    const auto& ca = lanelets[a].centre;
    const double ha = heading(ca[ca.size() - 2], ca.back());
    for (std::size_t b = 0; b < nl; ++b) {
      if (a == b) continue;
      const auto& cb = lanelets[b].centre;
      if ((ca.back() - cb.front()).norm() > 0.6) continue;
      const double hb = heading(cb[0], cb[1]);
      if (std::abs(wrap_angle_rad(ha - hb)) > 50.0 * std::numbers::pi / 180.0) continue;
      succ[a].push_back(b);
    }
  }
  // Longest chain (DFS with memo; nodes on the current stack end a chain, breaking cycles).
  std::vector<double> best(nl, -1.0);
  std::vector<int> next(nl, -1);
  std::vector<std::uint8_t> on_stack(nl, 0);
  std::function<double(std::size_t)> longest = [&](std::size_t v) -> double {
    if (best[v] >= 0) return best[v];
    on_stack[v] = 1;
    double b = 0;
    int nx = -1;
    for (std::size_t s : succ[v]) {
      if (on_stack[s]) continue;
      const double l = longest(s);
      if (l > b) {
        b = l;
        nx = static_cast<int>(s);
      }
    }
    on_stack[v] = 0;
    best[v] = lanelets[v].length + b;
    next[v] = nx;
    return best[v];
  };
  std::size_t start = 0;
  for (std::size_t v = 0; v < nl; ++v) {
    if (longest(v) > longest(start)) start = v;
  }
  std::vector<Eigen::Vector2d> route_pts;
  std::vector<std::uint8_t> used(nl, 0);
  for (int v = static_cast<int>(start); v >= 0 && !used[v]; v = next[v]) {
    used[v] = 1;
    for (const auto& p : lanelets[v].centre) {
      if (route_pts.empty() || (p - route_pts.back()).norm() > 0.05) route_pts.push_back(p);
    }
  }
  if (poly_length(route_pts) < 20.0) {
    throw FormatError(name, 0, "longest chain of connected road lanelets is shorter than 20 m");
  }
  if (max_length_m > 0 && poly_length(route_pts) > max_length_m) {
    std::vector<Eigen::Vector2d> cut{route_pts.front()};
    double acc = 0;
    for (std::size_t i = 1; i < route_pts.size() && acc < max_length_m; ++i) {
      acc += (route_pts[i] - route_pts[i - 1]).norm();
      cut.push_back(route_pts[i]);
    }
    route_pts = std::move(cut);
  }
  w.route = Path::from_polyline(route_pts, cfg.drive.trajectory_step_m, 4.0);
  w.road = oncoming_lane_road(cfg, 3.5, cfg.traffic.oncoming_per_km_hdmap);

  // Objects: tagged line strings -> scatterers.
  Rng rng(seed_of(seed, 0x6f736dULL));
  WorldBuilder b(w, rng, seed);
  const HdMapDensityConfig& dens = cfg.hdmap;
  std::vector<Eigen::Vector2d> lights;
  for (std::int64_t id : way_order) {
    const OsmWay& way = ways[id];
    const std::string src = "osm way " + std::to_string(id);
    const auto p = way_xy(way);
    if (p.empty()) continue;
    const std::string& t = way.type;
    if (p.size() >= 2 && (t == "curbstone" || t == "curbestone")) {
      b.curb_line(ObjectClass::Curbstone, p, src);
      b.lamps_along(p, dens.lamp_spacing_m, dens.lamp_offset_m);
    } else if (p.size() >= 2 && t == "road_border") {
      b.curb_line(ObjectClass::RoadBorder, p, src);
      b.lamps_along(p, dens.lamp_spacing_m, dens.lamp_offset_m);
    } else if (p.size() >= 2 && t == "wall") {
      b.wall_line(p, src);
    } else if (p.size() >= 2 && t == "fence") {
      b.fence_line(p, dens.fence_post_spacing_m, src);
    } else if (p.size() >= 2 && t == "guard_rail") {
      b.guardrail_line(p, dens.guardrail_post_spacing_m, src);
    } else if (t == "traffic_sign") {
      const Eigen::Vector2d mid = 0.5 * (p.front() + p.back());
      const double n = p.size() >= 2 ? heading(p.front(), p.back()) + 0.5 * std::numbers::pi : 0.0;
      b.sign_at(mid, n, src);
    } else if (t == "traffic_light") {
      const Eigen::Vector2d mid = 0.5 * (p.front() + p.back());
      b.pole_at(ObjectClass::TrafficLight, mid, src);
      lights.push_back(mid);
    } else if (t == "pole") {
      b.pole_at(ObjectClass::Pole, p.front(), src);
    }
  }
  // Stops: traffic lights within 30 m of the route stop the ego 15 m before their station.
  for (const auto& l : lights) {
    const double s = w.route.project(l);
    const PathPoint q = w.route.at(s);
    if ((Eigen::Vector2d(q.x_m, q.y_m) - l).norm() > 30.0) continue;
    const double stop = s - 15.0;
    if (stop < 20.0) continue;
    bool dup = false;
    for (double e : w.light_stations_m) dup = dup || std::abs(e - stop) < 30.0;
    if (!dup) w.light_stations_m.push_back(stop);
  }
  std::sort(w.light_stations_m.begin(), w.light_stations_m.end());
  w.build_index();
  return world;
}

}  // namespace polmap::sim
