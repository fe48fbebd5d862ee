// OpenDRIVE worlds: the longest road's reference line (planView: line, arc,
// spiral, poly3, paramPoly3), the route on its first right driving lane, point
// objects and signals at (s, t), implied road borders and lamps.
#include <algorithm>
#include <cmath>
#include <numbers>
#include <pugixml.hpp>
#include <regex>

#include "polmap/schema/errors.hpp"
#include "polmap/sim/world.hpp"
#include "world_builder.hpp"

namespace polmap::sim {

namespace {

constexpr double kPi = std::numbers::pi;

struct Geometry {
  double s = 0, x = 0, y = 0, hdg = 0, length = 0;
  enum Kind { Line, Arc, Spiral, Poly3, ParamPoly3 } kind = Line;
  double curvature = 0, curv_start = 0, curv_end = 0;
  double a = 0, b = 0, c = 0, d = 0;                                      // poly3
  double au = 0, bu = 0, cu = 0, du = 0, av = 0, bv = 0, cv = 0, dv = 0;  // paramPoly3
  bool normalized = true;
};

struct RefPose {
  double x, y, hdg;
};

/// Pose on one geometry at local distance ds (numerical integration for spirals/polys).
RefPose eval_geometry(const Geometry& g, double ds) {
  const double ch = std::cos(g.hdg), sh = std::sin(g.hdg);
  auto local_to_world = [&](double u, double v, double h) {
    return RefPose{g.x + ch * u - sh * v, g.y + sh * u + ch * v, g.hdg + h};
  };
  switch (g.kind) {
    case Geometry::Line:
      return local_to_world(ds, 0, 0);
    case Geometry::Arc: {
      const double k = g.curvature;
      if (std::abs(k) < 1e-12) return local_to_world(ds, 0, 0);
      return local_to_world(std::sin(k * ds) / k, (1 - std::cos(k * ds)) / k, k * ds);
    }
    case Geometry::Spiral: {
      // Heading h(s) = k0 s + (k1-k0) s^2 / (2L); integrate the position (Simpson, 0.05 m).
      const double k0 = g.curv_start, dk = (g.curv_end - g.curv_start) / std::max(g.length, 1e-9);
      const int n = std::max(2, static_cast<int>(std::ceil(ds / 0.05)) * 2);
      const double h = ds / n;
      double u = 0, v = 0;
      for (int i = 0; i <= n; ++i) {
        const double s = i * h;
        const double th = k0 * s + 0.5 * dk * s * s;
        const double wgt = (i == 0 || i == n) ? 1 : (i % 2 ? 4 : 2);
        u += wgt * std::cos(th);
        v += wgt * std::sin(th);
      }
      u *= h / 3;
      v *= h / 3;
      return local_to_world(u, v, k0 * ds + 0.5 * dk * ds * ds);
    }
    case Geometry::Poly3: {
      // v = a + b u + c u^2 + d u^3 over u; ds along the curve ~ u (adequate for gentle polys).
      const double u = ds;
      const double v = g.a + g.b * u + g.c * u * u + g.d * u * u * u;
      const double dvdu = g.b + 2 * g.c * u + 3 * g.d * u * u;
      return local_to_world(u, v, std::atan(dvdu));
    }
    case Geometry::ParamPoly3: {
      const double p = g.normalized ? ds / std::max(g.length, 1e-9) : ds;
      const double u = g.au + g.bu * p + g.cu * p * p + g.du * p * p * p;
      const double v = g.av + g.bv * p + g.cv * p * p + g.dv * p * p * p;
      const double du = g.bu + 2 * g.cu * p + 3 * g.du * p * p;
      const double dv = g.bv + 2 * g.cv * p + 3 * g.dv * p * p;
      return local_to_world(u, v, std::atan2(dv, du));
    }
  }
  return {g.x, g.y, g.hdg};
}

struct Road {
  std::string id;
  double length = 0;
  std::vector<Geometry> geoms;
  pugi::xml_node node;
  [[nodiscard]] RefPose at(double s) const {
    s = std::clamp(s, 0.0, length);
    std::size_t i = 0;
    while (i + 1 < geoms.size() && geoms[i + 1].s <= s) ++i;
    return eval_geometry(geoms[i], s - geoms[i].s);
  }
  [[nodiscard]] Eigen::Vector2d point(double s, double t) const {
    const RefPose p = at(s);
    return {p.x - t * std::sin(p.hdg), p.y + t * std::cos(p.hdg)};
  }
};

double width_at(pugi::xml_node lane, double ds) {
  pugi::xml_node best;
  for (pugi::xml_node w : lane.children("width")) {
    if (w.attribute("sOffset").as_double() <= ds + 1e-9) best = w;
  }
  if (!best) return 0.0;
  const double x = ds - best.attribute("sOffset").as_double();
  return best.attribute("a").as_double() + best.attribute("b").as_double() * x +
         best.attribute("c").as_double() * x * x + best.attribute("d").as_double() * x * x * x;
}

}  // namespace

std::shared_ptr<World> load_opendrive_world(const std::filesystem::path& path, const SimConfig& cfg,
                                            std::uint64_t seed, double max_length_m) {
  const std::string name = path.string();
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw IoError("cannot read map file " + name);
  pugi::xml_document doc;
  const pugi::xml_parse_result res = doc.load_file(path.c_str());
  if (!res) {
    throw FormatError(name, static_cast<std::uint64_t>(res.offset),
                      std::string("not valid XML: ") + res.description());
  }
  const pugi::xml_node od = doc.child("OpenDRIVE");
  if (!od) throw FormatError(name, 0, "no <OpenDRIVE> root element");

  // Georeference: +lat_0/+lon_0 of a PROJ string; otherwise the documented default.
  GeoPoint origin{cfg.hdmap.xodr_default_lat_deg, cfg.hdmap.xodr_default_lon_deg, 0.0};
  const std::string geo = od.child("header").child_value("geoReference");
  std::smatch m;
  const std::regex lat_re(R"(\+lat_0=([-0-9.eE+]+))"), lon_re(R"(\+lon_0=([-0-9.eE+]+))");
  if (std::regex_search(geo, m, lat_re)) origin.lat_deg = std::stod(m[1]);
  if (std::regex_search(geo, m, lon_re)) origin.lon_deg = std::stod(m[1]);

  std::vector<Road> roads;
  for (pugi::xml_node rn : od.children("road")) {
    Road r;
    r.id = rn.attribute("id").as_string();
    r.length = rn.attribute("length").as_double();
    r.node = rn;
    for (pugi::xml_node gn : rn.child("planView").children("geometry")) {
      Geometry g;
      g.s = gn.attribute("s").as_double();
      g.x = gn.attribute("x").as_double();
      g.y = gn.attribute("y").as_double();
      g.hdg = gn.attribute("hdg").as_double();
      g.length = gn.attribute("length").as_double();
      if (pugi::xml_node a = gn.child("arc")) {
        g.kind = Geometry::Arc;
        g.curvature = a.attribute("curvature").as_double();
      } else if (pugi::xml_node sp = gn.child("spiral")) {
        g.kind = Geometry::Spiral;
        g.curv_start = sp.attribute("curvStart").as_double();
        g.curv_end = sp.attribute("curvEnd").as_double();
      } else if (pugi::xml_node p = gn.child("poly3")) {
        g.kind = Geometry::Poly3;
        g.a = p.attribute("a").as_double();
        g.b = p.attribute("b").as_double();
        g.c = p.attribute("c").as_double();
        g.d = p.attribute("d").as_double();
      } else if (pugi::xml_node pp = gn.child("paramPoly3")) {
        g.kind = Geometry::ParamPoly3;
        g.au = pp.attribute("aU").as_double();
        g.bu = pp.attribute("bU").as_double();
        g.cu = pp.attribute("cU").as_double();
        g.du = pp.attribute("dU").as_double();
        g.av = pp.attribute("aV").as_double();
        g.bv = pp.attribute("bV").as_double();
        g.cv = pp.attribute("cV").as_double();
        g.dv = pp.attribute("dV").as_double();
        g.normalized =
            std::string_view(pp.attribute("pRange").as_string("normalized")) != "arcLength";
      } else if (!gn.child("line")) {
        throw FormatError(name, 0, "road " + r.id + ": unsupported planView geometry");
      }
      r.geoms.push_back(g);
    }
    if (r.geoms.empty() || r.length <= 0) continue;
    std::sort(r.geoms.begin(), r.geoms.end(),
              [](const Geometry& a, const Geometry& b) { return a.s < b.s; });
    roads.push_back(std::move(r));
  }
  if (roads.empty()) throw FormatError(name, 0, "no road with a planView");

  auto world = std::make_shared<World>(path.filename().string(), origin);
  World& w = *world;
  // Route: the longest road, first right driving lane centre, in +s direction.
  const Road& main = *std::max_element(
      roads.begin(), roads.end(), [](const Road& a, const Road& b) { return a.length < b.length; });
  const pugi::xml_node section = main.node.child("lanes").child("laneSection");
  double lane_w = 3.5;
  double right_edge = -3.5, left_edge = 3.5;
  if (section) {
    double acc = 0;
    bool first = true;
    // Lanes are listed outermost first on the left, innermost first on the right (-1, -2, ...).
    std::vector<pugi::xml_node> right;
    for (pugi::xml_node ln : section.child("right").children("lane")) right.push_back(ln);
    std::sort(right.begin(), right.end(), [](pugi::xml_node a, pugi::xml_node b) {
      return a.attribute("id").as_int() > b.attribute("id").as_int();
    });
    for (pugi::xml_node ln : right) {
      const double wd = width_at(ln, 0.0);
      if (std::string_view(ln.attribute("type").as_string()) != "driving") break;
      if (first) lane_w = wd, first = false;
      acc += wd;
    }
    right_edge = -acc;
    std::vector<pugi::xml_node> left;
    for (pugi::xml_node ln : section.child("left").children("lane")) left.push_back(ln);
    std::sort(left.begin(), left.end(), [](pugi::xml_node a, pugi::xml_node b) {
      return a.attribute("id").as_int() < b.attribute("id").as_int();
    });
    acc = 0;
    for (pugi::xml_node ln : left) {
      if (std::string_view(ln.attribute("type").as_string()) != "driving") break;
      acc += width_at(ln, 0.0);
    }
    left_edge = acc;
  }
  const double lane_t = -0.5 * lane_w;
  const double route_len = max_length_m > 0 ? std::min(main.length, max_length_m) : main.length;
  std::vector<Eigen::Vector2d> pts;
  for (double s = 0; s <= route_len + 1e-9; s += 0.5) pts.push_back(main.point(s, lane_t));
  if (pts.size() < 3) throw FormatError(name, 0, "road " + main.id + " is too short for a route");
  w.route = Path::from_polyline(pts, cfg.drive.trajectory_step_m, 1.0);
  w.road = oncoming_lane_road(cfg, -lane_t + 0.5 * lane_w, cfg.traffic.oncoming_per_km_hdmap);

  Rng rng(seed_of(seed, 0x786f6472ULL));
  WorldBuilder b(w, rng, seed);
  for (const Road& r : roads) {
    // Implied road borders at the edges of the driving lanes, with lamps.
    if (&r == &main) {
      for (double t : {right_edge, left_edge}) {
        std::vector<Eigen::Vector2d> edge;
        for (double s = 0; s <= r.length + 1e-9; s += 2.0) edge.push_back(r.point(s, t));
        b.curb_line(ObjectClass::RoadBorder, edge, "implied");
        b.lamps_along(edge, cfg.hdmap.lamp_spacing_m, cfg.hdmap.lamp_offset_m);
      }
    }
    for (pugi::xml_node o : r.node.child("objects").children("object")) {
      const std::string type = o.attribute("type").as_string();
      const std::string src = "xodr road " + r.id + " object " + o.attribute("id").as_string();
      std::vector<double> stations{o.attribute("s").as_double()};
      for (pugi::xml_node rep : o.children("repeat")) {
        const double s0 = rep.attribute("s").as_double(), len = rep.attribute("length").as_double();
        const double dist = rep.attribute("distance").as_double();
        if (dist > 0.1) {
          for (double s = s0; s <= s0 + len + 1e-9; s += dist) stations.push_back(s);
        }
      }
      const double t = o.attribute("t").as_double();
      for (double s : stations) {
        const Eigen::Vector2d p = r.point(s, t);
        if (type == "tree" || type == "vegetation") {
          b.pole_at(ObjectClass::TreeTrunk, p, src);
        } else if (type == "streetLamp") {
          b.pole_at(ObjectClass::LampPole, p, src);
        } else {
          b.pole_at(ObjectClass::Pole, p, src);
        }
      }
    }
    for (pugi::xml_node sg : r.node.child("signals").children("signal")) {
      const double s = sg.attribute("s").as_double(), t = sg.attribute("t").as_double();
      const RefPose ref = r.at(s);
      const std::string_view orient = sg.attribute("orientation").as_string("+");
      // "+": valid for traffic in +s direction -> the plate faces against +s.
      const double normal = ref.hdg + (orient == "-" ? 0.0 : kPi);
      b.sign_at(r.point(s, t), normal,
                "xodr road " + r.id + " signal " + sg.attribute("id").as_string());
    }
  }
  w.build_index();
  return world;
}

}  // namespace polmap::sim
