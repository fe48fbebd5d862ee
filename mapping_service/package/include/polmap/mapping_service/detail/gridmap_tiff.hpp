#pragma once
/// @file gridmap_tiff.hpp
/// The gridmap GeoTIFF writer (package writer and GIS export; detail/ headers may
/// change without notice).
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "polmap/mapping_service/drive_package.hpp"

class GDALDataset;

namespace polmap::mapping::detail {

inline constexpr int kGridmapBlockSize = 256;
/// N saturates here: the largest integer a Float32 band holds exactly.
inline constexpr std::uint32_t kMaxExactCount = 16'777'216;

struct GridmapTiffSpec {
  int width = 0;
  int height = 0;
  double origin_x_m = 0.0;  ///< western edge
  double origin_y_m = 0.0;  ///< northern edge
  double cell_size_m = 0.1;
  PolLevel level = PolLevel::Full;
  std::string crs_proj;
  int deflate_level = 6;
  /// Mantissa bits kept in the covariance bands (23 = lossless); see PackageWriteOptions.
  int mantissa_bits = 23;
  /// Format 2: 3 + q^2 UInt16 code bands (compact_gridmap_band_names), ZSTD + horizontal
  /// differencing; block buffers then hold the integer codes.
  bool compact = false;
  int zstd_level = 19;
  /// Dataset metadata items (domain ""), e.g. POLMAP_DRIVE_ID.
  std::vector<std::pair<std::string, std::string>> metadata;
};

/// One 256x256 block of all bands, band-major: data[(band * 256 + row) * 256 + col].
struct GridmapBlockBuffer {
  int num_bands = 0;
  std::vector<float> data;
  explicit GridmapBlockBuffer(int bands)
      : num_bands(bands),
        data(static_cast<std::size_t>(bands) * kGridmapBlockSize * kGridmapBlockSize, 0.0F) {}
  float* band(int b) {
    return data.data() + static_cast<std::size_t>(b) * kGridmapBlockSize * kGridmapBlockSize;
  }
  void clear() { std::fill(data.begin(), data.end(), 0.0F); }
};

/// Writes a gridmap GeoTIFF block by block (tiled 256x256, DEFLATE + floating-point
/// predictor, band-interleaved, SPARSE_OK so empty blocks take no bytes). Blocks must be
/// written in a fixed order for byte-identical output; each block is written exactly once
/// and directly (no GDAL block cache), so the file layout does not depend on cache size.
class GridmapTiffWriter {
 public:
  GridmapTiffWriter(const std::string& path, const GridmapTiffSpec& spec);
  ~GridmapTiffWriter();
  GridmapTiffWriter(const GridmapTiffWriter&) = delete;
  GridmapTiffWriter& operator=(const GridmapTiffWriter&) = delete;
  [[nodiscard]] int num_bands() const { return num_bands_; }
  [[nodiscard]] int blocks_x() const;
  [[nodiscard]] int blocks_y() const;
  /// Writes block (bx, by); an all-zero N band skips the block (sparse).
  void write_block(int bx, int by, GridmapBlockBuffer& block);
  /// Flushes and closes; throws IoError on failure.
  void close();

 private:
  std::string path_;
  GridmapTiffSpec spec_;
  int num_bands_ = 0;
  GDALDataset* ds_ = nullptr;
};

/// Fills block (bx, by) of `block` from a dense raster (cells outside -> 0).
void fill_block_from_raster(const GridmapRaster& raster, int bx, int by, GridmapBlockBuffer& block);

/// Writes a dense raster as a gridmap GeoTIFF.
void write_gridmap_tiff(const GridmapRaster& raster, const GridmapTiffSpec& spec,
                        const std::string& path);

}  // namespace polmap::mapping::detail
