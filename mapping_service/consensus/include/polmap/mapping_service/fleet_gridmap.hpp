#pragma once
/// @file fleet_gridmap.hpp
/// The fleet gridmap layer: the radar amplitude of all drives of a map
/// version, as raster tiles for web maps (GET /v1/gridmap/{z}/{x}/{y}.png)
/// and GeoTIFF export.
///
/// What is summed: per drive gridmap cell (drive frame, 0.1 m) the observation
/// count N and the covariance C = 1/N Σ Ω Ω^H; the fleet layer keeps, per
/// output pixel, Σ N·tr(C) (total received power) and Σ N over all cells of
/// all drives falling into the pixel. Pixel value = mean power
/// P = Σ N·tr(C) / Σ N, shown in dB. A map build feeds it from the store's merged
/// gridmap (gridmap_sums.hpp: the full per-cell covariance sums of all drives on a z20
/// grid, add_sums), one min-zoom region at a time; add() takes a drive raster directly.
///
/// Storage (table gridmap_tiles, TileLayer::Gridmap, content-addressed blobs
/// like localization tiles): XYZ Web-Mercator tiles, 256 × 256 pixels, at
/// base_zoom (18: pixel = 0.6 m × cos(lat), 0.39 m at 48.8° N) and overview
/// zooms down to min_zoom (each pixel the power-weighted mean of the 2 × 2
/// pixels below it). Payload: PNG, 8-bit RGBA: R = G = B = gray, A = 255 where
/// observed and 0 where no drive saw the pixel; gray = 1 + round(254 ·
/// (dB − db_min) / (db_max − db_min)) clamped to [1, 255], i.e. linear in dB
/// (0.2 dB steps at the defaults). The dB range is part of the config and is
/// recorded in the map version's statistics (`gridmap.db_min`, `gridmap.db_max`).
/// A GeoTIFF export reads the base-zoom tiles back (decode_gridmap_png_db) into
/// an EPSG:3857 raster whose geotransform follows from tile_bounds().
///
/// Scattering mechanisms (TileLayer::GridmapMechanism, the paper's colouring): per
/// pixel also Σ N·odd and Σ N·even, the odd- and even-bounce powers of each cell's
/// covariance (noise power subtracted; radar::mechanism_powers, per level). The
/// mechanism tile's colour is the amplitude tile's gray g times the mechanism mix:
/// R = B = g·even/(odd+even), G = g·odd/(odd+even) — odd bounce green, even bounce
/// magenta, brightness from amplitude; gray where the drives carry no mechanism
/// information (single polarization).
///
/// Pure core (no file I/O).
#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "polmap/mapping_service/drive_package.hpp"
#include "polmap/mapping_service/gridmap_sums.hpp"
#include "polmap/tiles/local_frame.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace polmap::mapping {

struct FleetGridmapConfig {
  /// Zoom of the full-resolution tiles (256 px): 18 gives 0.3–0.4 m pixels at
  /// mid latitudes, about 4 drive gridmap cells (0.1 m) a side.
  int base_zoom = 18;
  /// Lowest overview zoom stored (z14: 9.6 m × cos(lat) pixels).
  int min_zoom = 14;
  /// dB range mapped onto gray 1..255 (10·log10 of the mean power tr(C)).
  double db_min = -10.0;
  double db_max = 40.0;
};

/// Pixels a side of every gridmap tile.
inline constexpr int kGridmapTilePixels = 256;

/// Accumulates drive gridmaps into fleet tiles. Not thread-safe (one builder).
class FleetGridmapAccumulator {
 public:
  explicit FleetGridmapAccumulator(FleetGridmapConfig cfg = {});

  /// Adds a drive-frame raster (a whole gridmap or one block of it) of a drive
  /// whose frame is `drive_frame`. Cells with N = 0 are skipped. Each cell goes
  /// to the base-zoom pixel containing its centre (drive frame -> Web-Mercator
  /// pixel mapped by an affine fit per 64-cell block; error < 1 mm).
  /// `level`: the drive's polarimetric level (which components the layers hold).
  void add(const GridmapRaster& raster, const tiles::LocalFrame& drive_frame, PolLevel level);
  /// Adds a sum tile of the merged gridmap (gridmap_sums.hpp): each base-zoom pixel
  /// receives the 4^(20 - base_zoom) grid cells inside it. Needs base_zoom <= 20.
  void add_sums(const GridmapSumKey& key, const GridmapSumTile& tile);

  /// Number of base-zoom tiles with at least one observed pixel.
  [[nodiscard]] std::size_t num_base_tiles() const { return base_.size(); }
  /// Mean power of a base-zoom pixel (linear), nullopt if unobserved.
  [[nodiscard]] std::optional<double> mean_power(const tiles::TileKey& base_tile, int px,
                                                 int py) const;
  /// Σ N of a base-zoom pixel.
  [[nodiscard]] double count(const tiles::TileKey& base_tile, int px, int py) const;

  /// Amplitude PNG tiles of all zooms min_zoom..base_zoom, ordered by (z, x, y).
  [[nodiscard]] std::vector<std::pair<tiles::TileKey, std::string>> encode_png_tiles() const;
  /// Scattering-mechanism PNG tiles (file comment), same keys as encode_png_tiles().
  [[nodiscard]] std::vector<std::pair<tiles::TileKey, std::string>> encode_mechanism_png_tiles()
      const;
  /// Both layers from one pass over the zoom pyramid (what a map build writes).
  struct PngTiles {
    std::vector<std::pair<tiles::TileKey, std::string>> amplitude;
    std::vector<std::pair<tiles::TileKey, std::string>> mechanism;
  };
  [[nodiscard]] PngTiles encode_all_png_tiles() const;

  [[nodiscard]] const FleetGridmapConfig& config() const { return cfg_; }

 private:
  struct Acc {
    std::vector<float> power;  ///< Σ N·tr(C), row-major 256 × 256
    std::vector<float> count;  ///< Σ N
    std::vector<float> odd;    ///< Σ N·odd-bounce power
    std::vector<float> even;   ///< Σ N·even-bounce power
    void resize();
  };
  [[nodiscard]] PngTiles encode(bool amplitude, bool mechanism) const;
  FleetGridmapConfig cfg_;
  std::map<tiles::TileKey, Acc> base_;
};

/// Odd- and even-bounce power of one gridmap cell: the layers' values at a cell (upper
/// triangle, row-major, as GridmapRaster::layers) of a covariance of `level`, noise power
/// subtracted from each component (clamped at 0). The same as radar::mechanism_powers
/// without building a matrix per cell.
std::pair<double, double> cell_mechanism_powers(std::span<const cdouble> layers_at_cell,
                                                PolLevel level, double noise_power);

/// Gray value of a mean power (see file comment); 0 never (it means unobserved).
std::uint8_t gridmap_gray(double mean_power, const FleetGridmapConfig& cfg);

/// Decodes a gridmap PNG tile into dB per pixel (row-major 256 × 256, NaN where
/// unobserved); the inverse of the gray mapping up to its 0.2 dB steps.
/// Throws FormatError if the payload is not such a PNG.
std::vector<float> decode_gridmap_png_db(std::string_view png, const FleetGridmapConfig& cfg);

}  // namespace polmap::mapping
