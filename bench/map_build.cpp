// Benchmark: map build time against the number of drives, and ingest rate.
//
// Synthetic urban route of --length-km (default 2 km) with permanent point
// objects (poles, posts, signs: --points-per-km on both sides together) and
// walls/kerbs (--walls-per-km segments of 5–20 m), re-driven N times. Each drive
// sees 90 % of the permanent objects with 5 cm position noise (1–3 line
// candidates per wall, broken at random places), plus --temporaries-per-km
// single-drive objects (parked cars, bins) and clutter. Candidates go through
// the real path: put_drive into a SqliteMapStore (temp dir), MapBuilder::build
// (consensus, landmarks, tiles, atomic publish), then one more drive and an
// incremental build. The fleet gridmap is not part of this benchmark (the
// synthetic packages have no gridmap.tif). Each drive carries its trajectory
// (the route with a lateral offset of up to ±0.5 m, one drive per hour), so the
// builder judges support against the drives that passed with a place in view.
//
// Accuracy against the route's truth: a point landmark is correct when it is
// within --radius-m of a permanent object not matched by a nearer landmark
// (one-to-one, nearest first); precision = correct / landmarks, recall = matched
// objects / objects, RMSE over the matched pairs. Lines by length: precision =
// share of landmark length (sampled every 0.25 m) within --radius-m of a wall,
// recall = share of wall length within --radius-m of a line landmark.
//
//   bench_map_build [--drives 2,4,8,16] [--length-km 2] [--seed 1] [--keep DIR]
//                   [--view-fraction F] (default: the builder's; 0 = fixed count only)
//                   [--world urban [--sim-cache DIR]] (drives from the simulator)
//                   [--parked-shift-m M] (simulator: parked cars stand within +-M of their
//                   place in each drive, bins within +-M/2; --explain then names the
//                   object of the nearest nominal place, up to M away)
//                   [--sliding 0|1 --sliding-min-along-m M --sliding-ratio R
//                    --sliding-min-support N] (point_filter.hpp SlidingRule)
//                   [--mirror-ghosts 0|1 --mirror-image-radius-m R --mirror-image-drives N]
//                   (point_filter.hpp MirrorGhostRule)
//                   [--line-overhead 0|1 --range-streaks 0|1 --streak-share S
//                    --streak-max-length-m L --streak-angle-deg A --line-out-of-view 0|1]
//                   (line_filter.hpp)
//                   [--explain] [--dump DIR] (simulator: what false landmarks are near, and
//                   each 200 m window's own fit to truth; the map, line candidates and world
//                   objects as CSV for offline analysis)
#include <sys/resource.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <sstream>

#include "polmap/eval/map_geometry.hpp"
#include "polmap/eval/study.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/map_builder.hpp"
#include "polmap/mapping_service/merged_gridmap_extract.hpp"
#include "polmap/mapping_service/polyline_distance.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/world.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace {
namespace fs = std::filesystem;
using namespace polmap;
using namespace polmap::mapping;

struct Route {
  std::vector<Eigen::Vector2d> objects;
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> walls;
  double length_m = 0;
};

/// An L-shaped urban route (x east, then north), objects 3–8 m left/right of it.
Route make_route(double length_m, double points_per_km, double walls_per_km, std::mt19937& rng) {
  Route r;
  r.length_m = length_m;
  auto at = [&](double s, double offset) -> Eigen::Vector2d {
    const double half = length_m / 2;
    if (s < half) return {s - half, offset};
    return {0.0 - offset, s - half};
  };
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  const int n_points = static_cast<int>(points_per_km * length_m / 1000.0);
  for (int i = 0; i < n_points; ++i) {
    const double side = (i % 2 ? 1.0 : -1.0) * (3.0 + 5.0 * u01(rng));
    r.objects.push_back(at(u01(rng) * length_m, side));
  }
  const int n_walls = static_cast<int>(walls_per_km * length_m / 1000.0);
  for (int i = 0; i < n_walls; ++i) {
    const double s = u01(rng) * (length_m - 20.0);
    const double side = (i % 2 ? 1.0 : -1.0) * (8.0 + 4.0 * u01(rng));
    const double len = 5.0 + 15.0 * u01(rng);
    if (s < length_m / 2 && s + len > length_m / 2) continue;  // not across the corner
    r.walls.emplace_back(at(s, side), at(s + len, side));
  }
  return r;
}

/// Drive k over the route; with max_x only the part of the route west of max_x
/// (a short drive through a corner of the map).
DrivePackage drive(const Route& r, const GeoPoint& world_origin, int k, double temporaries_per_km,
                   std::mt19937& rng, double max_x = 1e18) {
  const tiles::LocalFrame world(world_origin);
  const GeoPoint origin = world.to_geo(Eigen::Vector2d(5.0 * k, -3.0 * k));
  const tiles::LocalFrame frame(origin);
  auto to_drive = [&](const Eigen::Vector2d& p) { return frame.to_local(world.to_geo(p)); };
  std::normal_distribution<double> noise(0.0, 0.05);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  DrivePackage pkg;
  pkg.manifest.drive_id = "drive_" + std::to_string(k);
  pkg.manifest.vehicle_id = "bench_" + std::to_string(k % 16);
  pkg.manifest.origin = origin;
  pkg.manifest.distance_m = r.length_m;
  pkg.manifest.start_time_s = 1.7e9 + 3600.0 * k;
  {
    const double lane = 1.0 * u01(rng) - 0.5;
    const double speed_mps = 10.0;
    for (double s = 0.0; s <= r.length_m; s += 1.0) {
      const double half = r.length_m / 2;
      const Eigen::Vector2d p =
          s < half ? Eigen::Vector2d(s - half, lane) : Eigen::Vector2d(0.0 - lane, s - half);
      if (p.x() > max_x) break;
      const GeoPoint g = world.to_geo(p);
      TrajectorySample t;
      t.time_s = pkg.manifest.start_time_s + s / speed_mps;
      t.lat_deg = g.lat_deg;
      t.lon_deg = g.lon_deg;
      t.yaw_enu_rad = s < half ? 0.0 : M_PI / 2;
      t.speed_mps = speed_mps;
      pkg.trajectory.push_back(t);
    }
    pkg.manifest.end_time_s = pkg.trajectory.back().time_s;
  }
  for (const auto& o : r.objects) {
    if (u01(rng) > 0.9 || o.x() > max_x) continue;
    PointCandidate c;
    c.position_m = to_drive(o + Eigen::Vector2d(noise(rng), noise(rng)));
    c.scattering = u01(rng) < 0.5 ? ScatteringClass::Odd : ScatteringClass::Even;
    c.strength = 5.0;
    pkg.points.push_back(c);
  }
  const int temps = static_cast<int>(temporaries_per_km * r.length_m / 1000.0);
  for (int i = 0; i < temps; ++i) {
    PointCandidate c;
    const auto& base = r.objects[static_cast<std::size_t>(u01(rng) * (r.objects.size() - 1))];
    if (base.x() > max_x) continue;
    c.position_m = to_drive(base + Eigen::Vector2d(6.0 * u01(rng) - 3.0, 6.0 * u01(rng) - 3.0));
    pkg.points.push_back(c);
  }
  for (const auto& [a, b] : r.walls) {
    if (u01(rng) > 0.9 || a.x() > max_x || b.x() > max_x) continue;
    // 1–3 pieces with small gaps (Hough segments break at occlusions).
    const int pieces = 1 + static_cast<int>(3 * u01(rng)) % 3;
    for (int p = 0; p < pieces; ++p) {
      const double t0 = static_cast<double>(p) / pieces + 0.02, t1 = (p + 1.0) / pieces - 0.02;
      LineCandidate l;
      l.start_m = to_drive(a + t0 * (b - a) + Eigen::Vector2d(noise(rng), noise(rng)) * 0.4);
      l.end_m = to_drive(a + t1 * (b - a) + Eigen::Vector2d(noise(rng), noise(rng)) * 0.4);
      l.strength = 1.0;
      pkg.lines.push_back(l);
    }
  }
  return pkg;
}

