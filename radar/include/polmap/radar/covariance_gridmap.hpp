#pragma once
/// @file covariance_gridmap.hpp
/// PreCFAR covariance gridmap (paper §III-B): static-reduced polar spectra of
/// many sensor frames accumulated in a Cartesian grid as per-cell sample
/// covariances C = 1/N Σ k k^H of the level vectors k (polarimetry.hpp).
///
/// Grid: cell (ix, iy) covers [ix·s, (ix+1)·s) × [iy·s, (iy+1)·s) of the map frame
/// (s = cell_size_m, x east, y north); its centre is ((ix+½)s, (iy+½)s).
///
/// Polar -> Cartesian mapping: nearest neighbour, no interpolation (§III-B3).
/// A cell takes the value of the polar bin nearest to its centre as seen from the
/// sensor: range bin round(r / Δr) and the beam whose azimuth interval contains the
/// cell's azimuth, the interval of a beam running between the midpoints to its
/// neighbours (the outer beams extend by half their spacing). A cell is observed
/// by a frame (N += 1) iff such a bin exists (the sensor footprint); it then adds
/// k k^H of that bin, zero for bins the recorder dropped below its floor. So C is
/// the mean over every frame that saw the cell, empty looks included. A per-cell
/// hit count (looks with a stored bin) gives the cell's persistence hits/N.
///
/// Cost: the work of one frame is proportional to the cells covered by the
/// non-zero bins (their footprints are scan-converted row by row) plus the
/// footprint's boundary; N over the footprint interior is counted per tile
/// (64×64 cells) or per 8×8 block, not per cell.
///
/// Storage: sparse tiles (kTileSizeCells² cells) in a hash map, so memory grows
/// with the observed area; per tile a frame count for full coverage plus 16-bit
/// per-cell counts for partial coverage (32-bit after 65535 partial frames), and
/// covariance sums allocated per 4×4 block only where data arrived, packed (real
/// diagonal, complex upper off-diagonal: q + 2·(L−q) scalars per cell). Sums are
/// float in both modes.
///
/// Modes (paper §III-B3): window_s = 0 keeps the full history (mapping); window_s > 0
/// keeps only frames with time ≥ newest time − window_s (localization). The window
/// records, per frame, the coverage masks and the cells and products it added and,
/// when the frame leaves, subtracts exactly those (no geometry or scan conversion is
/// recomputed), so counts and hits return exactly and sums to float rounding (a residue
/// of ~1e-7 of the largest sum a cell held; a tile no frame touches any more is freed,
/// which clears it). The window is in frame time order: add() frames with
/// non-decreasing time_s (sensors interleaved is fine).
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <complex>
#include <cstdint>
#include <functional>
#include <memory>
#include <opencv2/core.hpp>
#include <optional>
#include <span>
#include <vector>

#include "polmap/schema/polarimetry.hpp"
#include "polmap/schema/pose2.hpp"
#include "polmap/schema/recording.hpp"

namespace polmap::radar {

/// Cells per tile side (tiles are kTileSizeCells × kTileSizeCells cells).
inline constexpr int kTileSizeCells = 64;

struct GridmapConfig {
  /// Cell edge, metres. 0.1 m: the range resolution is 7.5 cm and landmark
  /// positions are wanted to ~0.1 m (consensus radius 0.3 m).
  double cell_size_m = 0.1;
  /// Polarimetric level of the stored covariance (q = pol_dimension(level)).
  PolLevel level = PolLevel::Full;
  /// 0: full history (mapping mode). > 0: sliding window of this many seconds
  /// (localization mode; the paper bounds it by odometry drift ≈ one cell).
  double window_s = 0.0;
  /// Use range bins up to this range only; 0: every bin of the spectrum.
  double max_range_m = 0.0;
};

/// A box of cells: min inclusive, max exclusive.
struct CellBox {
  int min_ix = 0;
  int min_iy = 0;
  int max_ix = 0;
  int max_iy = 0;
  [[nodiscard]] int width() const { return max_ix - min_ix; }
  [[nodiscard]] int height() const { return max_iy - min_iy; }
  [[nodiscard]] bool empty() const { return max_ix <= min_ix || max_iy <= min_iy; }
  [[nodiscard]] bool contains(int ix, int iy) const {
    return ix >= min_ix && ix < max_ix && iy >= min_iy && iy < max_iy;
  }
};

/// One tile of the gridmap as dense arrays (materialized by for_each_tile; valid
/// only during the callback). Index of the cell (col, row) = row·size_cells + col,
/// col = ix − tile_x·size, row = iy − tile_y·size: row 0 is the SOUTH edge
/// (y grows with row; flip for north-up rasters such as GeoTIFF).
struct CovarianceTileView {
  int tile_x = 0;
  int tile_y = 0;
  int size_cells = kTileSizeCells;
  double origin_x_m = 0.0;  ///< south-west corner of the tile in the map frame
  double origin_y_m = 0.0;
  double cell_size_m = 0.1;
  PolLevel level = PolLevel::Full;
  int q = 3;
  int num_layers = 6;  ///< q(q+1)/2
  /// N per cell (frames that observed it).
  std::span<const std::uint32_t> count;
  /// Covariance C = 1/N Σ k k^H, upper triangle, layer-major: layers[l·size² + index],
  /// layer order (0,0), (0,1), ..., (0,q−1), (1,1), ... (layer_index()). Zero where N = 0.
  std::span<const std::complex<float>> layers;
  /// Per cell: looks whose bin was stored (non-zero), ≤ N. hits/N is the cell's
  /// persistence (static landmarks high, traffic passing through low). May be empty
  /// in views built elsewhere (merge_tile then counts every look as a hit).
  std::span<const std::uint32_t> hits;

