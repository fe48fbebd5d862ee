// SqliteMapStore: HD-map comparisons per map version (hdmap_comparisons) and a landmark's
// provenance (its supporting drives and its history along landmark_changes).
#include "sqlite_store_impl.hpp"

namespace polmap::mapping {

namespace {

void check_name(std::string_view name) {
  if (!is_valid_hdmap_comparison_name(name)) {
    throw ValidationError("HD-map comparison name '" + std::string(name) +
                          "' must be 1..64 characters of [A-Za-z0-9._-], not starting with '.'");
  }
}

nlohmann::json parse_json_column(const std::string& text) {
  nlohmann::json j = nlohmann::json::parse(text, nullptr, false);
  return j.is_discarded() ? nlohmann::json(nullptr) : j;
}

}  // namespace

void SqliteMapStore::put_hdmap_comparison(const HdMapComparisonRecord& r) {
  check_name(r.name);
  impl_->write([&](Connection& c) {
    Impl::require_published(c, r.version);
    c.stmt(
         "INSERT OR REPLACE INTO hdmap_comparisons(version, name, hdmap_file, created_at, "
         "summary_json, features_json) VALUES (?1, ?2, ?3, ?4, ?5, ?6)")
        .bind(1, r.version)
        .bind(2, r.name)
        .bind(3, r.hdmap_file)
        .bind(4, now_iso())
        .bind(5, r.summary.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace))
        .bind(6, r.features.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace))
        .run();
  });
}

std::vector<HdMapComparisonRecord> SqliteMapStore::list_hdmap_comparisons(
    std::int64_t version) const {
  return impl_->read([&](Connection& c) {
    Impl::require_published(c, version);
    std::vector<HdMapComparisonRecord> out;
    auto s = c.stmt(
        "SELECT name, hdmap_file, created_at, summary_json FROM hdmap_comparisons WHERE version "
        "= ?1 ORDER BY name");
    s.bind(1, version);
    while (s.step()) {
      out.push_back(
          {version, s.text(0), s.text(1), s.text(2), parse_json_column(s.text(3)), nullptr});
    }
    return out;
  });
}

std::optional<HdMapComparisonRecord> SqliteMapStore::get_hdmap_comparison(
    std::int64_t version, std::string_view name) const {
  return impl_->read([&](Connection& c) -> std::optional<HdMapComparisonRecord> {
    Impl::require_published(c, version);
    auto s = c.stmt(
        "SELECT name, hdmap_file, created_at, summary_json, features_json FROM hdmap_comparisons "
        "WHERE version = ?1 AND name = ?2");
    s.bind(1, version).bind(2, name);
    if (!s.step()) return std::nullopt;
    return HdMapComparisonRecord{version,
                                 s.text(0),
                                 s.text(1),
                                 s.text(2),
                                 parse_json_column(s.text(3)),
                                 parse_json_column(s.text(4))};
  });
}

std::optional<LandmarkDetail> SqliteMapStore::landmark_detail(std::int64_t version,
                                                              std::int64_t key) const {
  return impl_->read([&](Connection& c) -> std::optional<LandmarkDetail> {
    Impl::require_published(c, version);
    LandmarkDetail d;
    std::int64_t links = 0;
    {
      auto s = c.stmt(
          "SELECT kind, lat_deg, lon_deg, polyline_json, scattering, support_drives, spread_m, "
          "COALESCE(support_of, id) FROM landmarks WHERE key = ?1 AND version = ?2 ORDER BY id "
          "LIMIT 1");
      s.bind(1, key).bind(2, version);
      if (!s.step()) return std::nullopt;
      d.version = version;
      d.key = key;
      d.is_line = s.i64(0) != 0;
      if (d.is_line) {
        for (const auto& v : nlohmann::json::parse(s.text(3))) {
          d.geometry.push_back({v.at(0).get<double>(), v.at(1).get<double>(), 0.0});
        }
      } else {
        d.geometry.push_back({s.f64(1), s.f64(2), 0.0});
        d.scattering = static_cast<ScatteringClass>(s.i64(4) & 3);
      }
      d.support_drives = static_cast<std::uint32_t>(s.i64(5));
      d.spread_m = s.f64(6);
      links = s.i64(7);  // a copied landmark's links are its source's
    }
    {
      auto s = c.stmt(
          "SELECT d.drive_id, d.vehicle_id, d.start_time_s, d.end_time_s, d.ingested_at, "
          "COUNT(*) FROM landmark_support ls JOIN candidates ca ON ca.id = ls.candidate JOIN "
          "drives d ON d.id = ca.drive WHERE ls.landmark = ?1 GROUP BY d.id ORDER BY "
          "d.start_time_s, d.drive_id");
      s.bind(1, links);
      while (s.step()) {
        d.drives.push_back({s.text(0), s.text(1), s.f64(2), s.f64(3), s.text(4), s.i64(5)});
      }
    }
    const auto latest = [&](std::int64_t k,
                            std::int64_t upto) -> std::optional<LandmarkHistoryEntry> {
      auto s = c.stmt(
          "SELECT lc.version, m.published_at, lc.change, lc.kind, lc.previous_key, "
          "lc.distance_m, lc.geometry_json, lc.previous_geometry_json, lc.reason_json FROM "
          "landmark_changes lc JOIN map_versions m ON m.version = lc.version WHERE lc.key = ?1 "
          "AND lc.version <= ?2 AND m.status = 'published' ORDER BY lc.version DESC, lc.seq DESC "
          "LIMIT 1");
      s.bind(1, k).bind(2, upto);
      if (!s.step()) return std::nullopt;
      LandmarkHistoryEntry e;
      e.version = s.i64(0);
      e.published_at = s.is_null(1) ? std::string() : s.text(1);
      e.change.change = parse_landmark_change_kind(s.text(2)).value_or(LandmarkChangeKind::Added);
      e.change.is_line = s.i64(3) != 0;
      e.change.key = k;
      e.change.previous_key = s.i64(4);
      e.change.distance_m = s.f64(5);
      e.change.geometry = geometry_from_json(parse_json_column(s.text(6)));
      e.change.previous_geometry = geometry_from_json(parse_json_column(s.text(7)));
      e.change.reason = parse_json_column(s.text(8));
      return e;
    };
    const auto first_version =
        [&](std::int64_t k,
            std::int64_t upto) -> std::optional<std::pair<std::int64_t, std::string>> {
      auto s = c.stmt(
          "SELECT l.version, m.published_at FROM landmarks l JOIN map_versions m ON m.version = "
          "l.version WHERE l.key = ?1 AND l.version <= ?2 AND m.status = 'published' ORDER BY "
          "l.version LIMIT 1");
      s.bind(1, k).bind(2, upto);
      if (!s.step()) return std::nullopt;
      return std::pair{s.i64(0), s.is_null(1) ? std::string() : s.text(1)};
    };
    d.history = walk_landmark_history(key, version, d.is_line, latest, first_version);
    return d;
  });
}

}  // namespace polmap::mapping
