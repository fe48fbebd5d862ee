// HD-map comparison: HD-map features from the Lanelet2 OSM reader, and the point/line metrics.
#include "polmap/mapping_service/hdmap_compare.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <unordered_map>

#include "polmap/hdmap/lanelet2_osm.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::mapping {

namespace fs = std::filesystem;

// ------------------------------------------------------------------------ OSM reader

namespace {

std::string canonical_type(const std::string& t, const HdMapReadOptions& o) {
  for (const auto& [alias, canon] : o.type_aliases) {
    if (t == alias) return canon;
  }
  return t;
}

bool contains(const std::vector<std::string>& v, const std::string& s) {
  return std::find(v.begin(), v.end(), s) != v.end();
}

}  // namespace

HdMap read_lanelet2_osm(const fs::path& path, const HdMapReadOptions& options) {
  const hdmap::Lanelet2Osm osm = hdmap::read_lanelet2_osm_file(path);
  HdMap map;
  for (const auto& n : osm.nodes) {
    ++map.num_nodes;
    const std::string type = canonical_type(n.type, options);
    if (!type.empty() && contains(options.point_types, type)) {
      map.points.push_back({n.id, type, n.subtype, n.position});
    }
  }
  for (const auto& w : osm.ways) {
    ++map.num_ways;
    const std::string type = canonical_type(w.type, options);
    const bool is_point = contains(options.point_types, type);
    const bool is_line = contains(options.line_types, type);
    if (type.empty() || (!is_point && !is_line)) continue;
    std::vector<GeoPoint> pl;
    bool complete = true;
    for (const std::int64_t ref : w.node_refs) {
      const hdmap::OsmNode* node = osm.node(ref);
      if (node == nullptr) {
        complete = false;
        break;
      }
      pl.push_back(node->position);
    }
    if (!complete || pl.empty()) continue;
    if (is_point) {
      // Centroid of the distinct vertices (a closed way repeats its first node).
      std::size_t n = pl.size();
      if (n > 1 && pl.front().lat_deg == pl.back().lat_deg &&
          pl.front().lon_deg == pl.back().lon_deg) {
        --n;
      }
      GeoPoint c;
      for (std::size_t i = 0; i < n; ++i) {
        c.lat_deg += pl[i].lat_deg / static_cast<double>(n);
        c.lon_deg += pl[i].lon_deg / static_cast<double>(n);
        c.alt_m += pl[i].alt_m / static_cast<double>(n);
      }
      map.points.push_back({w.id, type, w.subtype, c});
    } else if (pl.size() >= 2) {
      map.lines.push_back({w.id, type, w.subtype, std::move(pl)});
    }
  }
  return map;
}

// ------------------------------------------------------------------------ metrics

namespace {

using Vec = Eigen::Vector2d;

struct Segment {
  Vec a;
  Vec b;
};

double point_segment_distance(const Vec& p, const Segment& s) {
  const Vec d = s.b - s.a;
  const double len2 = d.squaredNorm();
  double t = len2 > 0 ? (p - s.a).dot(d) / len2 : 0.0;
  t = std::clamp(t, 0.0, 1.0);
  return (p - (s.a + t * d)).norm();
}

/// Uniform grid over segments: nearest-segment distance queries up to a cutoff.
class SegmentGrid {
 public:
  SegmentGrid(std::vector<Segment> segs, double cell_m) : segs_(std::move(segs)), cell_(cell_m) {
    for (std::size_t i = 0; i < segs_.size(); ++i) {
      const auto& s = segs_[i];
      const auto [x0, y0] = key(s.a.cwiseMin(s.b));
      const auto [x1, y1] = key(s.a.cwiseMax(s.b));
      // Long segments: insert only cells near the segment (its distance to the cell
      // centre below a cell diagonal), not the whole bounding box.
      for (std::int64_t x = x0; x <= x1; ++x) {
        for (std::int64_t y = y0; y <= y1; ++y) {
          const Vec c((x + 0.5) * cell_, (y + 0.5) * cell_);
          if (point_segment_distance(c, s) <= cell_ * 0.7072) cells_[pack(x, y)].push_back(i);
        }
      }
    }
  }
  /// Distance to the nearest segment if it is <= cutoff (cutoff <= cell size).
  [[nodiscard]] std::optional<double> nearest(const Vec& p, double cutoff) const {
    const auto [cx, cy] = key(p);
    double best = std::numeric_limits<double>::infinity();
    for (std::int64_t x = cx - 1; x <= cx + 1; ++x) {
      for (std::int64_t y = cy - 1; y <= cy + 1; ++y) {
        const auto it = cells_.find(pack(x, y));
        if (it == cells_.end()) continue;
        for (std::size_t i : it->second) best = std::min(best, point_segment_distance(p, segs_[i]));
      }
    }
    if (best <= cutoff) return best;
    return std::nullopt;
  }

