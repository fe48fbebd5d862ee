// SqliteMapStore: the merged PreCFAR gridmap's sum tiles and their inputs (tables
// gridmap_sums, gridmap_sum_inputs, gridmap_sum_cover; schema/store.sql, migration 7).
#include "sqlite_store_impl.hpp"

namespace polmap::mapping {

std::vector<GridmapSumInput> SqliteMapStore::gridmap_sum_inputs() const {
  return impl_->read([&](Connection& c) {
    std::vector<GridmapSumInput> out;
    auto s = c.stmt(
        "SELECT content_hash, tiles, placement FROM gridmap_sum_inputs ORDER BY content_hash");
    while (s.step()) out.push_back({s.text(0), s.i64(1), s.text(2)});
    return out;
  });
}

std::vector<GridmapSumRow> SqliteMapStore::gridmap_sums_in(int x0, int y0, int x1, int y1) const {
  return impl_->read([&](Connection& c) {
    std::vector<GridmapSumRow> out;
    // The primary key leads with level: one range scan per level present.
    auto s = c.stmt(
        "SELECT level, x, y, data, updated_by FROM gridmap_sums WHERE level IN (SELECT DISTINCT "
        "level FROM gridmap_sums) AND x BETWEEN ?1 AND ?3 AND y BETWEEN ?2 AND ?4 ORDER BY "
        "level, x, y");
    s.bind(1, x0).bind(2, y0).bind(3, x1).bind(4, y1);
    while (s.step()) {
      out.push_back({static_cast<int>(s.i64(0)), static_cast<int>(s.i64(1)),
                     static_cast<int>(s.i64(2)), s.blob(3), s.i64(4)});
    }
    return out;
  });
}

std::vector<GridmapSumRow> SqliteMapStore::gridmap_sum_keys(
    std::optional<std::int64_t> updated_after) const {
  return impl_->read([&](Connection& c) {
    std::vector<GridmapSumRow> out;
    auto s = c.stmt(
        "SELECT level, x, y, updated_by FROM gridmap_sums WHERE ?1 IS NULL OR updated_by > ?1 "
        "ORDER BY level, x, y");
    if (updated_after) {
      s.bind(1, *updated_after);
    } else {
      s.bind_null(1);
    }
    while (s.step()) {
      out.push_back({static_cast<int>(s.i64(0)),
                     static_cast<int>(s.i64(1)),
                     static_cast<int>(s.i64(2)),
                     {},
                     s.i64(3)});
    }
    return out;
  });
}

std::vector<std::array<int, 3>> SqliteMapStore::gridmap_sum_cover(
    std::string_view content_hash) const {
  return impl_->read([&](Connection& c) {
    std::vector<std::array<int, 3>> out;
    auto s = c.stmt(
        "SELECT level, x, y FROM gridmap_sum_cover WHERE content_hash = ?1 ORDER BY level, x, y");
    s.bind(1, content_hash);
    while (s.step()) {
      out.push_back(
          {static_cast<int>(s.i64(0)), static_cast<int>(s.i64(1)), static_cast<int>(s.i64(2))});
    }
    return out;
  });
}

std::vector<std::string> SqliteMapStore::gridmap_sum_contributors(int level, int x, int y) const {
  return impl_->read([&](Connection& c) {
    std::vector<std::string> out;
    auto s = c.stmt(
        "SELECT content_hash FROM gridmap_sum_cover WHERE level = ?1 AND x = ?2 AND y = ?3 "
        "ORDER BY content_hash");
    s.bind(1, level).bind(2, x).bind(3, y);
    while (s.step()) out.push_back(s.text(0));
    return out;
  });
}

void SqliteMapStore::commit_gridmap_sums(std::int64_t version, std::span<const GridmapSumRow> tiles,
                                         const GridmapSumInputChange& change) {
  impl_->write([&](Connection& c) {
    using Kind = GridmapSumInputChange::Kind;
    if (change.kind != Kind::None && change.content_hash.empty()) {
      throw ValidationError("commit_gridmap_sums: an input change needs a content hash");
    }
    if (change.kind == Kind::Add) {
      auto q = c.stmt("SELECT 1 FROM gridmap_sum_inputs WHERE content_hash = ?1");
      q.bind(1, change.content_hash);
      if (q.step()) {
        throw ConflictError("drive " + change.content_hash +
                            " is already in the merged gridmap (it would count twice)");
      }
    }
    for (const auto& t : tiles) {
      c.stmt(
           "INSERT INTO gridmap_sums(level, x, y, data, updated_by) VALUES (?1, ?2, ?3, ?4, ?5) "
           "ON CONFLICT(level, x, y) DO UPDATE SET data = excluded.data, updated_by = "
           "excluded.updated_by")
          .bind(1, t.level)
          .bind(2, t.x)
          .bind(3, t.y)
          .bind_blob(4, t.data)
          .bind(5, version)
          .run();
    }
    if (change.kind == Kind::Add) {
      c.stmt(
           "INSERT INTO gridmap_sum_inputs(content_hash, tiles, added_at, placement) VALUES (?1, "
           "?2, ?3, ?4)")
          .bind(1, change.content_hash)
          .bind(2, static_cast<std::int64_t>(change.cover.size()))
          .bind(3, now_iso())
          .bind(4, change.placement)
          .run();
      for (const auto& k : change.cover) {
        c.stmt(
             "INSERT OR IGNORE INTO gridmap_sum_cover(content_hash, level, x, y) VALUES (?1, ?2, "
             "?3, ?4)")
            .bind(1, change.content_hash)
            .bind(2, k[0])
            .bind(3, k[1])
            .bind(4, k[2])
            .run();
      }
    } else if (change.kind == Kind::Remove) {
      c.stmt("DELETE FROM gridmap_sum_inputs WHERE content_hash = ?1")
          .bind(1, change.content_hash)
          .run();  // its cover rows go by cascade
    }
  });
}

}  // namespace polmap::mapping
