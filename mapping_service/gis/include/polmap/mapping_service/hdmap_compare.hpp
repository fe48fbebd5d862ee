#pragma once
/// @file hdmap_compare.hpp
/// Comparison of a radar landmark map with an HD map (Lanelet2 OSM): how many radar
/// point landmarks sit at HD-map point features (signs, lights, poles), how far off,
/// and how well radar line landmarks follow HD-map linear features (curbs, road
/// borders, walls, fences, guard rails).
///
/// Metrics (all in one local metric frame, see compare_with_hdmap):
///  * Points: one-to-one matching of map points to HD points within
///    `point_match_radius_m` (default 1.0 m), greedy by ascending distance over all
///    pairs (equal to the optimal assignment unless two features of one map compete
///    for the same partner within 2 radii — rare for signs/poles, which stand metres
///    apart). precision = matched / map points, recall = matched / HD points,
///    median offset = median distance of matched pairs.
///  * Lines: map lines are sampled every `line_sample_step_m` (vertices plus
///    intermediate samples); each sample's lateral offset is its distance to the nearest
///    HD line segment of a linear type. Samples within `line_band_m` (default 1.0 m)
///    count as on an HD line; median lateral offset = median over those (samples
///    farther away are radar lines with no HD counterpart, e.g. building walls absent
///    from the HD map, and are reported as unmatched, not averaged in).
///    Coverage: HD lines are cut into pieces of <= `line_sample_step_m`; a piece is
///    covered if its midpoint lies within `line_band_m` of a map line;
///    covered length / total HD line length = line_coverage.
///  * Evaluation area: with restrict_to_overlap (default), only features inside the
///    overlap of both maps' bounding boxes (each grown by `overlap_margin_m`) count, so
///    HD-map areas never driven do not lower recall and radar landmarks beyond the HD
///    map do not lower precision.
/// Ratios with an empty denominator and medians of empty sets are std::nullopt; point
/// precision also when the HD map has no point features in the area (it cannot judge
/// radar points then, e.g. maps without signs or poles).
#include <Eigen/Core>
#include <cstdint>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "polmap/mapping_service/store.hpp"
#include "polmap/schema/geo.hpp"

namespace polmap::mapping {

/// A point feature of an HD map (line-string-shaped signs and lights: the centroid of
/// their vertices).
struct HdMapPoint {
  std::int64_t id = 0;  ///< OSM way or node id
  std::string type;     ///< e.g. "traffic_sign"
  std::string subtype;
  GeoPoint position;
};

/// A linear feature of an HD map.
struct HdMapLine {
  std::int64_t id = 0;  ///< OSM way id
  std::string type;     ///< canonical type, e.g. "curbstone"
  std::string subtype;
  std::vector<GeoPoint> polyline;
};

struct HdMap {
  std::vector<HdMapPoint> points;
  std::vector<HdMapLine> lines;
  std::size_t num_nodes = 0;  ///< in the file
  std::size_t num_ways = 0;
};

/// Which Lanelet2 `type` tags become points and lines. Defaults: what a radar sees.
struct HdMapReadOptions {
  std::vector<std::string> point_types{"traffic_sign", "traffic_light", "pole"};
  std::vector<std::string> line_types{"curbstone", "road_border", "wall", "fence", "guard_rail"};
  /// Spellings found in published maps, mapped to the canonical type.
  std::vector<std::pair<std::string, std::string>> type_aliases{{"curbestone", "curbstone"},
                                                                {"guardrail", "guard_rail"}};
};

/// Reads a Lanelet2 OSM file (XML: nodes with lat/lon, ways with nd refs and type/subtype
/// tags). Ways referencing unknown nodes are skipped. Throws IoError if unreadable,
/// FormatError (naming the file and element) for malformed XML or coordinates.
[[nodiscard]] HdMap read_lanelet2_osm(const std::filesystem::path& path,
                                      const HdMapReadOptions& options = {});

struct HdMapCompareConfig {
  double point_match_radius_m = 1.0;
  double line_band_m = 1.0;
  double line_sample_step_m = 0.5;
  bool restrict_to_overlap = true;
  double overlap_margin_m = 10.0;
};

/// One matched point pair (indices into the inputs of compare_hdmap_metric).
struct HdPointMatch {
  std::size_t map_index = 0;
  std::size_t hd_index = 0;
  double distance_m = 0.0;
};

/// A position along a polyline: segment `segment` (vertices segment, segment + 1) at
/// fraction `t` in [0, 1] of its length.
struct HdLinePosition {
  std::size_t segment = 0;
  double t = 0.0;
};

/// A stretch of one input line with one verdict, from `begin` to `end` along it: for HD
/// lines, consecutive pieces that are covered (or not) by a map line; for map lines,
/// consecutive samples that lie on (or off) an HD line. Runs of a line follow each other
/// without gaps, so a line's runs drawn together redraw the line.
struct HdLineRun {
  std::size_t line = 0;  ///< index into the hd_lines or map_lines input
  HdLinePosition begin;
  HdLinePosition end;
  bool in_area = true;  ///< inside the evaluation area (outside: never matched)
  bool matched = false;
  double length_m = 0.0;
  std::size_t samples = 0;  ///< map lines: samples in the run (HD lines: pieces)
  /// Map lines: median lateral offset of the run's samples to the HD line (matched runs).
  std::optional<double> median_offset_m;
};

struct HdMapComparison {
  // Points (counts inside the evaluation area).
  std::size_t map_points = 0;
  std::size_t hd_points = 0;
  std::size_t matched_points = 0;
  std::optional<double> point_precision;
  std::optional<double> point_recall;
  std::optional<double> point_median_offset_m;
  std::vector<HdPointMatch> point_matches;
  // Lines.
  std::size_t map_line_samples = 0;
  std::size_t matched_line_samples = 0;  ///< within line_band_m of an HD line
  std::optional<double> line_median_lateral_offset_m;
  double line_covered_length_m = 0.0;
  double line_total_length_m = 0.0;
  std::optional<double> line_coverage;

