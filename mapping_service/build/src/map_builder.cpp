// MapBuilder: store -> consensus -> landmarks, localization tiles, fleet
// gridmap tiles -> atomic publish (see map_builder.hpp).
#include "polmap/mapping_service/map_builder.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <fstream>
#include <iterator>
#include <map>
#include <set>
#include <unordered_map>

#include "build_steps.hpp"
#include "gridmap_build.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/landmark_diff.hpp"
#include "polmap/schema/json.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::mapping {
namespace detail {

struct Cancelled {};

class Clock {
 public:
  double lap() {
    const auto now = std::chrono::steady_clock::now();
    const double s = std::chrono::duration<double>(now - last_).count();
    last_ = now;
    return s;
  }
  [[nodiscard]] double total() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now();
  std::chrono::steady_clock::time_point last_ = start_;
};

constexpr double kMetresPerDegLat = 111320.0;

tiles::GeoBox grow_box(const tiles::GeoBox& b, double margin_m) {
  const double mid_lat = 0.5 * (b.min_lat_deg + b.max_lat_deg);
  const double dlat = margin_m / kMetresPerDegLat;
  const double dlon =
      margin_m / (kMetresPerDegLat * std::max(0.01, std::cos(mid_lat * M_PI / 180)));
  return {std::max(-90.0, b.min_lat_deg - dlat), b.min_lon_deg - dlon,
          std::min(90.0, b.max_lat_deg + dlat), b.max_lon_deg + dlon};
}

nlohmann::json box_json(const tiles::GeoBox& b) {
  return {{"min_lat_deg", b.min_lat_deg},
          {"min_lon_deg", b.min_lon_deg},
          {"max_lat_deg", b.max_lat_deg},
          {"max_lon_deg", b.max_lon_deg}};
}

nlohmann::json support_json(const SupportRule& s) {
  return {{"min_drives", s.min_drives},
          {"min_view_fraction", s.min_view_fraction},
          {"recent_passes", s.recent_passes},
          {"retire_min_misses", s.retire_min_misses},
          {"retire_min_vehicles", s.retire_min_vehicles}};
}

nlohmann::json request_json(const MapBuildRequest& r, const MapBuilderConfig& c) {
  nlohmann::json j;
  j["region"] = r.region ? box_json(*r.region) : nlohmann::json();
  j["excluded_drive_ids"] = r.excluded_drive_ids;
  j["notes"] = r.notes;
  j["make_current"] = r.make_current;
  j["incremental"] = r.incremental;
  j["build_gridmap"] = r.build_gridmap;
  const PointFilterConfig& f = r.points.filter;
  j["points"] = {{"max_pair_distance_m", r.points.max_pair_distance_m},
                 {"support", support_json(r.points.support)},
                 {"line_peaks", f.line_peaks},
                 {"surface_peaks", f.surface_peaks},
                 {"co_presence", f.co_presence},
                 {"sliding", f.sliding},
                 {"out_of_view", f.out_of_view},
                 {"mirror_ghosts", f.mirror_ghosts}};
  j["lines"] = {{"max_hull_distance_m", r.lines.max_hull_distance_m},
                {"max_projection_distance_m", r.lines.max_projection_distance_m},
                {"support", support_json(r.lines.support)},
                {"polyline_max_error_m", r.lines.polyline_max_error_m},
                {"snap_max_gap_m", r.lines.snap_max_gap_m},
                {"overhead", r.lines.filter.overhead},
                {"range_streaks", r.lines.filter.range_streaks},
                {"out_of_view", r.lines.filter.out_of_view}};
  j["visibility"] = {{"default_view_range_m", r.visibility.default_view_range_m},
                     {"min_view_range_m", r.visibility.min_view_range_m},
                     {"max_view_range_m", r.visibility.max_view_range_m},
                     {"range_quantile", r.visibility.range_quantile},
                     {"range_margin", r.visibility.range_margin}};
  if (r.partition) {  // absent otherwise: versions from before partitions compare equal
    j["partition"] = {{"zoom", r.partition->zoom},
                      {"halo_m", r.partition->halo_m},
                      {"min_line_piece_m", r.partition->min_line_piece_m}};
  }
  j["tile_zoom"] = c.tile_zoom;
  j["tile_quantum_m"] = c.encode.quantum_m;
  return j;
}

/// Tiles a geodetic polyline crosses, sampled every step_m along each edge.
std::set<tiles::TileKey> tiles_of_polyline(const std::vector<GeoPoint>& pl,
                                           const std::vector<Eigen::Vector2d>& pl_m, int z,
                                           double step_m) {
  std::set<tiles::TileKey> out;
  for (std::size_t i = 0; i + 1 < pl.size(); ++i) {
    const double len = (pl_m[i + 1] - pl_m[i]).norm();
    const int n = std::max(1, static_cast<int>(std::ceil(len / step_m)));
    for (int k = 0; k <= n; ++k) {
      const double t = static_cast<double>(k) / n;
      out.insert(tiles::tile_at(pl[i].lat_deg + t * (pl[i + 1].lat_deg - pl[i].lat_deg),
                                pl[i].lon_deg + t * (pl[i + 1].lon_deg - pl[i].lon_deg), z));
    }
  }
  return out;
}

}  // namespace detail
using namespace detail;  // NOLINT: this target's own build steps

double quantize_deg(double deg) { return std::round(deg * 1e8) / 1e8; }

std::int64_t landmark_key(bool is_line, std::span<const GeoPoint> vertices) {
  std::uint64_t h = 1469598103934665603ULL;  // FNV-1a 64
  auto mix = [&](std::uint64_t v) {
    for (int b = 0; b < 8; ++b) {
      h ^= (v >> (8 * b)) & 0xffU;
      h *= 1099511628211ULL;
    }
  };
  mix(is_line ? 1 : 0);
  for (const auto& g : vertices) {
    mix(static_cast<std::uint64_t>(std::llround(g.lat_deg * 1e8)));
    mix(static_cast<std::uint64_t>(std::llround(g.lon_deg * 1e8)));
  }
  // Final avalanche (splitmix64) and 63 bits: positive in SQLite, JSON and tiles.
  h ^= h >> 30;
  h *= 0xbf58476d1ce4e5b9ULL;
  h ^= h >> 27;
  h *= 0x94d049bb133111ebULL;
  h ^= h >> 31;
  return static_cast<std::int64_t>(h & 0x7fffffffffffffffULL);
}

std::string_view to_string(MapBuildResult::Status s) {
  switch (s) {
    case MapBuildResult::Status::Published:
      return "published";
    case MapBuildResult::Status::Cancelled:
      return "cancelled";
    default:
      return "failed";
  }
}

