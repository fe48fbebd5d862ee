#pragma once
// Drives for MapBuilder tests: a synthetic world of point objects and walls, drives that
// observe part of it (candidates with 3 cm noise), and real packages (written and
// validated by drive_package_io) with a gridmap strip.
#include <gtest/gtest.h>

#include <fstream>
#include <optional>
#include <random>

#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "test_dir.hpp"

namespace polmap::mapping::builder_fixtures {
namespace fs = std::filesystem;

struct TempDir : polmap::test::TestDir {
  TempDir() : TestDir("builder") {}
};

const GeoPoint kWorldOrigin{48.7758, 9.1829, 0.0};

/// A synthetic world in the frame of kWorldOrigin: permanent point objects
/// and walls (metres).
struct World {
  std::vector<Eigen::Vector2d> objects;
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> walls;
};

inline World make_world(unsigned seed, int n_objects, double extent_m) {
  World w;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-extent_m / 2, extent_m / 2);
  for (int i = 0; i < n_objects; ++i) w.objects.emplace_back(u(rng), u(rng));
  for (int i = 0; i < n_objects / 10; ++i) {
    const Eigen::Vector2d a(u(rng), u(rng));
    w.walls.emplace_back(a, a + Eigen::Vector2d(12.0, 3.0));
  }
  return w;
}

/// A drive observing the objects inside `seen` (a box in world metres) with 3 cm noise,
/// plus `temporaries` single-drive objects. Its frame origin is offset from the world's.
inline DrivePackage observe(const World& w, const std::string& id, unsigned seed,
                            Eigen::Vector2d lo, Eigen::Vector2d hi, int temporaries = 20) {
  const tiles::LocalFrame world(kWorldOrigin);
  const GeoPoint origin = world.to_geo(Eigen::Vector2d(37.0 * (seed % 5), -23.0 * (seed % 3)));
  const tiles::LocalFrame drive(origin);
  auto to_drive = [&](const Eigen::Vector2d& p) { return drive.to_local(world.to_geo(p)); };
  auto inside = [&](const Eigen::Vector2d& p) {
    return p.x() >= lo.x() && p.x() <= hi.x() && p.y() >= lo.y() && p.y() <= hi.y();
  };
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, 0.03);
  DrivePackage pkg;
  pkg.manifest.drive_id = id;
  pkg.manifest.vehicle_id = "veh";
  pkg.manifest.origin = origin;
  for (const auto& o : w.objects) {
    if (!inside(o)) continue;
    PointCandidate c;
    c.position_m = to_drive(o + Eigen::Vector2d(n(rng), n(rng)));
    c.scattering = ScatteringClass::Odd;
    pkg.points.push_back(c);
  }
  std::uniform_real_distribution<double> ux(lo.x(), hi.x()), uy(lo.y(), hi.y());
  for (int i = 0; i < temporaries; ++i) {
    PointCandidate c;
    c.position_m = to_drive(Eigen::Vector2d(ux(rng), uy(rng)));
    pkg.points.push_back(c);
  }
  for (const auto& [a, b] : w.walls) {
    if (!inside(a) || !inside(b)) continue;
    LineCandidate l;
    l.start_m = to_drive(a + Eigen::Vector2d(n(rng), n(rng)));
    l.end_m = to_drive(b + Eigen::Vector2d(n(rng), n(rng)));
    pkg.lines.push_back(l);
  }
  return pkg;
}

/// A width x height raster of 0.1 m cells with its north-west corner at (origin_x_m,
/// origin_y_m), q x q covariances, nothing observed yet.
inline GridmapRaster unobserved_raster(int q, int width, int height, double origin_x_m,
                                       double origin_y_m) {
  GridmapRaster r;
  r.q = q;
  r.cell_size_m = 0.1;
  r.width = width;
  r.height = height;
  r.origin_x_m = origin_x_m;
  r.origin_y_m = origin_y_m;
  r.count.assign(static_cast<std::size_t>(r.width) * r.height, 0);
  r.layers.assign(static_cast<std::size_t>(q * (q + 1) / 2),
                  std::vector<cdouble>(r.count.size(), cdouble(0, 0)));
  return r;
}

/// A real package (written and validated by drive_package_io) with a gridmap:
/// a 100 m x 60 m raster, observed (tr(C) = 1000, 30 dB) in a 20 m strip.
inline GridmapRaster make_raster(int q) {
  GridmapRaster r = unobserved_raster(q, 1000, 600, -70.0, 30.0);
  for (int row = 200; row < 400; ++row) {
    for (int col = 0; col < r.width; ++col) {
      const std::size_t i = static_cast<std::size_t>(row) * r.width + col;
      r.count[i] = 3;
      r.layers[0][i] = 1000.0;
    }
  }
  return r;
}

