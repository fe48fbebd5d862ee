#pragma once
/// @file gridmap_sums.hpp
/// The merged PreCFAR gridmap: per cell of a fixed global grid, the sums the
/// covariance estimate of all drives needs, so that the fleet's covariance
/// C = Σ N·C_d / Σ N is known everywhere and a new drive is added without
/// touching the rest.
///
/// Grid: the pixels of Web-Mercator tiles at zoom kGridmapSumZoom (20) with 256 pixels a
/// side, i.e. cells of 0.149 m × cos(lat) (0.098 m at 48.8° N, close to the drives'
/// 0.1 m cells). A sum tile is one such tile (≈ 25 m a side at 48.8° N). Web Mercator is
/// conformal, so a cell is square on the ground and the grid is the same for every drive
/// and every replica; no map-wide projection origin has to be agreed.
///
/// Planes per cell (float32, for the drives of one polarimetric level — circular and
/// linear bases are never summed together; each level has its own sum tiles):
///   0  Σ N          observation count (looks)
///   1  Σ hits       looks with a stored bin (persistence = plane1/plane0, what pCFAR tests)
///   2  Σ N·σ²       noise power of the contributing drives (so merged noise = plane2/plane0)
///   then, for every covariance component C_ij, i <= j, upper triangle row-major
///   (GridmapRaster::layer_index order): Σ N·C_ii (real, one plane) or
///   Re Σ N·C_ij, Im Σ N·C_ij (two planes).
/// So full polarimetry has 3 + 3 + 2·3 = 12 planes, dual 3 + 2 + 2 = 7, single 4.
///
/// Resampling (drive frame -> grid): each drive cell's N and N·C are split among the 4
/// grid cells around its centre with bilinear weights ("splatting"), so totals are
/// conserved exactly and no grid cell is left empty by the slightly different cell
/// sizes. Drive-frame -> Mercator pixel coordinates use one affine fit per 64-cell block
/// (error < 1 mm, as for the amplitude tiles).
///
/// Memory: a sum tile holds 16 chunks of 64 × 64 cells, allocated when first touched, so
/// a drive's working set follows its observed area (≈ 50 bytes per 0.01 m² at full
/// polarimetry), not its bounding box.
///
/// Pure core: no I/O. The store keeps the encoded tiles (gridmap_sums_codec.hpp), the map
/// builder adds drives and renders raster tiles from them (FleetGridmapAccumulator).
#include <array>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <vector>

#include "polmap/mapping_service/drive_package.hpp"
#include "polmap/schema/polarimetry.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace polmap::mapping {

/// Zoom of the sum grid's tiles (256 cells a side each).
inline constexpr int kGridmapSumZoom = 20;
/// Cells a side of a sum tile, and of one of its lazily allocated chunks.
inline constexpr int kSumTileCells = 256;
inline constexpr int kSumChunkCells = 64;
inline constexpr int kSumChunksPerSide = kSumTileCells / kSumChunkCells;

/// Number of float planes of a level's sum tile (file comment).
int gridmap_sum_planes(PolLevel level);

/// Identifies a sum tile: a level and a z20 tile.
struct GridmapSumKey {
  PolLevel level = PolLevel::Full;
  int x = 0;  ///< z20 tile column
  int y = 0;  ///< z20 tile row
  auto operator<=>(const GridmapSumKey&) const = default;
  [[nodiscard]] tiles::TileKey tile() const { return {kGridmapSumZoom, x, y}; }
};

/// One sum tile: planes × 256 × 256 float sums, chunked (file comment).
class GridmapSumTile {
 public:
  explicit GridmapSumTile(PolLevel level = PolLevel::Full);

  [[nodiscard]] PolLevel level() const { return level_; }
  [[nodiscard]] int planes() const { return planes_; }
  /// True if no chunk is allocated (nothing was ever added).
  [[nodiscard]] bool empty() const;
  /// Chunk c (row-major, 0..15) allocated?
  [[nodiscard]] bool has_chunk(int c) const {
    return chunks_[static_cast<std::size_t>(c)] != nullptr;
  }
  /// The planes of chunk c, plane-major (plane p, cell (y, x) at p·4096 + y·64 + x);
  /// allocates (zeros) on first use.
  float* chunk(int c);
  [[nodiscard]] const float* chunk(int c) const {
    return chunks_[static_cast<std::size_t>(c)].get();
  }
  /// Value of plane p at cell (x, y) of the tile; 0 where unallocated.
  [[nodiscard]] float at(int p, int x, int y) const;
  /// Adds `w` × values (planes() of them) at cell (x, y).
  void add(int x, int y, double w, const double* values);
  /// Adds another tile of the same level cell by cell.
  void add(const GridmapSumTile& other);
  /// Subtracts another tile of the same level cell by cell (a drive's contribution taken
  /// out again); cells left with N below n_floor_looks are cleared, so the float residue of
  /// a cell only that drive saw does not become a cell of noise.
  void subtract(const GridmapSumTile& other, float n_floor_looks = 1e-3F);

 private:
  PolLevel level_;
  int planes_;
  std::array<std::unique_ptr<float[]>, kSumChunksPerSide * kSumChunksPerSide> chunks_{};
};

using GridmapSumTiles = std::map<GridmapSumKey, GridmapSumTile>;

/// Moves a drive-frame position (metres) to where the drive's gridmap is added: the drive's
/// alignment correction (the map builder's drive_placement.hpp). Smooth over a few metres.
using GridmapWarp = std::function<Eigen::Vector2d(const Eigen::Vector2d&)>;

/// Adds a drive-frame raster (a whole gridmap or one block, N = 0 cells skipped) of a
/// drive with frame `drive_frame` and polarimetric level `level` to `out` (splatting,
/// file comment). The raster's noise_power is the drive's σ². With `warp`, every cell goes
/// where the warp moves it (the per-block affine fit follows the warped positions).
void splat_gridmap(const GridmapRaster& raster, const tiles::LocalFrame& drive_frame,
                   PolLevel level, GridmapSumTiles& out, const GridmapWarp& warp = {});

/// Merged covariance of one cell: N, hits, the mean covariance layers (GridmapRaster layer
/// order) and mean noise power. `n` = 0 where nothing was observed.
struct MergedCell {
  double n = 0.0;
  double hits = 0.0;
  double noise_power = 0.0;
  std::vector<cdouble> layers;
};
[[nodiscard]] MergedCell merged_cell(const GridmapSumTile& tile, int x, int y);

/// Mean power tr(C), odd- and even-bounce power (noise subtracted, as
/// cell_mechanism_powers) of a cell, each weighted by N: what the amplitude and
/// mechanism raster tiles sum (FleetGridmapAccumulator::add_sums).
struct CellPowers {
  double n = 0.0;
  double n_power = 0.0;
  double n_odd = 0.0;
  double n_even = 0.0;
};
[[nodiscard]] CellPowers cell_powers(const GridmapSumTile& tile, int x, int y);

}  // namespace polmap::mapping
