#pragma once
/// @file map_builder.hpp
/// Builds a map version from the drives in a MapStore: consensus over the
/// candidates of all included drives (consensus.hpp), landmarks (WGS84),
/// localization tiles (tiles/localization_tile.hpp) and fleet gridmap tiles
/// (fleet_gridmap.hpp), published atomically.
///
/// Usage:
///   SqliteMapStore store(db);
///   MapBuilder builder;                                  // MapBuilderConfig defaults
///   MapBuildResult r = builder.build(store, {});          // all drives, becomes current
///   // leave-one-out (paper §IV-B): a map without drive "d3", not made current
///   MapBuildRequest loo; loo.excluded_drive_ids = {"d3"}; loo.make_current = false;
///   builder.build(store, loo);
///   // HTTP server: answer 202 with the version, build on a worker thread
///   std::int64_t v = builder.begin(store, req);
///   std::thread([&, v, req] { builder.run(store, v, req, {&cancel_flag}); });
///
/// The build runs in a region frame: tiles::LocalFrame at the centre of the
/// region (or of the candidates' extent), which keeps scale errors below 2e-6
/// for regions up to ~10 km (larger areas are partitioned into regions, each
/// built in its own frame).
///
/// Support is judged against the drives that passed a place with it in view
/// (visibility.hpp, SupportRule in consensus.hpp): every included drive's stored
/// trajectory is a pass, its view range estimated from its own candidates.
///
/// Incremental builds (MapBuildRequest::incremental, the default). When the current
/// version was built with the same request from a subset of today's drives (versions
/// record their drive rows), only the area the new drives can influence is rebuilt:
/// their boxes grown by the largest view range and the consensus margin (consensus
/// is local — a landmark depends only on candidates within d_p (points) or the
/// projection threshold plus the segment length (lines) of it, and a pass changes
/// verdicts only within its view range). Candidates and passes are read for that
/// area only (memory and time follow the area, not the store); the current
/// version's landmarks outside it are copied (MapStore::copy_landmarks; copies share
/// the source's support links) and so are its tiles that hold none of the new or
/// replaced landmarks (MapStore::copy_tiles). Otherwise (drives removed, parameters
/// changed, most drives new, a region request) the build is full. Either way, each
/// re-encoded tile is encoded with the map_version stamp of the previous version's
/// tile first; identical bytes keep the previous blob (same ETag, so vehicle caches
/// stay valid). For this, landmark geometry is quantized to 1e-8 degrees (≈ 1.1 mm)
/// and landmark ids in tiles are stable keys (hash of the quantized geometry), so an
/// unchanged landmark encodes to identical bytes in every build.
///
/// Changes: each version records, against the version current when it started,
/// which landmarks were added, moved or retired and why (landmark_diff.hpp,
/// MapStore::landmark_changes); `GET /v1/maps/{v}/diff?from=U` serves them.
///
/// Thread safety: a MapBuilder is immutable; build/begin/run may run
/// concurrently with any store readers. Run at most one build per store at a
/// time (two concurrent builds are correct but race for "current").
#include <atomic>
#include <cstdint>
#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "polmap/mapping_service/consensus.hpp"
#include "polmap/mapping_service/drive_alignment.hpp"
#include "polmap/mapping_service/fleet_gridmap.hpp"
#include "polmap/mapping_service/landmark_diff.hpp"
#include "polmap/mapping_service/store.hpp"
#include "polmap/tiles/localization_tile.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace polmap::mapping {

/// How a partitioned build cuts the map (schema/build_jobs.md). Regions are the Web-Mercator
/// tiles of `zoom` that the included drives' paths come within `halo_m` of; each region is
/// one job: consensus in the region's own frame over the candidates and passes within
/// `halo_m` of it, keeping the point landmarks inside it and the line landmarks clipped to
/// it, and the localization tiles inside it. The same partition gives the same landmarks
/// and tile bytes however many processes run the jobs, in whatever order.
struct BuildPartition {
  /// Region zoom (14: 1.6 km squares at 48.8 deg N); at most the localization tile zoom.
  int zoom = 14;
  /// Candidates and passes this far outside a region take part in its consensus. Must
  /// cover the consensus margin (landmark groups reaching over the border come out the
  /// same on both sides) and the view range (every pass that saw the region).
  double halo_m = 120.0;
  /// Pieces of a clipped line landmark shorter than this are dropped (corner cuts).
  double min_line_piece_m = 0.5;
};

