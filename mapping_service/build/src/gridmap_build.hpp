#pragma once
// The map build's merged-gridmap stage (private to polmap_build): keeps the store's sum
// tiles (gridmap_sums.hpp) in step with its drives, one drive per transaction, and renders
// the version's amplitude and mechanism raster tiles from them one min-zoom region at a
// time (memory follows a region, not the store).
#include <functional>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "polmap/mapping_service/drive_placement.hpp"
#include "polmap/mapping_service/fleet_gridmap.hpp"
#include "polmap/mapping_service/gridmap_sums.hpp"
#include "polmap/mapping_service/store.hpp"

namespace polmap::mapping::detail {

/// Where this build places drives' gridmaps: the drives it aligned (by package hash), and
/// how far a stored placement may be from the new one before the drive is taken out of the
/// sums and added again.
struct GridmapPlacements {
  std::map<std::string, DrivePlacement> by_hash;
  double replace_threshold_m = 0.05;
};

struct GridmapSumsUpdate {
  std::int64_t drives_added = 0;     ///< drives whose gridmap went into the sums
  std::int64_t drives_replaced = 0;  ///< inputs whose placement moved: taken out, added again
  std::int64_t drives_removed = 0;   ///< inputs whose drive is no longer stored, taken out
  std::int64_t tiles_written = 0;    ///< sum tiles rewritten
  std::vector<std::string> errors;   ///< drives whose gridmap could not be read (retried later)
};

/// Adds every drive of `drives` that is not yet an input (each in its own commit, tiles
/// written by `version`; placed as `placements` says, else as uploaded), takes out inputs
/// whose package hash is not in `stored_hashes` (their tiles recomputed from the remaining
/// inputs), and re-places inputs whose stored placement differs from their new one by more
/// than the threshold (taken out, then added where they now belong; two commits). `tick`
/// is called between drives.
GridmapSumsUpdate update_gridmap_sums(MapStore& store, std::int64_t version,
                                      const std::vector<DriveRecord>& drives,
                                      const std::set<std::string>& stored_hashes,
                                      const std::function<void()>& tick,
                                      const GridmapPlacements& placements = {});

/// The sum tiles `keys` recomputed from the packages of the inputs that touched them, except
/// those in `without` (by package hash), each placed as it was added (`placements`: the
/// inputs' decoded placements when the caller has them, else read from the store): what
/// the tiles hold without those drives.
GridmapSumTiles recompute_sum_tiles(
    const MapStore& store, const std::set<GridmapSumKey>& keys,
    const std::set<std::string>& without, std::vector<std::string>& errors,
    const std::map<std::string, DrivePlacement>* placements = nullptr);

/// Renders min-zoom region `region` (a tile at cfg.min_zoom) from the store's sum tiles in it
/// (`keys`: those of the region), replacing the tiles in `override_tiles` (recomputed ones),
/// and returns both raster layers of the region's zoom pyramid.
FleetGridmapAccumulator::PngTiles render_gridmap_region(const MapStore& store,
                                                        const FleetGridmapConfig& cfg,
                                                        const std::vector<GridmapSumKey>& keys,
                                                        const GridmapSumTiles& override_tiles);

/// The tile at `zoom` that contains sum tile `key` (zoom <= kGridmapSumZoom).
tiles::TileKey sum_tile_ancestor(const GridmapSumKey& key, int zoom);

}  // namespace polmap::mapping::detail