 private:
  [[nodiscard]] std::pair<std::int64_t, std::int64_t> key(const Vec& p) const {
    return {static_cast<std::int64_t>(std::floor(p.x() / cell_)),
            static_cast<std::int64_t>(std::floor(p.y() / cell_))};
  }
  static std::uint64_t pack(std::int64_t x, std::int64_t y) {
    return (static_cast<std::uint64_t>(x) << 32U) ^ (static_cast<std::uint64_t>(y) & 0xffffffffULL);
  }
  std::vector<Segment> segs_;
  double cell_;
  std::unordered_map<std::uint64_t, std::vector<std::size_t>> cells_;
};

std::vector<Segment> segments_of(const std::vector<std::vector<Vec>>& lines) {
  std::vector<Segment> segs;
  for (const auto& l : lines) {
    for (std::size_t i = 1; i < l.size(); ++i) segs.push_back({l[i - 1], l[i]});
  }
  return segs;
}

std::optional<double> median(std::vector<double> v) {
  if (v.empty()) return std::nullopt;
  const std::size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(mid), v.end());
  double m = v[mid];
  if (v.size() % 2 == 0) {
    m = 0.5 * (m + *std::max_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(mid)));
  }
  return m;
}

struct Box {
  Vec lo{std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
  Vec hi{-std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity()};
  void add(const Vec& p) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  [[nodiscard]] bool empty() const { return lo.x() > hi.x(); }
  [[nodiscard]] Box grown(double m) const {
    Box b = *this;
    b.lo.array() -= m;
    b.hi.array() += m;
    return b;
  }
  [[nodiscard]] bool contains(const Vec& p) const {
    return p.x() >= lo.x() && p.x() <= hi.x() && p.y() >= lo.y() && p.y() <= hi.y();
  }
};

Box bounds_of(const std::vector<Vec>& pts, const std::vector<std::vector<Vec>>& lines) {
  Box b;
  for (const auto& p : pts) b.add(p);
  for (const auto& l : lines) {
    for (const auto& p : l) b.add(p);
  }
  return b;
}

}  // namespace

