#pragma once
// Walking a drive raster in 64-cell blocks with an affine map of cell centres into a
// global grid (private to polmap_consensus): what the fleet gridmap's raster accumulator
// and the merged gridmap's splatting both do per drive.
#include <Eigen/Core>
#include <algorithm>

#include "polmap/mapping_service/drive_package.hpp"

namespace polmap::mapping::detail {

/// Cells a side of a block: one affine fit of drive frame -> global grid per 6.4 m
/// (0.1 m cells) keeps the error below 1 mm.
inline constexpr int kAffineBlockCells = 64;

/// For every block of `r` holding a cell with N > 0, calls fn(row0, col0, row1, col1,
/// p0, dc, dr): rows [row0, row1) and columns [col0, col1), and the global coordinates of
/// cell (col, row)'s centre are p0 + (col − col0)·dc + (row − row0)·dr. `grid_of(col, row)`
/// maps a (fractional) cell position's centre exactly; it is called at three block corners.
template <class GridOf, class Fn>
void for_each_observed_block(const GridmapRaster& r, GridOf&& grid_of, Fn&& fn) {
  constexpr int B = kAffineBlockCells;
  for (int r0 = 0; r0 < r.height; r0 += B) {
    for (int c0 = 0; c0 < r.width; c0 += B) {
      const int c1 = std::min(r.width, c0 + B);
      const int r1 = std::min(r.height, r0 + B);
      bool any = false;
      for (int row = r0; row < r1 && !any; ++row) {
        const auto* n = &r.count[static_cast<std::size_t>(row) * r.width];
        any = std::any_of(n + c0, n + c1, [](std::uint32_t k) { return k > 0; });
      }
      if (!any) continue;
      const Eigen::Vector2d p0 = grid_of(c0, r0);
      const Eigen::Vector2d dc = (grid_of(c0 + B, r0) - p0) / B;
      const Eigen::Vector2d dr = (grid_of(c0, r0 + B) - p0) / B;
      fn(r0, c0, r1, c1, p0, dc, dr);
    }
  }
}

}  // namespace polmap::mapping::detail
