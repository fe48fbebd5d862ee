// PostgresMapStore: the merged PreCFAR gridmap's sum tiles and their inputs (tables
// gridmap_sums, gridmap_sum_inputs, gridmap_sum_cover; schema/store_postgres.sql).
#include "postgres_store_impl.hpp"

namespace polmap::mapping {

std::vector<GridmapSumInput> PostgresMapStore::gridmap_sum_inputs() const {
  return impl_->read([&](Connection& c) {
    std::vector<GridmapSumInput> out;
    const Result r = c.run(
        "SELECT content_hash, tiles, placement FROM gridmap_sum_inputs ORDER BY "
        "content_hash");
    for (int i = 0; i < r.rows(); ++i) out.push_back({r.text(i, 0), r.i64(i, 1), r.text(i, 2)});
    return out;
  });
}

std::vector<GridmapSumRow> PostgresMapStore::gridmap_sums_in(int x0, int y0, int x1, int y1) const {
  return impl_->read([&](Connection& c) {
    std::vector<GridmapSumRow> out;
    const Result r = c.run(
        "SELECT level, x, y, data, updated_by FROM gridmap_sums WHERE x BETWEEN $1 AND $3 AND y "
        "BETWEEN $2 AND $4 ORDER BY level, x, y",
        x0, y0, x1, y1);
    for (int i = 0; i < r.rows(); ++i) {
      out.push_back({static_cast<int>(r.i64(i, 0)), static_cast<int>(r.i64(i, 1)),
                     static_cast<int>(r.i64(i, 2)), r.bytes(i, 3), r.i64(i, 4)});
    }
    return out;
  });
}

std::vector<GridmapSumRow> PostgresMapStore::gridmap_sum_keys(
    std::optional<std::int64_t> updated_after) const {
  return impl_->read([&](Connection& c) {
    std::vector<GridmapSumRow> out;
    const Result r = c.run(
        "SELECT level, x, y, updated_by FROM gridmap_sums WHERE $1::bigint IS NULL OR "
        "updated_by > $1 ORDER BY level, x, y",
        updated_after);
    for (int i = 0; i < r.rows(); ++i) {
      out.push_back({static_cast<int>(r.i64(i, 0)),
                     static_cast<int>(r.i64(i, 1)),
                     static_cast<int>(r.i64(i, 2)),
                     {},
                     r.i64(i, 3)});
    }
    return out;
  });
}

std::vector<std::array<int, 3>> PostgresMapStore::gridmap_sum_cover(
    std::string_view content_hash) const {
  return impl_->read([&](Connection& c) {
    std::vector<std::array<int, 3>> out;
    const Result r = c.run(
        "SELECT level, x, y FROM gridmap_sum_cover WHERE content_hash = $1 ORDER BY level, x, y",
        content_hash);
    for (int i = 0; i < r.rows(); ++i) {
      out.push_back({static_cast<int>(r.i64(i, 0)), static_cast<int>(r.i64(i, 1)),
                     static_cast<int>(r.i64(i, 2))});
    }
    return out;
  });
}

std::vector<std::string> PostgresMapStore::gridmap_sum_contributors(int level, int x, int y) const {
  return impl_->read([&](Connection& c) {
    std::vector<std::string> out;
    const Result r = c.run(
        "SELECT content_hash FROM gridmap_sum_cover WHERE level = $1 AND x = $2 AND y = $3 "
        "ORDER BY content_hash",
        level, x, y);
    for (int i = 0; i < r.rows(); ++i) out.push_back(r.text(i, 0));
    return out;
  });
}

void PostgresMapStore::commit_gridmap_sums(std::int64_t version,
                                           std::span<const GridmapSumRow> tiles,
                                           const GridmapSumInputChange& change) {
  impl_->write([&](Connection& c) {
    using Kind = GridmapSumInputChange::Kind;
    if (change.kind != Kind::None && change.content_hash.empty()) {
      throw ValidationError("commit_gridmap_sums: an input change needs a content hash");
    }
    if (change.kind == Kind::Add &&
        !c.run("SELECT 1 FROM gridmap_sum_inputs WHERE content_hash = $1", change.content_hash)
             .empty()) {
      throw ConflictError("drive " + change.content_hash +
                          " is already in the merged gridmap (it would count twice)");
    }
    for (const auto& t : tiles) {
      c.run(
          "INSERT INTO gridmap_sums(level, x, y, data, updated_by) VALUES ($1, $2, $3, $4, $5) "
          "ON CONFLICT (level, x, y) DO UPDATE SET data = excluded.data, updated_by = "
          "excluded.updated_by",
          t.level, t.x, t.y, Bytea{t.data}, version);
    }
    if (change.kind == Kind::Add) {
      c.run(
          "INSERT INTO gridmap_sum_inputs(content_hash, tiles, added_at, placement) VALUES ($1, "
          "$2, $3, $4)",
          change.content_hash, static_cast<std::int64_t>(change.cover.size()), now_iso(),
          change.placement);
      std::vector<int> level, x, y;
      for (const auto& k : change.cover) {
        level.push_back(k[0]);
        x.push_back(k[1]);
        y.push_back(k[2]);
      }
      Params p;
      p.add(change.content_hash).add_array(level).add_array(x).add_array(y);
      c.query(
          "INSERT INTO gridmap_sum_cover(content_hash, level, x, y) SELECT $1, u.l, u.x, u.y "
          "FROM unnest($2::int[], $3::int[], $4::int[]) AS u(l, x, y) ON CONFLICT DO NOTHING",
          p);
    } else if (change.kind == Kind::Remove) {
      c.run("DELETE FROM gridmap_sum_inputs WHERE content_hash = $1",
            change.content_hash);  // its cover rows go by cascade
    }
  });
}

}  // namespace polmap::mapping
