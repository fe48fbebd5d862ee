#include "polmap/eval/detect_eval.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>
#include <unordered_map>

#include "polmap/schema/errors.hpp"

namespace polmap::eval {
namespace {

std::int64_t grid_key(int ix, int iy) {
  return (static_cast<std::int64_t>(ix) << 32) ^ static_cast<std::uint32_t>(iy);
}

/// Uniform-grid index of points for radius queries.
class PointIndex {
 public:
  explicit PointIndex(double cell_m) : cell_(cell_m) {}
  void add(const Eigen::Vector2d& p, std::size_t id) {
    cells_[grid_key(ix(p.x()), ix(p.y()))].push_back({p, id});
  }
  /// Whether some point within r satisfies pred(point, id).
  template <typename Pred>
  [[nodiscard]] bool any(const Eigen::Vector2d& q, double r, Pred&& pred) const {
    return visit(q, r, [&](const Eigen::Vector2d& p, std::size_t i, double) { return pred(p, i); });
  }
  /// Nearest point within r: (distance, id), distance = inf if none.
  [[nodiscard]] std::pair<double, std::size_t> nearest(const Eigen::Vector2d& q, double r) const {
    double best = std::numeric_limits<double>::infinity();
    std::size_t id = 0;
    visit(q, r, [&](const Eigen::Vector2d&, std::size_t i, double d) {
      if (d < best) {
        best = d;
        id = i;
      }
      return false;
    });
    return {best, id};
  }

 private:
  /// Calls fn(point, id, distance) for the points within r of q until it returns true.
  template <typename Fn>
  bool visit(const Eigen::Vector2d& q, double r, Fn&& fn) const {
    const int n = static_cast<int>(std::ceil(r / cell_));
    const int cx = ix(q.x()), cy = ix(q.y());
    for (int dy = -n; dy <= n; ++dy) {
      for (int dx = -n; dx <= n; ++dx) {
        auto it = cells_.find(grid_key(cx + dx, cy + dy));
        if (it == cells_.end()) continue;
        for (const auto& [p, i] : it->second) {
          const double d = (p - q).norm();
          if (d <= r && fn(p, i, d)) return true;
        }
      }
    }
    return false;
  }
  [[nodiscard]] int ix(double v) const { return static_cast<int>(std::floor(v / cell_)); }
  double cell_;
  std::unordered_map<std::int64_t, std::vector<std::pair<Eigen::Vector2d, std::size_t>>> cells_;
};

double dist_to_segment(const Eigen::Vector2d& p, const Eigen::Vector2d& a,
                       const Eigen::Vector2d& b) {
  const Eigen::Vector2d d = b - a;
  const double l2 = d.squaredNorm();
  const double t = l2 > 0.0 ? std::clamp(d.dot(p - a) / l2, 0.0, 1.0) : 0.0;
  return (a + t * d - p).norm();
}

/// Uniform-grid index of segments (each listed in every cell its padded box touches).
class SegmentIndex {
 public:
  SegmentIndex(double cell_m, double pad_m) : cell_(cell_m), pad_(pad_m) {}
  void add(const Eigen::Vector2d& a, const Eigen::Vector2d& b, std::size_t id) {
    const std::size_t k = segs_.size();
    segs_.push_back({a, b, id});
    const int x0 = ix(std::min(a.x(), b.x()) - pad_), x1 = ix(std::max(a.x(), b.x()) + pad_);
    const int y0 = ix(std::min(a.y(), b.y()) - pad_), y1 = ix(std::max(a.y(), b.y()) + pad_);
    for (int y = y0; y <= y1; ++y) {
      for (int x = x0; x <= x1; ++x) cells_[grid_key(x, y)].push_back(k);
    }
  }
  /// Nearest segment within pad: (distance, id).
  [[nodiscard]] std::pair<double, std::size_t> nearest(const Eigen::Vector2d& q) const {
    double best = std::numeric_limits<double>::infinity();
    std::size_t id = 0;
    auto it = cells_.find(grid_key(ix(q.x()), ix(q.y())));
    if (it == cells_.end()) return {best, id};
    for (std::size_t k : it->second) {
      const double d = dist_to_segment(q, segs_[k].a, segs_[k].b);
      if (d < best) {
        best = d;
        id = segs_[k].id;
      }
    }
    return {best, id};
  }

