// Partitioned map builds (map_builder.hpp BuildPartition, build_worker.hpp, schema/
// build_jobs.md): the plan (regions from the drives' paths), the three job kinds (region,
// gridmap, publish), the worker that claims and runs them, and the in-process driver.
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <mutex>
#include <set>
#include <thread>

#include "build_steps.hpp"
#include "polmap/mapping_service/build_worker.hpp"
#include "polmap/tiles/local_frame.hpp"

namespace polmap::mapping {
namespace detail {
namespace {

struct LeaseLost {};

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

/// Whether tile `k` (zoom >= region.z) lies in `region`.
bool inside(const tiles::TileKey& k, const tiles::TileKey& region) {
  if (k.z < region.z) return false;
  const int up = k.z - region.z;
  return (k.x >> up) == region.x && (k.y >> up) == region.y;
}

tiles::TileKey owner_of_line(const std::vector<GeoPoint>& pl, int z) {
  const tiles::GeoBox b = polyline_box(pl);
  return tiles::tile_at(0.5 * (b.min_lat_deg + b.max_lat_deg),
                        0.5 * (b.min_lon_deg + b.max_lon_deg), z);
}

/// The pieces of a geodetic polyline inside a lon/lat box (Liang-Barsky per edge, linear
/// in degrees as tiles_of_polyline samples), vertices quantized.
std::vector<std::vector<GeoPoint>> clip_polyline(const std::vector<GeoPoint>& pl,
                                                 const tiles::GeoBox& box) {
  std::vector<std::vector<GeoPoint>> pieces;
  std::vector<GeoPoint> cur;
  auto same = [](const GeoPoint& a, const GeoPoint& b) {
    return a.lat_deg == b.lat_deg && a.lon_deg == b.lon_deg;
  };
  auto flush = [&] {
    if (cur.size() >= 2) pieces.push_back(std::move(cur));
    cur.clear();
  };
  for (std::size_t i = 0; i + 1 < pl.size(); ++i) {
    const double x0 = pl[i].lon_deg, y0 = pl[i].lat_deg;
    const double dx = pl[i + 1].lon_deg - x0, dy = pl[i + 1].lat_deg - y0;
    double t0 = 0.0, t1 = 1.0;
    bool visible = true;
    auto clip = [&](double p, double q) {  // p t <= q
      if (p == 0.0) {
        if (q < 0.0) visible = false;
        return;
      }
      const double r = q / p;
      if (p < 0.0) {
        t0 = std::max(t0, r);
      } else {
        t1 = std::min(t1, r);
      }
    };
    clip(-dx, x0 - box.min_lon_deg);
    clip(dx, box.max_lon_deg - x0);
    clip(-dy, y0 - box.min_lat_deg);
    clip(dy, box.max_lat_deg - y0);
    if (!visible || t0 > t1) {
      flush();
      continue;
    }
    const GeoPoint a{quantize_deg(y0 + t0 * dy), quantize_deg(x0 + t0 * dx), 0.0};
    const GeoPoint b{quantize_deg(y0 + t1 * dy), quantize_deg(x0 + t1 * dx), 0.0};
    if (cur.empty() || !same(cur.back(), a)) {
      flush();
      cur.push_back(a);
    }
    if (!same(cur.back(), b)) cur.push_back(b);
    if (t1 < 1.0) flush();
  }
  flush();
  return pieces;
}

double polyline_length_m(const std::vector<GeoPoint>& pl, const tiles::LocalFrame& frame) {
  double len = 0.0;
  for (std::size_t i = 0; i + 1 < pl.size(); ++i) {
    len += (frame.to_local(pl[i + 1]) - frame.to_local(pl[i])).norm();
  }
  return len;
}

std::optional<std::int64_t> opt_i64(const nlohmann::json& j, const char* key) {
  if (!j.contains(key) || j[key].is_null()) return std::nullopt;
  return j[key].get<std::int64_t>();
}

MapBuilderConfig config_of(const nlohmann::json& params) {
  MapBuilderConfig c;
  c.tile_zoom = params.value("tile_zoom", c.tile_zoom);
  c.encode.quantum_m = params.value("tile_quantum_m", c.encode.quantum_m);
  return c;
}

/// Regions of `zoom` within halo_m of the included drives' paths (edges sampled at a
/// quarter of the halo so that long straight edges miss no region).
std::set<tiles::TileKey> plan_regions(const MapStore& store, const std::vector<DriveRecord>& drives,
                                      const BuildPartition& part) {
  std::set<tiles::TileKey> regions;
  for (const DriveRecord& d : drives) {
    const std::vector<GeoPoint> path = store.drive_path(d.drive_id);
    std::vector<GeoPoint> samples;
    for (std::size_t i = 0; i < path.size(); ++i) {
      samples.push_back(path[i]);
      if (i + 1 == path.size()) break;
      const tiles::LocalFrame f(path[i]);
      const double len = f.to_local(path[i + 1]).norm();
      const int n = static_cast<int>(std::ceil(len / (0.25 * part.halo_m)));
      for (int k = 1; k < n; ++k) {
        const double t = static_cast<double>(k) / n;
        samples.push_back({path[i].lat_deg + t * (path[i + 1].lat_deg - path[i].lat_deg),
                           path[i].lon_deg + t * (path[i + 1].lon_deg - path[i].lon_deg), 0.0});
      }
    }
    if (samples.empty()) {  // no trajectory: its box
      for (const auto& k : tiles::tiles_covering(d.bbox, part.zoom)) regions.insert(k);
    }
    for (const GeoPoint& g : samples) {
      const tiles::GeoBox b = grow_box({g.lat_deg, g.lon_deg, g.lat_deg, g.lon_deg}, part.halo_m);
      for (const auto& k : tiles::tiles_covering(b, part.zoom)) regions.insert(k);
    }
  }
  return regions;
}

/// What an incremental partitioned build copied from the version it follows: the landmarks
/// and localization tiles of every region the new drives cannot change.
struct Carried {
  std::int64_t regions = 0;
  std::int64_t points = 0;
  std::int64_t lines = 0;
  std::int64_t tiles = 0;
};

/// Copies into `version` everything of `previous` outside the `rebuilt` regions (landmarks
/// by the region that owns them, as region_job selects a region's previous landmarks;
/// tiles by the region they lie in). Memory: the rebuilt regions' landmarks and the
/// previous version's tile list, never its landmarks elsewhere.
Carried carry_regions(MapStore& store, std::int64_t previous, std::int64_t version,
                      const std::set<tiles::TileKey>& rebuilt, std::int64_t carried_regions) {
  Carried c;
  c.regions = carried_regions;
  std::set<std::int64_t> except;
  std::int64_t except_points = 0, except_lines = 0;
  for (const tiles::TileKey& k : rebuilt) {
    const LandmarkSet s = store.landmarks_in(previous, tiles::tile_bounds(k), false);
    for (const auto& p : s.points) {
      if (tiles::tile_at(p.position.lat_deg, p.position.lon_deg, k.z) == k &&
          except.insert(p.id).second) {
        ++except_points;
      }
    }
    for (const auto& l : s.lines) {
      if (owner_of_line(l.polyline, k.z) == k && except.insert(l.id).second) ++except_lines;
    }
  }
  const auto info = store.get_map_version(previous);
  const nlohmann::json& ps = info ? info->statistics : nlohmann::json();
  const std::vector<std::int64_t> ids(except.begin(), except.end());
  (void)store.copy_landmarks(previous, version, ids);
  c.points = ps.value("point_landmarks", std::int64_t{0}) - except_points;
  c.lines = ps.value("line_landmarks", std::int64_t{0}) - except_lines;
  std::vector<tiles::TileKey> except_tiles;
  for (const auto& t : store.list_tiles(previous, TileLayer::Localization)) {
    for (const tiles::TileKey& k : rebuilt) {
      if (inside(t.key, k)) {
        except_tiles.push_back(t.key);
        break;
      }
    }
  }
  c.tiles = store.copy_tiles(previous, version, TileLayer::Localization, except_tiles);
  return c;
}

}  // namespace

MapBuildRequest request_from_json(const nlohmann::json& p) {
  MapBuildRequest r;
  try {
    if (p.contains("region") && !p["region"].is_null()) {
      const auto& g = p["region"];
      r.region =
          tiles::GeoBox{g.at("min_lat_deg").get<double>(), g.at("min_lon_deg").get<double>(),
                        g.at("max_lat_deg").get<double>(), g.at("max_lon_deg").get<double>()};
    }
    r.excluded_drive_ids =
        p.value("excluded_drive_ids", nlohmann::json::array()).get<std::vector<std::string>>();
    r.notes = p.value("notes", std::string());
    r.make_current = p.value("make_current", r.make_current);
    r.incremental = p.value("incremental", r.incremental);
    r.build_gridmap = p.value("build_gridmap", r.build_gridmap);
    auto support = [](const nlohmann::json& s, SupportRule& out) {
      out.min_drives = s.value("min_drives", out.min_drives);
      out.min_view_fraction = s.value("min_view_fraction", out.min_view_fraction);
      out.recent_passes = s.value("recent_passes", out.recent_passes);
      out.retire_min_misses = s.value("retire_min_misses", out.retire_min_misses);
      out.retire_min_vehicles = s.value("retire_min_vehicles", out.retire_min_vehicles);
    };
    if (p.contains("points")) {
      const auto& j = p["points"];
      r.points.max_pair_distance_m = j.value("max_pair_distance_m", r.points.max_pair_distance_m);
      if (j.contains("support")) support(j["support"], r.points.support);
      // The point filter's rules as the version recorded them (request_json), so that
      // every worker filters as the one-process build would.
      PointFilterConfig& f = r.points.filter;
      f.line_peaks = j.value("line_peaks", f.line_peaks);
      f.surface_peaks = j.value("surface_peaks", f.surface_peaks);
      f.co_presence = j.value("co_presence", f.co_presence);
      f.sliding = j.value("sliding", f.sliding);
      f.out_of_view = j.value("out_of_view", f.out_of_view);
      f.mirror_ghosts = j.value("mirror_ghosts", f.mirror_ghosts);
    }
    if (p.contains("lines")) {
      const auto& j = p["lines"];
      auto& l = r.lines;
      l.max_hull_distance_m = j.value("max_hull_distance_m", l.max_hull_distance_m);
      l.max_projection_distance_m =
          j.value("max_projection_distance_m", l.max_projection_distance_m);
      l.polyline_max_error_m = j.value("polyline_max_error_m", l.polyline_max_error_m);
      l.snap_max_gap_m = j.value("snap_max_gap_m", l.snap_max_gap_m);
      if (j.contains("support")) support(j["support"], l.support);
      l.filter.overhead = j.value("overhead", l.filter.overhead);
      l.filter.range_streaks = j.value("range_streaks", l.filter.range_streaks);
      l.filter.out_of_view = j.value("out_of_view", l.filter.out_of_view);
    }
    if (p.contains("visibility")) {
      const auto& j = p["visibility"];
      auto& v = r.visibility;
      v.default_view_range_m = j.value("default_view_range_m", v.default_view_range_m);
      v.min_view_range_m = j.value("min_view_range_m", v.min_view_range_m);
      v.max_view_range_m = j.value("max_view_range_m", v.max_view_range_m);
      v.range_quantile = j.value("range_quantile", v.range_quantile);
      v.range_margin = j.value("range_margin", v.range_margin);
    }
    if (p.contains("partition") && !p["partition"].is_null()) {
      const auto& j = p["partition"];
      BuildPartition b;
      b.zoom = j.value("zoom", b.zoom);
      b.halo_m = j.value("halo_m", b.halo_m);
      b.min_line_piece_m = j.value("min_line_piece_m", b.min_line_piece_m);
      r.partition = b;
    }
  } catch (const nlohmann::json::exception& e) {
    throw ValidationError(std::string("map version parameters: ") + e.what());
  }
  return r;
}

namespace {

/// A region job: consensus over the candidates and passes within the halo, in the region's
/// frame; the point landmarks inside the region, the line landmarks clipped to it, their
/// changes against the previous version's landmarks of the region, and the localization
/// tiles inside it.
BuildJobOutput region_job(const MapStore& store, std::int64_t version, const MapBuildRequest& req,
                          const MapBuilderConfig& cfg, const BuildJob& job) {
  const auto t0 = std::chrono::steady_clock::now();
  const BuildPartition& part = *req.partition;
  const tiles::TileKey region = job.region;
  const tiles::GeoBox box = tiles::tile_bounds(region);
  const tiles::GeoBox query = grow_box(box, part.halo_m);
  const std::int64_t max_row = job.spec.at("max_drive_row").get<std::int64_t>();
  const std::optional<std::int64_t> previous = opt_i64(job.spec, "previous");

  CandidateSet cands = store.candidates_in(query, req.excluded_drive_ids);
  std::erase_if(cands.points, [&](const auto& c) { return c.drive > max_row; });
  std::erase_if(cands.lines, [&](const auto& c) { return c.drive > max_row; });
  const tiles::LocalFrame frame(tiles::tile_center(region));
  auto tp = tagged_points(cands, frame);
  auto tl = tagged_lines(cands, frame);
  MapBuildStats align_stats;  // a region job reports no statistics of its own
  const DriveCorrections corrections =
      align_candidates(store, query, req.excluded_drive_ids, tp, tl, frame, cfg, align_stats);
  std::vector<DrivePass> passes = drive_passes(store, query, req.excluded_drive_ids, tp, tl, frame,
                                               req.visibility, corrections);
  std::erase_if(passes, [&](const DrivePass& p) { return p.drive > max_row; });
  const VisibilityIndex view(std::move(passes), req.visibility);
  PointConsensusResult pc = consensus_points(tp, req.points, &view);
  LineConsensusResult lc = consensus_lines(tl, req.lines, &view);
  (void)filter_line_landmarks(lc, tl, &view, req.lines.filter);
  (void)filter_point_landmarks(pc, lc, tp, &view, req.points.filter);

  std::unordered_map<std::int64_t, SupportVerdict> verdicts;
  BuildJobOutput out;
  for (auto& p : stored_points(pc, frame, std::nullopt, verdicts)) {
    if (tiles::tile_at(p.position.lat_deg, p.position.lon_deg, region.z) == region) {
      out.points.push_back(std::move(p));
    }
  }
  for (const auto& l : stored_lines(lc, frame, std::nullopt, verdicts)) {
    const auto v = verdicts.find(l.key);
    for (auto& piece : clip_polyline(l.polyline, box)) {
      if (polyline_length_m(piece, frame) < part.min_line_piece_m) continue;
      StoredLineLandmark s = l;
      s.polyline = std::move(piece);
      s.key = landmark_key(true, s.polyline);
      if (v != verdicts.end()) verdicts[s.key] = v->second;
      out.lines.push_back(std::move(s));
    }
  }
  if (previous) {
    LandmarkSet before = store.landmarks_in(*previous, box, false);
    std::erase_if(before.points, [&](const StoredPointLandmark& p) {
      return tiles::tile_at(p.position.lat_deg, p.position.lon_deg, region.z) != region;
    });
    std::erase_if(before.lines, [&](const StoredLineLandmark& l) {
      return owner_of_line(l.polyline, region.z) != region;
    });
    out.changes =
        changes_with_reasons(before, out.points, out.lines, verdicts, pc, lc, frame, cfg.diff);
  }

  std::int64_t written = 0, reused = 0, bytes = 0;
  auto content = localization_tile_content(out.points, out.lines, frame, cfg.tile_zoom,
                                           cfg.line_tile_sample_m);
  for (auto& [key, t] : content) {
    if (!inside(key, region)) continue;
    TileWrite w;
    w.key = key;
    w.num_points = static_cast<std::int32_t>(t.points.size());
    w.num_lines = static_cast<std::int32_t>(t.lines.size());
    bool reuse = false;
    if (req.incremental && previous) {
      // Encoded with the previous tile's stamp: equal bytes keep its blob and ETag.
      if (const auto prev = store.get_tile(*previous, TileLayer::Localization, key)) {
        t.map_version = tiles::decode_localization_tile(prev->payload).map_version;
        const std::string b = tiles::encode_localization_tile(t, cfg.encode);
        if (content_etag(b) == prev->etag) {
          w.etag = prev->etag;
          w.reuse_blob = true;
          reuse = true;
          bytes += static_cast<std::int64_t>(b.size());
        }
      }
    }
    if (!reuse) {
      t.map_version = static_cast<std::uint64_t>(version);
      w.payload = tiles::encode_localization_tile(t, cfg.encode);
      w.etag = content_etag(w.payload);
      bytes += static_cast<std::int64_t>(w.payload.size());
    }
    (reuse ? reused : written) += 1;
    out.localization_tiles.push_back(std::move(w));
  }
  std::int64_t added = 0, moved = 0, retired = 0;
  for (const auto& c : out.changes) {
    (c.change == LandmarkChangeKind::Added   ? added
     : c.change == LandmarkChangeKind::Moved ? moved
                                             : retired) += 1;
  }
  std::set<std::int64_t> drives;
  for (const auto& p : cands.points) drives.insert(p.drive);
  for (const auto& l : cands.lines) drives.insert(l.drive);
  out.result = {{"point_candidates", cands.points.size()},
                {"line_candidates", cands.lines.size()},
                {"drives", std::vector<std::int64_t>(drives.begin(), drives.end())},
                {"drives_passing", view.passes().size()},
                {"point_landmarks", out.points.size()},
                {"line_landmarks", out.lines.size()},
                {"tiles_written", written},
                {"tiles_reused", reused},
                {"tile_bytes", bytes},
                {"landmarks_added", added},
                {"landmarks_moved", moved},
                {"landmarks_retired", retired},
                {"point_groups", pc.stats.groups},
                {"line_groups", lc.stats.groups},
                {"seconds", seconds_since(t0)}};
  return out;
}

nlohmann::json gridmap_job(MapStore& store, std::int64_t version, const MapBuildRequest& req,
                           const MapBuilderConfig& cfg, const BuildJob& job,
                           const std::function<void()>& tick) {
  const auto t0 = std::chrono::steady_clock::now();
  MapBuildStats st;
  const nlohmann::json info = build_gridmap(store, version, req, cfg, store.list_drives(),
                                            opt_i64(job.spec, "previous"), st, tick);
  return {{"gridmap", info},
          {"gridmap_tiles", st.gridmap_tiles},
          {"gridmap_drives", st.gridmap_drives},
          {"gridmap_drives_added", st.gridmap_drives_added},
          {"gridmap_drives_removed", st.gridmap_drives_removed},
          {"gridmap_sum_tiles_written", st.gridmap_sum_tiles_written},
          {"gridmap_regions_rendered", st.gridmap_regions_rendered},
          {"gridmap_tiles_copied", st.gridmap_tiles_copied},
          {"seconds", seconds_since(t0)}};
}

/// The publish job: the version's statistics from its jobs' results, then publish (which
/// also marks this job done, in the same transaction).
void publish_job(MapStore& store, std::int64_t version, const MapBuildRequest& req,
                 const BuildJob& job) {
  const std::optional<std::int64_t> previous = opt_i64(job.spec, "previous");
  MapBuildStats st;
  nlohmann::json gridmap_info;
  std::set<std::int64_t> drives;
  std::int64_t regions = 0;
  double job_seconds = 0.0;
  for (const BuildJob& j : store.build_jobs(version)) {
    const nlohmann::json& r = j.result;
    if (!r.is_object()) continue;
    job_seconds += r.value("seconds", 0.0);
    if (j.kind == "region") {
      ++regions;
      st.point_candidates += r.value("point_candidates", std::int64_t{0});
      st.line_candidates += r.value("line_candidates", std::int64_t{0});
      st.point_landmarks += r.value("point_landmarks", std::int64_t{0});
      st.line_landmarks += r.value("line_landmarks", std::int64_t{0});
      st.tiles_written += r.value("tiles_written", std::int64_t{0});
      st.tiles_reused += r.value("tiles_reused", std::int64_t{0});
      st.tile_bytes += r.value("tile_bytes", std::int64_t{0});
      st.landmarks_added += r.value("landmarks_added", std::int64_t{0});
      st.landmarks_moved += r.value("landmarks_moved", std::int64_t{0});
      st.landmarks_retired += r.value("landmarks_retired", std::int64_t{0});
      st.drives_passing = std::max(st.drives_passing, r.value("drives_passing", std::int64_t{0}));
      for (const auto& d : r.value("drives", nlohmann::json::array()))
        drives.insert(d.get<std::int64_t>());
    } else if (j.kind == "gridmap") {
      gridmap_info = r.value("gridmap", nlohmann::json());
      st.gridmap_tiles = r.value("gridmap_tiles", std::int64_t{0});
      st.gridmap_drives = r.value("gridmap_drives", std::int64_t{0});
      st.gridmap_drives_added = r.value("gridmap_drives_added", std::int64_t{0});
      st.gridmap_drives_removed = r.value("gridmap_drives_removed", std::int64_t{0});
      st.gridmap_sum_tiles_written = r.value("gridmap_sum_tiles_written", std::int64_t{0});
      st.gridmap_regions_rendered = r.value("gridmap_regions_rendered", std::int64_t{0});
      st.gridmap_tiles_copied = r.value("gridmap_tiles_copied", std::int64_t{0});
      st.seconds_gridmap = r.value("seconds", 0.0);
    }
  }
  st.drives_used = static_cast<std::int64_t>(drives.size());
  std::int64_t regions_carried = 0;
  if (job.spec.contains("carried") && previous) {
    // Regions copied from the previous version: their landmarks and tiles, and the drives
    // the previous version used (a new drive can only be in a rebuilt region).
    const nlohmann::json& c = job.spec["carried"];
    regions_carried = c.value("regions", std::int64_t{0});
    st.point_landmarks += c.value("point_landmarks", std::int64_t{0});
    st.line_landmarks += c.value("line_landmarks", std::int64_t{0});
    st.tiles_reused += c.value("tiles", std::int64_t{0});
    st.landmarks_copied =
        c.value("point_landmarks", std::int64_t{0}) + c.value("line_landmarks", std::int64_t{0});
    st.incremental_from = previous;
    const auto before = store.get_map_version(*previous);
    if (before) {
      std::set<std::int64_t> rows;
      for (const auto& r : before->statistics.value("drive_rows", nlohmann::json::array()))
        rows.insert(r.get<std::int64_t>());
      std::int64_t new_drives = 0;
      for (const std::int64_t d : drives) new_drives += rows.contains(d) ? 0 : 1;
      st.drives_used = before->statistics.value("drives_used", std::int64_t{0}) + new_drives;
    }
  }
  std::set<tiles::TileKey> now;
  for (const auto& t : store.list_tiles(version, TileLayer::Localization)) now.insert(t.key);
  st.tiles_total = static_cast<std::int64_t>(now.size());
  if (previous) {
    st.previous_version = previous;
    st.changes_against = previous;
    for (const auto& t : store.list_tiles(*previous, TileLayer::Localization)) {
      if (!now.contains(t.key)) ++st.tiles_removed;
    }
  }
  nlohmann::json stats = to_json(st);
  stats["drive_rows"] = job.spec.value("drive_rows", nlohmann::json::array());
  stats["gridmap"] = gridmap_info;
  stats["partition"] = {
      {"regions", regions}, {"regions_carried", regions_carried}, {"job_seconds", job_seconds}};
  store.publish_map_version(version, stats, req.make_current);
}

}  // namespace

MapBuildResult run_partitioned(MapStore& store, std::int64_t version, const MapBuildRequest& req,
                               const MapBuilderConfig& /*cfg*/, const BuildControl& ctl) {
  MapBuildResult result;
  result.version = version;
  const auto t0 = std::chrono::steady_clock::now();
  try {
    if (ctl.progress) ctl.progress("plan", 0.0);
    const std::optional<std::int64_t> current = store.current_map_version();
    const std::vector<DriveRecord> all = store.list_drives();
    const std::vector<std::int64_t> rows = drive_rows(all, req.excluded_drive_ids);
    std::vector<DriveRecord> included;
    for (const auto& d : all) {
      if (std::binary_search(rows.begin(), rows.end(), d.row)) included.push_back(d);
    }
    const nlohmann::json base = {
        {"previous", current ? nlohmann::json(*current) : nlohmann::json()},
        {"max_drive_row", rows.empty() ? 0 : rows.back()}};
    // Incremental (the one-process build's plan, incremental_plan): only regions whose
    // halo meets the area the new drives can change are rebuilt; the others are copied
    // from the current version now, before any job runs (so a retried job never copies
    // twice, and a planner that dies leaves a version the abandoned-build check fails).
    const auto self = store.get_map_version(version);
    if (!self) throw NotFoundError("map version " + std::to_string(version) + " was deleted");
    const std::optional<IncrementalPlan> inc =
        current
            ? incremental_plan(store, req, self->parameters, *current, all, consensus_margin_m(req))
            : std::nullopt;
    std::set<tiles::TileKey> rebuilt;
    std::int64_t carried_regions = 0;
    for (const auto& k : plan_regions(store, included, *req.partition)) {
      if (inc && !inc->area.intersects(grow_box(tiles::tile_bounds(k), req.partition->halo_m))) {
        ++carried_regions;
      } else {
        rebuilt.insert(k);
      }
    }
    std::vector<BuildJobSpec> jobs;
    // The gridmap job first: it is the longest, and runs beside the regions.
    if (req.build_gridmap) jobs.push_back({"gridmap", {0, 0, 0}, base});
    for (const auto& k : rebuilt) jobs.push_back({"region", k, base});
    nlohmann::json pub = base;
    pub["drive_rows"] = rows;
    if (inc) {
      if (ctl.progress) ctl.progress("carry", 0.0);
      const Carried c = carry_regions(store, *current, version, rebuilt, carried_regions);
      pub["carried"] = {{"regions", c.regions},
                        {"point_landmarks", c.points},
                        {"line_landmarks", c.lines},
                        {"tiles", c.tiles}};
    }
    jobs.push_back({"publish", {0, 0, 0}, pub});
    store.enqueue_build_jobs(version, jobs);

    const BuildWorker worker;
    for (;;) {
      if (ctl.cancel && ctl.cancel->load()) {
        store.fail_map_version(version, "cancelled");
        result.status = MapBuildResult::Status::Cancelled;
        result.error = "cancelled";
        return result;
      }
      const auto info = store.get_map_version(version);
      if (!info) throw NotFoundError("map version " + std::to_string(version) + " was deleted");
      if (info->status == MapVersionStatus::Published) {
        const nlohmann::json& s = info->statistics;
        auto& st = result.stats;
        st.point_landmarks = s.value("point_landmarks", std::int64_t{0});
        st.line_landmarks = s.value("line_landmarks", std::int64_t{0});
        st.tiles_total = s.value("tiles_total", std::int64_t{0});
        st.tiles_written = s.value("tiles_written", std::int64_t{0});
        st.tiles_reused = s.value("tiles_reused", std::int64_t{0});
        st.tile_bytes = s.value("tile_bytes", std::int64_t{0});
        st.gridmap_tiles = s.value("gridmap_tiles", std::int64_t{0});
        st.drives_used = s.value("drives_used", std::int64_t{0});
        st.landmarks_copied = s.value("landmarks_copied", std::int64_t{0});
        if (s.contains("incremental_from") && s["incremental_from"].is_number_integer()) {
          st.incremental_from = s["incremental_from"].get<std::int64_t>();
        }
        st.previous_version = current;
        st.seconds_total = seconds_since(t0);
        result.status = MapBuildResult::Status::Published;
        if (ctl.progress) ctl.progress("publish", 1.0);
        return result;
      }
      if (info->status == MapVersionStatus::Failed) {
        result.status = MapBuildResult::Status::Failed;
        result.error = info->error;
        return result;
      }
      if (ctl.progress) {
        const auto js = store.build_jobs(version);
        const auto done = std::count_if(
            js.begin(), js.end(), [](const BuildJob& j) { return j.state == BuildJobState::Done; });
        ctl.progress("jobs", js.empty() ? 0.0 : static_cast<double>(done) / js.size());
      }
      const bool idle =
          !ctl.run_jobs || worker.run_one(store, version).status == BuildJobRun::Status::Idle;
      if (idle) {
        std::this_thread::sleep_for(std::chrono::duration<double>(ctl.poll_interval_s));
      }
    }
  } catch (const std::exception& e) {
    result.status = MapBuildResult::Status::Failed;
    result.error = e.what();
    try {
      const auto info = store.get_map_version(version);
      if (info && info->status == MapVersionStatus::Building)
        store.fail_map_version(version, e.what());
    } catch (const std::exception&) {  // reported through result.error already
    }
  }
  return result;
}

}  // namespace detail

std::string_view to_string(BuildJobRun::Status s) {
  switch (s) {
    case BuildJobRun::Status::Done:
      return "done";
    case BuildJobRun::Status::Lost:
      return "lost";
    case BuildJobRun::Status::Failed:
      return "failed";
    default:
      return "idle";
  }
}

BuildWorker::BuildWorker(BuildWorkerConfig cfg) : cfg_(std::move(cfg)) {
  POLMAP_EXPECT(cfg_.lease_s > 0.0 && cfg_.renew_interval_s > 0.0 &&
                cfg_.renew_interval_s < cfg_.lease_s);
  if (cfg_.worker_id.empty()) {
    char host[256] = {};
    ::gethostname(host, sizeof host - 1);
    cfg_.worker_id = std::string(host) + ":" + std::to_string(::getpid());
  }
}

BuildJobRun BuildWorker::run_one(MapStore& store, std::optional<std::int64_t> version) const {
  BuildJobRun run;
  const std::optional<BuildJob> job = store.claim_build_job(cfg_.worker_id, cfg_.lease_s, version);
  if (!job) return run;
  const auto t0 = std::chrono::steady_clock::now();
  run.job = job->id;
  run.version = job->version;
  run.kind = job->kind;
  run.region = job->region;
  run.attempt = job->attempt;

  // The lease is renewed beside the job; a refused renewal means another worker owns it.
  std::atomic<bool> lost{false};
  std::mutex mu;
  std::condition_variable cv;
  bool finished = false;
  std::thread heartbeat([&] {
    std::unique_lock lock(mu);
    while (!cv.wait_for(lock, std::chrono::duration<double>(cfg_.renew_interval_s),
                        [&] { return finished; })) {
      lock.unlock();
      bool ok = false;
      try {
        ok = store.renew_build_job(job->id, job->attempt, cfg_.lease_s);
      } catch (const std::exception&) {  // the database is away: the lease may still hold
        ok = true;
      }
      if (!ok) lost = true;
      lock.lock();
    }
  });
  auto stop_heartbeat = [&] {
    {
      std::lock_guard lock(mu);
      finished = true;
    }
    cv.notify_all();
    if (heartbeat.joinable()) heartbeat.join();
  };
  try {
    const auto info = store.get_map_version(job->version);
    if (!info) throw NotFoundError("map version " + std::to_string(job->version) + " is gone");
    const MapBuildRequest req = detail::request_from_json(info->parameters);
    if (!req.partition) throw ValidationError("map version parameters: no partition");
    const MapBuilderConfig cfg = detail::config_of(info->parameters);
    bool committed = true;
    if (job->kind == "region") {
      const BuildJobOutput out = detail::region_job(store, job->version, req, cfg, *job);
      if (cfg_.hold_before_commit_s > 0.0) {
        std::this_thread::sleep_for(std::chrono::duration<double>(cfg_.hold_before_commit_s));
      }
      if (lost) throw detail::LeaseLost{};
      committed = store.complete_build_job(job->id, job->attempt, out);
    } else if (job->kind == "gridmap") {
      BuildJobOutput out;
      out.result = detail::gridmap_job(store, job->version, req, cfg, *job, [&] {
        if (lost) throw detail::LeaseLost{};
      });
      committed = store.complete_build_job(job->id, job->attempt, out);
    } else {
      if (lost) throw detail::LeaseLost{};
      detail::publish_job(store, job->version, req, *job);
    }
    run.status = committed ? BuildJobRun::Status::Done : BuildJobRun::Status::Lost;
  } catch (const detail::LeaseLost&) {
    run.status = BuildJobRun::Status::Lost;
  } catch (const std::exception& e) {
    // A lost lease explains a failure (a publish that found the version published by the
    // worker that took over); otherwise the job, and so the build, failed.
    std::optional<MapVersionInfo> info;
    try {
      info = store.get_map_version(job->version);
    } catch (const std::exception&) {
    }
    if (lost || (info && info->status != MapVersionStatus::Building)) {
      run.status = BuildJobRun::Status::Lost;
    } else {
      run.status = BuildJobRun::Status::Failed;
      run.error = job->kind + " job " + std::to_string(job->id) +
                  (job->kind == "region" ? " (region " + tiles::to_string(job->region) + ")" : "") +
                  " failed: " + e.what();
      try {
        if (store.fail_build_job(job->id, job->attempt, e.what())) {
          store.fail_map_version(job->version, run.error);
        }
      } catch (const std::exception&) {  // the lease expires and another worker retries
      }
    }
  }
  stop_heartbeat();
  run.seconds = detail::seconds_since(t0);
  return run;
}

}  // namespace polmap::mapping
