#pragma once
/// @file localization_runs.hpp
/// What the mapping service derives from a validated localization run report
/// (schema/localization_run.hpp): the record and summary it lists, the quality cells it
/// sums over the fleet (where localization degraded: the places the map is weak), and the
/// GeoJSON the console draws. Pure computation: values in, values out; the server stores
/// and serves them.
#include <cstdint>
#include <nlohmann/json.hpp>
#include <span>
#include <string>
#include <vector>

#include "polmap/mapping_service/store.hpp"
#include "polmap/schema/localization_run.hpp"

namespace polmap::mapping {

/// Web-Mercator zoom of the quality cells: tiles of ≈ 38 m · cos(latitude) (≈ 25 m in
/// central Europe), fine enough to point at a street section, coarse enough to pool runs.
inline constexpr int kRunCellZoom = 20;

/// When a cell counts as weak in the fleet layer (run_cells_geojson's `weak`).
struct RunQualityThresholds {
  double degraded_share = 0.2;    ///< share of degraded or lost samples
  double lat_rmse_m = 0.2;        ///< lateral RMSE where errors were reported
  double mean_sigma_lat_m = 0.3;  ///< the localizer's own lateral 1-σ, averaged
};

/// Lateral 1-σ (metres) of a sample: its position covariance across its heading.
[[nodiscard]] double lateral_sigma_m(const LocalizationRunSample& s);

/// Along-track distance (metres) at each sample from the first, in a local transverse
/// Mercator frame at the first sample.
[[nodiscard]] std::vector<double> run_distances_m(const LocalizationRun& run);

/// The record the store lists: bounds, sample count and the summary JSON
/// {samples, duration_s, length_m, status_share{...}, time_to_tracking_s, mean_sigma_lat_m,
/// reference, evaluated, lat_rmse_m, long_rmse_m, rot_rmse_deg, lat_max_m, lat_p95_m,
/// realtime_factor, pol}. Error figures are null when no sample was evaluated.
/// Contract: `run` is valid (parse_localization_run) — at least two samples.
[[nodiscard]] LocalizationRunRecord run_record(const LocalizationRun& run,
                                               const std::string& vehicle_id);

/// The run's samples (initializing ones left out: they carry no map-based pose) binned
/// into tiles of zoom `z`, ordered by (x, y).
[[nodiscard]] std::vector<LocalizationRunCell> run_cells(const LocalizationRun& run,
                                                         int z = kRunCellZoom);

/// The run as a GeoJSON FeatureCollection of segments (one LineString from each sample to
/// the next) with the later sample's status, lateral σ and error, cumulative distance and
/// time; `properties` holds the record's id and summary.
[[nodiscard]] nlohmann::json run_geojson(const LocalizationRun& run,
                                         const LocalizationRunRecord& record);

/// Fleet quality cells (summed over runs) as GeoJSON polygons with samples, runs,
/// map_version (the newest the runs localized against), degraded_share, mean_sigma_lat_m,
/// lat_rmse_m (null without evaluated samples), max_abs_err_lat_m and `weak` by `thresholds`.
[[nodiscard]] nlohmann::json run_cells_geojson(std::span<const LocalizationRunCell> cells,
                                               const RunQualityThresholds& thresholds = {});

/// JSON of a record for the run list (summary included).
[[nodiscard]] nlohmann::json run_record_json(const LocalizationRunRecord& record);

}  // namespace polmap::mapping
