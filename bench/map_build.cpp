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
#include <sys/resource.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <random>
#include <sstream>

#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/map_builder.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
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

double point_segment_distance(const Eigen::Vector2d& p, const Eigen::Vector2d& a,
                              const Eigen::Vector2d& b) {
  const Eigen::Vector2d ab = b - a;
  const double l2 = ab.squaredNorm();
  const double t = l2 > 0 ? std::clamp((p - a).dot(ab) / l2, 0.0, 1.0) : 0.0;
  return (p - (a + t * ab)).norm();
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

struct Accuracy {
  double point_precision = 0, point_recall = 0, point_rmse_m = 0;
  double line_precision = 0, line_recall = 0;
};

/// The map against the route's truth (see the file comment).
Accuracy accuracy(const MapStore& store, std::int64_t version, const Route& route,
                  const GeoPoint& world_origin, double radius_m) {
  const tiles::LocalFrame world(world_origin);
  const LandmarkSet lms = store.landmarks_in(version, std::nullopt, false);
  Accuracy a;
  // Points: all (landmark, object) pairs within the radius, nearest first, one-to-one.
  std::vector<Eigen::Vector2d> lp;
  for (const auto& p : lms.points) lp.push_back(world.to_local(p.position));
  struct Pair {
    double d;
    std::size_t l, o;
  };
  std::vector<Pair> pairs;
  {
    std::map<std::pair<long, long>, std::vector<std::size_t>> grid;
    for (std::size_t o = 0; o < route.objects.size(); ++o) {
      grid[{std::lround(std::floor(route.objects[o].x())),
            std::lround(std::floor(route.objects[o].y()))}]
          .push_back(o);
    }
    for (std::size_t l = 0; l < lp.size(); ++l) {
      const long cx = std::lround(std::floor(lp[l].x())), cy = std::lround(std::floor(lp[l].y()));
      for (long dx = -1; dx <= 1; ++dx) {
        for (long dy = -1; dy <= 1; ++dy) {
          auto it = grid.find({cx + dx, cy + dy});
          if (it == grid.end()) continue;
          for (std::size_t o : it->second) {
            const double d = (lp[l] - route.objects[o]).norm();
            if (d <= radius_m) pairs.push_back({d, l, o});
          }
        }
      }
    }
  }
  std::sort(pairs.begin(), pairs.end(), [](const Pair& x, const Pair& y) {
    return std::tie(x.d, x.l, x.o) < std::tie(y.d, y.l, y.o);
  });
  std::vector<char> lu(lp.size(), 0), ou(route.objects.size(), 0);
  std::size_t matched = 0;
  double ss = 0;
  for (const Pair& p : pairs) {
    if (lu[p.l] || ou[p.o]) continue;
    lu[p.l] = ou[p.o] = 1;
    ++matched;
    ss += p.d * p.d;
  }
  a.point_precision = lp.empty() ? 0.0 : double(matched) / double(lp.size());
  a.point_recall = route.objects.empty() ? 0.0 : double(matched) / double(route.objects.size());
  a.point_rmse_m = matched ? std::sqrt(ss / double(matched)) : 0.0;
  // Lines, by length.
  std::vector<std::vector<Eigen::Vector2d>> ll;
  for (const auto& l : lms.lines) {
    std::vector<Eigen::Vector2d> pl;
    for (const auto& g : l.polyline) pl.push_back(world.to_local(g));
    ll.push_back(std::move(pl));
  }
  auto near_wall = [&](const Eigen::Vector2d& p) {
    for (const auto& [wa, wb] : route.walls) {
      if (point_segment_distance(p, wa, wb) <= radius_m) return true;
    }
    return false;
  };
  auto near_landmark = [&](const Eigen::Vector2d& p) {
    for (const auto& pl : ll) {
      for (std::size_t i = 0; i + 1 < pl.size(); ++i) {
        if (point_segment_distance(p, pl[i], pl[i + 1]) <= radius_m) return true;
      }
    }
    return false;
  };
  std::size_t ln = 0, lok = 0, wn = 0, wok = 0;
  for (const auto& pl : ll) {
    for (const auto& p : samples(pl, 0.25)) ++ln, lok += near_wall(p) ? 1 : 0;
  }
  for (const auto& [wa, wb] : route.walls) {
    for (const auto& p : samples({wa, wb}, 0.25)) ++wn, wok += near_landmark(p) ? 1 : 0;
  }
  a.line_precision = ln ? double(lok) / double(ln) : 0.0;
  a.line_recall = wn ? double(wok) / double(wn) : 0.0;
  return a;
}

double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"polmap map build benchmark"};
  std::vector<int> counts{2, 4, 8, 16};
  double length_km = 2.0;
  double points_per_km = 600.0, walls_per_km = 60.0, temporaries_per_km = 100.0;
  unsigned seed = 1;
  std::string keep;
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
  CLI11_PARSE(app, argc, argv);

  const GeoPoint origin{48.7758, 9.1829, 0.0};
  std::mt19937 rng(seed);
  const Route route = make_route(length_km * 1000.0, points_per_km, walls_per_km, rng);
  const fs::path root =
      keep.empty() ? fs::temp_directory_path() / ("polmap_bench_map_build_" + std::to_string(seed))
                   : fs::path(keep);
  fs::remove_all(root);
  fs::create_directories(root);

  std::printf(
      "route %.1f km: %zu point objects, %zu walls; per drive ~%.0f point + ~%.0f line "
      "candidates\n",
      length_km, route.objects.size(), route.walls.size(),
      0.9 * route.objects.size() + temporaries_per_km * length_km, 0.9 * 2 * route.walls.size());
  std::printf(
      "%6s %9s %9s %7s %7s | %6s %6s %7s %6s %6s | %6s | %8s %8s %9s %8s | %8s %7s %7s | %8s %7s "
      "%7s %8s\n",
      "drives", "cand_pts", "cand_lin", "lm_pts", "lm_lin", "P_pts", "R_pts", "rmse_cm", "P_lin",
      "R_lin", "tiles", "ingest_s", "cand/s", "build_s", "consns_s", "incr_s", "written", "reused",
      "short_s", "written", "reused", "maxrss_MB");
  for (int n : counts) {
    const fs::path dir = root / ("n" + std::to_string(n));
    fs::create_directories(dir);
    SqliteMapStore store(dir / "map.db");
    std::mt19937 drng(seed * 1000 + static_cast<unsigned>(n));
    std::vector<DrivePackage> pkgs;
    for (int k = 0; k <= n; ++k) pkgs.push_back(drive(route, origin, k, temporaries_per_km, drng));
    // A short drive: the first 300 m of the route only.
    pkgs.push_back(
        drive(route, origin, n + 1, temporaries_per_km, drng, -route.length_m / 2 + 300.0));
    auto ingest = [&](const DrivePackage& p) {
      // The store keeps the archive as given; the candidates come from `p` (what
      // validation would have produced), so a placeholder archive suffices here.
      const fs::path tar = dir / (p.manifest.drive_id + ".tar");
      const std::string bytes =
          write_ustar({{kManifestFileName, "bench package " + p.manifest.drive_id}});
      std::ofstream(tar, std::ios::binary) << bytes;
      (void)store.put_drive(p, tar, content_etag(bytes));
    };
    std::size_t cand = 0;
    auto t0 = std::chrono::steady_clock::now();
    for (int k = 0; k < n; ++k) {
      ingest(pkgs[static_cast<std::size_t>(k)]);
      cand += pkgs[static_cast<std::size_t>(k)].points.size() +
              pkgs[static_cast<std::size_t>(k)].lines.size();
    }
    const double ingest_s = seconds_since(t0);
    MapBuildRequest req;
    req.build_gridmap = false;
    if (view_fraction)
      req.points.support.min_view_fraction = req.lines.support.min_view_fraction = *view_fraction;
    const MapBuilder builder;
    const auto r = builder.build(store, req);
    if (r.status != MapBuildResult::Status::Published) {
      std::fprintf(stderr, "build failed: %s\n", r.error.c_str());
      return 1;
    }
    ingest(pkgs[static_cast<std::size_t>(n)]);
    const auto inc = builder.build(store, req);
    ingest(pkgs[static_cast<std::size_t>(n + 1)]);
    const auto part = builder.build(store, req);
    const Accuracy acc = accuracy(store, r.version, route, origin, radius_m);
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    std::printf(
        "%6d %9lld %9lld %7lld %7lld | %6.3f %6.3f %7.2f %6.3f %6.3f | %6lld | %8.3f %8.0f %9.3f "
        "%8.3f | %8.3f %7lld %7lld | %8.3f %7lld %7lld %8.0f\n",
        n, static_cast<long long>(r.stats.point_candidates),
        static_cast<long long>(r.stats.line_candidates),
        static_cast<long long>(r.stats.point_landmarks),
        static_cast<long long>(r.stats.line_landmarks), acc.point_precision, acc.point_recall,
        100.0 * acc.point_rmse_m, acc.line_precision, acc.line_recall,
        static_cast<long long>(r.stats.tiles_total), ingest_s, static_cast<double>(cand) / ingest_s,
        r.stats.seconds_total, r.stats.seconds_consensus, inc.stats.seconds_total,
        static_cast<long long>(inc.stats.tiles_written),
        static_cast<long long>(inc.stats.tiles_reused), part.stats.seconds_total,
        static_cast<long long>(part.stats.tiles_written),
        static_cast<long long>(part.stats.tiles_reused),
        static_cast<double>(ru.ru_maxrss) / 1024.0);
    std::fflush(stdout);
  }
  std::printf(
      "build_s = load + consensus + landmarks + tiles + publish of a fresh version; incr_s = the\n"
      "same after one more full drive, short_s after one more 300 m drive (tiles whose bytes did\n"
      "not change are reused, not rewritten); P/R: precision and recall against the route's\n"
      "permanent objects and walls (file comment), maxrss_MB: peak resident memory of the process\n"
      "so far. Store: SQLite WAL in %s\n",
      root.c_str());
  if (keep.empty()) fs::remove_all(root);
  return 0;
}