/// What to build. Recorded in the version's parameters JSON.
struct MapBuildRequest {
  /// Restrict the map to a region (landmarks inside; candidates within a
  /// margin around it take part in the consensus). nullopt = all drives.
  std::optional<tiles::GeoBox> region;
  /// Manifest drive ids left out (leave-one-out evaluation, bad drives).
  std::vector<std::string> excluded_drive_ids;
  std::string notes;
  /// Move the current pointer to the new version when it is published.
  bool make_current = true;
  /// Reuse byte-identical tiles of the current version (see file comment).
  bool incremental = true;
  /// Build the fleet gridmap layer (reads every included drive's gridmap.tif).
  bool build_gridmap = true;
  PointConsensusConfig points;
  LineConsensusConfig lines;
  /// Which drives had a place in view (support is judged against them).
  VisibilityConfig visibility;
  /// Build as jobs by region (build workers, build_worker.hpp); nullopt: one process, one
  /// frame (incremental when only drives were added, see the file comment).
  std::optional<BuildPartition> partition;
};

/// Build controls that are not part of the map's description.
struct BuildControl {
  /// Checked between stages and tile batches; when set the build fails with
  /// error "cancelled" and status Cancelled.
  const std::atomic<bool>* cancel = nullptr;
  /// Progress: stage name ("load", "consensus", "landmarks", "tiles",
  /// "gridmap", "publish") and fraction of the whole build in [0, 1].
  std::function<void(std::string_view stage, double fraction)> progress;
  /// Partitioned builds: this process works on the version's jobs (with any build workers
  /// that join); false: it only enqueues them and waits until workers have published the
  /// version (or it failed).
  bool run_jobs = true;
  /// Partitioned builds: how often the store is polled while the last jobs run elsewhere.
  double poll_interval_s = 0.2;
};

/// Builder settings. Defaults are what `polmap build-map` and the server use.
struct MapBuilderConfig {
  /// Zoom of the localization tiles.
  int tile_zoom = tiles::kLocalizationZoom;
  tiles::TileEncodeOptions encode;
  FleetGridmapConfig gridmap;
  /// Landmarks (and tiles) are written in batches of this many items, one
  /// transaction each (bounded memory in the store; cancellation points).
  std::size_t write_batch = 5000;
  /// Line landmarks are assigned to every tile they cross, found by sampling
  /// the polyline this densely.
  double line_tile_sample_m = 1.0;
  /// How changes against the current version are found (recorded per version).
  LandmarkDiffConfig diff;
  /// Drives with consumer-grade GNSS (manifest "positioning": median reported accuracy of
  /// at least alignment.consumer_grade_std_m) are aligned to each other and to the
  /// survey-grade drives before consensus (drive_alignment.hpp); false: never.
  bool align_drives = true;
  DriveAlignmentConfig alignment;
  /// An aligned drive's gridmap is added to the merged gridmap sums where its alignment puts
  /// it (drive_placement.hpp); when a later build moves it by more than this anywhere
  /// (half a cell of the 0.1 m sum grid), it is taken out and added again.
  double gridmap_replace_threshold_m = 0.05;
};

