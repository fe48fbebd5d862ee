#pragma once
// Internal helpers of the drive package target (manifest JSON, candidates GeoPackage
// writer). Not installed.
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <utility>
#include <vector>

#include "polmap/mapping_service/detail/gdal.hpp"
#include "polmap/mapping_service/detail/gridmap_tiff.hpp"
#include "polmap/mapping_service/drive_package.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "polmap/util/file.hpp"
#include "polmap/util/sha256.hpp"

namespace polmap::mapping::detail {

// ---------------------------------------------------------------- candidates GeoPackage
/// Writes candidates.gpkg (layers points, lines, trajectory in EPSG:4326) deterministically.
void write_candidates_gpkg(const std::string& path, const tiles::LocalFrame& frame,
                           const std::vector<PointCandidate>& points,
                           const std::vector<LineCandidate>& lines,
                           const std::vector<TrajectorySample>& trajectory);

// ---------------------------------------------------------------- validation budget
/// Validation gave up at its deadline (PackageValidationConfig::max_validation_s): 413.
[[noreturn]] inline void budget_exceeded(const std::string& file, double budget_s) {
  throw PackageValidationError(file, "",
                               "validation exceeded its time budget of " +
                                   std::to_string(static_cast<long long>(budget_s)) +
                                   " s (the package is too large or too complex to check)",
                               413);
}

// ---------------------------------------------------------------- manifest
nlohmann::json manifest_to_json(const DriveManifest& m);
/// Strict parse; throws PackageFormatError / PackageValidationError naming manifest.json.
DriveManifest manifest_from_json(const nlohmann::json& j);

// The one SHA-256 and the whole-file helpers live in polmap_util.
using util::make_unique_dir;
using util::read_file_bytes;
using util::Sha256;
using util::write_file_bytes;

}  // namespace polmap::mapping::detail