/// Writes `pkg` with `raster` as tmp/pkg_<name> (kept if a package of that name was written
/// before: a drive put again after its delete) and its archive, validates the archive and
/// puts it into the store.
inline void put_written_package(MapStore& store, const fs::path& tmp, const std::string& name,
                                const DrivePackage& pkg, const GridmapRaster& raster,
                                const PackageWriteOptions& options) {
  const fs::path dir = tmp / ("pkg_" + name);
  if (!fs::exists(dir)) (void)write_drive_package(pkg, raster, dir, options);
  const fs::path tar = tmp / ("pkg_" + name + ".tar");
  if (!fs::exists(tar)) write_drive_package_archive(dir, tar);
  const DrivePackage valid = read_and_validate_package(tar);
  std::ifstream f(tar, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  ASSERT_EQ(store.put_drive(valid, tar, package_content_hash(bytes)).status,
            PutDriveResult::Status::Inserted);
}

/// Package writer options of one format version.
inline PackageWriteOptions package_format(int version) {
  PackageWriteOptions o;
  o.format_version = version;
  return o;
}

/// Writes drive d (0 or 1) of world w as a real package with make_raster(1) in the given
/// format, validates its archive and puts it into the store.
/// `origin_m`: moves the whole drive (frame origin, so candidates, trajectory and gridmap)
/// to this point of the world frame.
inline void put_real_package(MapStore& store, const fs::path& tmp, const World& w, int d,
                             const std::string& name, const PackageWriteOptions& options,
                             std::optional<Eigen::Vector2d> origin_m = std::nullopt,
                             double start_time_s = 0.0) {
  // Seeds 45 and 51: drive frames at (0, 0) and (37, 0) m from the world origin.
  DrivePackage pkg = observe(w, name, d == 0 ? 45 : 51, {-25, -25}, {25, 25}, 0);
  if (origin_m) pkg.manifest.origin = tiles::LocalFrame(kWorldOrigin).to_geo(*origin_m);
  pkg.manifest.start_time_s = start_time_s;
  pkg.manifest.end_time_s = start_time_s + 1.0;
  pkg.manifest.pol_level = PolLevel::SingleLR;
  pkg.manifest.sensors = default_front_mounts();
  const tiles::LocalFrame drive_frame(pkg.manifest.origin);
  for (int k = 0; k <= 10; ++k) {
    const GeoPoint g = drive_frame.to_geo(Eigen::Vector2d(-25.0 + 5.0 * k, 0.0));
    TrajectorySample t;
    t.time_s = start_time_s + 0.1 * k;
    t.lat_deg = g.lat_deg;
    t.lon_deg = g.lon_deg;
    t.speed_mps = 10.0;
    pkg.trajectory.push_back(t);
  }
  GridmapRaster raster = make_raster(1);
  raster.noise_power = 1.0;  // format 2 needs the noise figure; format 1 ignores it
  put_written_package(store, tmp, name, pkg, raster, options);
}

/// A real package of a drive that observes the objects and walls of `w` inside [lo, hi]
/// (world metres) along `path` (world metres, 10 m/s), with `temporaries` single-drive
/// objects and a small gridmap strip; put into the store.
inline void put_drive_along(MapStore& store, const fs::path& tmp, const World& w,
                            const std::string& name, unsigned seed, Eigen::Vector2d lo,
                            Eigen::Vector2d hi, const std::vector<Eigen::Vector2d>& path,
                            int temporaries = 20, double start_time_s = 0.0,
                            const Eigen::Vector2d& gnss_error_m = Eigen::Vector2d::Zero(),
                            float reported_std_m = 0.0F) {
  // gnss_error_m: the drive's positioning error, shifting its candidates and trajectory
  // alike (a consumer-grade receiver reports reported_std_m, solution standalone).
  DrivePackage pkg = observe(w, name, seed, lo, hi, temporaries);
  for (auto& c : pkg.points) c.position_m += gnss_error_m;
  for (auto& l : pkg.lines) l.start_m += gnss_error_m, l.end_m += gnss_error_m;
  pkg.manifest.start_time_s = start_time_s;
  pkg.manifest.pol_level = PolLevel::SingleLR;
  pkg.manifest.sensors = default_front_mounts();
  const tiles::LocalFrame world(kWorldOrigin);
  const tiles::LocalFrame drive_frame(pkg.manifest.origin);
  double t = start_time_s;
  for (std::size_t k = 0; k < path.size(); ++k) {
    if (k > 0) t += (path[k] - path[k - 1]).norm() / 10.0;
    const GeoPoint g = world.to_geo(path[k] + gnss_error_m);
    TrajectorySample s;
    s.time_s = t;
    s.lat_deg = g.lat_deg;
    s.lon_deg = g.lon_deg;
    s.speed_mps = 10.0;
    s.std_east_m = s.std_north_m = reported_std_m;
    s.solution = reported_std_m > 0.5F ? GnssSolution::Standalone : GnssSolution::CarrierPhaseFixed;
    pkg.trajectory.push_back(s);
  }
  pkg.manifest.end_time_s = t + 1.0;
  // 2 m cells over 1.2 km x 1.2 km (every candidate inside), observed in a 120 m block (at least as
  // many cells as candidates).
  GridmapRaster raster = unobserved_raster(1, 600, 600, -600.0, 600.0);
  raster.cell_size_m = 2.0;
  pkg.manifest.cell_size_m = 2.0;
  for (int row = 270; row < 330; ++row) {
    for (int col = 270; col < 330; ++col) {
      const std::size_t i = static_cast<std::size_t>(row) * raster.width + col;
      raster.count[i] = 3;
      raster.layers[0][i] = 1000.0;
    }
  }
  raster.noise_power = 1.0;
  PackageWriteOptions options;
  options.format_version = 2;
  put_written_package(store, tmp, name, pkg, raster, options);
}

}  // namespace polmap::mapping::builder_fixtures
