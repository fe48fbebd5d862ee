// Summary, quality cells and GeoJSON of localization run reports (localization_runs.hpp).
#include "polmap/mapping_service/localization_runs.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>

#include "polmap/schema/errors.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace polmap::mapping {
namespace {

using json = nlohmann::json;
constexpr double kDeg = std::numbers::pi / 180.0;

json optional_number(bool has, double v) { return has ? json(v) : json(nullptr); }

bool on_map(RunStatus s) { return s != RunStatus::Initializing; }

}  // namespace

double lateral_sigma_m(const LocalizationRunSample& s) {
  // n = unit vector across the heading (left); var = nᵀ C n.
  const double yaw = s.yaw_enu_deg * kDeg;
  const double nx = -std::sin(yaw), ny = std::cos(yaw);
  const double var = nx * nx * s.cov_xx_m2 + 2.0 * nx * ny * s.cov_xy_m2 + ny * ny * s.cov_yy_m2;
  return std::sqrt(std::max(var, 0.0));
}

std::vector<double> run_distances_m(const LocalizationRun& run) {
  std::vector<double> d(run.samples.size(), 0.0);
  if (run.samples.empty()) return d;
  const auto& s0 = run.samples.front();
  const tiles::LocalFrame frame(GeoPoint{s0.lat_deg, s0.lon_deg, 0.0});
  Eigen::Vector2d prev = frame.to_local(s0.lat_deg, s0.lon_deg);
  for (std::size_t i = 1; i < run.samples.size(); ++i) {
    const Eigen::Vector2d p = frame.to_local(run.samples[i].lat_deg, run.samples[i].lon_deg);
    d[i] = d[i - 1] + (p - prev).norm();
    prev = p;
  }
  return d;
}

LocalizationRunRecord run_record(const LocalizationRun& run, const std::string& vehicle_id) {
  POLMAP_EXPECT(run.samples.size() >= 2);
  LocalizationRunRecord r;
  r.vehicle_id = vehicle_id;
  r.map_version = run.map_version;
  r.label = run.label;
  r.samples = static_cast<std::int64_t>(run.samples.size());
  r.bounds = GeoBox{90, 180, -90, -180};
  std::array<std::int64_t, kRunStatusCount> status_n{};
  double sigma_sum = 0.0, lat2 = 0.0, long2 = 0.0, rot2 = 0.0, lat_max = 0.0;
  std::int64_t on_map_n = 0;
  std::vector<double> abs_lat;
  double t_tracking = -1.0;
  for (const LocalizationRunSample& s : run.samples) {
    r.bounds.min_lat_deg = std::min(r.bounds.min_lat_deg, s.lat_deg);
    r.bounds.max_lat_deg = std::max(r.bounds.max_lat_deg, s.lat_deg);
    r.bounds.min_lon_deg = std::min(r.bounds.min_lon_deg, s.lon_deg);
    r.bounds.max_lon_deg = std::max(r.bounds.max_lon_deg, s.lon_deg);
    ++status_n[static_cast<std::size_t>(s.status)];
    if (t_tracking < 0 && s.status == RunStatus::Tracking) {
      t_tracking = s.t_s - run.samples.front().t_s;
    }
    if (on_map(s.status)) {
      sigma_sum += lateral_sigma_m(s);
      ++on_map_n;
    }
    if (s.error) {
      lat2 += s.error->lat_m * s.error->lat_m;
      long2 += s.error->long_m * s.error->long_m;
      rot2 += s.error->rot_deg * s.error->rot_deg;
      lat_max = std::max(lat_max, std::abs(s.error->lat_m));
      abs_lat.push_back(std::abs(s.error->lat_m));
    }
  }
  const double n = static_cast<double>(run.samples.size());
  json share = json::object();
  for (int i = 0; i < kRunStatusCount; ++i) {
    share[std::string(to_string(static_cast<RunStatus>(i)))] =
        static_cast<double>(status_n[static_cast<std::size_t>(i)]) / n;
  }
  const auto ne = static_cast<double>(abs_lat.size());
  const bool has = !abs_lat.empty();
  double p95 = 0.0;
  if (has) {
    // Nearest-rank 95th percentile.
    const auto k = static_cast<std::size_t>(std::ceil(0.95 * ne)) - 1;
    std::nth_element(abs_lat.begin(), abs_lat.begin() + static_cast<std::ptrdiff_t>(k),
                     abs_lat.end());
    p95 = abs_lat[k];
  }
  const auto dist = run_distances_m(run);
  r.summary =
      json{{"samples", r.samples},
           {"duration_s", run.samples.back().t_s - run.samples.front().t_s},
           {"length_m", dist.back()},
           {"status_share", share},
           {"time_to_tracking_s", t_tracking >= 0 ? json(t_tracking) : json(nullptr)},
           {"mean_sigma_lat_m",
            optional_number(on_map_n > 0, sigma_sum / std::max<double>(on_map_n, 1))},
           {"reference", std::string(to_string(run.reference))},
           {"evaluated", abs_lat.size()},
           {"lat_rmse_m", optional_number(has, std::sqrt(lat2 / std::max(ne, 1.0)))},
           {"long_rmse_m", optional_number(has, std::sqrt(long2 / std::max(ne, 1.0)))},
           {"rot_rmse_deg", optional_number(has, std::sqrt(rot2 / std::max(ne, 1.0)))},
           {"lat_max_m", optional_number(has, lat_max)},
           {"lat_p95_m", optional_number(has, p95)},
           {"realtime_factor", run.realtime_factor ? json(*run.realtime_factor) : json(nullptr)},
           {"pol", run.pol}};
  return r;
}