HdMapComparison compare_hdmap_metric(const std::vector<Vec>& map_points,
                                     const std::vector<std::vector<Vec>>& map_lines,
                                     const std::vector<Vec>& hd_points,
                                     const std::vector<std::vector<Vec>>& hd_lines,
                                     const HdMapCompareConfig& cfg) {
  POLMAP_EXPECT(cfg.point_match_radius_m > 0 && cfg.line_band_m > 0 && cfg.line_sample_step_m > 0);
  HdMapComparison out;
  // Evaluation areas: each map's features count where the other map exists.
  Box map_area, hd_area;
  const bool restrict = cfg.restrict_to_overlap;
  if (restrict) {
    map_area = bounds_of(map_points, map_lines).grown(cfg.overlap_margin_m);
    hd_area = bounds_of(hd_points, hd_lines).grown(cfg.overlap_margin_m);
  }
  const auto in_hd_area = [&](const Vec& p) { return !restrict || hd_area.contains(p); };
  const auto in_map_area = [&](const Vec& p) { return !restrict || map_area.contains(p); };

  // ---------------------------------------------------------------- points
  std::vector<std::size_t> mp, hp;  // indices inside the area
  for (std::size_t i = 0; i < map_points.size(); ++i) {
    if (in_hd_area(map_points[i])) mp.push_back(i);
  }
  for (std::size_t j = 0; j < hd_points.size(); ++j) {
    if (in_map_area(hd_points[j])) hp.push_back(j);
  }
  out.map_points = mp.size();
  out.hd_points = hp.size();
  out.map_point_in_area.assign(map_points.size(), false);
  out.hd_point_in_area.assign(hd_points.size(), false);
  for (std::size_t i : mp) out.map_point_in_area[i] = true;
  for (std::size_t j : hp) out.hd_point_in_area[j] = true;
  {
    // Candidate pairs within the radius via a grid over HD points.
    const double r = cfg.point_match_radius_m;
    std::unordered_map<std::uint64_t, std::vector<std::size_t>> grid;
    const auto cell = [&](const Vec& p) {
      return std::pair{static_cast<std::int64_t>(std::floor(p.x() / r)),
                       static_cast<std::int64_t>(std::floor(p.y() / r))};
    };
    const auto pack = [](std::int64_t x, std::int64_t y) {
      return (static_cast<std::uint64_t>(x) << 32U) ^
             (static_cast<std::uint64_t>(y) & 0xffffffffULL);
    };
    for (std::size_t j : hp) {
      const auto [x, y] = cell(hd_points[j]);
      grid[pack(x, y)].push_back(j);
    }
    std::vector<HdPointMatch> pairs;
    for (std::size_t i : mp) {
      const auto [cx, cy] = cell(map_points[i]);
      for (std::int64_t x = cx - 1; x <= cx + 1; ++x) {
        for (std::int64_t y = cy - 1; y <= cy + 1; ++y) {
          const auto it = grid.find(pack(x, y));
          if (it == grid.end()) continue;
          for (std::size_t j : it->second) {
            const double d = (map_points[i] - hd_points[j]).norm();
            if (d <= r) pairs.push_back({i, j, d});
          }
        }
      }
    }
    std::sort(pairs.begin(), pairs.end(), [](const HdPointMatch& a, const HdPointMatch& b) {
      return a.distance_m != b.distance_m ? a.distance_m < b.distance_m
             : a.map_index != b.map_index ? a.map_index < b.map_index
                                          : a.hd_index < b.hd_index;
    });
    std::vector<bool> map_used(map_points.size()), hd_used(hd_points.size());
    std::vector<double> offsets;
    for (const auto& p : pairs) {
      if (map_used[p.map_index] || hd_used[p.hd_index]) continue;
      map_used[p.map_index] = hd_used[p.hd_index] = true;
      out.point_matches.push_back(p);
      offsets.push_back(p.distance_m);
    }
    out.matched_points = out.point_matches.size();
    // Without HD point features in the area the HD map says nothing about radar points:
    // precision is undefined there, not 0.
    if (out.map_points > 0 && out.hd_points > 0) {
      out.point_precision = double(out.matched_points) / double(out.map_points);
    }
    if (out.hd_points > 0) out.point_recall = double(out.matched_points) / double(out.hd_points);
    out.point_median_offset_m = median(offsets);
  }

  // ---------------------------------------------------------------- lines
  // Samples of map lines and pieces of HD lines are visited line by line, in order, so
  // that consecutive ones with the same verdict form the runs a caller draws.
  const double band = cfg.line_band_m;
  const double cell = std::max(band, 0.5);
  {
    const SegmentGrid hd_grid(segments_of(hd_lines), cell);
    std::vector<double> offsets;
    for (std::size_t li = 0; li < map_lines.size(); ++li) {
      const auto& l = map_lines[li];
      std::vector<double> run_offsets;
      Vec prev;
      bool first = true;
      const auto close_run = [&](HdLinePosition end) {
        if (out.map_line_runs.empty() || out.map_line_runs.back().line != li) return;
        HdLineRun& r = out.map_line_runs.back();
        r.end = end;
        r.median_offset_m = median(run_offsets);
        run_offsets.clear();
      };
      const auto visit = [&](const Vec& p, HdLinePosition pos) {
        const bool in = in_hd_area(p);
        std::optional<double> d;
        if (in) {
          ++out.map_line_samples;
          d = hd_grid.nearest(p, band);
          if (d) offsets.push_back(*d);
        }
        const bool on = d.has_value();
        const double step_m = first ? 0.0 : (p - prev).norm();
        // The stretch from the previous sample belongs to the run that sample is in.
        if (!first) out.map_line_runs.back().length_m += step_m;
        if (first || out.map_line_runs.back().in_area != in ||
            out.map_line_runs.back().matched != on) {
          close_run(pos);
          out.map_line_runs.push_back({li, pos, pos, in, on, 0.0, 0, std::nullopt});
        }
        HdLineRun& r = out.map_line_runs.back();
        ++r.samples;
        r.end = pos;
        if (d) run_offsets.push_back(*d);
        prev = p;
        first = false;
      };
      if (l.empty()) continue;
      visit(l.front(), {0, 0.0});
      for (std::size_t i = 1; i < l.size(); ++i) {
        const Vec d = l[i] - l[i - 1];
        const int n = std::max(1, static_cast<int>(std::ceil(d.norm() / cfg.line_sample_step_m)));
        for (int k = 1; k <= n; ++k) {
          const double t = static_cast<double>(k) / n;
          visit(l[i - 1] + d * t, {i - 1, t});
        }
      }
      close_run(out.map_line_runs.back().end);
    }
    out.matched_line_samples = offsets.size();
    out.line_median_lateral_offset_m = median(offsets);
  }
  {
    const SegmentGrid map_grid(segments_of(map_lines), cell);
    for (std::size_t li = 0; li < hd_lines.size(); ++li) {
      const auto& l = hd_lines[li];
      bool first = true;
      for (std::size_t i = 1; i < l.size(); ++i) {
        const Vec d = l[i] - l[i - 1];
        const double len = d.norm();
        if (len <= 0) continue;
        const int n = std::max(1, static_cast<int>(std::ceil(len / cfg.line_sample_step_m)));
        for (int k = 0; k < n; ++k) {
          const Vec mid = l[i - 1] + d * ((k + 0.5) / n);
          const double piece = len / n;
          const bool in = in_map_area(mid);
          const bool covered = in && map_grid.nearest(mid, band).has_value();
          if (in) {
            out.line_total_length_m += piece;
            if (covered) out.line_covered_length_m += piece;
          }
          const HdLinePosition b{i - 1, static_cast<double>(k) / n};
          const HdLinePosition e{i - 1, static_cast<double>(k + 1) / n};
          if (first || out.hd_line_runs.back().in_area != in ||
              out.hd_line_runs.back().matched != covered) {
            out.hd_line_runs.push_back({li, b, e, in, covered, 0.0, 0, std::nullopt});
          }
          HdLineRun& r = out.hd_line_runs.back();
          r.end = e;
          r.length_m += piece;
          ++r.samples;
          first = false;
        }
      }
    }
    if (out.line_total_length_m > 0) {
      out.line_coverage = out.line_covered_length_m / out.line_total_length_m;
    }
  }
  return out;
}