 private:
  struct Seg {
    Eigen::Vector2d a, b;
    std::size_t id;
  };
  [[nodiscard]] int ix(double v) const { return static_cast<int>(std::floor(v / cell_)); }
  double cell_, pad_;
  std::vector<Seg> segs_;
  std::unordered_map<std::int64_t, std::vector<std::size_t>> cells_;
};

PointIndex path_index(const std::vector<Eigen::Vector2d>& traj, double r) {
  PointIndex idx(std::max(1.0, r));
  Eigen::Vector2d last(std::numeric_limits<double>::infinity(), 0.0);
  for (std::size_t i = 0; i < traj.size(); ++i) {
    if ((traj[i] - last).norm() < 1.0 && i + 1 != traj.size()) continue;  // 1 m decimation
    idx.add(traj[i], i);
    last = traj[i];
  }
  return idx;
}

template <typename Fn>
void sample_polyline(const std::vector<Eigen::Vector2d>& poly, double step, Fn&& fn) {
  for (std::size_t i = 0; i + 1 < poly.size(); ++i) {
    const Eigen::Vector2d a = poly[i], b = poly[i + 1];
    const double len = (b - a).norm();
    const int n = std::max(1, static_cast<int>(std::ceil(len / step)));
    for (int k = 0; k < n; ++k) fn(a + (b - a) * ((k + 0.5) / n), len / n);
  }
}

}  // namespace

bool TruthObject::present_in(int drive) const {
  if (permanent) return true;
  return std::find(drives_present.begin(), drives_present.end(), drive) != drives_present.end();
}

std::vector<Eigen::Vector2d> TruthObject::geometry_in(int drive) const {
  if (positions_by_drive_m.empty()) return geometry_m;
  const auto it = std::find(drives_present.begin(), drives_present.end(), drive);
  if (it == drives_present.end()) return geometry_m;
  return {positions_by_drive_m[static_cast<std::size_t>(it - drives_present.begin())]};
}

WorldTruth parse_world_truth(const std::string& text, const tiles::LocalFrame& frame,
                             const std::string& source) {
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text);
  } catch (const std::exception& e) {
    throw FormatError(source + ": not JSON: " + e.what());
  }
  try {
    if (j.value("format", "") != "polmap-sim-world-truth") {
      throw FormatError(source + ": field 'format' is not polmap-sim-world-truth");
    }
    WorldTruth w;
    w.origin = {j.at("origin").at("lat_deg").get<double>(),
                j.at("origin").at("lon_deg").get<double>(), j.at("origin").value("alt_m", 0.0)};
    const tiles::LocalFrame world_frame(w.origin);
    auto to_frame = [&](const nlohmann::json& p) {
      return frame.to_local(p.at("lat_deg").get<double>(), p.at("lon_deg").get<double>());
    };
    if (j.contains("route")) {
      for (const auto& xy : j.at("route").at("xy")) {
        const Eigen::Vector2d p(xy.at(0).get<double>(), xy.at(1).get<double>());
        const GeoPoint g = world_frame.to_geo(p);
        w.route_m.push_back(frame.to_local(g.lat_deg, g.lon_deg));
      }
    }
    for (const auto& o : j.at("objects")) {
      TruthObject t;
      t.id = o.at("id").get<std::uint32_t>();
      t.cls = o.at("class").get<std::string>();
      t.mechanism = o.value("mechanism", "");
      t.permanent = o.value("permanent", true);
      if (o.contains("drives_present"))
        t.drives_present = o.at("drives_present").get<std::vector<int>>();
      if (o.contains("position")) {
        t.geometry_m.push_back(to_frame(o.at("position")));
        if (o.contains("positions_by_drive")) {
          for (const auto& p : o.at("positions_by_drive")) {
            t.positions_by_drive_m.push_back(to_frame(p));
          }
          if (t.positions_by_drive_m.size() != t.drives_present.size()) {
            throw FormatError(source + ": object " + std::to_string(t.id) +
                              ": positions_by_drive does not match drives_present");
          }
        }
      } else {
        for (const auto& p : o.at("polyline")) t.geometry_m.push_back(to_frame(p));
      }
      w.objects.push_back(std::move(t));
    }
    return w;
  } catch (const nlohmann::json::exception& e) {
    throw FormatError(source + ": missing or invalid field: " + e.what());
  }
}

