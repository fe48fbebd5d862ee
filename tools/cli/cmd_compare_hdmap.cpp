// `polmap compare-hdmap --db FILE --hdmap FILE.osm [--json] [--version V] [--radius M]
//  [--band M] [--no-overlap] [--store [--name NAME]]`: compares a published radar landmark
// map with a Lanelet2 HD map (mapping_service/hdmap_compare.hpp): point precision/recall/
// median offset against signs, lights and poles; line lateral offset and coverage against
// curbs, road borders, walls, fences and guard rails. --store keeps the result with the map
// version (summary and per-feature GeoJSON; GET /v1/maps/{v}/hdmap-comparison/{name}, the
// console's HD-map overlay); printing only is the default, so a read-only look never
// writes to the store.
#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include "command.hpp"
#include "map_db.hpp"
#include "polmap/mapping_service/hdmap_compare.hpp"
#include "polmap/mapping_service/open_store.hpp"

namespace polmap::cli {
namespace {

struct CompareOptions {
  std::string db;
  std::string hdmap;
  std::int64_t version = 0;
  bool json = false;
  bool no_overlap = false;
  bool store = false;
  std::string name;  ///< stored comparison's name (default: the HD map file's stem)
  mapping::HdMapCompareConfig cfg;
};

std::string fmt(const std::optional<double>& v, const char* spec, double scale = 1.0) {
  if (!v) return "n/a";
  char buf[64];
  std::snprintf(buf, sizeof(buf), spec, *v * scale);
  return buf;
}

/// The file stem with characters outside [A-Za-z0-9._-] replaced by '_' (a valid name).
std::string default_name(const std::string& file) {
  std::string n = std::filesystem::path(file).stem().string();
  for (char& ch : n) {
    const bool ok = (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') ||
                    (ch >= '0' && ch <= '9') || ch == '.' || ch == '_' || ch == '-';
    if (!ok) ch = '_';
  }
  if (n.empty() || n.front() == '.') n = "hdmap" + n;
  return n.substr(0, 64);
}

void run(CompareOptions o) {
  require_map_db(o.db);
  if (o.store) {
    if (o.name.empty()) o.name = default_name(o.hdmap);
    if (!mapping::is_valid_hdmap_comparison_name(o.name)) {
      throw ValidationError("--name '" + o.name +
                            "' must be 1..64 characters of [A-Za-z0-9._-], not starting with '.'");
    }
  }
  const mapping::HdMap hd = mapping::read_lanelet2_osm(o.hdmap);
  const auto opened = mapping::open_map_store(o.db);
  mapping::MapStore& store = *opened;
  const std::int64_t version = map_version_or_current(store, o.db, o.version);
  o.cfg.restrict_to_overlap = !o.no_overlap;
  // Landmarks near the HD map only (its box grown by the evaluation margin).
  std::optional<mapping::GeoBox> box = mapping::hdmap_bounds(hd);
  if (box && o.cfg.restrict_to_overlap) {
    const double dlat = (o.cfg.overlap_margin_m + 1.0) / 111'000.0;
    const double mid_lat = 0.5 * (box->min_lat_deg + box->max_lat_deg) * M_PI / 180.0;
    const double dlon = dlat / std::max(0.05, std::cos(mid_lat));
    box->min_lat_deg -= dlat;
    box->max_lat_deg += dlat;
    box->min_lon_deg -= dlon;
    box->max_lon_deg += dlon;
  } else {
    box.reset();
  }
  const mapping::LandmarkSet lm = store.landmarks_in(version, box, /*with_support=*/false);
  const mapping::HdMapComparison r = mapping::compare_with_hdmap(lm, hd, o.cfg);
  auto j = mapping::to_json(r);
  j["map_version"] = version;
  j["hdmap"] = o.hdmap;
  j["hdmap_point_features"] = hd.points.size();
  j["hdmap_line_features"] = hd.lines.size();
  j["point_match_radius_m"] = o.cfg.point_match_radius_m;
  j["line_band_m"] = o.cfg.line_band_m;
  j["line_sample_step_m"] = o.cfg.line_sample_step_m;
  j["restrict_to_overlap"] = o.cfg.restrict_to_overlap;
  if (o.store) {
    mapping::HdMapComparisonRecord rec;
    rec.version = version;
    rec.name = o.name;
    rec.hdmap_file = o.hdmap;
    rec.summary = j;
    rec.features = mapping::hdmap_comparison_geojson(lm, hd, r);
    rec.features["properties"]["summary"] = j;
    store.put_hdmap_comparison(rec);
    j["stored_as"] = o.name;
  }
  if (o.json) {
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  std::printf(
      "map version %lld vs %s (%zu point features, %zu line features; %s)\n",
      static_cast<long long>(version), o.hdmap.c_str(), hd.points.size(), hd.lines.size(),
      o.cfg.restrict_to_overlap ? "evaluated where both maps exist" : "evaluated everywhere");
  std::printf(
      "points: %zu of %zu map points matched %zu HD points within %.2f m: precision %s, "
      "recall %s, median offset %s m\n",
      r.matched_points, r.map_points, r.hd_points, o.cfg.point_match_radius_m,
      fmt(r.point_precision, "%.3f").c_str(), fmt(r.point_recall, "%.3f").c_str(),
      fmt(r.point_median_offset_m, "%.3f").c_str());
  std::printf(
      "lines: median lateral offset %s m (%zu of %zu samples within %.2f m of an HD line); "
      "covered %.1f m of %.1f m HD line length (%s %%)\n",
      fmt(r.line_median_lateral_offset_m, "%.3f").c_str(), r.matched_line_samples,
      r.map_line_samples, o.cfg.line_band_m, r.line_covered_length_m, r.line_total_length_m,
      fmt(r.line_coverage, "%.1f", 100.0).c_str());
  if (o.store) {
    std::printf("stored as '%s' with map version %lld (GET /v1/maps/%lld/hdmap-comparison/%s)\n",
                o.name.c_str(), static_cast<long long>(version), static_cast<long long>(version),
                o.name.c_str());
  }
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<CompareOptions>();
  CLI::App* cmd = app.add_subcommand(
      "compare-hdmap", "Compare a map version's landmarks with a Lanelet2 HD map (.osm)");
  cmd->add_option(
         "--db", opts->db,
         "Map store: a SQLite database file, or a PostgreSQL URL (postgresql://USER@HOST:PORT/DB)")
      ->required();
  cmd->add_option("--hdmap", opts->hdmap, "Lanelet2 OSM file")->required();
  cmd->add_option("--version", opts->version, "Published map version (default: current)")
      ->check(CLI::PositiveNumber);
  cmd->add_flag("--json", opts->json, "Print the metrics as JSON");
  cmd->add_option("--radius", opts->cfg.point_match_radius_m,
                  "Point match radius, metres (default 1.0)")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--band", opts->cfg.line_band_m,
                  "Lateral band for line offsets and coverage, metres (default 1.0)")
      ->check(CLI::PositiveNumber);
  cmd->add_flag("--no-overlap", opts->no_overlap,
                "Count all features, not only where both maps exist");
  cmd->add_flag("--store", opts->store,
                "Store the result (metrics and per-feature GeoJSON) with the map version, "
                "replacing a stored comparison of the same name");
  cmd->add_option("--name", opts->name,
                  "Name of the stored comparison (default: the HD map file's stem)");
  cmd->callback([opts] { run(*opts); });
}

}  // namespace
POLMAP_REGISTER_COMMAND(compare_hdmap, setup);
}  // namespace polmap::cli
