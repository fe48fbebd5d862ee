// Streaming pCFAR over one chunk of a gridmap: the fast path of extract_points(map).
//
// The dense reference (point_extractor.cpp) materializes the chunk as one CovarianceRaster
// (56 bytes per cell), an integral image of ten planes (80 bytes per cell) and full-size
// label images, although only the cells near bright candidates are ever tested. Here the
// chunk is read row by row from the tiles (CovarianceGridmap::read_row, the same values
// raster() writes), and the integral images are kept for the 2·train + 2 rows a
// neighbourhood spans only, so the working set stays in cache. Every sum is formed as the
// reference forms it, so the tests, statistics and candidates are the same bit for bit;
// connected components of the (few) detections come from a union-find instead of a label
// image. Only the regions that can hold a detection are streamed (Active, below): a
// cheap first pass over the stored bins (CovarianceGridmap::cells_above) finds the cells
// above the power floor, and the statistics are formed around them only.
#include <cstdint>
#include <numeric>
#include <unordered_map>

#include "block_regions.hpp"
#include "pcfar_kernels.hpp"

namespace polmap::radar::pcfar {
namespace {

/// Rolling storage of (at least) the last `rows` rows of something with `per_row`
/// elements, in a buffer that is reused from call to call (every row is written before it
/// is read). The ring holds a power of two rows, so finding a row is a mask, not a division.
template <typename T>
struct RowRing {
  int mask = 0;
  std::size_t per_row = 0;
  T* data = nullptr;
  RowRing(std::vector<T>& buffer, int rows_, std::size_t per_row_) : per_row(per_row_) {
    int rows = 1;
    while (rows < rows_) rows *= 2;
    mask = rows - 1;
    const std::size_t n = static_cast<std::size_t>(rows) * per_row_;
    if (buffer.size() < n) buffer.resize(n);
    data = buffer.data();
  }
  T* row(int y) { return data + static_cast<std::size_t>(y & mask) * per_row; }
};

/// Buffers of the rings, kept per thread: a localizer extracts a few times per second,
/// and fresh multi-megabyte buffers would be mapped and page-faulted every time.
struct Workspace {
  std::vector<std::uint32_t> count, hits;
  std::vector<std::complex<float>> layers;
  std::vector<float> power, diag;
  std::vector<double> full, trace;
};

/// Union-find over detections (path halving).
int find_root(std::vector<int>& parent, int i) {
  while (parent[i] != i) {
    parent[i] = parent[parent[i]];
    i = parent[i];
  }
  return i;
}

using Region = BlockRegion;

/// The parts of a chunk box that can hold a detection. Only cells that are observed,
/// persistent and above the power floor are ever tested (at a noise floor of 10 dB,
/// ~0.4 % of the cells of a localization window), and a test reads the cells within the
/// training radius only. So blocks of kBlock² cells that hold such a cell, dilated by
/// the training radius, are all the statistics need; each 8-connected group of them is
/// one region (its bounding box), processed on its own, and a cell is tested in the
/// region of its block's group only (bounding boxes may overlap). A cell's
/// neighbourhood lies inside its region, clipped where the chunk box clips it, so every
/// test sees the cells the whole-box pass would see. Only the integral images' origin
/// moves: float values summed in double stay exact while the ratio of the largest to the
/// smallest magnitude times the number of terms stays below 2^29 (53 − 24 bits), so in
/// practice the candidates are those of the reference (the tests compare bit for bit).
struct Active {
  static constexpr int kBlock = 16;
  BlockRegions blocks;
  bool whole = false;  ///< one region, the whole box: every cell is its own