std::optional<GeoBox> hdmap_bounds(const HdMap& hd) {
  GeoBox b{90.0, 180.0, -90.0, -180.0};
  bool any = false;
  const auto add = [&](const GeoPoint& p) {
    b.min_lat_deg = std::min(b.min_lat_deg, p.lat_deg);
    b.max_lat_deg = std::max(b.max_lat_deg, p.lat_deg);
    b.min_lon_deg = std::min(b.min_lon_deg, p.lon_deg);
    b.max_lon_deg = std::max(b.max_lon_deg, p.lon_deg);
    any = true;
  };
  for (const auto& p : hd.points) add(p.position);
  for (const auto& l : hd.lines) {
    for (const auto& p : l.polyline) add(p);
  }
  if (!any) return std::nullopt;
  return b;
}

HdMapComparison compare_with_hdmap(const LandmarkSet& landmarks, const HdMap& hd,
                                   const HdMapCompareConfig& cfg) {
  const auto box = hdmap_bounds(hd);
  GeoPoint origin;
  if (box) {
    origin.lat_deg = 0.5 * (box->min_lat_deg + box->max_lat_deg);
    origin.lon_deg = 0.5 * (box->min_lon_deg + box->max_lon_deg);
  } else if (!landmarks.points.empty()) {
    origin = landmarks.points.front().position;
  } else if (!landmarks.lines.empty() && !landmarks.lines.front().polyline.empty()) {
    origin = landmarks.lines.front().polyline.front();
  }
  const tiles::LocalFrame frame(origin);
  std::vector<Vec> mp, hp;
  std::vector<std::vector<Vec>> ml, hl;
  for (const auto& p : landmarks.points) mp.push_back(frame.to_local(p.position));
  for (const auto& l : landmarks.lines) {
    auto& v = ml.emplace_back();
    for (const auto& p : l.polyline) v.push_back(frame.to_local(p));
  }
  for (const auto& p : hd.points) hp.push_back(frame.to_local(p.position));
  for (const auto& l : hd.lines) {
    auto& v = hl.emplace_back();
    for (const auto& p : l.polyline) v.push_back(frame.to_local(p));
  }
  return compare_hdmap_metric(mp, ml, hp, hl, cfg);
}

