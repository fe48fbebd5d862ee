#pragma once
/// @file drive_package_io.hpp
/// Writing, packing, unpacking and validating drive packages (schema/drive_package.md).
/// Adapter code: files and GDAL. Value types: drive_package.hpp.
///
/// Errors. Every failure names the package file and, where there is one, the field:
///   "manifest.json: field 'pol_level': unknown level 'xx'"
///   "candidates.gpkg: layer 'points' feature 3: field 'x_m': not finite"
/// PackageFormatError (a FormatError) means the bytes cannot be parsed as the expected
/// container (truncated archive, not JSON, not a GeoTIFF/GeoPackage, wrong JSON type):
/// HTTP 400. PackageValidationError (a ValidationError) means the files parse but
/// violate the package schema (missing field, unknown enum, hash mismatch, band count,
/// non-finite or implausible coordinates, ...): HTTP 422.
#include <cstdint>
#include <expected>
#include <filesystem>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "polmap/mapping_service/drive_package.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::radar {
class CovarianceGridmap;
struct DriveProcessingResult;
struct DriveProcessingConfig;
}  // namespace polmap::radar

namespace polmap::mapping {

/// Options of write_drive_package. Defaults are what `polmap process` uses.
struct PackageWriteOptions {
  /// Overrides manifest.producer when non-empty.
  std::string producer;
  /// Replace an existing package directory. When false, an existing non-empty `dir` is an error.
  bool overwrite = false;
  /// zlib level of the GeoTIFF's DEFLATE tiles (1 fastest .. 9 smallest).
  int deflate_level = 6;
  /// Float32 mantissa bits kept in the covariance bands (1..23; N is always exact).
  /// 23 = lossless. Fewer bits round each value to nearest with relative error
  /// <= 2^-(bits+1) and let DEFLATE shrink the gridmap: speckle makes a covariance
  /// estimate from N looks uncertain by ~1/sqrt(N), so 10 bits (5e-4) lose nothing
  /// physical. Measured sizes: schema/drive_package.md "Size".
  int mantissa_bits = 23;
  /// Package format to write: 2 (compact: gridmap codes, candidates.bin; what `polmap
  /// process` writes) or 1 (Float32 gridmap and GeoPackage: lossless, GIS-readable, for
  /// mapping vehicles and consumers of the old format; the library default so that
  /// existing callers keep their bytes). schema/drive_package.md.
  std::uint32_t format_version = 1;
  /// Format 2 only: no gridmap.tif (candidates and trajectory only, ~15 kB/km).
  bool landmarks_only = false;
  /// Format 2 gridmap encoding.
  GridmapCodecConfig codec;
  /// ZSTD level of the format 2 gridmap tiles (1..22).
  int zstd_level = 19;
  /// Format 2 trajectory: samples are dropped while linear interpolation between the kept
  /// ones stays within this distance and yaw error and the kept ones are at most
  /// trajectory_max_gap_s apart (0 keeps every sample).
  /// (The server uses the trajectory for coverage, distance and display; the drive's
  /// poses at full rate stay on the vehicle.)
  double trajectory_max_error_m = 0.05;
  double trajectory_max_yaw_error_rad = 0.005;
  double trajectory_max_gap_s = 2.0;
  /// ... and while the vehicle's odometry integrated over the kept samples alone (trapezoid
  /// of yaw rate and of speed) stays within these of the full-rate integrals: the map
  /// builder aligns consumer-grade drives with that odometry (drive_alignment.hpp). Without
  /// the bound, a 90° turn lost ~0.3° of integrated yaw per 10 m.
  double trajectory_max_yaw_integral_error_rad = 0.0005;
  double trajectory_max_distance_error_m = 0.02;
  /// Re-read and fully validate the written package before it replaces `dir`, so a writer
  /// bug can never produce a package the server would reject.
  bool validate_after_write = true;
};

/// Plausibility limits of read_and_validate_package. Defaults accept any real drive of
/// up to ~100 km extent and reject garbage.
struct PackageValidationConfig {
  double max_abs_coordinate_m = 100'000.0;  ///< |x|, |y| of anything in the drive frame
  double max_speed_mps = 100.0;             ///< |speed| of trajectory samples
  std::uint64_t max_points = 2'000'000;     ///< also never more than observed (N > 0) cells
  std::uint64_t max_lines = 500'000;
  std::uint64_t max_trajectory_samples = 10'000'000;
  std::int64_t max_raster_cells = 4'000'000'000;  ///< width * height
  /// Candidates may lie this far outside the gridmap extent (extraction smoothing).
  double extent_margin_m = 2.0;
  /// Slack between the manifest time span and the trajectory's first/last sample.
  double time_span_tolerance_s = 1.0;
  /// Scan every gridmap block: N integral and >= 0, layers finite, zero where N = 0,
  /// non-negative diagonal. Off only for quick header-level checks.
  bool check_gridmap_values = true;
  /// Wall-clock budget of one validation (s); past it validation stops with 413, so no
  /// package can hold a request thread for minutes (decompression bombs, huge rasters).
  /// 0 = unlimited (trusted local packages).
  double max_validation_s = 60.0;
  /// manifest.json larger than this is refused before it is parsed (ours are a few kB).
  std::uint64_t max_manifest_bytes = 1u << 20;
};

/// A failed read/validation as a value (for the HTTP server).
struct PackageError {
  std::string file;     ///< package member, "archive" for the ustar container, or the path
  std::string field;    ///< offending field/band/layer (may be empty)
  std::string message;  ///< what is wrong
  /// 400: unparsable container/format, 422: schema/semantic violation, 413: not checkable
  /// within PackageValidationConfig::max_validation_s.
  int http_status = 422;
  /// "FILE: field 'FIELD': MESSAGE" (or "FILE: MESSAGE" without a field).
  [[nodiscard]] std::string what() const;
};

/// Thrown for unparsable package files (HTTP 400).
class PackageFormatError : public FormatError {
 public:
  PackageFormatError(std::string file, std::string field, std::string message);
  [[nodiscard]] const PackageError& error() const { return error_; }