/// Samples every `step` along a polyline (end points included).
std::vector<Eigen::Vector2d> samples(const std::vector<Eigen::Vector2d>& pl, double step) {
  std::vector<Eigen::Vector2d> out;
  for (std::size_t i = 0; i + 1 < pl.size(); ++i) {
    const int n = std::max(1, static_cast<int>(std::ceil((pl[i + 1] - pl[i]).norm() / step)));
    for (int k = 0; k < n; ++k) out.push_back(pl[i] + (pl[i + 1] - pl[i]) * (double(k) / n));
  }
  if (!pl.empty()) out.push_back(pl.back());
  return out;
}

/// What the map should contain, in a local metric frame.
struct Truth {
  std::vector<Eigen::Vector2d> points;              ///< permanent point objects
  std::vector<std::vector<Eigen::Vector2d>> lines;  ///< permanent line objects
};

struct Accuracy {
  double point_precision = 0, point_recall = 0, point_recall_all = 0, point_rmse_m = 0;
  double line_precision = 0, line_recall = 0, line_recall_all = 0;
  /// Recall of the weak objects: those fewer than half of the drives detected.
  double point_recall_weak = 0, line_recall_weak = 0;
  std::size_t detectable_points = 0, points = 0;
};

/// Grid of polyline pieces for near-distance queries (cell = 1 m).
class NearIndex {
 public:
  explicit NearIndex(const std::vector<std::vector<Eigen::Vector2d>>& lines) {
    for (std::size_t l = 0; l < lines.size(); ++l) {
      for (std::size_t i = 0; i + 1 < lines[l].size(); ++i) {
        for (const auto& p : samples({lines[l][i], lines[l][i + 1]}, 0.5)) {
          auto& v = grid_[key(p)];
          if (v.empty() || v.back() != std::pair{l, i}) v.emplace_back(l, i);
        }
      }
    }
    lines_ = &lines;
  }
  /// Whether p is within r (<= 0.5 m) of any polyline.
  [[nodiscard]] bool near(const Eigen::Vector2d& p, double r) const {
    const auto [cx, cy] = key(p);
    for (long dx = -1; dx <= 1; ++dx) {
      for (long dy = -1; dy <= 1; ++dy) {
        auto it = grid_.find({cx + dx, cy + dy});
        if (it == grid_.end()) continue;
        for (const auto& [l, i] : it->second) {
          if (point_segment_distance(p, (*lines_)[l][i], (*lines_)[l][i + 1]) <= r) return true;
        }
      }
    }
    return false;
  }

 private:
  static std::pair<long, long> key(const Eigen::Vector2d& p) {
    return {std::lround(std::floor(p.x())), std::lround(std::floor(p.y()))};
  }
  std::map<std::pair<long, long>, std::vector<std::pair<std::size_t, std::size_t>>> grid_;
  const std::vector<std::vector<Eigen::Vector2d>>* lines_ = nullptr;
};

/// Points within r of p (grid of 1 m cells over a point set).
class PointIndex {
 public:
  explicit PointIndex(const std::vector<Eigen::Vector2d>& pts) : pts_(&pts) {
    for (std::size_t i = 0; i < pts.size(); ++i) {
      grid_[{std::lround(std::floor(pts[i].x())), std::lround(std::floor(pts[i].y()))}].push_back(
          i);
    }
  }
  template <typename F>
  void within(const Eigen::Vector2d& p, double r, F&& f) const {
    const long cx = std::lround(std::floor(p.x())), cy = std::lround(std::floor(p.y()));
    for (long dx = -1; dx <= 1; ++dx) {
      for (long dy = -1; dy <= 1; ++dy) {
        auto it = grid_.find({cx + dx, cy + dy});
        if (it == grid_.end()) continue;
        for (std::size_t i : it->second) {
          const double d = ((*pts_)[i] - p).norm();
          if (d <= r) f(i, d);
        }
      }
    }
  }

 private:
  const std::vector<Eigen::Vector2d>* pts_;
  std::map<std::pair<long, long>, std::vector<std::size_t>> grid_;
};

/// The map against the truth (see the file comment). Detectable truth: objects (line
/// samples) with a candidate within the radius in at least half of the drives: what
/// any consensus of these candidates can find; recall is against it, recall_all against
/// all truth.
Accuracy accuracy(const LandmarkSet& lms, const CandidateSet& cands, const Truth& truth,
                  const tiles::LocalFrame& world, double radius_m) {
  std::set<std::int64_t> drive_set;
  for (const auto& c : cands.points) drive_set.insert(c.drive);
  for (const auto& c : cands.lines) drive_set.insert(c.drive);
  const double half = 0.5 * static_cast<double>(drive_set.size());
  Accuracy a;
  // Points: all (landmark, object) pairs within the radius, nearest first, one-to-one.
  std::vector<Eigen::Vector2d> lp;
  for (const auto& p : lms.points) lp.push_back(world.to_local(p.position));
  const PointIndex objects(truth.points);
  std::vector<std::set<std::int64_t>> seen_by(truth.points.size());
  for (const auto& c : cands.points) {
    objects.within(world.to_local(c.position), radius_m,
                   [&](std::size_t o, double) { seen_by[o].insert(c.drive); });
  }
  std::vector<char> detectable(truth.points.size(), 0);
  for (std::size_t o = 0; o < truth.points.size(); ++o) {
    detectable[o] = static_cast<double>(seen_by[o].size()) >= half ? 1 : 0;
    a.detectable_points += detectable[o];
  }
  struct Pair {
    double d;
    std::size_t l, o;
  };
  std::vector<Pair> pairs;
  for (std::size_t l = 0; l < lp.size(); ++l) {
    objects.within(lp[l], radius_m, [&](std::size_t o, double d) { pairs.push_back({d, l, o}); });
  }
  std::sort(pairs.begin(), pairs.end(), [](const Pair& x, const Pair& y) {
    return std::tie(x.d, x.l, x.o) < std::tie(y.d, y.l, y.o);
  });
  std::vector<char> lu(lp.size(), 0), ou(truth.points.size(), 0);
  std::size_t matched = 0, matched_detectable = 0;
  a.points = lp.size();
  double ss = 0;
  for (const Pair& p : pairs) {
    if (lu[p.l] || ou[p.o]) continue;
    lu[p.l] = ou[p.o] = 1;
    ++matched;
    matched_detectable += detectable[p.o];
    ss += p.d * p.d;
  }
  a.point_precision = lp.empty() ? 0.0 : double(matched) / double(lp.size());
  a.point_recall =
      a.detectable_points ? double(matched_detectable) / double(a.detectable_points) : 0.0;
  a.point_recall_all = truth.points.empty() ? 0.0 : double(matched) / double(truth.points.size());
  a.point_rmse_m = matched ? std::sqrt(ss / double(matched)) : 0.0;
  const std::size_t weak = truth.points.size() - a.detectable_points;
  a.point_recall_weak = weak ? double(matched - matched_detectable) / double(weak) : 0.0;
  // Lines, by length.
  std::vector<std::vector<Eigen::Vector2d>> ll;
  for (const auto& l : lms.lines) {
    std::vector<Eigen::Vector2d> pl;
    for (const auto& g : l.polyline) pl.push_back(world.to_local(g));
    ll.push_back(std::move(pl));
  }
  const NearIndex near_truth(truth.lines), near_landmark(ll);
  std::size_t ln = 0, lok = 0;
  for (const auto& pl : ll) {
    for (const auto& p : samples(pl, 0.25)) ++ln, lok += near_truth.near(p, radius_m) ? 1 : 0;
  }
  // Truth samples, and by how many drives' line candidates each is covered.
  std::vector<Eigen::Vector2d> ts;
  for (const auto& pl : truth.lines) {
    for (const auto& p : samples(pl, 0.25)) ts.push_back(p);
  }
  std::vector<std::set<std::int64_t>> covered_by(ts.size());
  {
    const PointIndex tsi(ts);
    for (const auto& c : cands.lines) {
      const Eigen::Vector2d a0 = world.to_local(c.start), a1 = world.to_local(c.end);
      std::set<std::size_t> hit;
      for (const auto& p : samples({a0, a1}, 0.25)) {
        tsi.within(p, radius_m + 0.25, [&](std::size_t i, double) {
          if (point_segment_distance(ts[i], a0, a1) <= radius_m) hit.insert(i);
        });
      }
      for (std::size_t i : hit) covered_by[i].insert(c.drive);
    }
  }
  std::size_t wn = 0, wok = 0, dn = 0, dok = 0;
  for (std::size_t i = 0; i < ts.size(); ++i) {
    const bool ok = near_landmark.near(ts[i], radius_m);
    ++wn, wok += ok ? 1 : 0;
    if (static_cast<double>(covered_by[i].size()) >= half) ++dn, dok += ok ? 1 : 0;
  }
  a.line_recall_weak = wn > dn ? double(wok - dok) / double(wn - dn) : 0.0;
  a.line_precision = ln ? double(lok) / double(ln) : 0.0;
  a.line_recall = dn ? double(dok) / double(dn) : 0.0;
  a.line_recall_all = wn ? double(wok) / double(wn) : 0.0;
  return a;
}