std::vector<LocalizationRunCell> run_cells(const LocalizationRun& run, int z) {
  POLMAP_EXPECT(z >= 0 && z <= tiles::kMaxZoom);
  std::map<std::pair<int, int>, LocalizationRunCell> cells;
  for (const LocalizationRunSample& s : run.samples) {
    if (!on_map(s.status)) continue;
    const tiles::TileKey k = tiles::tile_at(s.lat_deg, s.lon_deg, z);
    LocalizationRunCell& c = cells[{k.x, k.y}];
    c.z = z;
    c.x = k.x;
    c.y = k.y;
    ++c.samples;
    if (s.status == RunStatus::Degraded || s.status == RunStatus::Lost) ++c.degraded;
    c.sum_sigma_lat_m += lateral_sigma_m(s);
    if (s.error) {
      ++c.evaluated;
      c.sum_err_lat2_m2 += s.error->lat_m * s.error->lat_m;
      c.max_abs_err_lat_m = std::max(c.max_abs_err_lat_m, std::abs(s.error->lat_m));
    }
  }
  std::vector<LocalizationRunCell> out;
  out.reserve(cells.size());
  for (auto& [k, c] : cells) {
    c.runs = 1;
    out.push_back(c);
  }
  return out;
}

json run_record_json(const LocalizationRunRecord& r) {
  return json{{"id", r.id},
              {"received_at", r.received_at},
              {"vehicle_id", r.vehicle_id},
              {"map_version", r.map_version},
              {"label", r.label},
              {"samples", r.samples},
              {"bounds",
               {{"min_lat_deg", r.bounds.min_lat_deg},
                {"min_lon_deg", r.bounds.min_lon_deg},
                {"max_lat_deg", r.bounds.max_lat_deg},
                {"max_lon_deg", r.bounds.max_lon_deg}}},
              {"summary", r.summary},
              {"href", "/v1/runs/" + std::to_string(r.id)}};
}

json run_geojson(const LocalizationRun& run, const LocalizationRunRecord& record) {
  const auto dist = run_distances_m(run);
  json features = json::array();
  for (std::size_t i = 1; i < run.samples.size(); ++i) {
    const auto& a = run.samples[i - 1];
    const auto& b = run.samples[i];
    json props{{"i", i},
               {"t_s", b.t_s},
               {"distance_m", dist[i]},
               {"status", std::string(to_string(b.status))},
               {"sigma_lat_m", lateral_sigma_m(b)}};
    props["err_lat_m"] = b.error ? json(b.error->lat_m) : json(nullptr);
    props["err_long_m"] = b.error ? json(b.error->long_m) : json(nullptr);
    props["err_rot_deg"] = b.error ? json(b.error->rot_deg) : json(nullptr);
    props["abs_err_lat_m"] = b.error ? json(std::abs(b.error->lat_m)) : json(nullptr);
    features.push_back(json{{"type", "Feature"},
                            {"geometry",
                             {{"type", "LineString"},
                              {"coordinates", json::array({json::array({a.lon_deg, a.lat_deg}),
                                                           json::array({b.lon_deg, b.lat_deg})})}}},
                            {"properties", std::move(props)}});
  }
  return json{{"type", "FeatureCollection"},
              {"features", std::move(features)},
              {"properties", run_record_json(record)}};
}

json run_cells_geojson(std::span<const LocalizationRunCell> cells, const RunQualityThresholds& t) {
  json features = json::array();
  for (const LocalizationRunCell& c : cells) {
    if (c.samples <= 0) continue;
    const tiles::GeoBox b = tiles::tile_bounds(tiles::TileKey{c.z, c.x, c.y});
    const double n = static_cast<double>(c.samples);
    const double degraded_share = static_cast<double>(c.degraded) / n;
    const double sigma = c.sum_sigma_lat_m / n;
    const bool has_err = c.evaluated > 0;
    const double rmse =
        has_err ? std::sqrt(c.sum_err_lat2_m2 / static_cast<double>(c.evaluated)) : 0.0;
    const bool weak = degraded_share >= t.degraded_share || sigma >= t.mean_sigma_lat_m ||
                      (has_err && rmse >= t.lat_rmse_m);
    json ring = json::array(
        {json::array({b.min_lon_deg, b.min_lat_deg}), json::array({b.max_lon_deg, b.min_lat_deg}),
         json::array({b.max_lon_deg, b.max_lat_deg}), json::array({b.min_lon_deg, b.max_lat_deg}),
         json::array({b.min_lon_deg, b.min_lat_deg})});
    features.push_back(json{
        {"type", "Feature"},
        {"geometry", {{"type", "Polygon"}, {"coordinates", json::array({std::move(ring)})}}},
        {"properties",
         {{"tile", std::to_string(c.z) + "/" + std::to_string(c.x) + "/" + std::to_string(c.y)},
          {"samples", c.samples},
          {"runs", c.runs},
          {"map_version", c.map_version},
          {"degraded_share", degraded_share},
          {"mean_sigma_lat_m", sigma},
          {"evaluated", c.evaluated},
          {"lat_rmse_m", has_err ? json(rmse) : json(nullptr)},
          {"max_abs_err_lat_m", has_err ? json(c.max_abs_err_lat_m) : json(nullptr)},
          {"weak", weak}}}});
  }
  return json{{"type", "FeatureCollection"},
              {"features", std::move(features)},
              {"properties",
               {{"zoom", kRunCellZoom},
                {"thresholds",
                 {{"degraded_share", t.degraded_share},
                  {"lat_rmse_m", t.lat_rmse_m},
                  {"mean_sigma_lat_m", t.mean_sigma_lat_m}}}}}};
}

}  // namespace polmap::mapping
