#pragma once
/// @file drive_package.hpp
/// The drive package: what a vehicle uploads (format in schema/drive_package.md).
/// On disk a package is a directory; on the wire (HTTP upload) it is the same
/// files in one POSIX ustar archive (GDAL reads members through /vsitar/).
///   manifest.json   drive id, vehicle, time span, radar spec + mounts, polarimetric
///                   level, CRS (PROJ string of the drive's LocalFrame), cell size,
///                   format version, per-file SHA-256
///   gridmap.tif     covariance gridmap: tiled, DEFLATE GeoTIFF in the drive frame;
///                   band 1 = N (observation count), then the q(q+1)/2 upper-triangle
///                   layers (diagonal real, off-diagonal as real/imag band pairs)
///   candidates.gpkg layers `points`, `lines`, `trajectory` (WGS84 geometries with
///                   drive-frame x/y attributes)
#include <Eigen/Core>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "polmap/schema/geo.hpp"
#include "polmap/schema/landmark.hpp"
#include "polmap/schema/polarimetry.hpp"
#include "polmap/schema/radar_spec.hpp"
#include "polmap/schema/recording.hpp"

namespace polmap::mapping {

inline constexpr std::uint32_t kDrivePackageFormatVersion = 1;

/// manifest.json
struct DriveManifest {
  std::uint32_t format_version = kDrivePackageFormatVersion;
  std::string drive_id;
  std::string vehicle_id;
  double start_time_s = 0.0;
  double end_time_s = 0.0;
  GeoPoint origin;             ///< origin of the drive frame (tiles::LocalFrame)
  std::string crs_proj;        ///< PROJ string of the drive frame
  std::vector<SensorMount> sensors;
  PolLevel pol_level = PolLevel::Full;
  double cell_size_m = 0.1;
  double distance_m = 0.0;
  std::string producer;
};

/// Dense covariance raster of a drive (north-up; row 0 is the northern edge).
struct GridmapRaster {
  double origin_x_m = 0.0;  ///< drive-frame x of the western edge
  double origin_y_m = 0.0;  ///< drive-frame y of the northern edge
  double cell_size_m = 0.1;
  int width = 0;
  int height = 0;
  int q = 0;
  std::vector<std::uint32_t> count;            ///< N per cell, row-major
  std::vector<std::vector<cdouble>> layers;    ///< q(q+1)/2 layers, upper triangle row-major
};

/// A candidate tagged with its drive (consensus input), positions in the drive frame.
struct DrivePackage {
  DriveManifest manifest;
  std::vector<PointCandidate> points;
  std::vector<LineCandidate> lines;
  std::vector<TrajectorySample> trajectory;
  std::filesystem::path location;  ///< directory or .tar the package was read from
};

}  // namespace polmap::mapping
