#pragma once
// Synthetic drive packages for the package, validation and store tests: a small,
// deterministic drive with a valid covariance raster, candidates and trajectory.
#include <cmath>
#include <complex>
#include <filesystem>
#include <random>
#include <string>

#include "polmap/mapping_service/drive_package.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::mapping::testing {

struct SyntheticDrive {
  DrivePackage pkg;
  GridmapRaster raster;
};

/// A drive of `num_samples` trajectory samples along a gentle curve near 35.224 N 138.805 E,
/// a width x height raster (default spans 2x2 GeoTIFF blocks with partial edge blocks) of
/// level `level` with observed cells in a diagonal band, and point/line candidates on it.
inline SyntheticDrive make_synthetic_drive(const std::string& drive_id = "drive_0001",
                                           PolLevel level = PolLevel::Full, int width = 300,
                                           int height = 280, unsigned seed = 7, int num_points = 25,
                                           int num_lines = 6, int num_samples = 120) {
  SyntheticDrive d;
  DriveManifest& m = d.pkg.manifest;
  m.drive_id = drive_id;
  m.vehicle_id = "veh_01";
  m.world = "synthetic";
  m.origin = {35.2240, 138.8045, 100.0};
  m.sensors = default_front_mounts();
  m.pol_level = level;
  m.cell_size_m = 0.1;
  m.producer = "package_fixture";
  m.start_time_s = 1000.0;
  m.end_time_s = 1000.0 + 0.1 * (num_samples - 1);
  const tiles::LocalFrame frame(m.origin);

  GridmapRaster& r = d.raster;
  r.q = pol_dimension(level);
  r.cell_size_m = m.cell_size_m;
  r.width = width;
  r.height = height;
  r.origin_x_m = -10.0;
  r.origin_y_m = 18.0;
  const std::size_t cells = static_cast<std::size_t>(width) * height;
  r.count.assign(cells, 0);
  r.layers.assign(static_cast<std::size_t>(r.num_layers()), std::vector<cdouble>(cells));
  std::mt19937 rng(seed);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_int_distribution<int> nobs(1, 40);
  for (int row = 0; row < height; ++row) {
    for (int col = 0; col < width; ++col) {
      // Observed: a diagonal band of ~60 cells plus a few scattered cells.
      const bool band = std::abs(col - row) < 30;
      if (!band && (col * 7 + row * 13) % 97 != 0) continue;
      const std::size_t k = static_cast<std::size_t>(row) * width + col;
      const int n = nobs(rng);
      r.count[k] = static_cast<std::uint32_t>(n);
      // C = 1/N sum w w^H of random vectors: a valid Hermitian PSD covariance.
      std::vector<std::vector<cdouble>> c(r.q, std::vector<cdouble>(r.q));
      for (int s = 0; s < n; ++s) {
        std::vector<cdouble> w(r.q);
        for (auto& x : w) x = {gauss(rng) * 1e-3, gauss(rng) * 1e-3};
        for (int i = 0; i < r.q; ++i)
          for (int j = 0; j < r.q; ++j) c[i][j] += w[i] * std::conj(w[j]) / double(n);
      }
      for (int i = 0; i < r.q; ++i)
        for (int j = i; j < r.q; ++j)
          r.layers[GridmapRaster::layer_index(r.q, i, j)][k] =
              i == j ? cdouble(c[i][i].real(), 0.0) : c[i][j];
    }
  }
  std::uniform_real_distribution<double> ux(r.origin_x_m + 1, r.origin_x_m + width * 0.1 - 1);
  std::uniform_real_distribution<double> uy(r.origin_y_m - height * 0.1 + 1, r.origin_y_m - 1);
  for (int i = 0; i < num_points; ++i) {
    PointCandidate p;
    p.position_m = {ux(rng), uy(rng)};
    p.strength = 10.0 + i;
    p.power_db = -40.0 + 0.5 * i;
    p.scattering = static_cast<ScatteringClass>(i % 4);
    p.num_cells = static_cast<std::uint32_t>(1 + i % 9);
    d.pkg.points.push_back(p);
  }
  for (int i = 0; i < num_lines; ++i) {
    LineCandidate l;
    l.start_m = {ux(rng), uy(rng)};
    l.end_m = {ux(rng), uy(rng)};
    l.strength = 0.5 + 0.1 * i;
    d.pkg.lines.push_back(l);
  }
  for (int i = 0; i < num_samples; ++i) {
    const double t = 0.1 * i;
    const Eigen::Vector2d xy{-8.0 + 0.2 * i, 16.0 - 0.2 * i + 0.002 * i * i};
    const GeoPoint g = frame.to_geo(xy);
    TrajectorySample s;
    s.time_s = m.start_time_s + t;
    s.lat_deg = g.lat_deg;
    s.lon_deg = g.lon_deg;
    s.yaw_enu_rad = -0.78 + 0.001 * i;
    s.speed_mps = 2.83;
    s.yaw_rate_rps = 0.01;
    s.std_east_m = 0.014F;
    s.std_north_m = 0.015F;
    s.std_yaw_rad = 0.002F;
    s.solution = i % 10 == 9 ? GnssSolution::CarrierPhaseFloat : GnssSolution::CarrierPhaseFixed;
    d.pkg.trajectory.push_back(s);
  }
  m.distance_m = 0.2 * std::sqrt(2.0) * (num_samples - 1);
  return d;
}

}  // namespace polmap::mapping::testing