WorldTruth read_world_truth(const std::filesystem::path& path, const tiles::LocalFrame& frame) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IoError("cannot read " + path.string());
  std::ostringstream ss;
  ss << in.rdbuf();
  return parse_world_truth(ss.str(), frame, path.string());
}

DetectEval evaluate_detections(const std::vector<PointCandidate>& points,
                               const std::vector<LineCandidate>& lines,
                               const WorldTruth& world_truth, int drive,
                               const std::vector<Eigen::Vector2d>& trajectory,
                               const DetectEvalConfig& cfg) {
  // The truth as it stood in this drive: temporary objects where they were that day.
  WorldTruth truth = world_truth;
  for (TruthObject& o : truth.objects) o.geometry_m = o.geometry_in(drive);
  DetectEval ev;
  const PointIndex path = path_index(trajectory, cfg.max_distance_from_path_m);
  const double cos_bearing = std::cos(cfg.max_bearing_deg * 3.14159265358979323846 / 180.0);
  // Within range of a trajectory position and in front of it (the sensors look forward).
  auto observable = [&](const Eigen::Vector2d& p) {
    return path.any(p, cfg.max_distance_from_path_m, [&](const Eigen::Vector2d& x, std::size_t i) {
      const std::size_t j = i + 1 < trajectory.size() ? i + 1 : i;
      const std::size_t k = j == i && i > 0 ? i - 1 : i;
      Eigen::Vector2d h = trajectory[j] - trajectory[k];
      if (h.norm() < 1e-6) return true;  // standstill: no heading, accept
      const Eigen::Vector2d v = p - x;
      return v.norm() < 1e-6 || h.normalized().dot(v.normalized()) >= cos_bearing;
    });
  };
  // Truth indexes: point-like landmarks, and every present object as segments (structure).
  PointIndex truth_points(2.0);
  double max_obj_r = 0.0;
  for (const auto& [c, r] : cfg.object_radius_m) max_obj_r = std::max(max_obj_r, r);
  SegmentIndex structure(4.0, std::max(cfg.point_radius_m, cfg.line_radius_m) + max_obj_r);
  SegmentIndex line_truth(4.0, cfg.line_radius_m);
  std::vector<std::pair<std::size_t, double>> radius_objects;
  for (std::size_t i = 0; i < truth.objects.size(); ++i) {
    const TruthObject& o = truth.objects[i];
    if (!o.present_in(drive) || o.geometry_m.empty()) continue;
    if (o.is_point()) {
      if (auto it = cfg.object_radius_m.find(o.cls); it != cfg.object_radius_m.end()) {
        radius_objects.push_back({i, it->second});
      }
      if (cfg.point_classes.count(o.cls)) truth_points.add(o.geometry_m[0], i);
      structure.add(o.geometry_m[0], o.geometry_m[0], i);
    } else {
      for (std::size_t k = 0; k + 1 < o.geometry_m.size(); ++k) {
        structure.add(o.geometry_m[k], o.geometry_m[k + 1], i);
        if (cfg.line_classes.count(o.cls)) line_truth.add(o.geometry_m[k], o.geometry_m[k + 1], i);
      }
    }
  }

  // Within r of a present object (extended objects by their polyline, cars and bins
  // by their radius).
  auto on_structure = [&](const Eigen::Vector2d& q, double r) {
    const auto [d, id] = structure.nearest(q);
    if (!std::isfinite(d)) return false;
    if (d <= r) return true;
    // The nearest segment may be a point object with a radius, or another object may
    // be within its radius: check the radius objects near q explicitly.
    for (const auto& [idx, rad] : radius_objects) {
      if ((truth.objects[idx].geometry_m[0] - q).norm() <= rad + r) return true;
    }
    return false;
  };

  // ---- points
  PointEval& pe = ev.points;
  pe.candidates = points.size();
  PointIndex cand(2.0);
  double se = 0.0;
  std::size_t matched = 0;
  for (std::size_t k = 0; k < points.size(); ++k) {
    const PointCandidate& p = points[k];
    cand.add(p.position_m, k);
    const auto [d, id] = truth_points.nearest(p.position_m, cfg.point_radius_m);
    if (std::isfinite(d)) {
      ++pe.candidates_on_points;
      ++pe.candidates_on_structure;
      se += d * d;
      ++matched;
      const std::string& mech = truth.objects[id].mechanism;
      if (mech == "odd" || mech == "even") {
        ++pe.class_pairs;
        const ScatteringClass want = mech == "odd" ? ScatteringClass::Odd : ScatteringClass::Even;
        pe.class_correct += p.scattering == want;
      }
    } else if (on_structure(p.position_m, cfg.point_radius_m)) {
      ++pe.candidates_on_structure;
    }
  }
  for (const TruthObject& o : truth.objects) {
    if (!o.is_point() || !cfg.point_classes.count(o.cls) || !o.present_in(drive)) continue;
    if (!observable(o.geometry_m[0])) continue;
    ++pe.truth_observable;
    auto& byc = pe.recall_by_class[o.cls];
    ++byc.first;
    if (std::isfinite(cand.nearest(o.geometry_m[0], cfg.point_radius_m).first)) {
      ++pe.truth_found;
      ++byc.second;
    }
  }
  pe.precision = pe.candidates ? double(pe.candidates_on_points) / pe.candidates : 0.0;
  pe.structure_precision = pe.candidates ? double(pe.candidates_on_structure) / pe.candidates : 0.0;
  pe.recall = pe.truth_observable ? double(pe.truth_found) / pe.truth_observable : 0.0;
  pe.rms_error_m = matched ? std::sqrt(se / matched) : 0.0;
  pe.class_accuracy = pe.class_pairs ? double(pe.class_correct) / pe.class_pairs : 0.0;

  // ---- lines
  LineEval& le = ev.lines;
  le.candidates = lines.size();
  SegmentIndex cand_lines(4.0, cfg.line_radius_m);
  for (std::size_t k = 0; k < lines.size(); ++k) {
    cand_lines.add(lines[k].start_m, lines[k].end_m, k);
    sample_polyline({lines[k].start_m, lines[k].end_m}, cfg.sample_step_m,
                    [&](const Eigen::Vector2d& p, double w) {
                      le.candidate_length_m += w;
                      if (on_structure(p, cfg.line_radius_m)) {
                        le.candidate_length_on_truth_m += w;
                      }
                    });
  }
  for (const TruthObject& o : truth.objects) {
    if (o.is_point() || !cfg.line_classes.count(o.cls) || !o.present_in(drive)) continue;
    auto& byc = le.coverage_by_class[o.cls];
    sample_polyline(o.geometry_m, cfg.sample_step_m, [&](const Eigen::Vector2d& p, double w) {
      if (!observable(p)) return;
      le.truth_length_m += w;
      byc.first += w;
      if (cand_lines.nearest(p).first <= cfg.line_radius_m) {
        le.truth_covered_m += w;
        byc.second += w;
      }
    });
  }
  le.precision =
      le.candidate_length_m > 0 ? le.candidate_length_on_truth_m / le.candidate_length_m : 0.0;
  le.coverage = le.truth_length_m > 0 ? le.truth_covered_m / le.truth_length_m : 0.0;
  return ev;
}