  [[nodiscard]] std::complex<float> layer(int l, int col, int row) const {
    return layers[static_cast<std::size_t>(l) * size_cells * size_cells + row * size_cells + col];
  }
  /// Full Hermitian q×q covariance of a cell.
  [[nodiscard]] Eigen::MatrixXcd covariance(int col, int row) const;
};

/// A dense rectangle of the gridmap (what the extractors work on). Same layout
/// as CovarianceTileView over `box`: index = (iy − box.min_iy)·width + (ix − box.min_ix).
struct CovarianceRaster {
  CellBox box;
  double cell_size_m = 0.1;
  PolLevel level = PolLevel::Full;
  int q = 3;
  double noise_power = 0.0;  ///< mean noise σ² per level-vector component
  std::vector<std::uint32_t> count;
  std::vector<std::uint32_t> hits;          ///< looks with a stored bin (≤ count)
  std::vector<std::complex<float>> layers;  ///< num_layers(q) planes of width·height

  [[nodiscard]] std::size_t plane_size() const {
    return static_cast<std::size_t>(box.width()) * box.height();
  }
  [[nodiscard]] std::complex<float> layer(int l, std::size_t index) const {
    return layers[l * plane_size() + index];
  }
  /// trace(C) at a raster index.
  [[nodiscard]] float power(std::size_t index) const;
  [[nodiscard]] Eigen::MatrixXcd covariance(std::size_t index) const;
  [[nodiscard]] Eigen::Vector2d cell_center(std::size_t index) const;
  /// Allocates zeroed arrays for a box.
  static CovarianceRaster zeros(const CellBox& box, double cell_size_m, PolLevel level);
  /// Sets C of a cell (N set to n, hits to hits_n or n); for tests and synthetic inputs.
  void set_covariance(int ix, int iy, const Eigen::MatrixXcd& c, std::uint32_t n = 1,
                      std::optional<std::uint32_t> hits_n = std::nullopt);
};

class CovarianceGridmap {
 public:
  explicit CovarianceGridmap(GridmapConfig cfg = {});
  ~CovarianceGridmap();
  CovarianceGridmap(CovarianceGridmap&&) noexcept;
  CovarianceGridmap& operator=(CovarianceGridmap&&) noexcept;
  CovarianceGridmap(const CovarianceGridmap&) = delete;
  CovarianceGridmap& operator=(const CovarianceGridmap&) = delete;

  /// Adds one sensor frame's static-reduced spectrum seen from T_frame_sensor
  /// (sensor pose in the map frame) at time_s. In window mode, first drops frames
  /// older than time_s − window_s. Throws ValidationError for an inconsistent
  /// spectrum (fewer than 2 beams, beams not ascending or spanning ≥ 180°, cell
  /// indices outside the declared bins).
  void add(const PolSpectrum& spectrum, const Pose2& T_frame_sensor, double time_s);
  /// Window mode: removes every frame with time < time_s. No-op in mapping mode.
  void expire_before(double time_s);

  /// Adds one observation k (q components) to a single cell: N += 1, S += k k^H.
  /// Mapping mode only (never expires); for tests, synthetic maps and imports.
  void add_cell_sample(int ix, int iy, std::span<const cdouble> k);
  /// Adds a tile's content (N and N·C per cell) to the map, e.g. to rebuild a
  /// gridmap from a stored package or to merge drives. Mapping mode only; the
  /// view's level and cell size must match.
  void merge_tile(const CovarianceTileView& tile);

