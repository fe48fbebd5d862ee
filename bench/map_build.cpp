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
// synthetic packages have no gridmap.tif).
//
//   bench_map_build [--drives 2,4,8,16] [--length-km 2] [--seed 1] [--keep DIR]
#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "polmap/mapping_service/map_builder.hpp"
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
  pkg.manifest.vehicle_id = "bench";
  pkg.manifest.origin = origin;
  pkg.manifest.distance_m = r.length_m;
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
  std::printf("%6s %10s %10s %9s %8s %6s | %9s %9s %9s %9s | %9s %7s %7s | %8s %7s %7s\n", "drives",
              "cand_pts", "cand_lines", "lm_pts", "lm_lines", "tiles", "ingest_s", "cand/s",
              "build_s", "consens_s", "incr_s", "written", "reused", "short_s", "written",
              "reused");
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
      const fs::path tar = dir / (p.manifest.drive_id + ".tar");
      std::ofstream(tar) << "bench package " << p.manifest.drive_id;
      (void)store.put_drive(p, tar, content_etag("bench package " + p.manifest.drive_id));
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
    std::printf(
        "%6d %10lld %10lld %9lld %8lld %6lld | %9.3f %9.0f %9.3f %9.3f | %9.3f %7lld %7lld | %8.3f "
        "%7lld %7lld\n",
        n, static_cast<long long>(r.stats.point_candidates),
        static_cast<long long>(r.stats.line_candidates),
        static_cast<long long>(r.stats.point_landmarks),
        static_cast<long long>(r.stats.line_landmarks), static_cast<long long>(r.stats.tiles_total),
        ingest_s, static_cast<double>(cand) / ingest_s, r.stats.seconds_total,
        r.stats.seconds_consensus, inc.stats.seconds_total,
        static_cast<long long>(inc.stats.tiles_written),
        static_cast<long long>(inc.stats.tiles_reused), part.stats.seconds_total,
        static_cast<long long>(part.stats.tiles_written),
        static_cast<long long>(part.stats.tiles_reused));
    std::fflush(stdout);
  }
  std::printf(
      "build_s = load + consensus + landmarks + tiles + publish of a fresh version; incr_s = the\n"
      "same after one more full drive, short_s after one more 300 m drive (tiles whose bytes did\n"
      "not change are reused, not rewritten). Store: SQLite WAL in %s\n",
      root.c_str());
  if (keep.empty()) fs::remove_all(root);
  return 0;
}
