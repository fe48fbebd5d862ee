// The map build's merged-gridmap stage (gridmap_build.hpp).
#include "gridmap_build.hpp"

#include <filesystem>
#include <fstream>
#include <iterator>

#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/gridmap_sums_codec.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::mapping::detail {
namespace {

/// A stored drive's package as the builder reads it: the manifest.json validated at upload
/// (the canonical copy) says whether there is a gridmap and how it is encoded.
DrivePackage stored_package(const DriveRecord& d) {
  DrivePackage pkg;
  pkg.location = d.package_path;
  const std::filesystem::path mf = std::filesystem::path(d.package_path) / kManifestFileName;
  std::ifstream in(mf, std::ios::binary);
  if (!in) throw IoError(mf.string() + ": cannot open for reading");
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  pkg.manifest = parse_manifest(text);
  return pkg;
}

/// The drive's sum-tile contributions where `placement` puts them, restricted to `only` when
/// it is given.
GridmapSumTiles drive_sums(const DrivePackage& pkg, const DrivePlacement& placement,
                           const std::set<GridmapSumKey>* only) {
  GridmapSumTiles out;
  if (!pkg.manifest.has_gridmap) return out;
  const tiles::LocalFrame frame(pkg.manifest.origin);
  const GridmapWarp warp = placement_warp(placement, frame);
  for_each_gridmap_block(pkg, [&](const GridmapRaster& block) {
    if (only == nullptr) {
      splat_gridmap(block, frame, pkg.manifest.pol_level, out, warp);
      return;
    }
    GridmapSumTiles part;
    splat_gridmap(block, frame, pkg.manifest.pol_level, part, warp);
    for (auto& [k, t] : part) {
      if (!only->contains(k)) continue;
      auto [it, inserted] = out.try_emplace(k, k.level);
      it->second.add(t);
    }
  });
  return out;
}

GridmapSumRow row_of(const GridmapSumKey& k, const GridmapSumTile& t) {
  return {static_cast<int>(k.level), k.x, k.y, encode_gridmap_sum_tile(t), 0};
}

GridmapSumKey key_of(const GridmapSumRow& r) { return {static_cast<PolLevel>(r.level), r.x, r.y}; }

const DrivePlacement kAsUploaded{};

/// The stored placement of every input, decoded (an unreadable one is reported and the drive
/// taken as uploaded: the sums stay usable).
std::map<std::string, DrivePlacement> stored_placements(const MapStore& store,
                                                        std::vector<std::string>& errors) {
  std::map<std::string, DrivePlacement> out;
  for (const auto& in : store.gridmap_sum_inputs()) {
    try {
      out.emplace(in.content_hash,
                  decode_drive_placement(in.placement, "gridmap sum input " + in.content_hash));
    } catch (const ValidationError& e) {
      errors.emplace_back(e.what());
      out.emplace(in.content_hash, DrivePlacement{});
    }
  }
  return out;
}

std::string source_of(const GridmapSumRow& r) {
  return "gridmap sum tile (level " + std::to_string(r.level) + ", z20 " + std::to_string(r.x) +
         "/" + std::to_string(r.y) + ")";
}

}  // namespace

tiles::TileKey sum_tile_ancestor(const GridmapSumKey& key, int zoom) {
  POLMAP_EXPECT(zoom >= 0 && zoom <= kGridmapSumZoom);
  const int shift = kGridmapSumZoom - zoom;
  return {zoom, key.x >> shift, key.y >> shift};
}

GridmapSumTiles recompute_sum_tiles(const MapStore& store, const std::set<GridmapSumKey>& keys,
                                    const std::set<std::string>& without,
                                    std::vector<std::string>& errors,
                                    const std::map<std::string, DrivePlacement>* placements) {
  GridmapSumTiles out;
  std::map<std::string, DrivePlacement> read;
  if (placements == nullptr) {
    read = stored_placements(store, errors);
    placements = &read;
  }
  std::set<std::string> contributors;
  for (const auto& k : keys) {
    out.try_emplace(k, k.level);  // a tile with no remaining contributor is empty
    for (auto& h : store.gridmap_sum_contributors(static_cast<int>(k.level), k.x, k.y)) {
      if (!without.contains(h)) contributors.insert(std::move(h));
    }
  }
  for (const auto& h : contributors) {
    const auto d = store.find_drive_by_hash(h);
    if (!d) continue;  // removed too; its own removal handles it
    try {
      const auto p = placements->find(h);
      const DrivePlacement& as_stored = p == placements->end() ? kAsUploaded : p->second;
      for (auto& [k, t] : drive_sums(stored_package(*d), as_stored, &keys)) out.at(k).add(t);
    } catch (const std::exception& e) {
      errors.push_back(d->drive_id + ": " + e.what());
    }
  }
  return out;
}

