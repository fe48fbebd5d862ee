#pragma once
// The steps of a map build (private to polmap_build), shared by the one-process build
// (map_builder.cpp) and the jobs of a partitioned build (partitioned_build.cpp), so both
// compute landmarks, changes and tiles the same way. Definitions in map_builder.cpp.
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <unordered_map>
#include <vector>

#include "gridmap_build.hpp"
#include "polmap/mapping_service/map_builder.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::mapping {

// The point and line filters' rules in a version's parameters (request_json writes them,
// request_from_json reads them back for build workers): one key per field, a missing key
// keeps the default.
NLOHMANN_DEFINE_TYPE_NON_INTRUSIVE_WITH_DEFAULT(LinePeakRule, enabled, max_line_distance_m,
                                                min_along_across_ratio, min_along_spread_m)
NLOHMANN_DEFINE_TYPE_NON_INTRUSIVE_WITH_DEFAULT(SurfacePeakRule, enabled, max_line_distance_m,
                                                min_vertex_distance_m, min_detection_share)
NLOHMANN_DEFINE_TYPE_NON_INTRUSIVE_WITH_DEFAULT(CoPresenceRule, enabled, neighbour_radius_m,
                                                max_p_value, min_phi, min_passes_for_test,
                                                min_shared_misses, max_detection_share)
NLOHMANN_DEFINE_TYPE_NON_INTRUSIVE_WITH_DEFAULT(SlidingRule, enabled, min_support_drives,
                                                min_along_spread_m, min_along_across_ratio,
                                                max_detection_share)
NLOHMANN_DEFINE_TYPE_NON_INTRUSIVE_WITH_DEFAULT(OutOfViewRule, enabled, min_view_fraction)
NLOHMANN_DEFINE_TYPE_NON_INTRUSIVE_WITH_DEFAULT(MirrorGhostRule, enabled, max_reflector_distance_m,
                                                segment_margin_m, min_image_offset_m,
                                                image_radius_m, min_image_drives,
                                                min_image_support_share)
NLOHMANN_DEFINE_TYPE_NON_INTRUSIVE_WITH_DEFAULT(OverheadRule, enabled, min_crossing_share,
                                                min_crossing_drives)
NLOHMANN_DEFINE_TYPE_NON_INTRUSIVE_WITH_DEFAULT(RangeStreakRule, enabled, max_length_m,
                                                max_line_of_sight_angle_rad, reflector_margin_m,
                                                min_overhang_m, min_detection_share)
NLOHMANN_DEFINE_TYPE_NON_INTRUSIVE_WITH_DEFAULT(OutOfViewLineRule, enabled, min_view_fraction)

}  // namespace polmap::mapping