  Active(int w, int h) : blocks(w, h, kBlock) {}
  [[nodiscard]] const std::vector<Region>& regions() const { return blocks.regions; }
  [[nodiscard]] bool owns(const Region& r, int x, int y) const {
    return whole || blocks.label_at(x, y) == r.label;
  }
};

Active active_regions(const CovarianceGridmap& map, const CellBox& box,
                      const PointExtractorConfig& cfg, const Thresholds& th, int train,
                      bool has_floor) {
  const int w = box.width(), h = box.height();
  Active a(w, h);
  if (!has_floor) {
    // No power floor (synthetic maps): every observed cell is tested.
    a.whole = true;
    a.blocks.regions.push_back(Region{0, 0, w, h, 1});
    return a;
  }
  // The test's own first three conditions (stream(), below), on a superset.
  for (const auto& [ix, iy] :
       map.cells_above(box, th.min_power, cfg.min_persistence, th.min_count)) {
    a.blocks.mark(ix - box.min_ix, iy - box.min_iy);
  }
  a.blocks.group((train + Active::kBlock - 1) / Active::kBlock);
  return a;
}

template <int Q>
std::vector<PointCandidate> stream(const CovarianceGridmap& map, const Chunk& chunk,
                                   const PointExtractorConfig& cfg) {
  constexpr int L = num_layers(Q);
  constexpr int NP = 1 + Q + 2 * (L - Q);  // PlaneLayout::num
  const CellBox& box = chunk.box;
  const int box_w = box.width(), box_h = box.height();
  const double cs = map.cell_size_m();
  int guard = 0, train = 0;
  check_config(cfg, cs, guard, train);
  const double noise = map.noise_power();
  const Thresholds th(cfg, Q, noise, guard, train);
  const PlaneLayout layout(Q);

  std::vector<std::uint32_t> one_count(box_w), one_hits(box_w);
  std::vector<std::complex<float>> one_layers(static_cast<std::size_t>(box_w) * L);
  double eps = cfg.loading * noise;
  if (!(noise > 0.0)) {
    // Without a noise figure (synthetic maps): 1e-3 of the mean observed power, over the
    // whole box as the reference computes it.
    double sum = 0.0;
    std::size_t n = 0;
    for (int y = 0; y < box_h; ++y) {
      map.read_row(box.min_iy + y, box.min_ix, box.max_ix, one_count, one_hits, one_layers);
      for (int x = 0; x < box_w; ++x) {
        if (one_count[x] == 0) continue;
        sum += cell_power(one_layers.data() + static_cast<std::size_t>(x) * L, 1, Q);
        ++n;
      }
    }
    const double mean = n > 0 ? sum / n / Q : 1.0;
    eps = cfg.loading * 1e-3 * (mean > 0.0 ? mean : 1.0);
  }

  const CMat<Q> load = CMat<Q>::Identity() * eps;
  const auto strips = strip_offsets(guard, train);
  std::vector<double> sums(NP), strip(NP), best(NP);
  std::vector<DetectedCell> dets;
  std::vector<std::pair<int, int>> det_xy;
  thread_local Workspace ws;
  const Active active = active_regions(map, box, cfg, th, train, noise > 0.0);

  // One active region: its own raster rows y − train .. y + train and integral rows
  // y − train .. y + train + 1, in region coordinates (cell (x, y) of the region is cell
  // (x0 + x, y0 + y) of the chunk box).
  auto scan = [&](const Region& region) {
    const int x0 = region.x0, y0 = region.y0;
    const int w = region.x1 - region.x0, h = region.y1 - region.y0;
    RowRing<std::uint32_t> count(ws.count, 2 * train + 1, w), hits(ws.hits, 2 * train + 1, w);
    RowRing<std::complex<float>> layers(ws.layers, 2 * train + 1, static_cast<std::size_t>(w) * L);
    RowRing<float> power(ws.power, 2 * train + 1, w);
    // Per cell its Q diagonal layers and 1 if observed (0 if not), packed: what the line
    // strips compare (brightest_strip), in a sixth of the layers' bytes.
    RowRing<float> diag(ws.diag, 2 * train + 1, static_cast<std::size_t>(w) * (Q + 1));
    const std::size_t W = static_cast<std::size_t>(w) + 1;
    RowRing<double> full(ws.full, 2 * train + 2, W * NP), trace(ws.trace, 2 * train + 2, W * 2);
    std::fill(full.row(0), full.row(0) + W * NP, 0.0);
    std::fill(trace.row(0), trace.row(0) + W * 2, 0.0);

    auto trace_box = [&](int x0, int y0, int x1, int y1, double sign, double* acc) {
      if (!clip_to_raster(w, h, x0, y0, x1, y1)) return;
      const double* r0 = trace.row(y0);
      const double* r1 = trace.row(y1);
      for (int k = 0; k < 2; ++k) {
        acc[k] += sign * (r1[x1 * 2 + k] - r0[x1 * 2 + k] - r1[x0 * 2 + k] + r0[x0 * 2 + k]);
      }
    };
    auto full_box = [&](int x0, int y0, int x1, int y1, double sign, double* acc) {
      if (!clip_to_raster(w, h, x0, y0, x1, y1)) return;
      const double* a = full.row(y1) + x1 * NP;
      const double* b = full.row(y0) + x1 * NP;
      const double* c = full.row(y1) + x0 * NP;
      const double* d = full.row(y0) + x0 * NP;
      for (int k = 0; k < NP; ++k) acc[k] += sign * (a[k] - b[k] - c[k] + d[k]);
    };

    for (int r = 0; r < h + train; ++r) {
      if (r < h) {
        // Read raster row r and extend both integral images by row r + 1.
        std::uint32_t* cnt = count.row(r);
        std::complex<float>* lay = layers.row(r);
        float* pw = power.row(r);
        map.read_row(box.min_iy + y0 + r, box.min_ix + x0, box.min_ix + x0 + w,
                     {cnt, static_cast<std::size_t>(w)}, {hits.row(r), static_cast<std::size_t>(w)},
                     {lay, static_cast<std::size_t>(w) * L});
        float* dg = diag.row(r);
        for (int x = 0; x < w; ++x) {
          const std::complex<float>* v = lay + static_cast<std::size_t>(x) * L;
          pw[x] = cell_power(v, 1, Q);
          float* d = dg + static_cast<std::size_t>(x) * (Q + 1);
          for (int i = 0; i < Q; ++i) d[i] = v[layer_index(Q, i, i)].real();
          d[Q] = cnt[x] > 0 ? 1.0F : 0.0F;
        }
        const double* above = full.row(r);
        double* out = full.row(r + 1);
        const double* tabove = trace.row(r);
        double* tout = trace.row(r + 1);
        std::fill(out, out + NP, 0.0);
        tout[0] = tout[1] = 0.0;
        double row[NP] = {};
        double n = 0.0, t = 0.0;
        for (int x = 0; x < w; ++x) {
          if (cnt[x] > 0) {
            n += 1.0;
            t += pw[x];
            row[0] += 1.0;
            const std::complex<float>* v = lay + static_cast<std::size_t>(x) * L;
            int k = 1;
            for (int i = 0; i < Q; ++i) {
              for (int j = i; j < Q; ++j) {
                const std::complex<float> c = v[layer_index(Q, i, j)];
                row[k++] += c.real();
                if (i != j) row[k++] += c.imag();
              }
            }
          }
          const double* a = above + (x + 1) * NP;
          double* o = out + (x + 1) * NP;
          for (int k = 0; k < NP; ++k) o[k] = a[k] + row[k];
          tout[(x + 1) * 2] = tabove[(x + 1) * 2] + n;
          tout[(x + 1) * 2 + 1] = tabove[(x + 1) * 2 + 1] + t;
        }
      }
      const int y = r - train;
      if (y < 0) continue;
      // Test the cells of row y (its whole neighbourhood is available now).
      const std::uint32_t* cnt = count.row(y);
      const std::uint32_t* hit = hits.row(y);
      const float* pw = power.row(y);
      for (int x = 0; x < w; ++x) {
        // Cheapest and most selective condition first; owns() divides.
        if (!(pw[x] > th.min_power)) continue;
        if (cnt[x] < th.min_count) continue;
        if (hit[x] < cfg.min_persistence * cnt[x]) continue;
        if (!active.owns(region, x0 + x, y0 + y)) continue;
        double s[2] = {0.0, 0.0};
        trace_box(x - train, y - train, x + train + 1, y + train + 1, 1.0, s);
        trace_box(x - guard, y - guard, x + guard + 1, y + guard + 1, -1.0, s);
        if (s[0] < th.min_ring) continue;
        if (!(pw[x] > th.contrast * (s[1] / s[0]) * (1.0 - 1e-9))) continue;
        std::fill(sums.begin(), sums.end(), 0.0);
        full_box(x - train, y - train, x + train + 1, y + train + 1, 1.0, sums.data());
        full_box(x - guard, y - guard, x + guard + 1, y + guard + 1, -1.0, sums.data());
        if (sums[0] < th.min_ring) continue;
        const double tr_c = pw[x];
        double tr_s = 0.0;
        for (int i = 0; i < Q; ++i) tr_s += sums[layout.re[layer_index(Q, i, i)]];
        tr_s /= sums[0];
        if (!(tr_c > th.contrast * tr_s)) continue;
        const std::complex<float>* cell_layers = layers.row(y) + static_cast<std::size_t>(x) * L;
        const CMat<Q> c = cell_matrix<Q>(cell_layers, 1) + load;
        bool ok = false;
        double e = excess<Q>(mean_matrix<Q>(layout, sums.data()) + load, c, ok);
        if (!ok || !(e > cfg.threshold)) continue;
        const double* chosen = sums.data();
        if (cfg.line_aware) {
          double best_tr = tr_s;
          if (brightest_strip<Q>(
                  strips, layout, x, y, w, h, 1,
                  [&](int xx, int yy) -> const std::complex<float>* {
                    return count.row(yy)[xx] == 0
                               ? nullptr
                               : layers.row(yy) + static_cast<std::size_t>(xx) * L;
                  },
                  [&](int xx, int yy) -> const float* {
                    const float* d = diag.row(yy) + static_cast<std::size_t>(xx) * (Q + 1);
                    return d[Q] == 0.0F ? nullptr : d;
                  },
                  strip, best, best_tr)) {
            chosen = best.data();
          }
          if (chosen != sums.data()) {
            if (!(tr_c > th.contrast * best_tr)) continue;
            e = excess<Q>(mean_matrix<Q>(layout, chosen) + load, c, ok);
            if (!ok || !(e > cfg.threshold)) continue;
          }
        }
        const CMat<Q> sg = mean_matrix<Q>(layout, chosen);
        DetectedCell d;
        d.idx = static_cast<std::size_t>(y0 + y) * box_w + (x0 + x);
        d.stat = static_cast<float>(e);
        d.power = pw[x];
        d.layers.assign(cell_layers, cell_layers + L);
        d.sigma.resize(L);
        for (int i = 0; i < Q; ++i) {
          for (int j = i; j < Q; ++j) d.sigma[layer_index(Q, i, j)] = sg(i, j);
        }
        dets.push_back(std::move(d));
        det_xy.emplace_back(x0 + x, y0 + y);
      }
    }
  };
  for (const Region& region : active.regions()) scan(region);
  // Raster order of the chunk (the reference's), whatever the order of the regions.
  if (active.regions().size() > 1) {
    std::vector<int> order(dets.size());
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](int a, int b) { return dets[a].idx < dets[b].idx; });
    std::vector<DetectedCell> sorted_dets;
    std::vector<std::pair<int, int>> sorted_xy;
    sorted_dets.reserve(dets.size());
    sorted_xy.reserve(dets.size());
    for (int i : order) {
      sorted_dets.push_back(std::move(dets[i]));
      sorted_xy.push_back(det_xy[i]);
    }
    dets = std::move(sorted_dets);
    det_xy = std::move(sorted_xy);
  }
  std::unordered_map<std::size_t, int> det_at;
  for (std::size_t i = 0; i < dets.size(); ++i) det_at.emplace(dets[i].idx, static_cast<int>(i));
  if (dets.empty()) return {};