Accuracy accuracy(const MapStore& store, std::int64_t version, const Truth& truth,
                  const tiles::LocalFrame& world, double radius_m) {
  return accuracy(store.landmarks_in(version, std::nullopt, false),
                  store.candidates_in(std::nullopt), truth, world, radius_m);
}

/// Landmarks extracted from the store's merged gridmap over the truth's extent, as a
/// LandmarkSet for accuracy().
LandmarkSet merged_landmarks(const MapStore& store, const Truth& truth,
                             const tiles::LocalFrame& world, const MergedExtractionConfig& cfg) {
  Eigen::Vector2d lo(1e18, 1e18), hi(-1e18, -1e18);
  for (const auto& p : truth.points) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
  for (const auto& l : truth.lines)
    for (const auto& p : l) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
  const GeoPoint sw = world.to_geo(lo - Eigen::Vector2d(5, 5));
  const GeoPoint ne = world.to_geo(hi + Eigen::Vector2d(5, 5));
  const MergedExtraction x =
      extract_from_merged_gridmap(store, {sw.lat_deg, sw.lon_deg, ne.lat_deg, ne.lon_deg}, cfg);
  LandmarkSet out;
  for (const auto& g : x.points) {
    StoredPointLandmark p;
    p.position = g;
    out.points.push_back(p);
  }
  for (const auto& [a, b] : x.lines) {
    StoredLineLandmark l;
    l.polyline = {a, b};
    out.lines.push_back(l);
  }
  return out;
}

double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

/// Where the drives come from: the synthetic route or the simulator.
class DriveSource {
 public:
  virtual ~DriveSource() = default;
  /// Ingests drive k of a fleet of n (k == n: one more full drive; k == n + 1: a short
  /// drive over the first 300 m); returns its candidate count.
  virtual std::size_t ingest(MapStore& store, const fs::path& dir, int n, int k) = 0;
  [[nodiscard]] virtual const Truth& truth() const = 0;
  [[nodiscard]] virtual const tiles::LocalFrame& frame() const = 0;
  /// Prints what the false point landmarks are near (simulator: nearest world object).
  virtual void explain(const MapStore& /*store*/, std::int64_t /*version*/,
                       double /*radius_m*/) const {}
  /// Writes the map, the line candidates and the world objects as CSV (local metres) into
  /// dir, for offline analysis (simulator only).
  virtual void dump(const MapStore& /*store*/, std::int64_t /*version*/,
                    const fs::path& /*dir*/) const {}
};

class SyntheticSource final : public DriveSource {
 public:
  SyntheticSource(double length_km, double points_per_km, double walls_per_km,
                  double temporaries_per_km, unsigned seed)
      : temporaries_per_km_(temporaries_per_km), seed_(seed), frame_(kOrigin) {
    std::mt19937 rng(seed);
    route_ = make_route(length_km * 1000.0, points_per_km, walls_per_km, rng);
    truth_.points = route_.objects;
    for (const auto& [a, b] : route_.walls) truth_.lines.push_back({a, b});
    std::printf(
        "synthetic route %.1f km: %zu point objects, %zu walls; per drive ~%.0f point + ~%.0f "
        "line candidates\n",
        length_km, route_.objects.size(), route_.walls.size(),
        0.9 * route_.objects.size() + temporaries_per_km * length_km,
        0.9 * 2 * route_.walls.size());
  }
  std::size_t ingest(MapStore& store, const fs::path& dir, int n, int k) override {
    if (k == 0) rng_.seed(seed_ * 1000 + static_cast<unsigned>(n));
    const double max_x = k == n + 1 ? -route_.length_m / 2 + 300.0 : 1e18;
    const DrivePackage p = drive(route_, kOrigin, k, temporaries_per_km_, rng_, max_x);
    // The store keeps the archive as given; the candidates come from `p` (what
    // validation would have produced), so a placeholder archive suffices here.
    const fs::path tar = dir / (p.manifest.drive_id + ".tar");
    const std::string bytes =
        write_ustar({{kManifestFileName, "bench package " + p.manifest.drive_id}});
    std::ofstream(tar, std::ios::binary) << bytes;
    (void)store.put_drive(p, tar, content_etag(bytes));
    return p.points.size() + p.lines.size();
  }
  [[nodiscard]] const Truth& truth() const override { return truth_; }
  [[nodiscard]] const tiles::LocalFrame& frame() const override { return frame_; }

 private:
  static constexpr GeoPoint kOrigin{48.7758, 9.1829, 0.0};
  Route route_;
  Truth truth_;
  double temporaries_per_km_;
  unsigned seed_;
  std::mt19937 rng_;
  tiles::LocalFrame frame_;
};

