#pragma once
/// @file drive_package.hpp
/// The drive package: what a vehicle uploads (format in schema/drive_package.md).
/// On disk a package is a directory; on the wire (HTTP upload) it is the same
/// files in one POSIX ustar archive (deterministic: fixed member order, zero
/// mtimes), whose SHA-256 is the package's content hash.
///   manifest.json   drive id, vehicle, time span, radar spec + mounts, polarimetric
///                   level, CRS (PROJ string of the drive's LocalFrame), cell size,
///                   gridmap geometry, counts, format version, per-file size + SHA-256
///   gridmap.tif     covariance gridmap: 256x256-tiled, DEFLATE GeoTIFF in the drive
///                   frame, all bands Float32; band 1 = N (observation count), then the
///                   q(q+1)/2 upper-triangle layers (diagonal: one real band, off-diagonal:
///                   a real/imag band pair), 1 + q^2 bands in all
///   candidates.gpkg layers `points`, `lines`, `trajectory` (WGS84 geometries with
///                   drive-frame x/y attributes)
/// Reading, writing and validation: drive_package_io.hpp.
#include <Eigen/Core>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "polmap/mapping_service/gridmap_codec.hpp"
#include "polmap/schema/geo.hpp"
#include "polmap/schema/landmark.hpp"
#include "polmap/schema/polarimetry.hpp"
#include "polmap/schema/radar_spec.hpp"
#include "polmap/schema/recording.hpp"

namespace polmap::mapping {

/// The newest format this build reads and writes by default (1 is still read and written).
inline constexpr std::uint32_t kDrivePackageFormatVersion = 2;

/// Member file names of a package (directory entries and archive members, in archive order).
inline constexpr const char* kManifestFileName = "manifest.json";
inline constexpr const char* kGridmapFileName = "gridmap.tif";
inline constexpr const char* kCandidatesFileName = "candidates.gpkg";    ///< format 1
inline constexpr const char* kCandidatesBinFileName = "candidates.bin";  ///< format 2

/// One data file of a package as listed in the manifest (manifest.json itself is not listed).
struct PackageFileEntry {
  std::string name;  ///< file name inside the package, e.g. "gridmap.tif"
  std::uint64_t size_bytes = 0;
  std::string sha256;  ///< lower-case hex, 64 characters
};

/// Geometry of gridmap.tif (north-up raster in the drive frame).
struct GridmapInfo {
  int width = 0;            ///< columns
  int height = 0;           ///< rows
  double origin_x_m = 0.0;  ///< drive-frame x of the western edge
  double origin_y_m = 0.0;  ///< drive-frame y of the northern edge
  int num_bands = 0;        ///< 1 + q^2
  int block_size = 256;     ///< GeoTIFF tile edge in cells
  int mantissa_bits = 23;   ///< Float32 mantissa bits kept in the covariance bands (23 = all)
  /// Format 2: the compact encoding (gridmap_codec.hpp), 3 + q^2 UInt16 bands; its
  /// parameters and the drive's noise power σ² (> 0) decode the codes.
  bool compact = false;
  double noise_power = 0.0;
  GridmapCodecConfig codec;
};

/// Feature counts of candidates.gpkg (checked against the layers on validation).
struct PackageCounts {
  std::uint64_t points = 0;
  std::uint64_t lines = 0;
  std::uint64_t trajectory_samples = 0;
};

/// manifest.json
struct DriveManifest {
  std::uint32_t format_version = kDrivePackageFormatVersion;
  std::string drive_id;
  std::string vehicle_id;
  std::string world;  ///< scenario / map name from the recording header (may be empty)
  double start_time_s = 0.0;
  double end_time_s = 0.0;
  GeoPoint origin;       ///< origin of the drive frame (tiles::LocalFrame)
  std::string crs_proj;  ///< PROJ string of the drive frame
  std::vector<SensorMount> sensors;
  PolLevel pol_level = PolLevel::Full;
  double cell_size_m = 0.1;
  double distance_m = 0.0;
  std::string producer;
  /// False for a landmarks-only package (format 2, no gridmap.tif).
  bool has_gridmap = true;
  // Filled in by the writer (inputs to write_drive_package may leave them default):
  GridmapInfo gridmap;
  PackageCounts counts;
  /// Format 1: gridmap.tif, candidates.gpkg; format 2: [gridmap.tif,] candidates.bin.
  std::vector<PackageFileEntry> files;
};

/// Dense covariance raster of a drive (north-up; row 0 is the northern edge).
struct GridmapRaster {
  double origin_x_m = 0.0;  ///< drive-frame x of the western edge
  double origin_y_m = 0.0;  ///< drive-frame y of the northern edge
  double cell_size_m = 0.1;
  int width = 0;
  int height = 0;
  int q = 0;
  std::vector<std::uint32_t> count;  ///< N per cell, row-major
  /// Looks with a stored bin per cell (persistence hits/N); empty when the source does not
  /// carry them (format 1 packages).
  std::vector<std::uint32_t> hits;
  double noise_power = 0.0;                  ///< σ² per component; 0 when unknown (format 1)
  std::vector<std::vector<cdouble>> layers;  ///< q(q+1)/2 layers, upper triangle row-major

  /// Number of covariance layers q(q+1)/2.
  [[nodiscard]] int num_layers() const { return q * (q + 1) / 2; }
  /// Index of layer C_ij (i <= j) in `layers`: upper triangle, row-major.
  [[nodiscard]] static int layer_index(int q, int i, int j) {
    return i * q - i * (i - 1) / 2 + (j - i);
  }
};

/// A drive package as read back: manifest plus candidates, positions in the drive frame.
struct DrivePackage {
  DriveManifest manifest;
  std::vector<PointCandidate> points;
  std::vector<LineCandidate> lines;
  std::vector<TrajectorySample> trajectory;
  std::filesystem::path location;  ///< directory or .tar the package was read from (empty: bytes)
  /// SHA-256 (hex) of the package's canonical ustar archive: for an archive its bytes, for a
  /// directory the bytes pack_drive_package() produces from it. Empty for inputs to the writer.
  std::string content_sha256;
};

}  // namespace polmap::mapping