namespace polmap::mapping::detail {

/// `b` grown by margin_m on every side (metres, at its mid latitude).
tiles::GeoBox grow_box(const tiles::GeoBox& b, double margin_m);
tiles::GeoBox union_box(const tiles::GeoBox& a, const tiles::GeoBox& b);
tiles::GeoBox polyline_box(const std::vector<GeoPoint>& pl);
/// The version parameters of a request (what MapStore::begin_map_version records).
nlohmann::json request_json(const MapBuildRequest& r, const MapBuilderConfig& c);
/// The drive rows a build uses (all drives but the excluded ones), ascending.
std::vector<std::int64_t> drive_rows(const std::vector<DriveRecord>& drives,
                                     const std::vector<std::string>& excluded);
/// How far outside a build region candidates still change its landmarks (twice the
/// largest consensus association distance).
double consensus_margin_m(const MapBuildRequest& req);
/// Incremental build plan: when the current version was built with the same request
/// (whole store, same exclusions and parameters) from a subset of today's drives, only
/// the area the new drives can influence is rebuilt: their boxes, grown by the largest
/// view range (their passes change verdicts that far) and the consensus margin.
/// nullopt: a full build (drives were removed, parameters changed, or the new drives
/// touch most of the map). request_params: the version parameters (request_json).
struct IncrementalPlan {
  tiles::GeoBox area;                ///< rebuilt; the rest is copied
  std::int64_t previous_points = 0;  ///< landmark counts of the current version
  std::int64_t previous_lines = 0;
};
std::optional<IncrementalPlan> incremental_plan(const MapStore& store, const MapBuildRequest& req,
                                                const nlohmann::json& request_params,
                                                std::int64_t current,
                                                const std::vector<DriveRecord>& drives,
                                                double margin_m);
std::vector<TaggedPointCandidate> tagged_points(const CandidateSet& cands,
                                                const tiles::LocalFrame& frame);
std::vector<TaggedLineCandidate> tagged_lines(const CandidateSet& cands,
                                              const tiles::LocalFrame& frame);
/// Corrections of aligned consumer-grade drives by drive row (none: the drive as stored).
using DriveCorrections = std::unordered_map<std::int64_t, DriveCorrection>;
/// Aligns the consumer-grade drives the build loads and corrects their candidates in
/// place (cfg.align_drives; statistics into st).
DriveCorrections align_candidates(const MapStore& store, const std::optional<GeoBox>& query,
                                  const std::vector<std::string>& excluded,
                                  std::vector<TaggedPointCandidate>& tp,
                                  std::vector<TaggedLineCandidate>& tl,
                                  const tiles::LocalFrame& frame, const MapBuilderConfig& cfg,
                                  MapBuildStats& st);
/// The passes of the included drives whose box meets `query`, in the build frame, their
/// paths corrected like their candidates.
std::vector<DrivePass> drive_passes(const MapStore& store, const std::optional<GeoBox>& query,
                                    const std::vector<std::string>& excluded,
                                    const std::vector<TaggedPointCandidate>& tp,
                                    const std::vector<TaggedLineCandidate>& tl,
                                    const tiles::LocalFrame& frame, const VisibilityConfig& vcfg,
                                    const DriveCorrections& corrections = {});
/// The frame position as a geodetic point quantized to 1e-8 degrees (stable keys).
GeoPoint to_geo_quantized(const tiles::LocalFrame& frame, const Eigen::Vector2d& xy);
/// Consensus landmarks as stored rows (region filter as MapStore::landmarks_in), with the
/// verdict of each row by its key.
std::vector<StoredPointLandmark> stored_points(
    const PointConsensusResult& pc, const tiles::LocalFrame& frame,
    const std::optional<tiles::GeoBox>& region,
    std::unordered_map<std::int64_t, SupportVerdict>& verdicts);
std::vector<StoredLineLandmark> stored_lines(
    const LineConsensusResult& lc, const tiles::LocalFrame& frame,
    const std::optional<tiles::GeoBox>& region,
    std::unordered_map<std::int64_t, SupportVerdict>& verdicts);
/// The changes against the previous version's landmarks, each with its reason.
std::vector<LandmarkChange> changes_with_reasons(
    const LandmarkSet& previous, const std::vector<StoredPointLandmark>& points,
    const std::vector<StoredLineLandmark>& lines,
    const std::unordered_map<std::int64_t, SupportVerdict>& verdicts,
    const PointConsensusResult& pc, const LineConsensusResult& lc, const tiles::LocalFrame& frame,
    const LandmarkDiffConfig& dcfg);
/// The landmarks cut into localization tiles of zoom z.
std::map<tiles::TileKey, tiles::LocalizationTile> localization_tile_content(
    const std::vector<StoredPointLandmark>& points, const std::vector<StoredLineLandmark>& lines,
    const tiles::LocalFrame& frame, int z, double line_sample_m);
/// The merged gridmap stage (sums in step with the drives, raster tiles); returns the
/// version statistics' "gridmap" object and fills st's gridmap fields.
nlohmann::json build_gridmap(MapStore& store, std::int64_t version, const MapBuildRequest& req,
                             const MapBuilderConfig& cfg,
                             const std::vector<DriveRecord>& all_drives,
                             const std::optional<std::int64_t>& current, MapBuildStats& st,
                             const std::function<void()>& tick,
                             const GridmapPlacements& placements = {});

/// The request a version's parameters describe (inverse of request_json; fields it does
/// not record keep their defaults). ValidationError names a malformed field.
MapBuildRequest request_from_json(const nlohmann::json& parameters);
/// Partitioned build of `version` (request.partition set): plans and enqueues its jobs,
/// then works on them here (control.run_jobs) or waits for build workers.
MapBuildResult run_partitioned(MapStore& store, std::int64_t version, const MapBuildRequest& req,
                               const MapBuilderConfig& cfg, const BuildControl& control);

}  // namespace polmap::mapping::detail