GridmapSumsUpdate update_gridmap_sums(MapStore& store, std::int64_t version,
                                      const std::vector<DriveRecord>& drives,
                                      const std::set<std::string>& stored_hashes,
                                      const std::function<void()>& tick,
                                      const GridmapPlacements& placements) {
  GridmapSumsUpdate up;
  std::map<std::string, DrivePlacement> inputs = stored_placements(store, up.errors);
  // Takes input h out: its tiles recomputed from the other inputs, as they were placed.
  auto take_out = [&](const std::string& h) {
    std::set<GridmapSumKey> keys;
    for (const auto& c : store.gridmap_sum_cover(h)) {
      keys.insert({static_cast<PolLevel>(c[0]), c[1], c[2]});
    }
    const GridmapSumTiles fresh = recompute_sum_tiles(store, keys, {h}, up.errors, &inputs);
    std::vector<GridmapSumRow> rows;
    for (const auto& [k, t] : fresh) rows.push_back(row_of(k, t));
    GridmapSumInputChange change;
    change.kind = GridmapSumInputChange::Kind::Remove;
    change.content_hash = h;
    store.commit_gridmap_sums(version, rows, change);
    up.tiles_written += static_cast<std::int64_t>(rows.size());
  };
  // Inputs whose drive was deleted.
  for (auto it = inputs.begin(); it != inputs.end();) {
    if (stored_hashes.contains(it->first)) {
      ++it;
      continue;
    }
    if (tick) tick();
    take_out(it->first);
    ++up.drives_removed;
    it = inputs.erase(it);
  }
  for (const auto& d : drives) {
    const auto placement = placements.by_hash.find(d.content_hash);
    // The placement as the store will keep it (rounded): a later take-out subtracts exactly
    // what goes in now.
    const DrivePlacement place =
        placement == placements.by_hash.end()
            ? DrivePlacement{}
            : decode_drive_placement(encode_drive_placement(placement->second),
                                     "placement of drive " + d.drive_id);
    bool replacing = false;
    if (const auto in = inputs.find(d.content_hash); in != inputs.end()) {
      // Already in: re-placed only when this build aligned it somewhere else.
      if (placement == placements.by_hash.end() ||
          placement_difference_m(in->second, place) <= placements.replace_threshold_m) {
        continue;
      }
      if (tick) tick();
      // Its own contribution subtracted where it went in: the other drives' packages are not
      // read again (recomputing the tiles would cost every overlapping drive's splat).
      try {
        const GridmapSumTiles old = drive_sums(stored_package(d), in->second, nullptr);
        std::vector<GridmapSumRow> rows;
        for (const auto& [k, t] : old) {
          GridmapSumTile now(k.level);
          for (const auto& r : store.gridmap_sums_in(k.x, k.y, k.x, k.y)) {
            if (key_of(r) == k) now = decode_gridmap_sum_tile(r.data, source_of(r));
          }
          now.subtract(t);
          rows.push_back(row_of(k, now));
        }
        GridmapSumInputChange change;
        change.kind = GridmapSumInputChange::Kind::Remove;
        change.content_hash = d.content_hash;
        store.commit_gridmap_sums(version, rows, change);
        up.tiles_written += static_cast<std::int64_t>(rows.size());
      } catch (const std::exception&) {
        take_out(d.content_hash);  // its package unreadable now: recompute without it
      }
      replacing = true;
    }
    if (tick) tick();
    GridmapSumTiles mine;
    try {
      mine = drive_sums(stored_package(d), place, nullptr);
    } catch (const std::exception& e) {
      // A drive without a readable gridmap still contributes its candidates (taken out
      // already when it was being re-placed: the next build adds it again).
      up.errors.push_back(d.drive_id + ": " + e.what());
      if (replacing) inputs.erase(d.content_hash);
      continue;
    }
    GridmapSumInputChange change;
    change.kind = GridmapSumInputChange::Kind::Add;
    change.content_hash = d.content_hash;
    change.placement = encode_drive_placement(place);
    std::vector<GridmapSumRow> rows;
    for (auto& [k, t] : mine) {
      change.cover.push_back({static_cast<int>(k.level), k.x, k.y});
      for (const auto& old : store.gridmap_sums_in(k.x, k.y, k.x, k.y)) {
        if (key_of(old) == k) t.add(decode_gridmap_sum_tile(old.data, source_of(old)));
      }
      rows.push_back(row_of(k, t));
    }
    store.commit_gridmap_sums(version, rows, change);
    // Later take-outs recompute shared tiles with this drive where it now is.
    inputs.insert_or_assign(d.content_hash, place);
    up.tiles_written += static_cast<std::int64_t>(rows.size());
    ++(replacing ? up.drives_replaced : up.drives_added);
  }
  return up;
}

FleetGridmapAccumulator::PngTiles render_gridmap_region(const MapStore& store,
                                                        const FleetGridmapConfig& cfg,
                                                        const std::vector<GridmapSumKey>& keys,
                                                        const GridmapSumTiles& override_tiles) {
  FleetGridmapAccumulator acc(cfg);
  // One base-zoom tile's sums at a time: the decoded sums of a whole region could be
  // hundreds of MB, the accumulator holds 1 MB per base tile.
  std::map<tiles::TileKey, std::vector<GridmapSumKey>> by_base;
  for (const auto& k : keys) by_base[sum_tile_ancestor(k, cfg.base_zoom)].push_back(k);
  for (const auto& [base, ks] : by_base) {
    const int shift = kGridmapSumZoom - cfg.base_zoom;
    const int x0 = base.x << shift, y0 = base.y << shift;
    const int x1 = x0 + (1 << shift) - 1, y1 = y0 + (1 << shift) - 1;
    for (const auto& row : store.gridmap_sums_in(x0, y0, x1, y1)) {
      const GridmapSumKey k = key_of(row);
      if (override_tiles.contains(k)) continue;
      acc.add_sums(k, decode_gridmap_sum_tile(row.data, source_of(row)));
    }
    for (const auto& k : ks) {
      if (auto it = override_tiles.find(k); it != override_tiles.end()) acc.add_sums(k, it->second);
    }
  }
  return acc.encode_all_png_tiles();
}

}  // namespace polmap::mapping::detail