 private:
  PackageError error_;
};

/// Thrown for package files that parse but violate the schema (HTTP 422), or that could
/// not be checked within the validation budget (413).
class PackageValidationError : public ValidationError {
 public:
  PackageValidationError(std::string file, std::string field, std::string message,
                         int http_status = 422);
  [[nodiscard]] const PackageError& error() const { return error_; }

 private:
  PackageError error_;
};

/// Band descriptions of gridmap.tif for a level: "N", then per upper-triangle layer
/// "C_A_A" (diagonal) or "C_A_B.re", "C_A_B.im" (off-diagonal), A/B the level's
/// components (full: LL, LR, RR; ll-lr: LL, LR; hh-vv: HH, VV; lr; rr; hh).
[[nodiscard]] std::vector<std::string> gridmap_band_names(PolLevel level);
/// Band descriptions of a format 2 (compact) gridmap.tif: "N", "hits", "P", then per
/// upper-triangle element of the Cholesky factor "U_A_A" or "U_A_B.re", "U_A_B.im".
[[nodiscard]] std::vector<std::string> compact_gridmap_band_names(PolLevel level);
/// Component names of a level's scattering vector, e.g. {"LL", "LR", "RR"} for full.
[[nodiscard]] std::vector<std::string> pol_component_names(PolLevel level);

/// Writes a package directory from plain values. `pkg.manifest` supplies the metadata
/// (drive_id, vehicle_id, times, origin, sensors, pol_level, distance); crs_proj may be
/// empty (filled from LocalFrame(origin)) and must otherwise name the same CRS;
/// cell_size_m and q must match `raster`; gridmap/counts/files are filled in.
/// Candidate positions are in the drive frame. The directory is written beside `dir`
/// and renamed into place, so a failure never leaves a half-written package.
/// Throws ValidationError for inconsistent inputs, IoError for file system failures.
/// Returns the manifest as written.
DriveManifest write_drive_package(const DrivePackage& pkg, const GridmapRaster& raster,
                                  const std::filesystem::path& dir,
                                  const PackageWriteOptions& options = {});

/// Writes a package whose gridmap comes straight from a radar::CovarianceGridmap: the
/// GeoTIFF is aligned to the gridmap's cell grid (origin = bounds() corner) and written
/// block by block from the allocated tiles (memory: one 256x256 block, never the bounding
/// box). `pkg` supplies manifest metadata, candidates and trajectory as in the plain
/// overload; the gridmap's level and cell size must match the manifest's.
DriveManifest write_drive_package(const DrivePackage& pkg, const radar::CovarianceGridmap& gridmap,
                                  const std::filesystem::path& dir,
                                  const PackageWriteOptions& options = {});

/// Writes a package from a processed drive (radar::process_drive): metadata from the
/// recording header and processing stats (time span = first/last trajectory sample,
/// distance = trajectory path length), the gridmap streamed tile by tile (never
/// densified), candidates and the (strictly time-ordered) trajectory.
DriveManifest write_drive_package(const radar::DriveProcessingResult& result,
                                  const std::filesystem::path& dir,
                                  const PackageWriteOptions& options = {});

/// The package directory's files as one deterministic ustar archive (members
/// manifest.json, gridmap.tif, candidates.gpkg in that order, mtime 0). The same
/// package always gives the same bytes. Throws IoError if a file is missing.
[[nodiscard]] std::string pack_drive_package(const std::filesystem::path& dir);
/// pack_drive_package(dir) written to `tar_path` (atomically, via a temporary file).
void write_drive_package_archive(const std::filesystem::path& dir,
                                 const std::filesystem::path& tar_path);

/// Extracts an archive's members into `dir` (created; must not exist or be empty).
/// Checks the ustar structure and the member set, not the contents (validate after).
void unpack_drive_package(std::string_view tar_bytes, const std::filesystem::path& dir);
/// Extracts into a new unique directory under the system temp dir and returns it
/// (the caller removes it).
[[nodiscard]] std::filesystem::path unpack_drive_package_to_temp(std::string_view tar_bytes);

/// SHA-256 of bytes, lower-case hex.
[[nodiscard]] std::string sha256_hex(std::string_view bytes);
/// The content hash of a package archive: sha256_hex(tar_bytes).
[[nodiscard]] inline std::string package_content_hash(std::string_view tar_bytes) {
  return sha256_hex(tar_bytes);
}

/// Reads and validates a whole package — a directory or a ustar archive file — before
/// anyone commits it: manifest schema (required fields, types, version, enums), file
/// presence, size and SHA-256 of every file, gridmap.tif (GeoTIFF, band count/type/names,
/// CRS same as the manifest's and the LocalFrame of its origin, geotransform, values),
/// candidates.gpkg (layers, fields, geometry types, SRS, counts, finite and plausible
/// coordinates, geometry consistent with x/y), trajectory times strictly increasing.
/// Throws PackageFormatError / PackageValidationError; IoError if `dir_or_tar` is unreadable.
[[nodiscard]] DrivePackage read_and_validate_package(const std::filesystem::path& dir_or_tar,
                                                     const PackageValidationConfig& cfg = {});
/// Same for an archive held in memory (an HTTP upload); location stays empty.
[[nodiscard]] DrivePackage validate_package_bytes(std::string_view tar_bytes,
                                                  const PackageValidationConfig& cfg = {});

/// Non-throwing variants for the server (IoError maps to a PackageError with status 400).
[[nodiscard]] std::expected<DrivePackage, PackageError> try_read_and_validate_package(
    const std::filesystem::path& dir_or_tar, const PackageValidationConfig& cfg = {});
[[nodiscard]] std::expected<DrivePackage, PackageError> try_validate_package_bytes(
    std::string_view tar_bytes, const PackageValidationConfig& cfg = {});

/// The dense gridmap of a package read from `pkg.location` (directory or archive).
/// Memory: width * height * (4 + 16 q(q+1)/2) bytes; for large drives prefer
/// for_each_gridmap_block. Throws PackageFormatError if the GeoTIFF cannot be read.
[[nodiscard]] GridmapRaster read_gridmap(const DrivePackage& pkg);
/// Same from a gridmap GeoTIFF path (any GDAL path, e.g. "/vsitar/x.tar/gridmap.tif").
[[nodiscard]] GridmapRaster read_gridmap(const std::string& gdal_path);
/// Calls fn for every non-empty 256x256 block of the package's gridmap (row-major block
/// order), each as a small raster with its own origin; blocks without any N > 0 cell
/// are skipped. Memory: one block.
void for_each_gridmap_block(const DrivePackage& pkg,
                            const std::function<void(const GridmapRaster& block)>& fn);

/// The package's gridmap as a mapping-mode radar::CovarianceGridmap (tiles rebuilt by
/// merge_tile, hits and the noise power of a format 2 package set), so the vehicle's
/// detectors can be re-run on what was uploaded. Format 1 packages carry no hits (every
/// look counts as a hit) and no noise power (0). Throws NotFoundError without a gridmap.
[[nodiscard]] radar::CovarianceGridmap read_covariance_gridmap(const DrivePackage& pkg);

/// The gridmap exactly as a compact (format 2) package carries it: every cell encoded with
/// `codec` and decoded again, as read_covariance_gridmap gives it back to the backend
/// (noise power set). Memory: one more gridmap.
[[nodiscard]] radar::CovarianceGridmap compact_round_trip(const radar::CovarianceGridmap& gridmap,
                                                          const GridmapCodecConfig& codec = {});

/// Replaces the candidates of a processed drive by those cfg.points / cfg.lines find in
/// compact_round_trip(result.gridmap, codec) (only the kinds cfg extracts); updates the
/// extraction times. process_drive_for_package calls it.
void extract_candidates_as_sent(radar::DriveProcessingResult& result,
                                const radar::DriveProcessingConfig& cfg,
                                const GridmapCodecConfig& codec);

/// True when a package written with these options carries the compact gridmap (format 2,
/// not landmarks-only): its candidates must then be extracted from what it sends.
[[nodiscard]] bool sends_compact_gridmap(const PackageWriteOptions& options);

/// radar::process_drive for a package written with `options`. When the package carries the
/// compact gridmap, the candidates are extracted from compact_round_trip(gridmap), not from
/// the exact gridmap: what the package sends is then exactly what the backend re-extracts
/// from it. (The line extractor's threshold decisions flip on a ~0.002 dB change of the
/// power image, the codec's power step: candidates of the exact gridmap were reproduced
/// from the decoded one at 0.98-0.99 for dual and single polarization, not 1.) The result's
/// gridmap stays the exact one; the package is written from it and its codes are the ones
/// decoded here. Otherwise this is process_drive.
[[nodiscard]] radar::DriveProcessingResult process_drive_for_package(
    RecordSource& source, radar::DriveProcessingConfig cfg, const PackageWriteOptions& options,
    const std::function<void(double time_s)>& progress = {});

/// Parses manifest.json text with the validator's strict parser (e.g. the copy a store
/// kept of a validated package). Throws PackageFormatError / PackageValidationError.
[[nodiscard]] DriveManifest parse_manifest(std::string_view json_text);

/// GDAL path of a package member: DIR/NAME for a directory, /vsitar/TAR/NAME for an archive.
[[nodiscard]] std::string package_member_gdal_path(const std::filesystem::path& location,
                                                   const std::string& name);

}  // namespace polmap::mapping