namespace {

GeoPoint along(const std::vector<GeoPoint>& pl, HdLinePosition p) {
  const GeoPoint& a = pl[p.segment];
  if (p.segment + 1 >= pl.size()) return a;
  const GeoPoint& b = pl[p.segment + 1];
  // Linear in degrees: a segment spans metres to a few hundred metres, where the
  // difference to the metric interpolation is far below the comparison's tolerances.
  return {a.lat_deg + p.t * (b.lat_deg - a.lat_deg), a.lon_deg + p.t * (b.lon_deg - a.lon_deg),
          a.alt_m + p.t * (b.alt_m - a.alt_m)};
}

/// The part of `pl` between two positions (consecutive duplicates dropped).
std::vector<GeoPoint> sub_polyline(const std::vector<GeoPoint>& pl, HdLinePosition b,
                                   HdLinePosition e) {
  std::vector<GeoPoint> out;
  const auto push = [&](const GeoPoint& g) {
    if (out.empty() || out.back().lat_deg != g.lat_deg || out.back().lon_deg != g.lon_deg) {
      out.push_back(g);
    }
  };
  push(along(pl, b));
  for (std::size_t v = b.segment + 1; v <= e.segment && v < pl.size(); ++v) push(pl[v]);
  push(along(pl, e));
  return out;
}

nlohmann::json lonlat(const GeoPoint& g) { return nlohmann::json::array({g.lon_deg, g.lat_deg}); }

nlohmann::json feature(nlohmann::json geometry, nlohmann::json properties) {
  return {{"type", "Feature"},
          {"geometry", std::move(geometry)},
          {"properties", std::move(properties)}};
}

nlohmann::json point_geometry(const GeoPoint& g) {
  return {{"type", "Point"}, {"coordinates", lonlat(g)}};
}

nlohmann::json opt_json(const std::optional<double>& v) {
  return v ? nlohmann::json(*v) : nlohmann::json(nullptr);
}

}  // namespace

