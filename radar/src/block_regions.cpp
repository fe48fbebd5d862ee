#include "block_regions.hpp"

#include <algorithm>

namespace polmap::radar {

BlockRegions::BlockRegions(int w, int h, int block_cells)
    : block(block_cells),
      blocks_w((w + block_cells - 1) / block_cells),
      blocks_h((h + block_cells - 1) / block_cells),
      seed(static_cast<std::size_t>(blocks_w) * blocks_h, 0),
      w_(w),
      h_(h) {}

void BlockRegions::group(int dilation_blocks) {
  const int bw = blocks_w, bh = blocks_h, R = dilation_blocks;
  std::vector<std::uint8_t> mask(seed.size(), 0);
  for (int by = 0; by < bh; ++by) {
    for (int bx = 0; bx < bw; ++bx) {
      if (!seed[static_cast<std::size_t>(by) * bw + bx]) continue;
      for (int yy = std::max(0, by - R); yy <= std::min(bh - 1, by + R); ++yy) {
        for (int xx = std::max(0, bx - R); xx <= std::min(bw - 1, bx + R); ++xx) {
          mask[static_cast<std::size_t>(yy) * bw + xx] = 1;
        }
      }
    }
  }
  label.assign(mask.size(), 0);
  regions.clear();
  std::vector<int> stack;
  for (std::size_t start = 0; start < mask.size(); ++start) {
    if (!mask[start] || label[start] != 0) continue;
    const int id = static_cast<int>(regions.size()) + 1;
    int bx0 = bw, by0 = bh, bx1 = -1, by1 = -1;
    label[start] = id;
    stack.assign(1, static_cast<int>(start));
    while (!stack.empty()) {
      const int k = stack.back();
      stack.pop_back();
      const int bx = k % bw, by = k / bw;
      bx0 = std::min(bx0, bx);
      bx1 = std::max(bx1, bx);
      by0 = std::min(by0, by);
      by1 = std::max(by1, by);
      for (int yy = std::max(0, by - 1); yy <= std::min(bh - 1, by + 1); ++yy) {
        for (int xx = std::max(0, bx - 1); xx <= std::min(bw - 1, bx + 1); ++xx) {
          const std::size_t n = static_cast<std::size_t>(yy) * bw + xx;
          if (!mask[n] || label[n] != 0) continue;
          label[n] = id;
          stack.push_back(static_cast<int>(n));
        }
      }
    }
    regions.push_back(BlockRegion{bx0 * block, by0 * block, std::min(w_, (bx1 + 1) * block),
                                  std::min(h_, (by1 + 1) * block), id});
  }
}

}  // namespace polmap::radar