nlohmann::json to_json(const MapBuildStats& s) {
  nlohmann::json j;
  j["drives_used"] = s.drives_used;
  j["drives_passing"] = s.drives_passing;
  j["point_candidates"] = s.point_candidates;
  j["line_candidates"] = s.line_candidates;
  j["point_landmarks"] = s.point_landmarks;
  j["line_landmarks"] = s.line_landmarks;
  j["point_line_peaks"] = s.point_line_peaks;
  j["point_surface_peaks"] = s.point_surface_peaks;
  j["point_temporary"] = s.point_temporary;
  j["point_sliding"] = s.point_sliding;
  j["point_out_of_view"] = s.point_out_of_view;
  j["point_mirror_ghosts"] = s.point_mirror_ghosts;
  j["line_overhead"] = s.line_overhead;
  j["line_range_streaks"] = s.line_range_streaks;
  j["line_out_of_view"] = s.line_out_of_view;
  j["tiles_total"] = s.tiles_total;
  j["tiles_written"] = s.tiles_written;
  j["tiles_reused"] = s.tiles_reused;
  j["tiles_removed"] = s.tiles_removed;
  j["tile_bytes"] = s.tile_bytes;
  j["gridmap_tiles"] = s.gridmap_tiles;
  j["gridmap_drives"] = s.gridmap_drives;
  j["gridmap_sums"] = {{"drives_added", s.gridmap_drives_added},
                       {"drives_removed", s.gridmap_drives_removed},
                       {"drives_replaced", s.gridmap_drives_replaced},
                       {"sum_tiles_written", s.gridmap_sum_tiles_written},
                       {"regions_rendered", s.gridmap_regions_rendered},
                       {"tiles_copied", s.gridmap_tiles_copied}};
  j["previous_version"] =
      s.previous_version ? nlohmann::json(*s.previous_version) : nlohmann::json();
  j["incremental_from"] =
      s.incremental_from ? nlohmann::json(*s.incremental_from) : nlohmann::json();
  j["landmarks_copied"] = s.landmarks_copied;
  j["changes"] = {{"against_version",
                   s.changes_against ? nlohmann::json(*s.changes_against) : nlohmann::json()},
                  {"added", s.landmarks_added},
                  {"moved", s.landmarks_moved},
                  {"retired", s.landmarks_retired}};
  j["point_consensus"] = {{"candidates", s.point_consensus.candidates},
                          {"pairs", s.point_consensus.pairs},
                          {"groups", s.point_consensus.groups},
                          {"rejected_groups", s.point_consensus.rejected_groups},
                          {"retired_groups", s.point_consensus.retired_groups},
                          {"split_groups", s.point_consensus.split_groups},
                          {"largest_group", s.point_consensus.largest_group}};
  j["line_consensus"] = {{"candidates", s.line_consensus.candidates},
                         {"pairs", s.line_consensus.pairs},
                         {"groups", s.line_consensus.groups},
                         {"rejected_groups", s.line_consensus.rejected_groups},
                         {"retired_groups", s.line_consensus.retired_groups},
                         {"polylines", s.line_consensus.polylines},
                         {"snapped_ends", s.line_consensus.snapped_ends}};
  j["alignment"] = {{"status", s.alignment_status},
                    {"aligned_drives", s.aligned_drives},
                    {"anchor_drives", s.alignment_anchor_drives},
                    {"clusters", s.alignment_clusters},
                    {"residual_rms_m", s.alignment_residual_rms_m},
                    {"mean_correction_m", s.alignment_mean_correction_m},
                    {"odometry_drives", s.alignment_odometry_drives},
                    {"odometry_steps_rejected", s.alignment_odometry_steps_rejected},
                    {"scale_error_mean", s.alignment_scale_error_mean},
                    {"scale_error_rms", s.alignment_scale_error_rms},
                    {"gyro_bias_mean_rps", s.alignment_gyro_bias_mean_rps},
                    {"gyro_bias_rms_rps", s.alignment_gyro_bias_rms_rps},
                    {"seconds", s.seconds_alignment}};
  j["seconds"] = {{"load", s.seconds_load},           {"consensus", s.seconds_consensus},
                  {"landmarks", s.seconds_landmarks}, {"tiles", s.seconds_tiles},
                  {"gridmap", s.seconds_gridmap},     {"total", s.seconds_total}};
  return j;
}