double point_repeatability(const std::vector<PointCandidate>& a,
                           const std::vector<Eigen::Vector2d>& traj_a,
                           const std::vector<PointCandidate>& b,
                           const std::vector<Eigen::Vector2d>& traj_b,
                           const DetectEvalConfig& cfg) {
  const PointIndex pa = path_index(traj_a, cfg.max_distance_from_path_m);
  const PointIndex pb = path_index(traj_b, cfg.max_distance_from_path_m);
  auto common = [&](const Eigen::Vector2d& p) {
    return std::isfinite(pa.nearest(p, cfg.max_distance_from_path_m).first) &&
           std::isfinite(pb.nearest(p, cfg.max_distance_from_path_m).first);
  };
  auto share = [&](const std::vector<PointCandidate>& x, const std::vector<PointCandidate>& y) {
    PointIndex iy(2.0);
    for (std::size_t k = 0; k < y.size(); ++k) iy.add(y[k].position_m, k);
    std::size_t n = 0, hit = 0;
    for (const auto& p : x) {
      if (!common(p.position_m)) continue;
      ++n;
      hit += std::isfinite(iy.nearest(p.position_m, cfg.point_radius_m).first);
    }
    return n ? double(hit) / n : 0.0;
  };
  return 0.5 * (share(a, b) + share(b, a));
}

}  // namespace polmap::eval