/// Drives of the simulator (tools/sim) over one world: moving traffic, parked cars and
/// bins present in a share of the drives, vegetation; processed by the real front end
/// (mapping mode, full polarimetry) into landmarks-only packages, validated and
/// ingested. Packages are cached in CACHE/drive_K (drive K is the same for every fleet
/// size). Truth: the world's permanent point objects (poles, posts, signs, trunks,
/// facade corners and recesses) and permanent line objects (curbs, road borders, walls,
/// facades, guardrails, fences); parked cars and bins are not truth.
class SimSource final : public DriveSource {
 public:
  SimSource(const std::string& world, double length_m, unsigned seed, fs::path cache,
            bool with_gridmap, sim::GnssGrade gnss = sim::GnssGrade::Rtk, int rtk_drives = 0,
            double canyon_multipath_m = -1.0, double heading_sigma_deg = -1.0,
            double bias_sigma_m = -1.0, double parked_shift_m = -1.0,
            std::string_view realism = "ideal", std::string_view realism_sources = "")
      : cache_(std::move(cache)), rtk_drives_(rtk_drives) {
    sim_.seed = seed;
    sim_.realism = sim::realism_preset(realism);
    if (!realism_sources.empty()) sim_.realism = sim::only_sources(sim_.realism, realism_sources);
    if (parked_shift_m >= 0.0) {  // where parked cars (and bins, half of it) stand per drive
      sim_.traffic.parked_shift_m = parked_shift_m;
      sim_.traffic.bin_shift_m = 0.5 * parked_shift_m;
    }
    sim_.gnss.grade = gnss;
    if (canyon_multipath_m >= 0.0) sim_.gnss.consumer.canyon_multipath_m = canyon_multipath_m;
    if (heading_sigma_deg >= 0.0) sim_.gnss.consumer.heading_sigma_deg = heading_sigma_deg;
    if (bias_sigma_m >= 0.0) {
      sim_.gnss.consumer.bias_sigma_m = bias_sigma_m;
      sim_.gnss.consumer.outages_per_km =
          bias_sigma_m > 0.0 ? sim_.gnss.consumer.outages_per_km : 0.0;
    }
    world_ = sim::load_world(world, length_m, seed, sim_);
    truth_.points = eval::truth_point_objects(*world_);  // the study's truth too
    for (const auto& o : world_->objects) {
      if (!o.permanent || o.geometry_m.size() < 2) continue;
      using C = sim::ObjectClass;
      switch (o.cls) {
        case C::GuardrailBeam:
        case C::Curbstone:
        case C::RoadBorder:
        case C::Wall:
        case C::Facade:
        case C::FenceMesh:
          truth_.lines.push_back(o.geometry_m);
          break;
        default:
          break;
      }
    }
    study_.landmarks_only = !with_gridmap;
    std::printf("simulated world %s, %.0f m, seed %u: %zu permanent point objects, %zu lines\n",
                world.c_str(), world_->route.length_m(), seed, truth_.points.size(),
                truth_.lines.size());
  }
  std::size_t ingest(MapStore& store, const fs::path& /*dir*/, int n, int k) override {
    sim::SimConfig cfg = sim_;
    if (k < rtk_drives_) cfg.gnss.grade = sim::GnssGrade::Rtk;  // survey-grade anchors
    int index = k;
    std::string name = "drive_" + std::to_string(k);
    if (k == n + 1) {  // the short drive: 30 s (about 300 m) of a drive no fleet has
      cfg.duration_s = 30.0;
      index = 100000 + n;
      name = "short_" + std::to_string(n);
    }
    const fs::path pkg_dir = cache_ / name;
    if (!fs::exists(pkg_dir / kManifestFileName)) {
      std::fprintf(stderr, "  simulating %s ...\n", name.c_str());
      (void)eval::simulate_and_package(world_, cfg, index, PolLevel::Full, study_, pkg_dir);
    }
    const DrivePackage pkg = read_and_validate_package(pkg_dir);
    (void)store.put_drive(pkg, pkg_dir, pkg.content_sha256);
    return pkg.points.size() + pkg.lines.size();
  }
  [[nodiscard]] const Truth& truth() const override { return truth_; }
  [[nodiscard]] const tiles::LocalFrame& frame() const override { return world_->frame; }
  [[nodiscard]] const sim::World& world() const { return *world_; }
  /// Prints, per window of the map geometry g, the positioning error averaged over the
  /// first n drives' trajectories there (the error every drive shares, which consensus
  /// cannot see) next to the window fit's shift; and for the first drives their wheel-speed
  /// integral against the true path.
  void explain_positioning(int n, const eval::MapGeometry& g) const {
    const double edge_m = eval::MapGeometryConfig{}.window_m;
    std::map<std::pair<long, long>, std::pair<Eigen::Vector2d, long>> sum;  // per window
    Eigen::Vector2d all = Eigen::Vector2d::Zero();
    long all_n = 0;
    for (int k = 0; k < n; ++k) {
      sim::SimConfig cfg = sim_;
      if (k < rtk_drives_) cfg.gnss.grade = sim::GnssGrade::Rtk;
      const sim::DriveSimulator drive(world_, cfg, k);
      const std::vector<sim::ExactState> exact = drive.exact_trajectory();
      const std::vector<TrajectorySample> rec = drive.recorded_trajectory();
      if (k < 3) {  // the odometry against the path: wheel speed integral, true arc length
        double odo_m = 0.0, arc_m = 0.0;
        for (std::size_t i = 1; i < rec.size() && i < exact.size(); ++i) {
          odo_m +=
              0.5 * (rec[i].speed_mps + rec[i - 1].speed_mps) * (rec[i].time_s - rec[i - 1].time_s);
          arc_m += std::hypot(exact[i].x_m - exact[i - 1].x_m, exact[i].y_m - exact[i - 1].y_m);
        }
        std::printf("  drive %d: wheel-speed integral %.2f m, true path %.2f m (%+.3f %%)\n", k,
                    odo_m, arc_m, 100.0 * (odo_m / arc_m - 1.0));
      }
      for (std::size_t i = 0; i < rec.size() && i < exact.size(); i += 10) {
        const Eigen::Vector2d p(exact[i].x_m, exact[i].y_m);
        const Eigen::Vector2d e =
            world_->frame.to_local(GeoPoint{rec[i].lat_deg, rec[i].lon_deg, 0.0}) - p;
        auto& [s, c] =
            sum[{std::lround(std::floor(p.x() / edge_m)), std::lround(std::floor(p.y() / edge_m))}];
        if (c == 0) s.setZero();
        s += e;
        ++c;
        all += e;
        ++all_n;
      }
    }
    if (all_n == 0) return;
    all /= static_cast<double>(all_n);
    std::printf("  positioning error of the %d drives, mean over all: east %+.2f north %+.2f m\n",
                n, all.x(), all.y());
    for (const eval::MapWindowFit& w : g.window_fits) {
      const auto it = sum.find({w.ix, w.iy});
      if (it == sum.end()) continue;
      const Eigen::Vector2d e = it->second.first / static_cast<double>(it->second.second) - all;
      const Eigen::Vector2d c((w.ix + 0.5) * edge_m, (w.iy + 0.5) * edge_m);
      const Eigen::Vector2d d =
          (w.R_truth_map * c + w.t_truth_map_m) - (g.R_truth_map * c + g.t_truth_map_m);
      // A map that inherited the shared error e sits at truth + e: its window fit moves it
      // back by -e relative to the whole map's fit.
      std::printf(
          "    window (%ld, %ld): shared positioning error east %+.2f north %+.2f m (vs. the "
          "mean); the map's window shift east %+.2f north %+.2f m\n",
          w.ix, w.iy, e.x(), e.y(), d.x(), d.y());
    }
  }
  /// Class of the world object nearest to x (within 2 m), "(temporary)" marked.
  [[nodiscard]] std::string nearest_object(const Eigen::Vector2d& x) const {
    double best = 2.0;
    std::string name = "nothing within 2 m";
    auto take = [&](double d, const sim::WorldObject& o) {
      if (d < best) {
        best = d;
        name = std::string(sim::to_string(o.cls)) + (o.permanent ? "" : " (temporary)");
      }
    };
    for (const auto& o : world_->objects) take(point_polyline_distance(x, o.geometry_m), o);
    // A car's geometry is its centre; its scattering centres sit at its corners and sides.
    for (const auto& p : world_->points) take((p.pos_m - x).norm(), world_->objects[p.object]);
    return name;
  }
  void explain(const MapStore& store, std::int64_t version, double radius_m) const override {
    const LandmarkSet lms = store.landmarks_in(version, std::nullopt, false);
    const PointIndex truth(truth_.points);
    std::map<std::string, int> cls;
    // Support histogram (tenths of the fleet) of true and false point landmarks.
    std::map<std::string, std::array<int, 11>> hist;
    std::set<std::int64_t> drives;
    for (const auto& d : store.list_drives()) drives.insert(d.row);
    const double fleet = static_cast<double>(std::max<std::size_t>(1, drives.size() - 2));
    for (const auto& p : lms.points) {
      const Eigen::Vector2d x = world_->frame.to_local(p.position);
      bool ok = false;
      truth.within(x, radius_m, [&](std::size_t, double) { ok = true; });
      const int bin = std::clamp(static_cast<int>(10.0 * p.support_drives / fleet), 0, 10);
      if (ok) {
        ++hist["true"][static_cast<std::size_t>(bin)];
        continue;
      }
      const std::string name = nearest_object(x);
      ++cls[name];
      ++hist[name][static_cast<std::size_t>(bin)];
    }
    for (const auto& [k, h] : hist) {
      std::printf("  support/fleet histogram %-28s", k.c_str());
      for (int v : h) std::printf(" %4d", v);
      std::printf("\n");
    }
    // False line length (0.25 m samples farther than the radius from line truth) by the
    // nearest world object.
    std::map<std::string, double> line_cls;
    const NearIndex near_truth(truth_.lines);
    for (const auto& l : lms.lines) {
      std::vector<Eigen::Vector2d> pl;
      for (const auto& g : l.polyline) pl.push_back(world_->frame.to_local(g));
      for (const auto& x : samples(pl, 0.25)) {
        if (near_truth.near(x, radius_m)) continue;
        const std::string name = nearest_object(x);
        line_cls[name] += 0.25;
      }
    }
    std::printf("  false line length (m) by nearest world object:");
    for (const auto& [k, v] : line_cls) std::printf(" %s %.0f;", k.c_str(), v);
    std::printf("\n");
    std::printf("  false point landmarks by nearest world object:");
    for (const auto& [k, v] : cls) std::printf(" %s %d;", k.c_str(), v);
    std::printf("\n");
  }
  void dump(const MapStore& store, std::int64_t version, const fs::path& dir) const override {
    fs::create_directories(dir);
    const auto& f = world_->frame;
    std::ofstream objs(dir / "objects.csv");
    objs << "id,class,permanent,presence,x,y\n";
    for (const auto& o : world_->objects) {
      for (const auto& p : o.geometry_m) {
        objs << o.id << ',' << sim::to_string(o.cls) << ',' << (o.permanent ? 1 : 0) << ','
             << o.presence_probability << ',' << p.x() << ',' << p.y() << '\n';
      }
    }
    const LandmarkSet lms = store.landmarks_in(version, std::nullopt, false);
    std::ofstream ll(dir / "line_landmarks.csv");
    ll << "id,support,spread,x,y\n";
    for (std::size_t i = 0; i < lms.lines.size(); ++i) {
      for (const auto& g : lms.lines[i].polyline) {
        const Eigen::Vector2d x = f.to_local(g);
        ll << i << ',' << lms.lines[i].support_drives << ',' << lms.lines[i].spread_m << ','
           << x.x() << ',' << x.y() << '\n';
      }
    }
    std::ofstream pl(dir / "point_landmarks.csv");
    pl << "id,support,spread,scattering,x,y,true,nearest\n";
    const PointIndex truth(truth_.points);
    for (std::size_t i = 0; i < lms.points.size(); ++i) {
      const auto& p = lms.points[i];
      const Eigen::Vector2d x = f.to_local(p.position);
      bool ok = false;
      truth.within(x, 0.3, [&](std::size_t, double) { ok = true; });
      pl << i << ',' << p.support_drives << ',' << p.spread_m << ','
         << static_cast<int>(p.scattering) << ',' << x.x() << ',' << x.y() << ',' << (ok ? 1 : 0)
         << ",\"" << nearest_object(x) << "\"\n";
    }
    const CandidateSet cands = store.candidates_in(std::nullopt);
    std::ofstream lc(dir / "line_candidates.csv");
    lc << "drive,x0,y0,x1,y1,strength\n";
    for (const auto& c : cands.lines) {
      const Eigen::Vector2d a = f.to_local(c.start), b = f.to_local(c.end);
      lc << c.drive << ',' << a.x() << ',' << a.y() << ',' << b.x() << ',' << b.y() << ','
         << c.candidate.strength << '\n';
    }
    std::ofstream pc(dir / "point_candidates.csv");
    pc << "drive,x,y,strength,power_db,scattering,num_cells\n";
    for (const auto& c : cands.points) {
      const Eigen::Vector2d a = f.to_local(c.position);
      pc << c.drive << ',' << a.x() << ',' << a.y() << ',' << c.candidate.strength << ','
         << c.candidate.power_db << ',' << static_cast<int>(c.candidate.scattering) << ','
         << c.candidate.num_cells << '\n';
    }
    std::ofstream tr(dir / "route.csv");
    tr << "x,y\n";
    for (double s = 0; s < world_->route.length_m(); s += 1.0) {
      const sim::PathPoint p = world_->route.at(s);
      tr << p.x_m << ',' << p.y_m << '\n';
    }
  }