namespace detail {

/// Centre of the build's frame: the region's centre, or that of the candidates' extent.
GeoPoint region_centre(const std::optional<tiles::GeoBox>& region, const CandidateSet& cands) {
  if (region) {
    return {0.5 * (region->min_lat_deg + region->max_lat_deg),
            0.5 * (region->min_lon_deg + region->max_lon_deg), 0.0};
  }
  if (cands.points.empty() && cands.lines.empty()) return {};
  double la0 = 90, la1 = -90, lo0 = 180, lo1 = -180;
  auto grow = [&](const GeoPoint& g) {
    la0 = std::min(la0, g.lat_deg);
    la1 = std::max(la1, g.lat_deg);
    lo0 = std::min(lo0, g.lon_deg);
    lo1 = std::max(lo1, g.lon_deg);
  };
  for (const auto& p : cands.points) grow(p.position);
  for (const auto& l : cands.lines) grow(l.start), grow(l.end);
  return {0.5 * (la0 + la1), 0.5 * (lo0 + lo1), 0.0};
}

std::vector<TaggedPointCandidate> tagged_points(const CandidateSet& cands,
                                                const tiles::LocalFrame& frame) {
  std::vector<TaggedPointCandidate> tp;
  tp.reserve(cands.points.size());
  for (const auto& p : cands.points) {
    TaggedPointCandidate t;
    t.candidate_id = p.id;
    t.drive = p.drive;
    t.candidate = p.candidate;
    t.candidate.position_m = frame.to_local(p.position);
    tp.push_back(t);
  }
  return tp;
}

std::vector<TaggedLineCandidate> tagged_lines(const CandidateSet& cands,
                                              const tiles::LocalFrame& frame) {
  std::vector<TaggedLineCandidate> tl;
  tl.reserve(cands.lines.size());
  for (const auto& l : cands.lines) {
    TaggedLineCandidate t;
    t.candidate_id = l.id;
    t.drive = l.drive;
    t.candidate = l.candidate;
    t.candidate.start_m = frame.to_local(l.start);
    t.candidate.end_m = frame.to_local(l.end);
    tl.push_back(t);
  }
  return tl;
}

double positioning_std_m(const DriveRecord& d, const char* key, double fallback) {
  const auto it = d.manifest.find("positioning");
  if (it == d.manifest.end() || !it->is_object()) return fallback;
  const auto v = it->find(key);
  return v != it->end() && v->is_number() ? v->get<double>() : fallback;
}

/// Aligns the consumer-grade drives among those the build loads (drive_alignment.hpp) in
/// the build frame and corrects their candidates in place. Survey-grade fleets cost one
/// look at each drive's record: trajectories are read only when a consumer drive is there.
/// Drives stored before the store kept "positioning" count as survey-grade (they are).
DriveCorrections align_candidates(const MapStore& store, const std::optional<GeoBox>& query,
                                  const std::vector<std::string>& excluded,
                                  std::vector<TaggedPointCandidate>& tp,
                                  std::vector<TaggedLineCandidate>& tl,
                                  const tiles::LocalFrame& frame, const MapBuilderConfig& cfg,
                                  MapBuildStats& st) {
  DriveCorrections out;
  if (!cfg.align_drives) return out;
  const auto t0 = std::chrono::steady_clock::now();
  const std::set<std::string> skip(excluded.begin(), excluded.end());
  std::vector<DriveRecord> drives;
  bool any_consumer = false;
  for (DriveRecord& d : query ? store.drives_in(*query) : store.list_drives()) {
    if (skip.contains(d.drive_id)) continue;
    any_consumer = any_consumer ||
                   positioning_std_m(d, "median_std_m", 0.0) >= cfg.alignment.consumer_grade_std_m;
    drives.push_back(std::move(d));
  }
  st.alignment_status = "not_needed";
  if (!any_consumer) return out;
  std::unordered_map<std::int64_t, std::size_t> index;
  std::vector<AlignmentDrive> in;
  for (const DriveRecord& d : drives) {
    AlignmentDrive a;
    a.drive = d.row;
    const double sd = positioning_std_m(d, "median_std_m", 0.014);
    const double sy = positioning_std_m(d, "median_std_yaw_rad", 0.001);
    for (const TrajectorySample& s : store.drive_trajectory(d.drive_id)) {
      AlignmentSample smp;
      smp.time_s = s.time_s;
      smp.position_m = frame.to_local(GeoPoint{s.lat_deg, s.lon_deg, 0.0});
      smp.std_m = sd;
      smp.std_yaw_rad = sy;
      // Heading in the build frame: ENU yaw plus the frame's meridian convergence there.
      smp.yaw_rad = s.yaw_enu_rad + frame.convergence_rad(smp.position_m);
      smp.speed_mps = s.speed_mps;
      smp.yaw_rate_rps = s.yaw_rate_rps;
      a.trajectory.push_back(smp);
    }
    index[d.row] = in.size();
    in.push_back(std::move(a));
  }
  for (const auto& p : tp) {
    if (const auto it = index.find(p.drive); it != index.end()) {
      in[it->second].points_m.push_back(p.candidate.position_m);
    }
  }
  const DriveAlignmentResult r = align_drives(in, cfg.alignment);
  st.alignment_status = std::string(to_string(r.status));
  st.aligned_drives = r.consumer_grade_drives;
  st.alignment_anchor_drives = r.survey_grade_drives;
  st.alignment_clusters = r.clusters;
  st.alignment_residual_rms_m = r.residual_rms_m;
  st.alignment_mean_correction_m = r.mean_correction_m;
  st.alignment_odometry_drives = r.odometry_drives;
  st.alignment_odometry_steps_rejected = r.odometry_steps_rejected;
  st.alignment_scale_error_mean = r.scale_error_mean;
  st.alignment_scale_error_rms = r.scale_error_rms;
  st.alignment_gyro_bias_mean_rps = r.gyro_bias_mean_rps;
  st.alignment_gyro_bias_rms_rps = r.gyro_bias_rms_rps;
  if (r.status == DriveAlignmentResult::Status::Aligned) {
    for (const DriveCorrection& c : r.corrections) {
      if (!c.survey_grade) out.emplace(c.drive, c);
    }
    for (auto& p : tp) {
      if (const auto it = out.find(p.drive); it != out.end()) {
        p.candidate.position_m = it->second.apply(p.candidate.position_m);
      }
    }
    for (auto& l : tl) {
      if (const auto it = out.find(l.drive); it != out.end()) {
        l.candidate.start_m = it->second.apply(l.candidate.start_m);
        l.candidate.end_m = it->second.apply(l.candidate.end_m);
      }
    }
  }
  st.seconds_alignment =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

/// The passes of the drives that may have had the region in view: every included drive
/// whose box meets the query box (also those without candidates there: a pass that saw
/// nothing is evidence too), with its trajectory in the build frame and its view range
/// estimated from its own candidates.
std::vector<DrivePass> drive_passes(const MapStore& store, const std::optional<GeoBox>& query,
                                    const std::vector<std::string>& excluded,
                                    const std::vector<TaggedPointCandidate>& tp,
                                    const std::vector<TaggedLineCandidate>& tl,
                                    const tiles::LocalFrame& frame, const VisibilityConfig& vcfg,
                                    const DriveCorrections& corrections) {
  const std::set<std::string> skip(excluded.begin(), excluded.end());
  std::unordered_map<std::int64_t, std::vector<Eigen::Vector2d>> cand_of_drive;
  for (const auto& p : tp) cand_of_drive[p.drive].push_back(p.candidate.position_m);
  for (const auto& l : tl) {
    cand_of_drive[l.drive].push_back(l.candidate.start_m);
    cand_of_drive[l.drive].push_back(l.candidate.end_m);
  }
  std::map<std::string, std::int64_t> vehicles;
  std::vector<DrivePass> passes;
  for (const DriveRecord& d : query ? store.drives_in(*query) : store.list_drives()) {
    if (skip.contains(d.drive_id)) continue;
    DrivePass pass;
    pass.drive = d.row;
    pass.start_time_s = d.start_time_s;
    pass.vehicle =
        vehicles.emplace(d.vehicle_id, static_cast<std::int64_t>(vehicles.size())).first->second;
    const auto corr = corrections.find(d.row);
    for (const GeoPoint& g : store.drive_path(d.drive_id)) {
      const Eigen::Vector2d p = frame.to_local(g);
      pass.path_m.push_back(corr == corrections.end() ? p : corr->second.apply(p, false));
    }
    if (pass.path_m.empty()) continue;  // no trajectory: judged by its candidates alone
    const auto it = cand_of_drive.find(d.row);
    pass.view_range_m = it == cand_of_drive.end()
                            ? vcfg.default_view_range_m
                            : estimate_view_range_m(pass.path_m, it->second, vcfg);
    passes.push_back(std::move(pass));
  }
  return passes;
}

tiles::GeoBox polyline_box(const std::vector<GeoPoint>& pl) {
  tiles::GeoBox b{90, 180, -90, -180};
  for (const auto& g : pl) {
    b.min_lat_deg = std::min(b.min_lat_deg, g.lat_deg);
    b.max_lat_deg = std::max(b.max_lat_deg, g.lat_deg);
    b.min_lon_deg = std::min(b.min_lon_deg, g.lon_deg);
    b.max_lon_deg = std::max(b.max_lon_deg, g.lon_deg);
  }
  return b;
}

tiles::GeoBox union_box(const tiles::GeoBox& a, const tiles::GeoBox& b) {
  return {std::min(a.min_lat_deg, b.min_lat_deg), std::min(a.min_lon_deg, b.min_lon_deg),
          std::max(a.max_lat_deg, b.max_lat_deg), std::max(a.max_lon_deg, b.max_lon_deg)};
}

/// The drive rows a build uses (all drives but the excluded ones), ascending.
std::vector<std::int64_t> drive_rows(const std::vector<DriveRecord>& drives,
                                     const std::vector<std::string>& excluded) {
  const std::set<std::string> skip(excluded.begin(), excluded.end());
  std::vector<std::int64_t> rows;
  for (const auto& d : drives) {
    if (!skip.contains(d.drive_id)) rows.push_back(d.row);
  }
  std::sort(rows.begin(), rows.end());
  return rows;
}

double consensus_margin_m(const MapBuildRequest& req) {
  return 2.0 * std::max(req.points.max_pair_distance_m,
                        req.lines.max_projection_distance_m + req.lines.max_hull_distance_m);
}

std::optional<IncrementalPlan> incremental_plan(const MapStore& store, const MapBuildRequest& req,
                                                const nlohmann::json& request_params,
                                                std::int64_t current,
                                                const std::vector<DriveRecord>& drives,
                                                double margin_m) {
  if (!req.incremental || req.region) return std::nullopt;
  const auto info = store.get_map_version(current);
  if (!info || !info->statistics.is_object() || !info->statistics.contains("drive_rows")) {
    return std::nullopt;
  }
  nlohmann::json a = info->parameters, b = request_params;
  for (auto* j : {&a, &b}) {
    j->erase("notes");
    j->erase("make_current");
    j->erase("incremental");
  }
  if (a != b) return std::nullopt;
  std::vector<std::int64_t> before;
  for (const auto& r : info->statistics["drive_rows"]) {
    if (!r.is_number_integer()) return std::nullopt;
    before.push_back(r.get<std::int64_t>());
  }
  std::sort(before.begin(), before.end());
  const std::vector<std::int64_t> now = drive_rows(drives, req.excluded_drive_ids);
  if (!std::includes(now.begin(), now.end(), before.begin(), before.end())) return std::nullopt;
  std::optional<tiles::GeoBox> added;
  std::size_t n_added = 0;
  for (const auto& d : drives) {
    if (!std::binary_search(now.begin(), now.end(), d.row)) continue;
    if (!std::binary_search(before.begin(), before.end(), d.row)) {
      added = added ? union_box(*added, d.bbox) : d.bbox;
      ++n_added;
    }
  }
  // Mostly new drives: a full build costs about the same and has no seams.
  if (!added || 2 * n_added >= now.size()) return std::nullopt;
  return IncrementalPlan{grow_box(*added, req.visibility.max_view_range_m + margin_m),
                         info->statistics.value("point_landmarks", std::int64_t{0}),
                         info->statistics.value("line_landmarks", std::int64_t{0})};
}

/// The frame position as a geodetic point quantized to 1e-8 degrees (stable keys).
GeoPoint to_geo_quantized(const tiles::LocalFrame& frame, const Eigen::Vector2d& xy) {
  const GeoPoint g = frame.to_geo(xy);
  return GeoPoint{quantize_deg(g.lat_deg), quantize_deg(g.lon_deg), 0.0};
}

/// Consensus point landmarks as stored rows (inside the region, if one is given).
/// `verdicts` receives the verdict of each row, keyed by the row's stable key.
std::vector<StoredPointLandmark> stored_points(
    const PointConsensusResult& pc, const tiles::LocalFrame& frame,
    const std::optional<tiles::GeoBox>& region,
    std::unordered_map<std::int64_t, SupportVerdict>& verdicts) {
  std::vector<StoredPointLandmark> points;
  for (std::size_t i = 0; i < pc.landmarks.size(); ++i) {
    const auto& lm = pc.landmarks[i];
    StoredPointLandmark s;
    s.position = to_geo_quantized(frame, lm.position_m);
    if (region && !region->contains(s.position.lat_deg, s.position.lon_deg)) continue;
    if (i < pc.verdicts.size()) {
      verdicts[landmark_key(false, std::span<const GeoPoint>(&s.position, 1))] = pc.verdicts[i];
    }
    s.key = landmark_key(false, std::span<const GeoPoint>(&s.position, 1));
    s.scattering = lm.scattering;
    s.support_drives = lm.support_drives;
    s.spread_m = lm.spread_m;
    s.support = pc.support[i];
    points.push_back(std::move(s));
  }
  return points;
}

/// Consensus line landmarks as stored rows (touching the region, if one is given).
std::vector<StoredLineLandmark> stored_lines(
    const LineConsensusResult& lc, const tiles::LocalFrame& frame,
    const std::optional<tiles::GeoBox>& region,
    std::unordered_map<std::int64_t, SupportVerdict>& verdicts) {
  std::vector<StoredLineLandmark> lines;
  for (std::size_t i = 0; i < lc.landmarks.size(); ++i) {
    const auto& lm = lc.landmarks[i];
    StoredLineLandmark s;
    for (const auto& v : lm.polyline_m) s.polyline.push_back(to_geo_quantized(frame, v));
    // Lines whose bounding box meets the region (as MapStore::landmarks_in selects them).
    if (region && !region->intersects(polyline_box(s.polyline))) continue;
    s.key = landmark_key(true, s.polyline);
    if (i < lc.verdicts.size()) verdicts[s.key] = lc.verdicts[i];
    s.support_drives = lm.support_drives;
    s.spread_m = lm.spread_m;
    s.support = lc.support[i];
    lines.push_back(std::move(s));
  }
  return lines;
}

nlohmann::json verdict_json(const SupportVerdict& v) {
  nlohmann::json j{
      {"support_drives", v.support_drives}, {"drives_in_view", v.drives_in_view},
      {"recent_passes", v.recent_passes},   {"recent_support", v.recent_support},
      {"miss_streak", v.miss_streak},       {"miss_streak_vehicles", v.miss_streak_vehicles}};
  // The day only: diffs are public, and when some vehicle passed a place is trajectory
  // data (never public, docs/security.md).
  if (v.last_support_time_s > 0.0) {
    const auto t = static_cast<std::time_t>(std::floor(v.last_support_time_s / 86400.0) * 86400.0);
    std::tm tm{};
    gmtime_r(&t, &tm);
    char day[16];
    std::strftime(day, sizeof day, "%Y-%m-%d", &tm);
    j["last_support_day"] = day;
  }
  return j;
}

/// The changes against the previous version, each with the builder's reason: the
/// support verdict of an added or moved landmark, the miss streak of a retired one (or
/// "unsupported" when no retired group explains it: its candidates are gone, e.g. a
/// deleted drive, or the consensus no longer groups them).
std::vector<LandmarkChange> changes_with_reasons(
    const LandmarkSet& previous, const std::vector<StoredPointLandmark>& points,
    const std::vector<StoredLineLandmark>& lines,
    const std::unordered_map<std::int64_t, SupportVerdict>& verdicts,
    const PointConsensusResult& pc, const LineConsensusResult& lc, const tiles::LocalFrame& frame,
    const LandmarkDiffConfig& dcfg) {
  LandmarkSet now;
  now.points = points;
  now.lines = lines;
  LandmarkDiff diff = diff_landmarks(previous, now, dcfg);
  for (LandmarkChange& c : diff.changes) {
    if (c.change != LandmarkChangeKind::Retired) {
      const auto it = verdicts.find(c.key);
      c.reason =
          it == verdicts.end() ? nlohmann::json{{"rule", "support"}} : verdict_json(it->second);
      c.reason["rule"] = "support";
      continue;
    }
    // The retired group nearest to the old landmark (points: position; lines: midpoint).
    auto mid = [&](const std::vector<Eigen::Vector2d>& pl) {
      return Eigen::Vector2d(0.5 * (pl.front() + pl.back()));
    };
    std::vector<Eigen::Vector2d> old_m;
    for (const auto& g : c.geometry) old_m.push_back(frame.to_local(g));
    const Eigen::Vector2d at = old_m.size() == 1 ? old_m[0] : mid(old_m);
    const SupportVerdict* best = nullptr;
    double best_d = c.is_line ? 2.0 : dcfg.match_radius_m;
    if (c.is_line) {
      for (std::size_t i = 0; i < lc.retired.size(); ++i) {
        const double d = (mid(lc.retired[i].polyline_m) - at).norm();
        if (d <= best_d) best_d = d, best = &lc.retired_verdicts[i];
      }
    } else {
      for (std::size_t i = 0; i < pc.retired.size(); ++i) {
        const double d = (pc.retired[i].position_m - at).norm();
        if (d <= best_d) best_d = d, best = &pc.retired_verdicts[i];
      }
    }
    if (best != nullptr) {
      c.reason = verdict_json(*best);
      c.reason["rule"] = "missed";
    } else {
      c.reason = {{"rule", "unsupported"}};
    }
  }
  return std::move(diff.changes);
}

/// The landmarks cut into localization tiles of zoom z (each in its tile's frame; a line
/// goes into every tile it passes through).
std::map<tiles::TileKey, tiles::LocalizationTile> localization_tile_content(
    const std::vector<StoredPointLandmark>& points, const std::vector<StoredLineLandmark>& lines,
    const tiles::LocalFrame& frame, int z, double line_sample_m) {
  std::map<tiles::TileKey, tiles::LocalizationTile> content;
  std::map<tiles::TileKey, tiles::LocalFrame> frames;
  auto tile = [&](const tiles::TileKey& k)
      -> std::pair<tiles::LocalizationTile&, const tiles::LocalFrame&> {
    auto it = content.find(k);
    if (it == content.end()) {
      it = content.emplace(k, tiles::LocalizationTile{}).first;
      it->second.key = k;
      frames.emplace(k, tiles::LocalFrame(tiles::tile_center(k)));
    }
    return {it->second, frames.at(k)};
  };
  for (const auto& p : points) {
    auto [t, f] = tile(tiles::tile_at(p.position.lat_deg, p.position.lon_deg, z));
    PointLandmark lm;
    lm.id = p.key;
    lm.position_m = f.to_local(p.position);
    lm.scattering = p.scattering;
    lm.support_drives = p.support_drives;
    lm.spread_m = p.spread_m;
    t.points.push_back(lm);
  }
  for (const auto& l : lines) {
    std::vector<Eigen::Vector2d> pl_m;
    for (const auto& g : l.polyline) pl_m.push_back(frame.to_local(g));
    for (const auto& k : tiles_of_polyline(l.polyline, pl_m, z, line_sample_m)) {
      auto [t, f] = tile(k);
      LineLandmark lm;
      lm.id = l.key;
      for (const auto& g : l.polyline) lm.polyline_m.push_back(f.to_local(g));
      lm.support_drives = l.support_drives;
      lm.spread_m = l.spread_m;
      t.lines.push_back(std::move(lm));
    }
  }
  return content;
}

}  // namespace detail

MapBuilder::MapBuilder(MapBuilderConfig cfg) : cfg_(std::move(cfg)) {
  POLMAP_EXPECT(cfg_.tile_zoom >= 0 && cfg_.tile_zoom <= tiles::kMaxZoom);
  POLMAP_EXPECT(cfg_.write_batch > 0 && cfg_.line_tile_sample_m > 0.0);
}

namespace detail {

/// The merged gridmap stage: brings the store's sum tiles up to date with its drives, then
/// renders the version's raster tiles (amplitude, mechanism) from them, one min-zoom region
/// at a time. Regions without changed sums since the current version (when it was rendered
/// completely from the sums with this config) are copied from it. Returns the version's
/// `gridmap` statistics.
nlohmann::json build_gridmap(MapStore& store, std::int64_t version, const MapBuildRequest& req,
                             const MapBuilderConfig& cfg,
                             const std::vector<DriveRecord>& all_drives,
                             const std::optional<std::int64_t>& current, MapBuildStats& st,
                             const std::function<void()>& tick,
                             const detail::GridmapPlacements& placements) {
  const FleetGridmapConfig& gc = cfg.gridmap;
  std::set<std::string> stored_hashes;
  for (const auto& d : all_drives) stored_hashes.insert(d.content_hash);
  const std::vector<DriveRecord> drives = req.region ? store.drives_in(*req.region) : all_drives;
  detail::GridmapSumsUpdate up =
      detail::update_gridmap_sums(store, version, drives, stored_hashes, tick, placements);
  st.gridmap_drives_added = up.drives_added;
  st.gridmap_drives_replaced = up.drives_replaced;
  st.gridmap_drives_removed = up.drives_removed;
  st.gridmap_sum_tiles_written = up.tiles_written;
  for (const auto& in : store.gridmap_sum_inputs()) {
    if (in.tiles > 0) ++st.gridmap_drives;  // landmarks-only drives are inputs without tiles
  }

  const bool complete = !req.region && req.excluded_drive_ids.empty();
  nlohmann::json info = {{"base_zoom", gc.base_zoom},  {"min_zoom", gc.min_zoom},
                         {"db_min", gc.db_min},        {"db_max", gc.db_max},
                         {"sums_through", version},    {"complete", complete},
                         {"sum_zoom", kGridmapSumZoom}};
  // Incremental rendering: the current version was rendered completely, with this config,
  // from the sums as they were after its own build (tiles written later say updated_by >
  // its number).
  std::optional<std::int64_t> from;
  if (req.incremental && complete && current) {
    if (const auto prev = store.get_map_version(*current)) {
      const auto& g = prev->statistics.value("gridmap", nlohmann::json::object());
      if (g.is_object() && g.value("complete", false) && g.contains("sums_through") &&
          g.value("base_zoom", -1) == gc.base_zoom && g.value("min_zoom", -1) == gc.min_zoom &&
          g.value("db_min", 0.0) == gc.db_min && g.value("db_max", 0.0) == gc.db_max) {
        from = *current;
      }
    }
  }
  const std::vector<GridmapSumRow> all_keys = store.gridmap_sum_keys(std::nullopt);
  std::map<tiles::TileKey, std::vector<GridmapSumKey>> regions;
  for (const auto& r : all_keys) {
    const GridmapSumKey k{static_cast<PolLevel>(r.level), r.x, r.y};
    const tiles::TileKey reg = detail::sum_tile_ancestor(k, gc.min_zoom);
    if (req.region && !tiles::tile_bounds(reg).intersects(*req.region)) continue;
    regions[reg].push_back(k);
  }
  std::set<tiles::TileKey> dirty;
  if (from) {
    for (const auto& r : store.gridmap_sum_keys(*from)) {
      dirty.insert(
          detail::sum_tile_ancestor({static_cast<PolLevel>(r.level), r.x, r.y}, gc.min_zoom));
    }
  } else {
    for (const auto& [reg, ks] : regions) dirty.insert(reg);
  }
  // Drives left out of this version: the tiles they touched, recomputed without them.
  GridmapSumTiles without;
  if (!req.excluded_drive_ids.empty()) {
    std::set<std::string> hashes;
    std::set<GridmapSumKey> keys;
    for (const auto& id : req.excluded_drive_ids) {
      const auto d = store.get_drive(id);
      if (!d) continue;
      hashes.insert(d->content_hash);
      for (const auto& c : store.gridmap_sum_cover(d->content_hash)) {
        keys.insert({static_cast<PolLevel>(c[0]), c[1], c[2]});
      }
    }
    without = detail::recompute_sum_tiles(store, keys, hashes, up.errors);
  }
  for (const TileLayer layer : {TileLayer::Gridmap, TileLayer::GridmapMechanism}) {
    if (!from) break;
    // Tiles of untouched regions carry over; those of re-rendered regions are replaced.
    std::vector<tiles::TileKey> except;
    for (const auto& t : store.list_tiles(*from, layer)) {
      const int up_z = t.key.z - gc.min_zoom;
      if (up_z >= 0 && dirty.contains({gc.min_zoom, t.key.x >> up_z, t.key.y >> up_z})) {
        except.push_back(t.key);
      }
    }
    const std::int64_t n = store.copy_tiles(*from, version, layer, except);
    if (layer == TileLayer::Gridmap) {
      st.gridmap_tiles += n;
      st.gridmap_tiles_copied = n;
    }
  }
  // Previous ETags: a re-rendered tile with the same bytes keeps its blob.
  std::map<std::pair<TileLayer, tiles::TileKey>, std::string> prev_etags;
  if (current) {
    for (const TileLayer layer : {TileLayer::Gridmap, TileLayer::GridmapMechanism}) {
      for (const auto& t : store.list_tiles(*current, layer)) {
        prev_etags.emplace(std::make_pair(layer, t.key), t.etag);
      }
    }
  }
  for (const auto& reg : dirty) {
    const auto it = regions.find(reg);
    if (it == regions.end()) continue;  // every sum tile of it is gone
    if (tick) tick();
    FleetGridmapAccumulator::PngTiles pngs =
        detail::render_gridmap_region(store, gc, it->second, without);
    ++st.gridmap_regions_rendered;
    for (const TileLayer layer : {TileLayer::Gridmap, TileLayer::GridmapMechanism}) {
      std::vector<TileWrite> batch;
      for (auto& [key, png] : layer == TileLayer::Gridmap ? pngs.amplitude : pngs.mechanism) {
        TileWrite w;
        w.key = key;
        w.etag = content_etag(png);
        if (auto e = prev_etags.find({layer, key}); e != prev_etags.end() && e->second == w.etag) {
          w.reuse_blob = true;
        } else {
          w.payload = std::move(png);
        }
        batch.push_back(std::move(w));
        if (layer == TileLayer::Gridmap) ++st.gridmap_tiles;
      }
      if (!batch.empty()) store.put_tiles(version, layer, batch);
    }
  }
  info["errors"] = up.errors;
  return info;
}

}  // namespace detail

std::int64_t MapBuilder::begin(MapStore& store, const MapBuildRequest& request) const {
  for (const auto& id : request.excluded_drive_ids) {
    if (!store.get_drive(id))
      throw NotFoundError("excluded drive '" + id + "' is not in the store");
  }
  if (request.region && (request.region->min_lat_deg > request.region->max_lat_deg)) {
    throw ValidationError("region: min_lat_deg > max_lat_deg");
  }
  if (const auto& p = request.partition) {
    const double margin_m = detail::consensus_margin_m(request);
    if (p->zoom < 0 || p->zoom > cfg_.tile_zoom) {
      throw ValidationError("partition.zoom: must be in [0, " + std::to_string(cfg_.tile_zoom) +
                            "] (the localization tile zoom)");
    }
    if (!(p->halo_m >= std::max(margin_m, request.visibility.max_view_range_m))) {
      throw ValidationError(
          "partition.halo_m: must cover the consensus margin and the view range (" +
          std::to_string(std::max(margin_m, request.visibility.max_view_range_m)) + " m)");
    }
    if (request.region) throw ValidationError("partition: not with a region (a region is one job)");
  }
  return store.begin_map_version(request_json(request, cfg_));
}

MapBuildResult MapBuilder::build(MapStore& store, const MapBuildRequest& request,
                                 const BuildControl& control) const {
  const std::int64_t v = begin(store, request);
  return run(store, v, request, control);
}

MapBuildResult MapBuilder::run(MapStore& store, std::int64_t version, const MapBuildRequest& req,
                               const BuildControl& ctl) const {
  if (req.partition) return detail::run_partitioned(store, version, req, cfg_, ctl);
  MapBuildResult result;
  result.version = version;
  MapBuildStats& st = result.stats;
  Clock clock;
  auto stage = [&](std::string_view name, double fraction) {
    if (ctl.cancel && ctl.cancel->load()) throw Cancelled{};
    if (ctl.progress) ctl.progress(name, fraction);
  };
  try {
    // ---------------------------------------------------------------- load
    stage("load", 0.0);
    const double margin_m = consensus_margin_m(req);
    // The version this build follows: tiles are reused from it and changes recorded
    // against it (read once, so both refer to the same version).
    const std::optional<std::int64_t> current = store.current_map_version();
    const std::vector<DriveRecord> all_drives = store.list_drives();
    const nlohmann::json params = request_json(req, cfg_);
    // Incremental: only `area` is rebuilt; the rest of the current version carries over.
    const std::optional<IncrementalPlan> plan =
        current ? incremental_plan(store, req, params, *current, all_drives, margin_m)
                : std::nullopt;
    const std::optional<tiles::GeoBox> area =
        plan ? std::optional<tiles::GeoBox>(plan->area) : std::nullopt;
    const std::optional<tiles::GeoBox> build_region = area ? area : req.region;
    st.incremental_from = area ? current : std::nullopt;
    std::optional<tiles::GeoBox> query;
    if (build_region) query = grow_box(*build_region, margin_m);
    const CandidateSet cands = store.candidates_in(query, req.excluded_drive_ids);
    st.point_candidates = static_cast<std::int64_t>(cands.points.size());
    st.line_candidates = static_cast<std::int64_t>(cands.lines.size());
    {
      std::set<std::int64_t> drives;
      for (const auto& p : cands.points) drives.insert(p.drive);
      for (const auto& l : cands.lines) drives.insert(l.drive);
      st.drives_used = static_cast<std::int64_t>(drives.size());
    }
    const tiles::LocalFrame frame(region_centre(build_region, cands));
    std::vector<TaggedPointCandidate> tp = tagged_points(cands, frame);
    std::vector<TaggedLineCandidate> tl = tagged_lines(cands, frame);
    const DriveCorrections corrections =
        align_candidates(store, query, req.excluded_drive_ids, tp, tl, frame, cfg_, st);
    const VisibilityIndex view(drive_passes(store, query, req.excluded_drive_ids, tp, tl, frame,
                                            req.visibility, corrections),
                               req.visibility);
    st.drives_passing = static_cast<std::int64_t>(view.passes().size());
    st.seconds_load = clock.lap();

    // ---------------------------------------------------------------- consensus
    stage("consensus", 0.1);
    PointConsensusResult pc = consensus_points(tp, req.points, &view);
    LineConsensusResult lc = consensus_lines(tl, req.lines, &view);
    const LineFilterResult lf = filter_line_landmarks(lc, tl, &view, req.lines.filter);
    st.line_overhead = static_cast<std::int64_t>(lf.overhead);
    st.line_range_streaks = static_cast<std::int64_t>(lf.range_streaks);
    st.line_out_of_view = static_cast<std::int64_t>(lf.out_of_view);
    const PointFilterResult pf = filter_point_landmarks(pc, lc, tp, &view, req.points.filter);
    st.point_line_peaks = static_cast<std::int64_t>(pf.line_peaks);
    st.point_surface_peaks = static_cast<std::int64_t>(pf.surface_peaks);
    st.point_temporary = static_cast<std::int64_t>(pf.temporary);
    st.point_sliding = static_cast<std::int64_t>(pf.sliding);
    st.point_out_of_view = static_cast<std::int64_t>(pf.out_of_view);
    st.point_mirror_ghosts = static_cast<std::int64_t>(pf.mirror_ghosts);
    st.point_consensus = pc.stats;
    st.line_consensus = lc.stats;
    st.seconds_consensus = clock.lap();

    // ---------------------------------------------------------------- landmarks
    stage("landmarks", 0.4);
    std::unordered_map<std::int64_t, SupportVerdict> verdicts;
    const std::vector<StoredPointLandmark> points =
        stored_points(pc, frame, build_region, verdicts);
    const std::vector<StoredLineLandmark> lines = stored_lines(lc, frame, build_region, verdicts);
    st.point_landmarks = static_cast<std::int64_t>(points.size());
    st.line_landmarks = static_cast<std::int64_t>(lines.size());
    // The current version's landmarks in the rebuilt area (replaced) and outside it
    // (copied unchanged).
    LandmarkSet replaced;
    if (area) {
      replaced = store.landmarks_in(*current, area, false);
      std::vector<std::int64_t> ids;
      for (const auto& p : replaced.points) ids.push_back(p.id);
      for (const auto& l : replaced.lines) ids.push_back(l.id);
      st.landmarks_copied = store.copy_landmarks(*current, version, ids);
      st.point_landmarks +=
          plan->previous_points - static_cast<std::int64_t>(replaced.points.size());
      st.line_landmarks += plan->previous_lines - static_cast<std::int64_t>(replaced.lines.size());
    }
    for (std::size_t b = 0; b < points.size(); b += cfg_.write_batch) {
      stage("landmarks", 0.4);
      const std::size_t e = std::min(points.size(), b + cfg_.write_batch);
      store.put_landmarks(version, std::span(points).subspan(b, e - b), {});
    }
    for (std::size_t b = 0; b < lines.size(); b += cfg_.write_batch) {
      stage("landmarks", 0.45);
      const std::size_t e = std::min(lines.size(), b + cfg_.write_batch);
      store.put_landmarks(version, {}, std::span(lines).subspan(b, e - b));
    }
    // What changed against the current version (recorded with this version; the
    // diff endpoint reads the reasons from here).
    if (const auto& prev = current) {
      const LandmarkSet previous = area ? replaced : store.landmarks_in(*prev, req.region, false);
      const std::vector<LandmarkChange> changes =
          changes_with_reasons(previous, points, lines, verdicts, pc, lc, frame, cfg_.diff);
      for (const auto& ch : changes) {
        (ch.change == LandmarkChangeKind::Added   ? st.landmarks_added
         : ch.change == LandmarkChangeKind::Moved ? st.landmarks_moved
                                                  : st.landmarks_retired) += 1;
      }
      for (std::size_t b = 0; b < changes.size(); b += cfg_.write_batch) {
        stage("landmarks", 0.47);
        const std::size_t e = std::min(changes.size(), b + cfg_.write_batch);
        store.put_landmark_changes(version, std::span(changes).subspan(b, e - b));
      }
      st.changes_against = *prev;
    }
    st.seconds_landmarks = clock.lap();

    // ---------------------------------------------------------------- tiles
    stage("tiles", 0.5);
    const int z = cfg_.tile_zoom;
    std::map<tiles::TileKey, tiles::LocalizationTile> content =
        localization_tile_content(points, lines, frame, z, cfg_.line_tile_sample_m);
    std::int64_t tiles_copied = 0;
    std::set<tiles::TileKey> affected;
    if (area) {
      // Tiles that hold a new or a replaced landmark are re-encoded from everything the
      // new version has there (new landmarks plus copied ones); the others are copied.
      for (const auto& [k, t] : content) affected.insert(k);
      for (const auto& [k, t] : localization_tile_content(replaced.points, replaced.lines, frame, z,
                                                          cfg_.line_tile_sample_m)) {
        affected.insert(k);
      }
      if (!affected.empty()) {
        std::optional<tiles::GeoBox> box;
        for (const auto& k : affected) {
          box = box ? union_box(*box, tiles::tile_bounds(k)) : tiles::tile_bounds(k);
        }
        std::set<std::int64_t> replaced_ids;
        for (const auto& p : replaced.points) replaced_ids.insert(p.id);
        for (const auto& l : replaced.lines) replaced_ids.insert(l.id);
        LandmarkSet around = store.landmarks_in(*current, box, false);
        std::vector<StoredPointLandmark> all_points = points;
        std::vector<StoredLineLandmark> all_lines = lines;
        for (auto& p : around.points) {
          if (!replaced_ids.contains(p.id)) all_points.push_back(std::move(p));
        }
        for (auto& l : around.lines) {
          if (!replaced_ids.contains(l.id)) all_lines.push_back(std::move(l));
        }
        content =
            localization_tile_content(all_points, all_lines, frame, z, cfg_.line_tile_sample_m);
        std::erase_if(content, [&](const auto& kv) { return !affected.contains(kv.first); });
      }
      const std::vector<tiles::TileKey> except(affected.begin(), affected.end());
      tiles_copied = store.copy_tiles(*current, version, TileLayer::Localization, except);
      st.tiles_reused += tiles_copied;
    }
    std::map<tiles::TileKey, std::string> prev_etags;
    if (req.incremental) {
      st.previous_version = current;
      if (st.previous_version) {
        for (const auto& t : store.list_tiles(*st.previous_version, TileLayer::Localization)) {
          prev_etags.emplace(t.key, t.etag);
        }
      }
    }
    std::vector<TileWrite> batch;
    std::size_t batch_bytes = 0;
    auto flush = [&](TileLayer layer) {
      if (batch.empty()) return;
      store.put_tiles(version, layer, batch);
      batch.clear();
      batch_bytes = 0;
    };
    std::size_t done = 0;
    for (auto& [key, t] : content) {
      if (++done % 64 == 0) stage("tiles", 0.5 + 0.3 * static_cast<double>(done) / content.size());
      TileWrite w;
      w.key = key;
      w.num_points = static_cast<std::int32_t>(t.points.size());
      w.num_lines = static_cast<std::int32_t>(t.lines.size());
      bool reused = false;
      if (auto it = prev_etags.find(key); it != prev_etags.end()) {
        // Encode with the previous tile's version stamp: identical bytes mean
        // identical content, and the previous blob (and ETag) is kept.
        const auto prev = store.get_tile(*st.previous_version, TileLayer::Localization, key);
        if (prev) {
          t.map_version = tiles::decode_localization_tile(prev->payload).map_version;
          const std::string bytes = tiles::encode_localization_tile(t, cfg_.encode);
          if (content_etag(bytes) == it->second) {
            w.etag = it->second;
            w.reuse_blob = true;
            reused = true;
            st.tile_bytes += static_cast<std::int64_t>(bytes.size());
          }
        }
      }
      if (!reused) {
        t.map_version = static_cast<std::uint64_t>(version);
        w.payload = tiles::encode_localization_tile(t, cfg_.encode);
        w.etag = content_etag(w.payload);
        st.tile_bytes += static_cast<std::int64_t>(w.payload.size());
      }
      (reused ? st.tiles_reused : st.tiles_written) += 1;
      batch_bytes += w.payload.size();
      batch.push_back(std::move(w));
      if (batch.size() >= cfg_.write_batch || batch_bytes > (16U << 20))
        flush(TileLayer::Localization);
    }
    flush(TileLayer::Localization);
    st.tiles_total = static_cast<std::int64_t>(content.size()) + tiles_copied;
    for (const auto& [key, etag] : prev_etags) {
      // Previous tiles with no successor (incremental: only affected ones can vanish).
      if (!content.contains(key) && (!area || affected.contains(key))) ++st.tiles_removed;
    }
    st.seconds_tiles = clock.lap();

    // ---------------------------------------------------------------- fleet gridmap
    nlohmann::json gridmap_info;
    if (req.build_gridmap) {
      stage("gridmap", 0.8);
      // The drives this build aligned go into the sums where the alignment put them.
      detail::GridmapPlacements placements;
      placements.replace_threshold_m = cfg_.gridmap_replace_threshold_m;
      for (const DriveRecord& d : all_drives) {
        if (const auto c = corrections.find(d.row); c != corrections.end()) {
          placements.by_hash.emplace(d.content_hash, drive_placement(frame, c->second));
        }
      }
      gridmap_info = build_gridmap(
          store, version, req, cfg_, all_drives, current, st, [&] { stage("gridmap", 0.8); },
          placements);
      st.seconds_gridmap = clock.lap();
    }

    // ---------------------------------------------------------------- publish
    stage("publish", 0.95);
    st.seconds_total = clock.total();
    nlohmann::json stats = to_json(st);
    // The drives this version was built from (the next build's incremental plan).
    stats["drive_rows"] = drive_rows(all_drives, req.excluded_drive_ids);
    stats["gridmap"] = gridmap_info;
    store.publish_map_version(version, stats, req.make_current);
    if (ctl.progress) ctl.progress("publish", 1.0);
    result.status = MapBuildResult::Status::Published;
  } catch (const Cancelled&) {
    result.status = MapBuildResult::Status::Cancelled;
    result.error = "cancelled";
  } catch (const std::exception& e) {
    result.status = MapBuildResult::Status::Failed;
    result.error = e.what();
  }
  if (result.status != MapBuildResult::Status::Published) {
    try {
      store.fail_map_version(version, result.error);
    } catch (const std::exception& e) {
      result.error += std::string(" (and marking the version failed failed: ") + e.what() + ")";
    }
  }
  st.seconds_total = clock.total();
  return result;
}

}  // namespace polmap::mapping
