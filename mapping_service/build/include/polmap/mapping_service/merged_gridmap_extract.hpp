#pragma once
/// @file merged_gridmap_extract.hpp
/// Landmarks extracted from the merged PreCFAR gridmap (gridmap_sums.hpp) instead of from
/// each drive: the vehicle's own detectors (pCFAR points, ridge/Hough lines) run on the
/// fleet covariance Σ N C / Σ N of a region, where a weak scatterer's contrast has grown
/// with every pass while the noise of the estimate shrank. What the benchmark
/// `bench_map_build --world W --merged` compares with candidate consensus.
///
/// Grid: the z20 sum grid read into a radar::CovarianceGridmap whose cell (ix, iy) is sum-
/// grid cell (X0 + ix, Y0 − 1 − iy) (north up), cell size = the z20 cell's ground size at
/// the region's centre latitude; detections convert back to WGS84 through the exact
/// Mercator inverse, so only the detector windows (not positions) see the < 2e-4 relative
/// scale change of Mercator across a few km.
#include <optional>
#include <vector>

#include "polmap/mapping_service/store.hpp"
#include "polmap/radar/line_extractor.hpp"
#include "polmap/radar/point_extractor.hpp"

namespace polmap::mapping {

struct MergedExtractionConfig {
  radar::PointExtractorConfig points;
  radar::LineExtractorConfig lines;
  /// Polarimetric level whose sums are read (nullopt: the level with most sum tiles).
  std::optional<PolLevel> level;
};

struct MergedExtraction {
  enum class Status { Ok, NoGridmap };
  Status status = Status::NoGridmap;
  PolLevel level = PolLevel::Full;
  std::vector<GeoPoint> points;
  std::vector<PointCandidate> point_candidates;  ///< with strength/class, positions in metres
  std::vector<std::pair<GeoPoint, GeoPoint>> lines;
  std::int64_t sum_tiles = 0;
  double noise_power = 0.0;  ///< Σ N σ² / Σ N over the region
};

/// Runs the detectors over the store's merged gridmap inside `region`.
[[nodiscard]] MergedExtraction extract_from_merged_gridmap(const MapStore& store,
                                                           const GeoBox& region,
                                                           const MergedExtractionConfig& cfg = {});

}  // namespace polmap::mapping