/// Figures of one build (also stored as the version's statistics JSON).
struct MapBuildStats {
  std::int64_t drives_used = 0;     ///< drives with candidates in the region
  std::int64_t drives_passing = 0;  ///< drives with a trajectory through the region
  std::int64_t point_candidates = 0;
  std::int64_t line_candidates = 0;
  std::int64_t point_landmarks = 0;
  std::int64_t line_landmarks = 0;
  /// Point landmarks removed by filter_point_landmarks (point_filter.hpp).
  std::int64_t point_line_peaks = 0;
  std::int64_t point_surface_peaks = 0;
  std::int64_t point_temporary = 0;
  std::int64_t point_sliding = 0;
  std::int64_t point_out_of_view = 0;
  std::int64_t point_mirror_ghosts = 0;  ///< point landmarks removed as mirror images
  /// Line landmarks removed by filter_line_landmarks (line_filter.hpp).
  std::int64_t line_overhead = 0;
  std::int64_t line_range_streaks = 0;
  std::int64_t line_out_of_view = 0;
  std::int64_t tiles_total = 0;     ///< localization tiles of the new version
  std::int64_t tiles_written = 0;   ///< newly encoded (content changed or new)
  std::int64_t tiles_reused = 0;    ///< byte-identical to the previous version's tile
  std::int64_t tiles_removed = 0;   ///< tiles of the previous version now empty
  std::int64_t tile_bytes = 0;      ///< total payload bytes of the version's tiles
  std::int64_t gridmap_tiles = 0;   ///< amplitude raster tiles of the new version
  std::int64_t gridmap_drives = 0;  ///< drives whose gridmap is in the merged sums
  /// Merged gridmap upkeep: drives added to / taken out of / re-placed in the sums (their
  /// alignment moved), sum tiles rewritten, min-zoom regions rendered and raster tiles
  /// copied unchanged from the previous version.
  std::int64_t gridmap_drives_added = 0;
  std::int64_t gridmap_drives_removed = 0;
  std::int64_t gridmap_drives_replaced = 0;
  std::int64_t gridmap_sum_tiles_written = 0;
  std::int64_t gridmap_regions_rendered = 0;
  std::int64_t gridmap_tiles_copied = 0;
  std::optional<std::int64_t> previous_version;
  /// Incremental build: the version whose landmarks outside the rebuilt area were copied.
  std::optional<std::int64_t> incremental_from;
  std::int64_t landmarks_copied = 0;
  /// Landmark changes recorded against the version current when the build started.
  std::optional<std::int64_t> changes_against;
  std::int64_t landmarks_added = 0;
  std::int64_t landmarks_moved = 0;
  std::int64_t landmarks_retired = 0;
  PointConsensusResult::Stats point_consensus;
  LineConsensusResult::Stats line_consensus;
  /// Drive alignment: "off", "not_needed", "aligned" or "no_overlap" (drive_alignment.hpp).
  std::string alignment_status = "off";
  std::int64_t aligned_drives = 0;           ///< consumer-grade drives aligned
  std::int64_t alignment_anchor_drives = 0;  ///< survey-grade drives among those loaded
  std::int64_t alignment_clusters = 0;
  double alignment_residual_rms_m = 0.0;
  double alignment_mean_correction_m = 0.0;
  std::int64_t alignment_odometry_drives = 0;  ///< of those, constrained by odometry
  /// DriveAlignmentResult::odometry_steps_rejected, scale_error_mean, scale_error_rms,
  /// gyro_bias_mean_rps and gyro_bias_rms_rps.
  std::int64_t alignment_odometry_steps_rejected = 0;
  double alignment_scale_error_mean = 0.0;
  double alignment_scale_error_rms = 0.0;
  double alignment_gyro_bias_mean_rps = 0.0;
  double alignment_gyro_bias_rms_rps = 0.0;
  double seconds_alignment = 0.0;
  double seconds_load = 0.0;
  double seconds_consensus = 0.0;
  double seconds_landmarks = 0.0;  ///< geodetic conversion and writing landmarks
  double seconds_tiles = 0.0;
  double seconds_gridmap = 0.0;
  double seconds_total = 0.0;
};
nlohmann::json to_json(const MapBuildStats& s);

struct MapBuildResult {
  enum class Status { Published, Failed, Cancelled };
  Status status = Status::Failed;
  std::int64_t version = 0;
  std::string error;  ///< empty when published
  MapBuildStats stats;
};
std::string_view to_string(MapBuildResult::Status s);

class MapBuilder {
 public:
  explicit MapBuilder(MapBuilderConfig cfg = {});

  /// Creates the Building version (validates the request: excluded drives
  /// must exist -> NotFoundError) and returns its number.
  std::int64_t begin(MapStore& store, const MapBuildRequest& request) const;
  /// Builds into `version` (from begin) and publishes it, or marks it failed.
  /// Never throws for build failures: they come back as status + error.
  MapBuildResult run(MapStore& store, std::int64_t version, const MapBuildRequest& request,
                     const BuildControl& control = {}) const;
  /// begin + run.
  MapBuildResult build(MapStore& store, const MapBuildRequest& request,
                       const BuildControl& control = {}) const;

  [[nodiscard]] const MapBuilderConfig& config() const { return cfg_; }

 private:
  MapBuilderConfig cfg_;
};

/// Stable key of a landmark: 63-bit hash of its kind and its vertices'
/// coordinates quantized to 1e-8 degrees (the builder quantizes geometry to
/// the same grid first). Equal geometry -> equal key in every build.
std::int64_t landmark_key(bool is_line, std::span<const GeoPoint> vertices);

/// Rounds a coordinate to the builder's 1e-8 degree grid.
double quantize_deg(double deg);

}  // namespace polmap::mapping
