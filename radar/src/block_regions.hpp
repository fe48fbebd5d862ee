#pragma once
// Internal to polmap_radar: groups of image blocks around sparse seed cells, for
// detectors that do their work only near cells that can produce a result (the
// streaming pCFAR, the line ridge filters).
#include <cstdint>
#include <vector>

namespace polmap::radar {

/// A rectangle of cells [x0, x1) × [y0, y1) of a w × h image: the bounding box of one
/// group of blocks (label = the group's number, 1, 2, …).
struct BlockRegion {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;
  int label = 0;
};

/// Blocks of block × block cells of a w × h image, marked where a seed cell lies, dilated
/// by `dilation_blocks` blocks (Chebyshev), and grouped 8-connected: every cell within
/// dilation_blocks·block cells of a seed lies in the bounding box of its seed's group.
/// Bounding boxes of different groups may overlap; `label` (per block, row-major, 0 for
/// none) tells which group a block belongs to.
struct BlockRegions {
  int block = 16;
  int blocks_w = 0, blocks_h = 0;
  std::vector<std::uint8_t> seed;  ///< per block: holds a seed (fill before group())
  std::vector<int> label;          ///< per block, after group()
  std::vector<BlockRegion> regions;

  BlockRegions(int w, int h, int block_cells);
  void mark(int x, int y) { seed[static_cast<std::size_t>(y / block) * blocks_w + x / block] = 1; }
  [[nodiscard]] int label_at(int x, int y) const {
    return label[static_cast<std::size_t>(y / block) * blocks_w + x / block];
  }
  /// Dilates the seeded blocks and fills label and regions.
  void group(int dilation_blocks);

 private:
  int w_ = 0, h_ = 0;
};

}  // namespace polmap::radar
