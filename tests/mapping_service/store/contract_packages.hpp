#pragma once
// Synthetic packages for the store tests of every backend: a validated DrivePackage with
// points, lines and a trajectory, and a package-shaped archive to store it from.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <utility>

#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/store.hpp"
#include "polmap/mapping_service/ustar.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::mapping::testing {

inline const GeoPoint kOrigin{48.7758, 9.1829, 250.0};  // Stuttgart

/// A synthetic validated package: n points and m lines scattered in a
/// `extent_m` square around the drive origin, plus a short trajectory.
inline DrivePackage make_package(const std::string& drive_id, int n_points, int n_lines,
                                 unsigned seed, double extent_m = 200.0,
                                 GeoPoint origin = kOrigin) {
  DrivePackage p;
  p.manifest.drive_id = drive_id;
  p.manifest.vehicle_id = "veh-1";
  p.manifest.start_time_s = 10.0;
  p.manifest.end_time_s = 70.0;
  p.manifest.origin = origin;
  p.manifest.pol_level = PolLevel::DualLLLR;
  p.manifest.distance_m = 500.0;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-extent_m / 2, extent_m / 2);
  for (int i = 0; i < n_points; ++i) {
    PointCandidate c;
    c.position_m = {u(rng), u(rng)};
    c.strength = 3.0 + i;
    c.power_db = -10.0;
    c.scattering = static_cast<ScatteringClass>(i % 4);
    c.num_cells = 5;
    p.points.push_back(c);
  }
  for (int i = 0; i < n_lines; ++i) {
    LineCandidate l;
    l.start_m = {u(rng), u(rng)};
    l.end_m = l.start_m + Eigen::Vector2d(u(rng) / 10, u(rng) / 10);
    l.strength = 0.5;
    p.lines.push_back(l);
  }
  const tiles::LocalFrame frame(origin);
  for (int i = 0; i < 10; ++i) {
    const GeoPoint g = frame.to_geo(Eigen::Vector2d(10.0 * i, 0.0));
    TrajectorySample t;
    t.time_s = 10.0 + i;
    t.lat_deg = g.lat_deg;
    t.lon_deg = g.lon_deg;
    t.speed_mps = 10.0;
    t.yaw_rate_rps = 0.001 * (i % 3);  // distinct values for the store's round trip
    p.trajectory.push_back(t);
  }
  return p;
}

/// Writes a package-shaped ustar archive (the three members; `content` as manifest.json,
/// the store does not validate) and returns (path, content hash).
inline std::pair<std::filesystem::path, std::string> write_archive(const std::filesystem::path& dir,
                                                                   const std::string& name,
                                                                   const std::string& content) {
  const std::filesystem::path p = dir / (name + ".tar");
  std::ofstream(p, std::ios::binary) << write_ustar({{kManifestFileName, content},
                                                     {kGridmapFileName, "tif " + name},
                                                     {kCandidatesFileName, "gpkg " + name}});
  return {p, content_etag(content)};
}

/// Puts pkg with a fake archive (write_archive(dir, name, content)).
inline PutDriveResult put_with_archive(MapStore& store, const std::filesystem::path& dir,
                                       const DrivePackage& pkg, const std::string& name,
                                       const std::string& content) {
  const auto [tar, hash] = write_archive(dir, name, content);
  return store.put_drive(pkg, tar, hash);
}

/// Entries of a directory; in a package directory, without the upload session directory
/// that the PostgreSQL backend keeps there ("uploads").
inline std::size_t entries(const std::filesystem::path& dir) {
  std::size_t n = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    if (e.path().filename() != "uploads") ++n;
  }
  return n;
}

}  // namespace polmap::mapping::testing