  // 8-connected components of the detections.
  std::vector<int> parent(dets.size());
  std::iota(parent.begin(), parent.end(), 0);
  for (std::size_t i = 0; i < dets.size(); ++i) {
    const auto [x, y] = det_xy[i];
    for (const auto& [dx, dy] : {std::pair{-1, 0}, {-1, -1}, {0, -1}, {1, -1}}) {
      const int xx = x + dx, yy = y + dy;
      if (xx < 0 || yy < 0 || xx >= box_w) continue;
      const auto it = det_at.find(static_cast<std::size_t>(yy) * box_w + xx);
      if (it == det_at.end()) continue;
      const int a = find_root(parent, static_cast<int>(i)), b = find_root(parent, it->second);
      if (a != b) parent[std::max(a, b)] = std::min(a, b);
    }
  }
  std::vector<int> label(dets.size());
  std::vector<std::array<int, 4>> bbox(1, {0, 0, 0, 0});
  std::unordered_map<int, int> label_of_root;
  for (std::size_t i = 0; i < dets.size(); ++i) {
    const int root = find_root(parent, static_cast<int>(i));
    const auto [it, inserted] = label_of_root.try_emplace(root, static_cast<int>(bbox.size()));
    const auto [x, y] = det_xy[i];
    if (inserted) bbox.push_back({x, y, x, y});
    auto& b = bbox[it->second];
    b = {std::min(b[0], x), std::min(b[1], y), std::max(b[2], x), std::max(b[3], y)};
    label[i] = it->second;
  }
  return candidates_from_components(dets, label, bbox, box, cs, map.level(), cfg, &chunk.core,
                                    [&](int ix, int iy) {
                                      map.read_row(iy, ix, ix + 1, one_count, one_hits, one_layers);
                                      return cell_power(one_layers.data(), 1, Q);
                                    });
}

}  // namespace

std::vector<PointCandidate> extract_chunk_streaming(const CovarianceGridmap& map,
                                                    const Chunk& chunk,
                                                    const PointExtractorConfig& cfg) {
  switch (map.q()) {
    case 1:
      return stream<1>(map, chunk, cfg);
    case 2:
      return stream<2>(map, chunk, cfg);
    case 3:
      return stream<3>(map, chunk, cfg);
    default:
      throw ContractViolation("pCFAR: unsupported q");
  }
}

}  // namespace polmap::radar::pcfar