  // Per feature, what the counts above are made of (indices as in the inputs), so a
  // caller can draw where the maps agree.
  std::vector<bool> map_point_in_area;   ///< one per map point
  std::vector<bool> hd_point_in_area;    ///< one per HD point
  std::vector<HdLineRun> map_line_runs;  ///< by line, then along it
  std::vector<HdLineRun> hd_line_runs;   ///< by line, then along it
};

/// The metric core: all inputs in one metric frame (metres).
[[nodiscard]] HdMapComparison compare_hdmap_metric(
    const std::vector<Eigen::Vector2d>& map_points,
    const std::vector<std::vector<Eigen::Vector2d>>& map_lines,
    const std::vector<Eigen::Vector2d>& hd_points,
    const std::vector<std::vector<Eigen::Vector2d>>& hd_lines, const HdMapCompareConfig& cfg = {});

/// Geodetic inputs: projects landmarks and HD features into the LocalFrame at the
/// centre of the HD map's bounding box, then compare_hdmap_metric.
[[nodiscard]] HdMapComparison compare_with_hdmap(const LandmarkSet& landmarks, const HdMap& hdmap,
                                                 const HdMapCompareConfig& cfg = {});

/// Bounding box of an HD map's features (points and line vertices).
[[nodiscard]] std::optional<GeoBox> hdmap_bounds(const HdMap& hdmap);

/// The comparison as a GeoJSON FeatureCollection (WGS84, longitude first) for display:
/// one Point feature per HD point and per map point landmark, one LineString per run of
/// HD lines and map lines (comparison.hd_line_runs / map_line_runs). Properties: `role`
/// ("hd" | "map"), `type` (the HD type, or "point_landmark" / "line_landmark"),
/// `matched`, `in_area`, `judged` (false when the other map has no features of that kind in
/// the area, e.g. radar points against an HD map without signs or poles: neither matched
/// nor unmatched); HD features `hd_id`, `subtype`; landmarks `key` (decimal string:
/// keys use 63 bits, more than a JavaScript number holds), `class`, `support_drives`;
/// matched points `distance_m` and the partner (`landmark_key` or `hd_id`); runs
/// `length_m`, HD line runs `line_coverage` (the covered share of their whole HD line),
/// map line runs `median_offset_m`. `landmarks` and `hdmap` must be the inputs the
/// comparison was computed from (ContractViolation otherwise). `properties.summary` is
/// to_json(comparison). Pure: no I/O.
[[nodiscard]] nlohmann::json hdmap_comparison_geojson(const LandmarkSet& landmarks,
                                                      const HdMap& hdmap,
                                                      const HdMapComparison& comparison);

/// JSON with keys point_precision, point_recall, point_median_offset_m,
/// line_median_lateral_offset_m, line_covered_length_m, line_total_length_m,
/// line_coverage (null when undefined), plus the counts.
[[nodiscard]] nlohmann::json to_json(const HdMapComparison& c);

}  // namespace polmap::mapping
