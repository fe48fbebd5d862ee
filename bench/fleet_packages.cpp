// bench_fleet_packages: a declared synthetic fleet for scale campaigns
// (bench/cluster_campaign.sh). A street grid of `--grid` x `--grid` blocks of `--block-m`
// (roads: 2 * (grid + 1) lines of grid * block_m each; 10 x 1 km: 220 km), permanent point
// objects (poles, signs: `--points-per-km`, 3-8 m either side) and wall segments
// (`--walls-per-km`, 8-12 m either side) along every road; `--drives` drives, each of
// `--drive-km` along one road from a random start, seeing 90 % of the objects it passes with
// 5 cm noise plus `--temporaries-per-km` single-drive clutter points, written as
// landmarks-only packages (format 2, candidates and trajectory; ~15 kB/km) in
// OUT/drive_NNNN.tar. Prints the number of drives, drive-km and bytes.
#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace {
namespace fs = std::filesystem;
using namespace polmap;
using namespace polmap::mapping;

struct Road {
  Eigen::Vector2d a, b;  ///< end points (world metres)
  std::vector<Eigen::Vector2d> points;
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> walls;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Synthetic fleet of landmarks-only drive packages on a street grid"};
  std::string out;
  int drives = 1000, grid = 10;
  double block_m = 1000.0, drive_km = 1.0, points_per_km = 100.0, walls_per_km = 20.0,
         temporaries_per_km = 30.0;
  unsigned seed = 1;
  app.add_option("--out", out, "output directory")->required();
  app.add_option("--drives", drives, "number of drives");
  app.add_option("--grid", grid, "blocks per side");
  app.add_option("--block-m", block_m, "block size (m)");
  app.add_option("--drive-km", drive_km, "length of each drive (km)");
  app.add_option("--points-per-km", points_per_km, "permanent point objects per road km");
  app.add_option("--walls-per-km", walls_per_km, "wall segments per road km");
  app.add_option("--temporaries-per-km", temporaries_per_km, "single-drive clutter per km");
  app.add_option("--seed", seed, "random seed");
  CLI11_PARSE(app, argc, argv);

  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  const double side_m = grid * block_m;
  std::vector<Road> roads;
  for (int i = 0; i <= grid; ++i) {
    const double c = -side_m / 2 + i * block_m;
    roads.push_back({{-side_m / 2, c}, {side_m / 2, c}, {}, {}});  // east-west
    roads.push_back({{c, -side_m / 2}, {c, side_m / 2}, {}, {}});  // north-south
  }
  double road_km = 0.0;
  for (Road& r : roads) {
    const Eigen::Vector2d d = (r.b - r.a).normalized(), n(-d.y(), d.x());
    const double len = (r.b - r.a).norm();
    road_km += len / 1000.0;
    const int np = static_cast<int>(points_per_km * len / 1000.0);
    for (int k = 0; k < np; ++k) {
      const double side = (k % 2 ? 1.0 : -1.0) * (3.0 + 5.0 * u01(rng));
      r.points.push_back(r.a + u01(rng) * len * d + side * n);
    }
    const int nw = static_cast<int>(walls_per_km * len / 1000.0);
    for (int k = 0; k < nw; ++k) {
      const double s = u01(rng) * (len - 20.0), l = 5.0 + 15.0 * u01(rng);
      const double side = (k % 2 ? 1.0 : -1.0) * (8.0 + 4.0 * u01(rng));
      r.walls.emplace_back(r.a + s * d + side * n, r.a + (s + l) * d + side * n);
    }
  }
  const GeoPoint world_origin{48.7758, 9.1829, 0.0};
  const tiles::LocalFrame world(world_origin);
  fs::create_directories(out);
  std::uintmax_t bytes = 0;
  std::normal_distribution<double> noise(0.0, 0.05);
  for (int k = 0; k < drives; ++k) {
    const Road& r = roads[static_cast<std::size_t>(u01(rng) * roads.size()) % roads.size()];
    const Eigen::Vector2d d = (r.b - r.a).normalized();
    const double len = (r.b - r.a).norm();
    const double drive_m = std::min(len, 1000.0 * drive_km);
    const double s0 = u01(rng) * (len - drive_m);
    const Eigen::Vector2d start = r.a + s0 * d;
    const GeoPoint origin = world.to_geo(start);
    const tiles::LocalFrame frame(origin);
    auto to_drive = [&](const Eigen::Vector2d& p) { return frame.to_local(world.to_geo(p)); };
    auto along = [&](const Eigen::Vector2d& p) { return (p - r.a).dot(d) - s0; };
    DrivePackage pkg;
    char id[32];
    std::snprintf(id, sizeof id, "drive_%04d", k);
    pkg.manifest.drive_id = id;
    pkg.manifest.vehicle_id = "fleet_" + std::to_string(k % 50);
    pkg.manifest.origin = origin;
    pkg.manifest.distance_m = drive_m;
    pkg.manifest.start_time_s = 1.7e9 + 600.0 * k;
    pkg.manifest.pol_level = PolLevel::SingleLR;
    pkg.manifest.sensors = default_front_mounts();
    const double lane = u01(rng) - 0.5;
    const Eigen::Vector2d n(-d.y(), d.x());
    for (double s = 0.0; s <= drive_m; s += 1.0) {
      const GeoPoint g = world.to_geo(start + s * d + lane * n);
      TrajectorySample t;
      t.time_s = pkg.manifest.start_time_s + s / 10.0;
      t.lat_deg = g.lat_deg;
      t.lon_deg = g.lon_deg;
      t.yaw_enu_rad = std::atan2(d.y(), d.x());
      t.speed_mps = 10.0;
      pkg.trajectory.push_back(t);
    }
    pkg.manifest.end_time_s = pkg.trajectory.back().time_s;
    for (const auto& o : r.points) {
      const double s = along(o);
      if (s < 0.0 || s > drive_m || u01(rng) > 0.9) continue;
      PointCandidate c;
      c.position_m = to_drive(o + Eigen::Vector2d(noise(rng), noise(rng)));
      c.scattering = u01(rng) < 0.5 ? ScatteringClass::Odd : ScatteringClass::Even;
      c.strength = 5.0;
      c.power_db = 20.0;
      pkg.points.push_back(c);
    }
    const int temps = static_cast<int>(temporaries_per_km * drive_m / 1000.0);
    for (int i = 0; i < temps; ++i) {
      PointCandidate c;
      c.power_db = 12.0;
      const double side = (u01(rng) < 0.5 ? -1.0 : 1.0) * (3.0 + 10.0 * u01(rng));
      c.position_m = to_drive(start + u01(rng) * drive_m * d + side * n);
      pkg.points.push_back(c);
    }
    for (const auto& [a, b] : r.walls) {
      if (along(a) < 0.0 || along(b) > drive_m || u01(rng) > 0.9) continue;
      LineCandidate l;
      l.start_m = to_drive(a + Eigen::Vector2d(noise(rng), noise(rng)) * 0.4);
      l.end_m = to_drive(b + Eigen::Vector2d(noise(rng), noise(rng)) * 0.4);
      l.strength = 1.0;
      pkg.lines.push_back(l);
    }
    PackageWriteOptions o;
    o.format_version = 2;
    o.landmarks_only = true;
    const fs::path dir = fs::path(out) / (std::string(id) + ".d");
    GridmapRaster none;  // landmarks-only: no cells
    none.q = 1;
    none.cell_size_m = pkg.manifest.cell_size_m;
    none.layers.assign(1, {});
    (void)write_drive_package(pkg, none, dir, o);
    const fs::path tar = fs::path(out) / (std::string(id) + ".tar");
    write_drive_package_archive(dir, tar);
    fs::remove_all(dir);
    bytes += fs::file_size(tar);
    if ((k + 1) % 100 == 0) std::fprintf(stderr, "\r%d / %d drives", k + 1, drives);
  }
  std::fprintf(stderr, "\n");
  std::printf("drives %d drive_km %.1f road_km %.1f bytes %ju\n", drives, drives * drive_km,
              road_km, bytes);
  return 0;
}