nlohmann::json hdmap_comparison_geojson(const LandmarkSet& lm, const HdMap& hd,
                                        const HdMapComparison& c) {
  POLMAP_EXPECT(c.map_point_in_area.size() == lm.points.size() &&
                c.hd_point_in_area.size() == hd.points.size());
  std::unordered_map<std::size_t, const HdPointMatch*> by_map, by_hd;
  for (const auto& m : c.point_matches) {
    POLMAP_EXPECT(m.map_index < lm.points.size() && m.hd_index < hd.points.size());
    by_map[m.map_index] = &m;
    by_hd[m.hd_index] = &m;
  }
  // A feature is judged only when the other map has features of its kind in the area: radar
  // points against an HD map without signs or poles are neither matched nor unmatched (as
  // their precision is undefined then).
  const bool judged_hd_points = c.map_points > 0;
  const bool judged_map_points = c.hd_points > 0;
  const bool judged_hd_lines = !lm.lines.empty();
  const bool judged_map_lines = c.line_total_length_m > 0;
  nlohmann::json features = nlohmann::json::array();
  for (std::size_t j = 0; j < hd.points.size(); ++j) {
    const HdMapPoint& p = hd.points[j];
    nlohmann::json props{{"role", "hd"},
                         {"type", p.type},
                         {"subtype", p.subtype},
                         {"hd_id", p.id},
                         {"in_area", bool(c.hd_point_in_area[j])},
                         {"judged", judged_hd_points},
                         {"matched", false}};
    if (const auto it = by_hd.find(j); it != by_hd.end()) {
      props["matched"] = true;
      props["distance_m"] = it->second->distance_m;
      props["landmark_key"] = std::to_string(lm.points[it->second->map_index].key);
    }
    features.push_back(feature(point_geometry(p.position), std::move(props)));
  }
  for (std::size_t i = 0; i < lm.points.size(); ++i) {
    const StoredPointLandmark& p = lm.points[i];
    nlohmann::json props{{"role", "map"},
                         {"type", "point_landmark"},
                         {"key", std::to_string(p.key)},
                         {"class", std::string(to_string(p.scattering))},
                         {"support_drives", p.support_drives},
                         {"in_area", bool(c.map_point_in_area[i])},
                         {"judged", judged_map_points},
                         {"matched", false}};
    if (const auto it = by_map.find(i); it != by_map.end()) {
      props["matched"] = true;
      props["distance_m"] = it->second->distance_m;
      props["hd_id"] = hd.points[it->second->hd_index].id;
      props["hd_type"] = hd.points[it->second->hd_index].type;
    }
    features.push_back(feature(point_geometry(p.position), std::move(props)));
  }
  // Per HD line: covered share of its length inside the evaluation area.
  std::vector<double> in_len(hd.lines.size(), 0.0), cov_len(hd.lines.size(), 0.0);
  for (const HdLineRun& r : c.hd_line_runs) {
    POLMAP_EXPECT(r.line < hd.lines.size());
    if (!r.in_area) continue;
    in_len[r.line] += r.length_m;
    if (r.matched) cov_len[r.line] += r.length_m;
  }
  const auto line_feature = [&](const std::vector<GeoPoint>& pl, const HdLineRun& r, bool judged,
                                nlohmann::json props) {
    const std::vector<GeoPoint> part = sub_polyline(pl, r.begin, r.end);
    if (part.size() < 2) return;  // a single-vertex line has nothing to draw
    nlohmann::json coords = nlohmann::json::array();
    for (const auto& g : part) coords.push_back(lonlat(g));
    props["in_area"] = r.in_area;
    props["judged"] = judged;
    props["matched"] = r.matched;
    props["length_m"] = r.length_m;
    features.push_back(
        feature({{"type", "LineString"}, {"coordinates", std::move(coords)}}, std::move(props)));
  };
  for (const HdLineRun& r : c.hd_line_runs) {
    const HdMapLine& l = hd.lines[r.line];
    line_feature(
        l.polyline, r, judged_hd_lines,
        {{"role", "hd"},
         {"type", l.type},
         {"subtype", l.subtype},
         {"hd_id", l.id},
         {"line_coverage", in_len[r.line] > 0 ? nlohmann::json(cov_len[r.line] / in_len[r.line])
                                              : nlohmann::json(nullptr)}});
  }
  for (const HdLineRun& r : c.map_line_runs) {
    POLMAP_EXPECT(r.line < lm.lines.size());
    const StoredLineLandmark& l = lm.lines[r.line];
    line_feature(l.polyline, r, judged_map_lines,
                 {{"role", "map"},
                  {"type", "line_landmark"},
                  {"key", std::to_string(l.key)},
                  {"support_drives", l.support_drives},
                  {"samples", r.samples},
                  {"median_offset_m", opt_json(r.median_offset_m)}});
  }
  return {{"type", "FeatureCollection"},
          {"features", std::move(features)},
          {"properties", {{"summary", to_json(c)}}}};
}

nlohmann::json to_json(const HdMapComparison& c) {
  const auto opt = [](const std::optional<double>& v) -> nlohmann::json {
    return v ? nlohmann::json(*v) : nlohmann::json(nullptr);
  };
  return {{"point_precision", opt(c.point_precision)},
          {"point_recall", opt(c.point_recall)},
          {"point_median_offset_m", opt(c.point_median_offset_m)},
          {"line_median_lateral_offset_m", opt(c.line_median_lateral_offset_m)},
          {"line_covered_length_m", c.line_covered_length_m},
          {"line_total_length_m", c.line_total_length_m},
          {"line_coverage", opt(c.line_coverage)},
          {"map_points", c.map_points},
          {"hd_points", c.hd_points},
          {"matched_points", c.matched_points},
          {"map_line_samples", c.map_line_samples},
          {"matched_line_samples", c.matched_line_samples}};
}

}  // namespace polmap::mapping