  [[nodiscard]] int q() const;
  [[nodiscard]] PolLevel level() const { return cfg_.level; }
  [[nodiscard]] double cell_size_m() const { return cfg_.cell_size_m; }
  [[nodiscard]] const GridmapConfig& config() const { return cfg_; }
  /// Mean noise σ² per level-vector component over the frames in the map
  /// (PolSpectrum::noise_sigma²); 0 before any frame.
  [[nodiscard]] double noise_power() const;
  /// Noise power of a map rebuilt from stored cells (merge_tile; no frames added), e.g.
  /// a drive package's decoded gridmap: what noise_power() returns while num_frames() = 0.
  void set_noise_power(double noise_power);
  /// Frames currently accumulated (in window mode: inside the window).
  [[nodiscard]] std::size_t num_frames() const;
  [[nodiscard]] std::size_t num_tiles() const;
  /// Heap bytes held by tiles (counts and sums) and the window's frame records.
  [[nodiscard]] std::size_t memory_bytes() const;

  /// Cells of all allocated tiles (empty box when the map is empty).
  [[nodiscard]] CellBox bounds() const;
  /// Same in metres (map frame).
  [[nodiscard]] Eigen::AlignedBox2d bounds_m() const;
  /// Cell containing a map-frame point.
  [[nodiscard]] std::array<int, 2> cell_of(const Eigen::Vector2d& xy_m) const;
  [[nodiscard]] Eigen::Vector2d cell_center(int ix, int iy) const;

  /// N of a cell (0 when never observed).
  [[nodiscard]] std::uint32_t count(int ix, int iy) const;
  /// Looks of a cell whose nearest bin was stored (non-zero): hits/N is its persistence.
  [[nodiscard]] std::uint32_t hits(int ix, int iy) const;
  /// C of a cell (q×q, zero when N = 0).
  [[nodiscard]] Eigen::MatrixXcd covariance(int ix, int iy) const;
  /// trace(C) of a cell.
  [[nodiscard]] double power(int ix, int iy) const;

  /// Calls fn for every allocated tile (any order). The view is valid during the call.
  void for_each_tile(const std::function<void(const CovarianceTileView&)>& fn) const;
  /// Tile indices (tile_x, tile_y) of allocated tiles, sorted.
  [[nodiscard]] std::vector<std::array<int, 2>> tile_indices() const;
  /// Chunks of chunk_tiles × chunk_tiles tiles that hold allocated tiles, each with the
  /// bounding box of its allocated tiles (cells outside read as N = 0), ordered by
  /// (chunk_x, chunk_y). Chunk (cx, cy) covers tiles [cx·chunk_tiles, (cx+1)·chunk_tiles).
  struct PopulatedChunk {
    int chunk_x = 0;
    int chunk_y = 0;
    CellBox populated;
  };
  [[nodiscard]] std::vector<PopulatedChunk> populated_chunks(int chunk_tiles) const;
  /// Dense copy of a box (cells outside allocated tiles read as N = 0, C = 0).
  [[nodiscard]] CovarianceRaster raster(const CellBox& box) const;
  /// One row of cells [ix0, ix1) at iy, with exactly the values raster() writes: N,
  /// hits and the upper-triangle layers of C, interleaved per cell (layers[(ix − ix0)·L + l],
  /// L = q(q+1)/2 in layer order; zero where N = 0 or no bin was stored). Streaming
  /// detectors read the map row by row through this instead of one dense raster. The
  /// spans must hold ix1 − ix0 cells (layers: L per cell).
  void read_row(int iy, int ix0, int ix1, std::span<std::uint32_t> count,
                std::span<std::uint32_t> hits, std::span<std::complex<float>> layers) const;
  /// Cells of `box` that may pass a detector's first test: N ≥ min_count, persistence
  /// hits ≥ min_persistence·N and trace(C) > min_power, as read_row() gives them. A
  /// superset (the test is made on the sums before the float conversion, with a margin of
  /// 1e-6 relative), each cell once, in no particular order. Only stored bins are visited,
  /// so this is much cheaper than reading the box: a first pass for detectors that test
  /// only cells above a power floor (min_power > 0).
  [[nodiscard]] std::vector<std::array<int, 2>> cells_above(const CellBox& box, double min_power,
                                                            double min_persistence,
                                                            std::uint32_t min_count) const;
  /// trace(C) of a box as CV_32F (linear power); row r ↔ iy = box.min_iy + r (south at row 0).
  /// Cells with persistence hits/N below min_persistence read as 0.
  [[nodiscard]] cv::Mat trace_image(const CellBox& box, double min_persistence = 0.0) const;

  struct Impl;  ///< implementation detail (covariance_gridmap.cpp)

 private:
  GridmapConfig cfg_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace polmap::radar