 private:
  fs::path cache_;
  sim::SimConfig sim_;
  eval::StudyConfig study_;
  std::shared_ptr<const sim::World> world_;
  int rtk_drives_ = 0;
  Truth truth_;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"polmap map build benchmark"};
  std::vector<int> counts{2, 4, 8, 16};
  double length_km = 2.0;
  double points_per_km = 600.0, walls_per_km = 60.0, temporaries_per_km = 100.0;
  unsigned seed = 1;
  std::string keep, world, sim_cache;
  double radius_m = 0.3;
  std::optional<double> view_fraction;
  app.add_option("--radius-m", radius_m, "truth matching radius");
  app.add_option("--view-fraction", view_fraction,
                 "min share of in-view drives supporting a landmark (0: fixed count only)");
  app.add_option("--drives", counts, "drive counts to build maps from")->delimiter(',');
  app.add_option("--length-km", length_km, "route length");
  app.add_option("--points-per-km", points_per_km, "permanent point objects per km");
  app.add_option("--walls-per-km", walls_per_km, "wall/kerb segments per km");
  app.add_option("--temporaries-per-km", temporaries_per_km,
                 "single-drive objects per km and drive");
  app.add_option("--seed", seed, "random seed");
  app.add_option("--keep", keep, "keep the databases in this directory");
  app.add_option("--world", world,
                 "drives from the simulator over this world (urban | industrial | rural | "
                 "FILE.osm | FILE.xodr) instead of the synthetic route");
  bool explain = false;
  std::string dump;
  app.add_option("--dump", dump,
                 "write the map, line candidates and world objects as CSV into DIR/nN (simulator)");
  app.add_flag("--explain", explain, "print what false point landmarks are near (simulator)");
  bool explain_gnss = false;
  app.add_flag("--explain-positioning", explain_gnss,
               "print each 200 m window's positioning error shared by the drives next to the "
               "map's shift there, and the first drives' wheel-speed integral against their "
               "true path (simulator)");
  app.add_option("--sim-cache", sim_cache,
                 "simulated packages are kept here and reused (default: KEEP/packages)");
  bool merged = false;
  int partition_zoom = -1;
  app.add_option("--partition-zoom", partition_zoom,
                 "build partitioned into regions of this zoom (the jobs run in this process; "
                 "-1: one-process build)");
  app.add_flag("--merged", merged,
               "simulated drives with their gridmaps: also extract landmarks from the merged "
               "gridmap (pCFAR, lines) and compare them with candidate consensus");
  std::vector<double> merged_thresholds{2.0};
  app.add_option("--merged-thresholds", merged_thresholds,
                 "pCFAR thresholds (d_ex) for the merged gridmap, one row each")
      ->delimiter(',');
  int line_peaks = 0, co_presence = 1, surface_peaks = 1;
  app.add_option("--surface-peaks", surface_peaks,
                 "1: odd-bounce points inside line landmarks need a higher detection share "
                 "(point_filter.hpp SurfacePeakRule), 0: off");
  app.add_option("--line-peaks", line_peaks,
                 "remove point landmarks that are peaks of line landmarks (1) or not (0, default)");
  app.add_option("--co-presence", co_presence,
                 "remove neighbouring point landmarks present and absent together (temporary "
                 "objects: 1, default) or not (0)");
  PointFilterConfig filter;
  app.add_option("--co-presence-p", filter.co_presence.max_p_value, "co-presence: max Fisher p");
  app.add_option("--co-presence-phi", filter.co_presence.min_phi, "co-presence: min phi");
  app.add_option("--co-presence-share", filter.co_presence.max_detection_share,
                 "co-presence: landmarks detected by more than this share are kept");
  int sliding = 1;
  app.add_option("--sliding", sliding,
                 "remove point landmarks whose candidates spread along the road (objects that "
                 "stand elsewhere in each drive: 1, default) or not (0)");
  app.add_option("--sliding-min-along-m", filter.sliding.min_along_spread_m,
                 "sliding: min RMS spread along the road");
  app.add_option("--sliding-ratio", filter.sliding.min_along_across_ratio,
                 "sliding: min along/across spread ratio");
  app.add_option("--sliding-min-support", filter.sliding.min_support_drives,
                 "sliding: judged from this many supporting drives");
  int mirror_ghosts = 1;
  app.add_option("--mirror-ghosts", mirror_ghosts,
                 "remove point landmarks that are mirror images behind a line landmark (1, "
                 "default) or not (0)");
  app.add_option("--mirror-image-radius-m", filter.mirror_ghosts.image_radius_m,
                 "mirror ghosts: candidates within this radius of the image");
  app.add_option("--mirror-image-drives", filter.mirror_ghosts.min_image_drives,
                 "mirror ghosts: distinct drives needed at the image");
  app.add_option("--mirror-segment-margin-m", filter.mirror_ghosts.segment_margin_m,
                 "mirror ghosts: the mirror point's foot may lie this far beyond a line's ends");
  LineFilterConfig line_filter;
  int line_overhead = 1, range_streaks = 1, line_out_of_view = 1;
  double streak_angle_deg = line_filter.range_streaks.max_line_of_sight_angle_rad * 180.0 / M_PI;
  app.add_option("--line-overhead", line_overhead,
                 "remove line landmarks the supporting drives drove through (overhead "
                 "structures: 1, default) or not (0)");
  app.add_option("--range-streaks", range_streaks,
                 "short lines along the line of sight need nearly every pass (1, default) or "
                 "are judged like other lines (0)");
  app.add_option("--streak-share", line_filter.range_streaks.min_detection_share,
                 "range streaks: the share of the passes in view they must exceed");
  app.add_option("--streak-max-length-m", line_filter.range_streaks.max_length_m,
                 "range streaks: judged up to this length");
  app.add_option("--streak-angle-deg", streak_angle_deg,
                 "range streaks: judged within this angle of the line of sight");
  app.add_option("--line-out-of-view", line_out_of_view,
                 "judge lines beyond most supporters' modelled view against every pass as "
                 "close (1, default) or not (0)");
  std::string gnss = "rtk";
  int rtk_drives = 0;
  app.add_option("--gnss", gnss,
                 "simulated drives' positioning: rtk (survey-grade) | consumer (metre-level "
                 "drifting errors; the build aligns the drives, drive_alignment.hpp)")
      ->check(CLI::IsMember({"rtk", "consumer"}));
  app.add_option("--rtk-drives", rtk_drives, "with --gnss consumer: the first N drives are RTK");
  double canyon_multipath_m = -1.0;
  app.add_option("--canyon-multipath-m", canyon_multipath_m,
                 "with --gnss consumer: canyon multipath amplitude (default: the simulator's)");
  double heading_sigma_deg = -1.0, bias_sigma_m = -1.0;
  app.add_option("--consumer-bias-m", bias_sigma_m,
                 "with --gnss consumer: bias sigma per axis (0 also turns outages off; default: "
                 "the simulator's)");
  app.add_option("--consumer-heading-deg", heading_sigma_deg,
                 "with --gnss consumer: heading error sigma (default: the simulator's)");
  mapping::DriveAlignmentConfig alignment;
  struct AlignFlag {
    const char* name;
    double* value;
    const char* help;
  };
  for (const AlignFlag& f : {
           AlignFlag{"--align-gyro-bias-sigma-rps", &alignment.gyro_bias_sigma_rps,
                     "prior sigma of each drive's yaw-rate bias"},
           AlignFlag{"--align-scale-sigma", &alignment.odometry_scale_sigma,
                     "prior sigma of each drive's wheel-speed scale error"},
           AlignFlag{"--align-odometry-parameters-gate-m", &alignment.odometry_parameters_gate_m,
                     "wheel scale and yaw-rate bias are estimated in association rounds with "
                     "this gate or finer (held at 0 in coarser ones)"},
           AlignFlag{"--align-fleet-scale-sigma", &alignment.fleet_scale_sigma,
                     "the mean wheel-speed scale error of the consumer drives is 0 within this "
                     "(0: no such factor)"},
           AlignFlag{"--align-node-spacing-m", &alignment.node_spacing_m,
                     "spacing of the correction nodes"},
           AlignFlag{"--align-gnss-correlation-m", &alignment.gnss_correlation_length_m,
                     "length over which one drive's GNSS error is correlated"},
           AlignFlag{"--align-side-slip-gradient",
                     &alignment.odometry_side_slip_gradient_rad_per_mps2,
                     "side-slip angle per lateral acceleration in the odometry, rad per m/s^2 "
                     "(0: off)"},
           AlignFlag{"--align-slip-stiffness", &alignment.odometry_slip_stiffness,
                     "longitudinal slip stiffness in the odometry (0: off)"},
           AlignFlag{"--align-odometry-sigma-m", &alignment.odometry_sigma_m,
                     "odometry displacement noise per step, metres"},
           AlignFlag{"--align-odometry-sigma-per-m", &alignment.odometry_sigma_per_m,
                     "odometry displacement noise per metre of step"},
           AlignFlag{"--align-gyro-sigma-rad", &alignment.gyro_sigma_rad,
                     "integrated yaw-rate noise per step, radians"},
           AlignFlag{"--align-candidate-sigma-m", &alignment.candidate_sigma_m,
                     "position noise of a point candidate in the association residuals"},
           AlignFlag{"--align-candidate-lead-m", &alignment.candidate_lead_m,
                     "candidates take the correction this far ahead of their nearest "
                     "trajectory point"},
           AlignFlag{"--align-odometry-max-mismatch-m", &alignment.odometry_max_length_mismatch_m,
                     "an odometry step whose length differs from the GNSS displacement by more "
                     "than this (plus the share below) is rejected"},
           AlignFlag{"--align-odometry-max-mismatch-share",
                     &alignment.odometry_max_length_mismatch_share,
                     "... plus this share of the step's length"},
       }) {
    app.add_option(f.name, *f.value, std::string("with --gnss consumer: ") + f.help);
  }
  app.add_option("--align-min-cluster-drives", alignment.min_cluster_drives,
                 "with --gnss consumer: drives a landmark needs to tie them (more than the "
                 "fleet: no associations, each drive fitted to its own GNSS and odometry)");
  app.add_option("--align-vote-rounds", alignment.vote_rounds,
                 "with --gnss consumer: rounds of the coarse displacement vote");
  app.add_option("--align-max-iterations", alignment.max_iterations,
                 "with --gnss consumer: Ceres iterations per association round");
  app.add_option("--align-odometry", alignment.use_odometry,
                 "with --gnss consumer: odometry factors between nodes (1, default) or "
                 "smoothness priors only (0)");
  std::string realism = "realistic";
  app.add_option("--realism", realism,
                 "simulated drives' error sources: realistic (default: wheel scale, gyro bias, "
                 "radar noise, mounts, multipath, ...: tools/sim/README.md) | ideal")
      ->check(CLI::IsMember({"ideal", "realistic"}));
  std::string realism_sources;
  app.add_option("--realism-sources", realism_sources,
                 "with --realism realistic: only these sources on (comma separated: noise, "
                 "mounts, timing, slip, multipath, elevation, ins)");
  double parked_shift_m = -1.0;
  app.add_option("--parked-shift-m", parked_shift_m,
                 "simulator: parked cars stand within +- this of their place in each drive, "
                 "bins within half of it (TrafficSimConfig::parked_shift_m; default: the "
                 "simulator's)");
  CLI11_PARSE(app, argc, argv);
  if (gnss != "rtk" && world.empty()) {
    std::fprintf(stderr, "--gnss needs --world (the synthetic route has no trajectories)\n");
    return 2;
  }
  if (!realism_sources.empty() && realism != "realistic") {
    std::fprintf(stderr, "--realism-sources needs --realism realistic\n");
    return 2;
  }
  if (merged && world.empty()) {
    std::fprintf(stderr, "--merged needs --world (the synthetic route has no gridmaps)\n");
    return 2;
  }

  const fs::path root =
      keep.empty() ? fs::temp_directory_path() / ("polmap_bench_map_build_" + std::to_string(seed))
                   : fs::path(keep);
  for (int n : counts) fs::remove_all(root / ("n" + std::to_string(n)));
  fs::create_directories(root);
  std::unique_ptr<DriveSource> source;
  if (world.empty()) {
    source = std::make_unique<SyntheticSource>(length_km, points_per_km, walls_per_km,
                                               temporaries_per_km, seed);
  } else {
    fs::path cache = sim_cache.empty() ? root / "packages" : fs::path(sim_cache);
    // The drives depend on the world, its length and the seed: a cache of one must not serve
    // another (until 2026-12-07 it did, and a --seed 2 run reused seed 1's drives).
    char length_name[32];
    std::snprintf(length_name, sizeof length_name, "%.0fm", length_km * 1000.0);
    cache /=
        fs::path(world).filename().string() + "_" + length_name + "_seed" + std::to_string(seed);
    if (gnss == "consumer") {
      cache /= "consumer_rtk" + std::to_string(rtk_drives) +
               (canyon_multipath_m >= 0.0 ? "_mp" + std::to_string(canyon_multipath_m) : "") +
               (heading_sigma_deg >= 0.0 ? "_hd" + std::to_string(heading_sigma_deg) : "") +
               (bias_sigma_m >= 0.0 ? "_b" + std::to_string(bias_sigma_m) : "");
    }
    // Always named by the shift the drives were simulated with: the simulator's default
    // changed (0 -> 1 m on 2026-12-07), and a cache of one must not serve the other.
    if (realism != "ideal") {
      cache /= realism + (realism_sources.empty() ? "" : "_" + realism_sources);
    }
    cache /= "parked_shift_" + std::to_string(parked_shift_m >= 0.0
                                                  ? parked_shift_m
                                                  : sim::TrafficSimConfig{}.parked_shift_m);
    source = std::make_unique<SimSource>(
        world, length_km * 1000.0, seed, merged ? cache / "with_gridmap" : cache, merged,
        gnss == "consumer" ? sim::GnssGrade::Consumer : sim::GnssGrade::Rtk, rtk_drives,
        canyon_multipath_m, heading_sigma_deg, bias_sigma_m, parked_shift_m, realism,
        realism_sources);
  }

  std::printf(
      "%6s %9s %9s %7s %7s | %6s %6s %6s %7s %6s %6s %6s | %6s | %8s %8s %9s %8s | %8s %7s %7s | "
      "%8s %7s %7s %8s\n",
      "drives", "cand_pts", "cand_lin", "lm_pts", "lm_lin", "P_pts", "R_pts", "Ra_pts", "rmse_cm",
      "P_lin", "R_lin", "Ra_lin", "tiles", "ingest_s", "cand/s", "build_s", "consns_s", "incr_s",
      "written", "reused", "short_s", "written", "reused", "maxrss_MB");
  for (int n : counts) {
    const fs::path dir = root / ("n" + std::to_string(n));
    fs::create_directories(dir);
    SqliteMapStore store(dir / "map.db");
    std::size_t cand = 0;
    auto t0 = std::chrono::steady_clock::now();
    for (int k = 0; k < n; ++k) cand += source->ingest(store, dir, n, k);
    const double ingest_s = seconds_since(t0);
    MapBuildRequest req;
    req.build_gridmap = merged;
    if (partition_zoom >= 0) {
      req.partition = BuildPartition{};
      req.partition->zoom = partition_zoom;
    }
    if (view_fraction)
      req.points.support.min_view_fraction = req.lines.support.min_view_fraction = *view_fraction;
    req.points.filter.co_presence = filter.co_presence;
    req.points.filter.line_peaks.enabled = line_peaks != 0;
    req.points.filter.surface_peaks.enabled = surface_peaks != 0;
    req.points.filter.co_presence.enabled = co_presence != 0;
    req.points.filter.sliding = filter.sliding;
    req.points.filter.sliding.enabled = sliding != 0;
    req.points.filter.mirror_ghosts = filter.mirror_ghosts;
    req.points.filter.mirror_ghosts.enabled = mirror_ghosts != 0;
    req.lines.filter = line_filter;
    req.lines.filter.overhead.enabled = line_overhead != 0;
    req.lines.filter.range_streaks.enabled = range_streaks != 0;
    req.lines.filter.range_streaks.max_line_of_sight_angle_rad = streak_angle_deg * M_PI / 180.0;
    req.lines.filter.out_of_view.enabled = line_out_of_view != 0;
    MapBuilderConfig builder_cfg;
    builder_cfg.alignment = alignment;
    const MapBuilder builder(builder_cfg);
    const auto r = builder.build(store, req);
    if (r.status != MapBuildResult::Status::Published) {
      std::fprintf(stderr, "build failed: %s\n", r.error.c_str());
      return 1;
    }
    const Accuracy acc = accuracy(store, r.version, source->truth(), source->frame(), radius_m);
    std::printf(
        "  filters (%d drives): points removed: %lld line peaks, %lld surface peaks, %lld "
        "temporary, %lld sliding, %lld out of view, %lld mirror images; lines removed: %lld "
        "overhead, %lld range streaks, %lld out of view\n",
        n, static_cast<long long>(r.stats.point_line_peaks),
        static_cast<long long>(r.stats.point_surface_peaks),
        static_cast<long long>(r.stats.point_temporary),
        static_cast<long long>(r.stats.point_sliding),
        static_cast<long long>(r.stats.point_out_of_view),
        static_cast<long long>(r.stats.point_mirror_ghosts),
        static_cast<long long>(r.stats.line_overhead),
        static_cast<long long>(r.stats.line_range_streaks),
        static_cast<long long>(r.stats.line_out_of_view));
    if (const auto* sim_source = dynamic_cast<const SimSource*>(source.get())) {
      // The map's geometry against truth (absolute offset; relative after a rigid fit per
      // 200 m window) and what the drive alignment did.
      std::vector<Eigen::Vector2d> lm;
      for (const auto& p : store.landmarks_in(r.version, std::nullopt, false).points) {
        lm.push_back(source->frame().to_local(p.position));
      }
      const eval::MapGeometry g =
          eval::map_geometry(lm, eval::truth_point_objects(sim_source->world()));
      std::printf(
          "  geometry (%d drives, gnss %s, %d rtk): matched %d, offset %.3f m, raw rms %.3f m, "
          "rigid-fit rms %.3f m, 200 m window rms %.3f m (%d windows, matched share %.2f, "
          "worst %.2f, %d unfitted, bend %.2f m), yaw %.3f deg | "
          "alignment %s: %lld drives (%lld with odometry), %lld anchors, %lld clusters, "
          "residual %.3f m, mean correction %.2f m, wheel scale mean %+.4f rms %.4f, yaw-rate "
          "bias mean %+.4f rms %.4f deg/s, %lld odometry steps rejected, %.2f s\n",
          n, gnss.c_str(), std::min(rtk_drives, n), g.matched, g.offset_m, g.raw_rms_m,
          g.global_rms_m, g.window_rms_m, g.windows, g.window_matched_share, g.worst_window_share,
          g.windows_unfitted, g.max_window_shift_m, g.yaw_truth_map_rad * 180.0 / M_PI,
          r.stats.alignment_status.c_str(), static_cast<long long>(r.stats.aligned_drives),
          static_cast<long long>(r.stats.alignment_odometry_drives),
          static_cast<long long>(r.stats.alignment_anchor_drives),
          static_cast<long long>(r.stats.alignment_clusters), r.stats.alignment_residual_rms_m,
          r.stats.alignment_mean_correction_m, r.stats.alignment_scale_error_mean,
          r.stats.alignment_scale_error_rms, r.stats.alignment_gyro_bias_mean_rps * 180.0 / M_PI,
          r.stats.alignment_gyro_bias_rms_rps * 180.0 / M_PI,
          static_cast<long long>(r.stats.alignment_odometry_steps_rejected),
          r.stats.seconds_alignment);
      if (explain) {  // each window's own fit
        const double edge_m = eval::MapGeometryConfig{}.window_m;
        for (const eval::MapWindowFit& w : g.window_fits) {
          // Where the window's own fit puts its centre against the whole map's fit (truth
          // frame: x east, y north of the world's origin).
          const Eigen::Vector2d c((w.ix + 0.5) * edge_m, (w.iy + 0.5) * edge_m);
          const Eigen::Vector2d d =
              (w.R_truth_map * c + w.t_truth_map_m) - (g.R_truth_map * c + g.t_truth_map_m);
          std::printf(
              "    window (%ld, %ld): %d landmarks, %d near an object, %d within %.1f m "
              "(share %.2f), rms %.3f m, own fit %.2f m (east %+.2f, north %+.2f) / %.3f deg "
              "off the whole map's\n",
              w.ix, w.iy, w.landmarks, w.near, w.matched,
              eval::MapGeometryConfig{}.window_gates_m.back(), w.share(), w.rms_m, w.shift_m, d.x(),
              d.y(), w.yaw_rad * 180.0 / M_PI);
        }
      }
      if (explain_gnss) sim_source->explain_positioning(n, g);
      std::fflush(stdout);
    }
    if (explain) source->explain(store, r.version, radius_m);
    if (!dump.empty()) source->dump(store, r.version, fs::path(dump) / ("n" + std::to_string(n)));
    if (merged) {
      // The same drives' merged gridmap, the vehicle's detectors on it (weak = objects fewer
      // than half of the drives detected on their own).
      const CandidateSet cands = store.candidates_in(std::nullopt);
      std::printf(
          "  %-22s %6s %6s %6s %6s %7s | %6s %6s %6s %6s   (n = %d drives, gridmap %.1f s)\n",
          "source", "points", "P_pts", "R_pts", "Rw_pts", "rmse_cm", "P_lin", "R_lin", "Rw_lin",
          "lines", n, r.stats.seconds_gridmap);
      std::printf("  %-22s %6zu %6.3f %6.3f %6.3f %7.2f | %6.3f %6.3f %6.3f %6lld\n",
                  "candidate consensus", acc.points, acc.point_precision, acc.point_recall,
                  acc.point_recall_weak, 100.0 * acc.point_rmse_m, acc.line_precision,
                  acc.line_recall, acc.line_recall_weak,
                  static_cast<long long>(r.stats.line_landmarks));
      for (double th : merged_thresholds) {
        MergedExtractionConfig mc;
        mc.points.threshold = th;
        const LandmarkSet ml = merged_landmarks(store, source->truth(), source->frame(), mc);
        const Accuracy m = accuracy(ml, cands, source->truth(), source->frame(), radius_m);
        char label[64];
        std::snprintf(label, sizeof label, "merged gridmap d_ex>%.1f", th);
        std::printf("  %-22s %6zu %6.3f %6.3f %6.3f %7.2f | %6.3f %6.3f %6.3f %6zu\n", label,
                    m.points, m.point_precision, m.point_recall, m.point_recall_weak,
                    100.0 * m.point_rmse_m, m.line_precision, m.line_recall, m.line_recall_weak,
                    ml.lines.size());
      }
      std::fflush(stdout);
    }
    (void)source->ingest(store, dir, n, n);
    const auto inc = builder.build(store, req);
    (void)source->ingest(store, dir, n, n + 1);
    const auto part = builder.build(store, req);
    for (const auto* b : {&inc, &part}) {
      if (b->status != MapBuildResult::Status::Published) {
        std::printf("  build after one more drive: %s\n", b->error.c_str());
      }
    }
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    std::printf(
        "%6d %9lld %9lld %7lld %7lld | %6.3f %6.3f %6.3f %7.2f %6.3f %6.3f %6.3f | %6lld | %8.3f "
        "%8.0f %9.3f %8.3f | %8.3f %7lld %7lld | %8.3f %7lld %7lld %8.0f\n",
        n, static_cast<long long>(r.stats.point_candidates),
        static_cast<long long>(r.stats.line_candidates),
        static_cast<long long>(r.stats.point_landmarks),
        static_cast<long long>(r.stats.line_landmarks), acc.point_precision, acc.point_recall,
        acc.point_recall_all, 100.0 * acc.point_rmse_m, acc.line_precision, acc.line_recall,
        acc.line_recall_all, static_cast<long long>(r.stats.tiles_total), ingest_s,
        static_cast<double>(cand) / ingest_s, r.stats.seconds_total, r.stats.seconds_consensus,
        inc.stats.seconds_total, static_cast<long long>(inc.stats.tiles_written),
        static_cast<long long>(inc.stats.tiles_reused), part.stats.seconds_total,
        static_cast<long long>(part.stats.tiles_written),
        static_cast<long long>(part.stats.tiles_reused),
        static_cast<double>(ru.ru_maxrss) / 1024.0);
    if (merged) {  // what the merged gridmap's upkeep cost (aligned drives move between builds)
      std::printf(
          "       merged gridmap: build %lld added in %.1f s; one more drive %lld added, %lld "
          "re-placed in %.1f s; 300 m drive %lld added, %lld re-placed in %.1f s\n",
          static_cast<long long>(r.stats.gridmap_drives_added), r.stats.seconds_gridmap,
          static_cast<long long>(inc.stats.gridmap_drives_added),
          static_cast<long long>(inc.stats.gridmap_drives_replaced), inc.stats.seconds_gridmap,
          static_cast<long long>(part.stats.gridmap_drives_added),
          static_cast<long long>(part.stats.gridmap_drives_replaced), part.stats.seconds_gridmap);
    }
    std::printf(
        "       short build: load %.3f s, consensus %.3f s, landmarks %.3f s, tiles %.3f s, "
        "total %.3f s (%s, %lld landmarks copied)\n",
        part.stats.seconds_load, part.stats.seconds_consensus, part.stats.seconds_landmarks,
        part.stats.seconds_tiles, part.stats.seconds_total,
        part.stats.incremental_from ? "incremental" : "full",
        static_cast<long long>(part.stats.landmarks_copied));
    std::fflush(stdout);
  }
  std::printf(
      "build_s = load + consensus + landmarks + tiles + publish of a fresh version; incr_s = the\n"
      "same after one more full drive, short_s after one more 300 m drive (tiles whose bytes did\n"
      "not change are reused, not rewritten); P/R: precision and recall against the permanent\n"
      "objects that at least half of the drives detected (Ra: against all permanent objects),\n"
      "rmse over matched points (file comment); maxrss_MB: peak resident memory of the process\n"
      "so far. Store: SQLite WAL in %s\n",
      root.c_str());
  if (keep.empty()) fs::remove_all(root);
  return 0;
}
