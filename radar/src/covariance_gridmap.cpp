#include "polmap/radar/covariance_gridmap.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <deque>
#include <limits>
#include <map>
#include <numbers>
#include <string>
#include <type_traits>
#include <unordered_map>

#include "polmap/radar/polarimetry.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::radar {
namespace {

constexpr int kT = kTileSizeCells;       // cells per tile side
constexpr int kB = 8;                    // cells per block side
constexpr int kBlocksPerSide = kT / kB;  // blocks per tile side
constexpr int kCellsPerBlock = kB * kB;  // coverage blocks (one 64-bit mask)
/// Covariance sums are allocated per data block of kD × kD cells: small, because
/// isolated far-range bins (2 m arcs) would otherwise allocate mostly empty blocks.
constexpr int kD = 4;
constexpr int kDataBlocksPerSide = kT / kD;
constexpr int kCellsPerDataBlock = kD * kD;
constexpr int kCellsPerTile = kT * kT;
static_assert(kT == 64, "tile index math below uses shifts by 6");
/// Gaps of up to this many zero range bins inside a beam are scanned with the
/// surrounding run (cheaper than restarting the scan conversion).
constexpr int kRunGapBins = 4;

std::uint64_t tile_key(int tx, int ty) {
  return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(tx)) << 32) |
         static_cast<std::uint32_t>(ty);
}
int key_tx(std::uint64_t k) {
  return static_cast<std::int32_t>(static_cast<std::uint32_t>(k >> 32));
}
int key_ty(std::uint64_t k) { return static_cast<std::int32_t>(static_cast<std::uint32_t>(k)); }

inline double cross(double ax, double ay, double bx, double by) { return ax * by - ay * bx; }

/// One frame's sensor footprint geometry in the map frame. Every membership test
/// (coverage and data) goes through the same arithmetic below, so a cell that
/// receives data is always counted in N and beams partition the footprint exactly.
struct Geometry {
  double px = 0, py = 0;       // sensor position
  std::vector<double> ex, ey;  // M+1 beam edge directions (unit), ascending azimuth
  double dr = 0, inv_dr = 0;   // range bin size
  int num_bins = 0;            // usable range bins
  double r_max = 0;            // (num_bins − ½)·dr
  double cs = 0;               // cell size

  [[nodiscard]] int range_bin(double r2) const {
    return static_cast<int>(std::sqrt(r2) * inv_dr + 0.5);
  }
  [[nodiscard]] bool in_wedge(int k_lo, int k_hi, double vx, double vy) const {
    return cross(ex[k_lo], ey[k_lo], vx, vy) >= 0.0 && cross(vx, vy, ex[k_hi], ey[k_hi]) > 0.0;
  }
  /// The footprint predicate: nearest polar bin exists.
  [[nodiscard]] bool in_footprint(double vx, double vy) const {
    return in_wedge(0, static_cast<int>(ex.size()) - 1, vx, vy) &&
           range_bin(vx * vx + vy * vy) < num_bins;
  }
  [[nodiscard]] double cx(int ix) const { return (ix + 0.5) * cs - px; }
  [[nodiscard]] double cy(int iy) const { return (iy + 0.5) * cs - py; }

  /// y (or x) extent of the annular wedge between edges k_lo..k_hi, radii [r_in, r_out].
  void wedge_bbox(int k_lo, int k_hi, double r_in, double r_out, double& xmin, double& xmax,
                  double& ymin, double& ymax) const {
    xmin = ymin = std::numeric_limits<double>::infinity();
    xmax = ymax = -std::numeric_limits<double>::infinity();
    for (int k : {k_lo, k_hi}) {
      for (double r : {r_in, r_out}) {
        xmin = std::min(xmin, r * ex[k]);
        xmax = std::max(xmax, r * ex[k]);
        ymin = std::min(ymin, r * ey[k]);
        ymax = std::max(ymax, r * ey[k]);
      }
    }
    auto contains_dir = [&](double dx, double dy) {
      return cross(ex[k_lo], ey[k_lo], dx, dy) >= 0.0 && cross(dx, dy, ex[k_hi], ey[k_hi]) >= 0.0;
    };
    if (contains_dir(1, 0)) xmax = std::max(xmax, r_out);
    if (contains_dir(-1, 0)) xmin = std::min(xmin, -r_out);
    if (contains_dir(0, 1)) ymax = std::max(ymax, r_out);
    if (contains_dir(0, -1)) ymin = std::min(ymin, -r_out);
    xmin += px;
    xmax += px;
    ymin += py;
    ymax += py;
  }
};

enum class Cover { Outside, Inside, Partial };

/// Classifies the rectangle of cell centres [x0,x1]×[y0,y1] (map frame) against
/// the footprint. The footprint (wedge < 180° ∩ disk) is convex, so a rectangle
/// whose four corner centres are inside is inside entirely. Outside is decided
/// conservatively (separating half-plane or disk); everything else is Partial.
Cover classify_rect(const Geometry& g, double x0, double x1, double y0, double y1) {
  const int last = static_cast<int>(g.ex.size()) - 1;
  const double xs[2] = {x0 - g.px, x1 - g.px};
  const double ys[2] = {y0 - g.py, y1 - g.py};
  int inside = 0, out_lo = 0, out_hi = 0;
  for (double vx : xs) {
    for (double vy : ys) {
      if (g.in_footprint(vx, vy)) ++inside;
      if (cross(g.ex[0], g.ey[0], vx, vy) < 0.0) ++out_lo;
      if (cross(vx, vy, g.ex[last], g.ey[last]) <= 0.0) ++out_hi;
    }
  }
  if (inside == 4) return Cover::Inside;
  if (out_lo == 4 || out_hi == 4) return Cover::Outside;
  const double dx = std::max({xs[0], 0.0, -xs[1]});
  const double dy = std::max({ys[0], 0.0, -ys[1]});
  // Margin of a cell: the disk test only needs to be conservative.
  if (dx * dx + dy * dy > (g.r_max + g.cs) * (g.r_max + g.cs)) return Cover::Outside;
  return Cover::Partial;
}

template <typename T>
struct Tile {
  std::uint32_t base = 0;     // frames that covered every cell of the tile
  std::uint32_t touch = 0;    // frames/samples that touched the tile (frees it at 0)
  std::uint32_t partial = 0;  // upper bound of any per-cell residual count
  std::unique_ptr<std::uint16_t[]> n16;
  std::unique_ptr<std::uint32_t[]> n32;
  /// Packed sums per data block: per cell `stride` scalars (see ImplT::off_).
  std::array<std::unique_ptr<T[]>, kDataBlocksPerSide * kDataBlocksPerSide> blocks{};

  [[nodiscard]] std::uint32_t count(int local) const {
    if (n32) return base + n32[local];
    if (n16) return base + n16[local];
    return base;
  }
  /// Makes room for `more` additional partial counts (16 bit until that could overflow).
  void reserve_partial(std::uint32_t more) {
    partial += more;
    if (n32) return;
    if (partial > std::numeric_limits<std::uint16_t>::max()) {
      n32 = std::make_unique<std::uint32_t[]>(kCellsPerTile);  // zero-initialised
      if (n16) {
        for (int i = 0; i < kCellsPerTile; ++i) n32[i] = n16[i];
        n16.reset();
      }
    } else if (!n16) {
      n16 = std::make_unique<std::uint16_t[]>(kCellsPerTile);
    }
  }
  void add_count(int local, int sign) {
    if (n32) {
      n32[local] += static_cast<std::uint32_t>(sign);
    } else {
      n16[local] = static_cast<std::uint16_t>(n16[local] + sign);
    }
  }
  T* block(int b, int stride) {
    if (!blocks[b]) blocks[b] = std::make_unique<T[]>(kCellsPerDataBlock * stride);
    return blocks[b].get();
  }
  [[nodiscard]] std::size_t bytes(int stride) const {
    std::size_t b = sizeof(*this);
    if (n16) b += kCellsPerTile * sizeof(std::uint16_t);
    if (n32) b += kCellsPerTile * sizeof(std::uint32_t);
    for (const auto& blk : blocks) {
      if (blk) b += kCellsPerDataBlock * stride * sizeof(T);
    }
    return b;
  }
};

inline int local_index(int ix, int iy) { return (iy & (kT - 1)) * kT + (ix & (kT - 1)); }
inline int block_of(int local) {
  return ((local / kT) / kD) * kDataBlocksPerSide + (local % kT) / kD;
}
inline int cell_in_block(int local) { return ((local / kT) % kD) * kD + (local % kT) % kD; }

/// Calls f(blk, c, local, ix, iy) for every cell c of every stored data block of tile
/// (tx, ty) that lies inside box (blk: the block's sums, local: the cell in the tile).
template <typename T, typename F>
void for_each_stored_cell(const Tile<T>& t, int tx, int ty, const CellBox& box, F&& f) {
  for (int b = 0; b < kDataBlocksPerSide * kDataBlocksPerSide; ++b) {
    const T* blk = t.blocks[b].get();
    if (!blk) continue;
    const int row0 = (b / kDataBlocksPerSide) * kD, col0 = (b % kDataBlocksPerSide) * kD;
    const int ix0 = tx * kT + col0, iy0 = ty * kT + row0;
    // Blocks entirely outside the box contribute nothing.
    if (ix0 + kD <= box.min_ix || ix0 >= box.max_ix || iy0 + kD <= box.min_iy ||
        iy0 >= box.max_iy) {
      continue;
    }
    for (int c = 0; c < kCellsPerDataBlock; ++c) {
      const int ix = ix0 + c % kD, iy = iy0 + c / kD;
      if (ix < box.min_ix || ix >= box.max_ix || iy < box.min_iy || iy >= box.max_iy) continue;
      f(blk, c, (row0 + c / kD) * kT + col0 + c % kD, ix, iy);
    }
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------------

struct CovarianceGridmap::Impl {
  virtual ~Impl() = default;
  virtual void apply(const PolSpectrum& s, const Pose2& T, int sign) = 0;
  virtual void add_sample(int ix, int iy, std::span<const cdouble> k) = 0;
  virtual void merge(const CovarianceTileView& v) = 0;
  [[nodiscard]] virtual std::size_t num_tiles() const = 0;
  [[nodiscard]] virtual std::size_t tile_bytes() const = 0;
  [[nodiscard]] virtual std::vector<std::uint64_t> keys() const = 0;
  /// Writes N and C (layers) of one tile into dense arrays (kT² counts, L·kT² layers);
  /// returns false if the tile does not exist.
  virtual bool materialize(int tx, int ty, std::uint32_t* counts, std::complex<float>* layers,
                           std::uint32_t* hits) const = 0;
  /// Writes N, hits and C of the cells of tile (tx, ty) inside r.box straight into
  /// the raster (which is zero elsewhere); cells with N = 0 are left untouched.
  virtual void blit(int tx, int ty, CovarianceRaster& r) const = 0;
  virtual std::uint32_t hits(int ix, int iy) const = 0;
  /// CovarianceGridmap::read_row for the cells of one tile (ix0..ix1 inside tile tx).
  virtual void read_tile_row(int tx, int iy, int ix0, int ix1, std::uint32_t* count,
                             std::uint32_t* hits, std::complex<float>* layers) const = 0;
  /// Writes trace(C) of one tile (kT² floats, 0 where N = 0); false if the tile does not exist.
  /// CovarianceGridmap::cells_above for the cells of tile (tx, ty) inside box.
  virtual void cells_above(int tx, int ty, const CellBox& box, double min_power,
                           double min_persistence, std::uint32_t min_count,
                           std::vector<std::array<int, 2>>& out) const = 0;
  virtual bool materialize_trace(int tx, int ty, float* trace, double min_persistence) const = 0;
  virtual std::uint32_t count(int ix, int iy) const = 0;
  virtual void cell_sums(int ix, int iy, cdouble* out) const = 0;

  /// What one window frame did to the map, recorded when it was added, so that its
  /// removal replays exactly those cells (counts return exactly, sums to rounding)
  /// without recomputing the footprint geometry and scan conversion.
  struct FrameOps {
    struct Cover {
      std::uint64_t tile = 0;
      bool inside = false;                    ///< the whole tile was covered (base count)
      std::array<std::uint64_t, 64> masks{};  ///< partial: per 8×8 block, covered cells
    };
    struct Cell {
      int ix = 0, iy = 0;
      std::uint32_t product = 0;  ///< offset into products
    };
    std::vector<Cover> cover;
    std::vector<Cell> cells;
    std::vector<float> products;  ///< per stored bin: its packed k k^H and hit
    [[nodiscard]] std::size_t bytes() const {
      return cover.capacity() * sizeof(Cover) + cells.capacity() * sizeof(Cell) +
             products.capacity() * sizeof(float);
    }
  };
  /// Removes a frame recorded by apply(..., +1, &ops) (window mode only).
  virtual void unapply(const FrameOps& ops) = 0;
  virtual void apply_recorded(const PolSpectrum& s, const Pose2& T, FrameOps& ops) = 0;

  struct FrameRecord {
    double time_s;
    float noise_sigma;
    FrameOps ops;
  };
  std::deque<FrameRecord> window;
  double noise_sum = 0.0;
  std::int64_t frames = 0;
  std::size_t window_bytes = 0;
  double imported_noise_power = 0.0;  ///< set_noise_power() of a map built by merge_tile
};

namespace {

template <typename T>
class ImplT final : public CovarianceGridmap::Impl {
  // The window records its products as float (FrameOps::products) and subtracts them.
  static_assert(std::is_same_v<T, float>, "sums are float in both modes");

 public:
  ImplT(const GridmapConfig& cfg) : cfg_(cfg), q_(pol_dimension(cfg.level)), L_(num_layers(q_)) {
    // Packed layout per cell: diagonal layers are real (one scalar), off-diagonal
    // layers complex (two): q + 2·(L − q) scalars instead of 2L.
    off_.resize(L_);
    cplx_.resize(L_);
    int k = 0;
    for (int i = 0; i < q_; ++i) {
      for (int j = i; j < q_; ++j) {
        const int l = layer_index(q_, i, j);
        off_[l] = k;
        cplx_[l] = i != j;
        k += i != j ? 2 : 1;
      }
    }
    hit_ = k;  // last scalar: number of non-zero contributions (persistence)
    stride_ = k + 1;
  }

  void apply(const PolSpectrum& s, const Pose2& T_frame_sensor, int sign) override {
    const Geometry g = make_geometry(s, T_frame_sensor);
    touched_.clear();
    cover(g, sign);
    scatter(g, s, sign);
    if (sign < 0) free_untouched();
  }

  void apply_recorded(const PolSpectrum& s, const Pose2& T_frame_sensor, FrameOps& ops) override {
    const Geometry g = make_geometry(s, T_frame_sensor);
    touched_.clear();
    record_ = &ops;
    cover(g, +1);
    scatter(g, s, +1);
    record_ = nullptr;
  }

  void unapply(const FrameOps& ops) override {
    touched_.clear();
    for (const FrameOps::Cover& c : ops.cover) {
      Tile<T>& t = tile(key_tx(c.tile), key_ty(c.tile));
      t.touch -= 1;
      touched_.push_back(c.tile);
      if (c.inside) {
        t.base -= 1;
        continue;
      }
      t.partial -= 1;
      for (int b = 0; b < kBlocksPerSide * kBlocksPerSide; ++b) {
        if (c.masks[b] == 0) continue;
        const int row0 = (b / kBlocksPerSide) * kB, col0 = (b % kBlocksPerSide) * kB;
        if (t.n32) {
          count_block(t.n32.get(), row0, col0, c.masks[b], -1);
        } else {
          count_block(t.n16.get(), row0, col0, c.masks[b], -1);
        }
      }
    }
    for (const FrameOps::Cell& c : ops.cells) {
      Tile<T>& t = tile(c.ix >> 6, c.iy >> 6);
      const int local = local_index(c.ix, c.iy);
      T* sums = t.block(block_of(local), stride_) + cell_in_block(local) * stride_;
      const float* p = ops.products.data() + c.product;
      // s − p equals s + (−p): the same value the re-applied negative frame adds.
      for (int k = 0; k < stride_; ++k) sums[k] -= p[k];
      // No frame left with data in the cell: its sums are zero, not a rounding residue
      // (residues of far smaller magnitude than the data would make the pCFAR's
      // integral images inexact).
      if (sums[hit_] == T(0)) std::fill(sums, sums + stride_, T(0));
    }
    free_untouched();
  }

  /// Frees the tiles of touched_ that no frame touches any more.
  void free_untouched() {
    for (std::uint64_t k : touched_) {
      auto it = tiles_.find(k);
      if (it != tiles_.end() && it->second->touch == 0) tiles_.erase(it);
    }
    cache_tile_ = nullptr;  // may point at an erased tile
  }

  void add_sample(int ix, int iy, std::span<const cdouble> k) override {
    POLMAP_EXPECT(static_cast<int>(k.size()) == q_);
    Tile<T>& t = tile(ix >> 6, iy >> 6);
    t.touch += 1;
    t.reserve_partial(1);
    const int local = local_index(ix, iy);
    t.add_count(local, +1);
    T* s = t.block(block_of(local), stride_) + cell_in_block(local) * stride_;
    for (int i = 0; i < q_; ++i) {
      for (int j = i; j < q_; ++j) {
        const int l = layer_index(q_, i, j);
        const cdouble p = k[i] * std::conj(k[j]);
        s[off_[l]] += static_cast<T>(p.real());
        if (cplx_[l]) s[off_[l] + 1] += static_cast<T>(p.imag());
      }
    }
    bool nonzero = false;
    for (const cdouble& x : k) nonzero = nonzero || x != cdouble(0.0, 0.0);
    if (nonzero) s[hit_] += T(1);
  }

  void merge(const CovarianceTileView& v) override {
    POLMAP_EXPECT(v.size_cells == kT && v.q == q_);
    std::uint32_t max_n = 0;
    for (std::uint32_t n : v.count) max_n = std::max(max_n, n);
    if (max_n == 0) return;
    Tile<T>& t = tile(v.tile_x, v.tile_y);
    t.touch += 1;
    t.reserve_partial(max_n);
    const std::size_t plane = static_cast<std::size_t>(kT) * kT;
    for (int local = 0; local < kCellsPerTile; ++local) {
      const std::uint32_t n = v.count[local];
      if (n == 0) continue;
      if (t.n32) {
        t.n32[local] += n;
      } else {
        t.n16[local] = static_cast<std::uint16_t>(t.n16[local] + n);
      }
      T* s = t.block(block_of(local), stride_) + cell_in_block(local) * stride_;
      for (int l = 0; l < L_; ++l) {
        const std::complex<float> c = v.layers[l * plane + local];
        s[off_[l]] += static_cast<T>(c.real()) * n;
        if (cplx_[l]) s[off_[l] + 1] += static_cast<T>(c.imag()) * n;
      }
      // Without persistence information every look counts as a hit.
      s[hit_] += static_cast<T>(v.hits.empty() ? n : v.hits[local]);
    }
  }

  [[nodiscard]] std::size_t num_tiles() const override { return tiles_.size(); }
  [[nodiscard]] std::size_t tile_bytes() const override {
    std::size_t b = tiles_.bucket_count() * sizeof(void*);
    for (const auto& [k, t] : tiles_) b += t->bytes(stride_) + 32;
    return b;
  }
  [[nodiscard]] std::vector<std::uint64_t> keys() const override {
    std::vector<std::uint64_t> k;
    k.reserve(tiles_.size());
    for (const auto& [key, t] : tiles_) k.push_back(key);
    return k;
  }

  bool materialize(int tx, int ty, std::uint32_t* counts, std::complex<float>* layers,
                   std::uint32_t* hits) const override {
    auto it = tiles_.find(tile_key(tx, ty));
    if (it == tiles_.end()) return false;
    const Tile<T>& t = *it->second;
    const std::size_t plane = kCellsPerTile;
    for (int local = 0; local < kCellsPerTile; ++local) counts[local] = t.count(local);
    std::fill(layers, layers + L_ * plane, std::complex<float>(0.0F, 0.0F));
    std::fill(hits, hits + plane, 0U);
    for (int b = 0; b < kDataBlocksPerSide * kDataBlocksPerSide; ++b) {
      const T* blk = t.blocks[b].get();
      if (!blk) continue;
      const int row0 = (b / kDataBlocksPerSide) * kD, col0 = (b % kDataBlocksPerSide) * kD;
      for (int c = 0; c < kCellsPerDataBlock; ++c) {
        const int local = (row0 + c / kD) * kT + col0 + c % kD;
        const std::uint32_t n = counts[local];
        if (n == 0) continue;
        const T inv = T(1) / static_cast<T>(n);
        const T* cell = blk + c * stride_;
        for (int l = 0; l < L_; ++l) {
          const T re = cell[off_[l]] * inv, im = cplx_[l] ? cell[off_[l] + 1] * inv : T(0);
          layers[l * plane + local] =
              std::complex<float>(static_cast<float>(re), static_cast<float>(im));
        }
        hits[local] = static_cast<std::uint32_t>(std::lround(std::max<T>(cell[hit_], T(0))));
      }
    }
    return true;
  }

  void blit(int tx, int ty, CovarianceRaster& r) const override {
    auto it = tiles_.find(tile_key(tx, ty));
    if (it == tiles_.end()) return;
    const Tile<T>& t = *it->second;
    const CellBox& box = r.box;
    const std::size_t plane = r.plane_size();
    const int w = box.width();
    // N first for every cell: a cell can be observed without a stored bin (no
    // data block), and it still counts as observed (CFAR ring statistics).
    const int ixa = std::max(box.min_ix, tx * kT), ixb = std::min(box.max_ix, tx * kT + kT);
    const int iya = std::max(box.min_iy, ty * kT), iyb = std::min(box.max_iy, ty * kT + kT);
    for (int iy = iya; iy < iyb; ++iy) {
      const std::size_t row = static_cast<std::size_t>(iy - box.min_iy) * w;
      for (int ix = ixa; ix < ixb; ++ix) {
        r.count[row + (ix - box.min_ix)] = t.count((iy - ty * kT) * kT + (ix - tx * kT));
      }
    }
    for_each_stored_cell(t, tx, ty, box, [&](const T* blk, int c, int local, int ix, int iy) {
      const std::uint32_t n = t.count(local);
      if (n == 0) return;
      const std::size_t idx =
          static_cast<std::size_t>(iy - box.min_iy) * w + static_cast<std::size_t>(ix - box.min_ix);
      const T inv = T(1) / static_cast<T>(n);
      const T* cell = blk + c * stride_;
      for (int l = 0; l < L_; ++l) {
        const T re = cell[off_[l]] * inv, im = cplx_[l] ? cell[off_[l] + 1] * inv : T(0);
        r.layers[l * plane + idx] =
            std::complex<float>(static_cast<float>(re), static_cast<float>(im));
      }
      r.hits[idx] = static_cast<std::uint32_t>(std::lround(std::max<T>(cell[hit_], T(0))));
    });
  }

  void read_tile_row(int tx, int iy, int ix0, int ix1, std::uint32_t* count, std::uint32_t* hits,
                     std::complex<float>* layers) const override {
    const int n_cells = ix1 - ix0;
    std::fill(layers, layers + static_cast<std::size_t>(n_cells) * L_,
              std::complex<float>(0.0F, 0.0F));
    std::fill(hits, hits + n_cells, 0U);
    auto it = tiles_.find(tile_key(tx, iy >> 6));
    if (it == tiles_.end()) {
      std::fill(count, count + n_cells, 0U);
      return;
    }
    const Tile<T>& t = *it->second;
    const int row = iy & (kT - 1);
    const int local0 = row * kT;
    for (int ix = ix0; ix < ix1; ++ix) count[ix - ix0] = t.count(local0 + (ix & (kT - 1)));
    // Per data block of the row (kD cells): one block pointer, then the cells.
    for (int ix = ix0; ix < ix1;) {
      const int col = ix & (kT - 1);
      const int block_end = std::min(ix1, ix + (kD - col % kD));
      const T* blk = t.blocks[block_of(local0 + col)].get();
      if (blk != nullptr) {
        const T* cell = blk + cell_in_block(local0 + col) * stride_;
        for (int x = ix; x < block_end; ++x, cell += stride_) {
          const int i = x - ix0;
          const std::uint32_t n = count[i];
          if (n == 0) continue;
          // Same arithmetic as blit(): the values are bit-identical to raster()'s.
          const T inv = T(1) / static_cast<T>(n);
          std::complex<float>* out = layers + static_cast<std::size_t>(i) * L_;
          for (int l = 0; l < L_; ++l) {
            const T re = cell[off_[l]] * inv, im = cplx_[l] ? cell[off_[l] + 1] * inv : T(0);
            out[l] = std::complex<float>(static_cast<float>(re), static_cast<float>(im));
          }
          // The hit sums are whole numbers (±1 per look): rounding is lround's.
          const T h = cell[hit_];
          hits[i] = h > T(0) ? static_cast<std::uint32_t>(h + T(0.5)) : 0U;
        }
      }
      ix = block_end;
    }
  }

  void cells_above(int tx, int ty, const CellBox& box, double min_power, double min_persistence,
                   std::uint32_t min_count, std::vector<std::array<int, 2>>& out) const override {
    auto it = tiles_.find(tile_key(tx, ty));
    if (it == tiles_.end()) return;
    const Tile<T>& t = *it->second;
    int diag[3] = {0, 0, 0};
    for (int i = 0; i < q_; ++i) diag[i] = off_[layer_index(q_, i, i)];
    // trace = Σ_d sum_d / N rounded per term to float: above min_power only if the exact
    // sum is above min_power·N within float rounding (≈ 1e-7 relative).
    const T floor = static_cast<T>(min_power * (1.0 - 1e-6));
    // Cells without a stored bin have trace 0: only stored blocks are visited.
    for_each_stored_cell(t, tx, ty, box, [&](const T* blk, int c, int local, int ix, int iy) {
      const std::uint32_t n = t.count(local);
      if (n == 0 || n < min_count) return;
      const T* cell = blk + c * stride_;
      // read_row's hits are round(h); h + ½ ≥ p·N keeps every cell it lets pass.
      if (cell[hit_] + T(0.5) < static_cast<T>(min_persistence * n)) return;
      T sum = 0;
      for (int d = 0; d < q_; ++d) sum += cell[diag[d]];
      if (sum > floor * static_cast<T>(n)) out.push_back({ix, iy});
    });
  }

  bool materialize_trace(int tx, int ty, float* trace, double min_persistence) const override {
    auto it = tiles_.find(tile_key(tx, ty));
    if (it == tiles_.end()) return false;
    const Tile<T>& t = *it->second;
    std::fill(trace, trace + kCellsPerTile, 0.0F);
    int diag[3] = {0, 0, 0};
    for (int i = 0; i < q_; ++i) diag[i] = layer_index(q_, i, i);
    for (int b = 0; b < kDataBlocksPerSide * kDataBlocksPerSide; ++b) {
      const T* blk = t.blocks[b].get();
      if (!blk) continue;
      const int row0 = (b / kDataBlocksPerSide) * kD, col0 = (b % kDataBlocksPerSide) * kD;
      for (int c = 0; c < kCellsPerDataBlock; ++c) {
        const int local = (row0 + c / kD) * kT + col0 + c % kD;
        const std::uint32_t n = t.count(local);
        if (n == 0) continue;
        if (blk[c * stride_ + hit_] < static_cast<T>(min_persistence * n) - T(0.5)) continue;
        T sum = 0;
        for (int i = 0; i < q_; ++i) sum += blk[c * stride_ + off_[diag[i]]];
        trace[local] = static_cast<float>(sum / static_cast<T>(n));
      }
    }
    return true;
  }

  std::uint32_t count(int ix, int iy) const override {
    auto it = tiles_.find(tile_key(ix >> 6, iy >> 6));
    if (it == tiles_.end()) return 0;
    return it->second->count(local_index(ix, iy));
  }

  std::uint32_t hits(int ix, int iy) const override {
    auto it = tiles_.find(tile_key(ix >> 6, iy >> 6));
    if (it == tiles_.end()) return 0;
    const int local = local_index(ix, iy);
    const T* blk = it->second->blocks[block_of(local)].get();
    if (!blk) return 0;
    return static_cast<std::uint32_t>(
        std::lround(std::max<T>(blk[cell_in_block(local) * stride_ + hit_], T(0))));
  }

  void cell_sums(int ix, int iy, cdouble* out) const override {
    std::fill(out, out + L_, cdouble(0, 0));
    auto it = tiles_.find(tile_key(ix >> 6, iy >> 6));
    if (it == tiles_.end()) return;
    const int local = local_index(ix, iy);
    const T* blk = it->second->blocks[block_of(local)].get();
    if (!blk) return;
    const T* cell = blk + cell_in_block(local) * stride_;
    for (int l = 0; l < L_; ++l) {
      out[l] = cdouble(cell[off_[l]], cplx_[l] ? cell[off_[l] + 1] : T(0));
    }
  }

 private:
  Tile<T>& tile(int tx, int ty) {
    const std::uint64_t k = tile_key(tx, ty);
    if (k == cache_key_ && cache_tile_ != nullptr) return *cache_tile_;
    auto& slot = tiles_[k];
    if (!slot) slot = std::make_unique<Tile<T>>();
    cache_key_ = k;
    cache_tile_ = slot.get();
    return *slot;
  }

  Geometry make_geometry(const PolSpectrum& s, const Pose2& pose) const {
    const std::size_t m = s.azimuth_bins_rad.size();
    if (m < 2) throw ValidationError("PolSpectrum: fewer than 2 azimuth bins");
    for (std::size_t k = 1; k < m; ++k) {
      if (!(s.azimuth_bins_rad[k] > s.azimuth_bins_rad[k - 1])) {
        throw ValidationError("PolSpectrum: azimuth_bins_rad not strictly ascending at bin " +
                              std::to_string(k));
      }
    }
    if (!(s.range_bin_m > 0.0)) throw ValidationError("PolSpectrum: range_bin_m must be > 0");
    std::vector<double> edges(m + 1);
    edges[0] = s.azimuth_bins_rad[0] - 0.5 * (s.azimuth_bins_rad[1] - s.azimuth_bins_rad[0]);
    for (std::size_t k = 1; k < m; ++k) {
      edges[k] = 0.5 * (double(s.azimuth_bins_rad[k - 1]) + double(s.azimuth_bins_rad[k]));
    }
    edges[m] =
        s.azimuth_bins_rad[m - 1] + 0.5 * (s.azimuth_bins_rad[m - 1] - s.azimuth_bins_rad[m - 2]);
    if (!(edges[m] - edges[0] < std::numbers::pi)) {
      throw ValidationError("PolSpectrum: beams span 180° or more (footprint must be convex)");
    }
    Geometry g;
    g.px = pose.x_m;
    g.py = pose.y_m;
    g.ex.resize(m + 1);
    g.ey.resize(m + 1);
    for (std::size_t k = 0; k <= m; ++k) {
      g.ex[k] = std::cos(pose.yaw_rad + edges[k]);
      g.ey[k] = std::sin(pose.yaw_rad + edges[k]);
    }
    g.dr = s.range_bin_m;
    g.inv_dr = 1.0 / s.range_bin_m;
    g.num_bins = s.num_range_bins;
    if (cfg_.max_range_m > 0.0) {
      g.num_bins = std::min(g.num_bins, static_cast<int>(cfg_.max_range_m * g.inv_dr + 0.5) + 1);
    }
    g.r_max = (g.num_bins - 0.5) * g.dr;
    g.cs = cfg_.cell_size_m;
    return g;
  }

  // ---- N: footprint coverage, hierarchical (tile / 8×8 block / cell) ----
  void cover(const Geometry& g, int sign) {
    if (g.num_bins <= 0) return;
    const int last = static_cast<int>(g.ex.size()) - 1;
    double xmin, xmax, ymin, ymax;
    g.wedge_bbox(0, last, 0.0, g.r_max, xmin, xmax, ymin, ymax);
    const double cs = g.cs;
    const int ix0 = static_cast<int>(std::floor(xmin / cs)) - 1;
    const int ix1 = static_cast<int>(std::floor(xmax / cs)) + 1;
    const int iy0 = static_cast<int>(std::floor(ymin / cs)) - 1;
    const int iy1 = static_cast<int>(std::floor(ymax / cs)) + 1;
    std::array<std::uint64_t, kBlocksPerSide * kBlocksPerSide> masks{};
    for (int ty = iy0 >> 6; ty <= iy1 >> 6; ++ty) {
      for (int tx = ix0 >> 6; tx <= ix1 >> 6; ++tx) {
        const int cx0 = tx * kT, cy0 = ty * kT;
        const Cover c = classify_rect(g, (cx0 + 0.5) * cs, (cx0 + kT - 0.5) * cs, (cy0 + 0.5) * cs,
                                      (cy0 + kT - 0.5) * cs);
        if (c == Cover::Outside) continue;
        if (c == Cover::Inside) {
          Tile<T>& t = tile(tx, ty);
          t.base += static_cast<std::uint32_t>(sign);
          t.touch += static_cast<std::uint32_t>(sign);
          touched_.push_back(tile_key(tx, ty));
          if (record_ != nullptr) record_->cover.push_back({tile_key(tx, ty), true, {}});
          continue;
        }
        // Partial tile: per block, full mask or per-cell mask.
        bool any = false;
        for (int b = 0; b < kBlocksPerSide * kBlocksPerSide; ++b) {
          const int bx0 = cx0 + (b % kBlocksPerSide) * kB, by0 = cy0 + (b / kBlocksPerSide) * kB;
          const Cover cb = classify_rect(g, (bx0 + 0.5) * cs, (bx0 + kB - 0.5) * cs,
                                         (by0 + 0.5) * cs, (by0 + kB - 0.5) * cs);
          std::uint64_t mask = 0;
          if (cb == Cover::Inside) {
            mask = ~std::uint64_t{0};
          } else if (cb == Cover::Partial) {
            for (int r = 0; r < kB; ++r) {
              const double vy = g.cy(by0 + r);
              for (int col = 0; col < kB; ++col) {
                if (g.in_footprint(g.cx(bx0 + col), vy)) mask |= std::uint64_t{1} << (r * kB + col);
              }
            }
          }
          masks[b] = mask;
          any = any || mask != 0;
        }
        if (!any) continue;
        Tile<T>& t = tile(tx, ty);
        t.touch += static_cast<std::uint32_t>(sign);
        touched_.push_back(tile_key(tx, ty));
        if (record_ != nullptr) {
          record_->cover.push_back({tile_key(tx, ty), false, {}});
          std::copy(masks.begin(), masks.end(), record_->cover.back().masks.begin());
        }
        if (sign > 0) {
          t.reserve_partial(1);
        } else {
          t.partial -= 1;
        }
        for (int b = 0; b < kBlocksPerSide * kBlocksPerSide; ++b) {
          const std::uint64_t mask = masks[b];
          if (mask == 0) continue;
          const int row0 = (b / kBlocksPerSide) * kB, col0 = (b % kBlocksPerSide) * kB;
          if (t.n32) {
            count_block(t.n32.get(), row0, col0, mask, sign);
          } else {
            count_block(t.n16.get(), row0, col0, mask, sign);
          }
        }
      }
    }
  }

  template <typename C>
  static void count_block(C* n, int row0, int col0, std::uint64_t mask, int sign) {
    const C d = static_cast<C>(sign);
    if (mask == ~std::uint64_t{0}) {
      for (int r = 0; r < kB; ++r) {
        C* p = n + (row0 + r) * kT + col0;
        for (int c = 0; c < kB; ++c) p[c] = static_cast<C>(p[c] + d);
      }
      return;
    }
    for (int i = 0; i < kCellsPerBlock; ++i) {
      if (mask & (std::uint64_t{1} << i)) {
        C& v = n[(row0 + i / kB) * kT + col0 + i % kB];
        v = static_cast<C>(v + d);
      }
    }
  }

  // ---- sums: scan conversion of non-zero bins ----
  void scatter(const Geometry& g, const PolSpectrum& s, int sign) {
    const auto& cells = s.cells;
    if (cells.empty()) return;
    const int m = static_cast<int>(s.azimuth_bins_rad.size());
    // Cells must be sorted by (azimuth_bin, range_bin); sort an index if they are not.
    std::vector<std::uint32_t> order;
    const bool sorted =
        std::is_sorted(cells.begin(), cells.end(), [](const auto& a, const auto& b) {
          return a.azimuth_bin != b.azimuth_bin ? a.azimuth_bin < b.azimuth_bin
                                                : a.range_bin < b.range_bin;
        });
    if (!sorted) {
      order.resize(cells.size());
      for (std::size_t i = 0; i < cells.size(); ++i) order[i] = static_cast<std::uint32_t>(i);
      std::stable_sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) {
        return cells[a].azimuth_bin != cells[b].azimuth_bin
                   ? cells[a].azimuth_bin < cells[b].azimuth_bin
                   : cells[a].range_bin < cells[b].range_bin;
      });
    }
    auto at = [&](std::size_t i) -> const SpectrumCell& {
      return sorted ? cells[i] : cells[order[i]];
    };

    std::array<cfloat, 4> kv{};
    std::size_t i = 0;
    while (i < cells.size()) {
      const SpectrumCell& first = at(i);
      if (first.azimuth_bin >= m || first.range_bin >= s.num_range_bins) {
        throw ValidationError("PolSpectrum: cell (range " + std::to_string(first.range_bin) +
                              ", azimuth " + std::to_string(first.azimuth_bin) +
                              ") outside the declared bins");
      }
      if (first.range_bin >= g.num_bins) {  // beyond max_range_m
        ++i;
        continue;
      }
      // Collect a run of the same beam with gaps ≤ kRunGapBins.
      const int beam = first.azimuth_bin;
      const int ia = first.range_bin;
      int ib = ia;
      std::size_t j = i;
      while (j < cells.size()) {
        const SpectrumCell& c = at(j);
        if (c.azimuth_bin != beam || c.range_bin >= g.num_bins) break;
        if (c.range_bin > ib + kRunGapBins + 1) break;
        if (c.range_bin >= s.num_range_bins) {
          throw ValidationError("PolSpectrum: range bin " + std::to_string(c.range_bin) +
                                " outside the declared bins");
        }
        ib = c.range_bin;
        ++j;
      }
      // Products k k^H per bin of the run (absent bins stay null).
      const int len = ib - ia + 1;
      prod_.assign(static_cast<std::size_t>(len) * stride_, T(0));
      has_.assign(len, 0);
      for (std::size_t c = i; c < j; ++c) {
        const SpectrumCell& sc = at(c);
        level_vector(sc.s, cfg_.level, kv.data());
        bool nonzero = false;
        for (int a = 0; a < q_; ++a) nonzero = nonzero || kv[a] != cfloat(0.0F, 0.0F);
        if (!nonzero) continue;
        T* p = prod_.data() + static_cast<std::size_t>(sc.range_bin - ia) * stride_;
        for (int a = 0; a < q_; ++a) {
          for (int b = a; b < q_; ++b) {
            const int l = layer_index(q_, a, b);
            const std::complex<T> x(kv[a].real(), kv[a].imag()), y(kv[b].real(), kv[b].imag());
            const std::complex<T> v = static_cast<T>(sign) * x * std::conj(y);
            p[off_[l]] += v.real();
            if (cplx_[l]) p[off_[l] + 1] += v.imag();
          }
        }
        p[hit_] = static_cast<T>(sign);
        has_[sc.range_bin - ia] = 1;
      }
      if (record_ != nullptr) {
        run_products_ = static_cast<std::uint32_t>(record_->products.size());
        record_->products.insert(record_->products.end(), prod_.begin(), prod_.end());
      }
      scan_run(g, beam, ia, ib);
      i = j;
    }
  }

  /// Visits every cell whose nearest polar bin is (range ∈ [ia, ib], beam) and adds
  /// the run's products. Rows are scan-converted analytically (wedge ∩ annulus) with
  /// a one-cell margin; the exact per-cell predicate decides.
  void scan_run(const Geometry& g, int beam, int ia, int ib) {
    const double cs = g.cs;
    const double r_in = std::max(0.0, (ia - 0.5) * g.dr);
    const double r_out = (ib + 0.5) * g.dr;
    double xmin, xmax, ymin, ymax;
    g.wedge_bbox(beam, beam + 1, r_in, r_out, xmin, xmax, ymin, ymax);
    const int iy0 = static_cast<int>(std::ceil(ymin / cs - 0.5)) - 1;
    const int iy1 = static_cast<int>(std::floor(ymax / cs - 0.5)) + 1;
    const double elx = g.ex[beam], ely = g.ey[beam];
    const double ehx = g.ex[beam + 1], ehy = g.ey[beam + 1];
    const double rin2 = r_in * r_in, rout2 = r_out * r_out;
    for (int iy = iy0; iy <= iy1; ++iy) {
      const double dy = g.cy(iy);
      const double dy2 = dy * dy;
      if (dy2 > rout2) continue;
      // Wedge: cross(e_lo, v) = elx·dy − ely·u ≥ 0 and cross(v, e_hi) = u·ehy − dy·ehx > 0.
      double umin = -std::numeric_limits<double>::infinity();
      double umax = std::numeric_limits<double>::infinity();
      bool empty = false;
      auto constrain = [&](double a, double b) {  // a·u + b ≥ 0
        if (a > 1e-12) {
          umin = std::max(umin, -b / a);
        } else if (a < -1e-12) {
          umax = std::min(umax, -b / a);
        } else if (b < -1e-9) {
          empty = true;
        }
      };
      constrain(-ely, elx * dy);
      constrain(ehy, -ehx * dy);
      if (empty) continue;
      const double uo = std::sqrt(std::max(0.0, rout2 - dy2));
      const double ui = rin2 > dy2 ? std::sqrt(rin2 - dy2) : 0.0;
      // Annulus pieces [−uo, −ui] and [ui, uo]; when ui = 0 they touch and merge.
      const double pieces[2][2] = {{-uo, -ui}, {ui, uo}};
      const int npieces = ui > 0.0 ? 2 : 1;
      for (int pi = 0; pi < npieces; ++pi) {
        const double lo = std::max(umin, npieces == 2 ? pieces[pi][0] : -uo);
        const double hi = std::min(umax, npieces == 2 ? pieces[pi][1] : uo);
        if (lo > hi + cs) continue;
        const int ixa = static_cast<int>(std::ceil((g.px + lo) / cs - 0.5)) - 1;
        const int ixb = static_cast<int>(std::floor((g.px + hi) / cs - 0.5)) + 1;
        for (int ix = ixa; ix <= ixb; ++ix) {
          const double vx = g.cx(ix);
          if (!g.in_wedge(beam, beam + 1, vx, dy)) continue;
          const int rb = g.range_bin(vx * vx + dy2);
          if (rb < ia || rb > ib) continue;
          if (!has_[rb - ia]) continue;
          accumulate(ix, iy, prod_.data() + static_cast<std::size_t>(rb - ia) * stride_);
          if (record_ != nullptr) {
            record_->cells.push_back(
                {ix, iy, run_products_ + static_cast<std::uint32_t>((rb - ia) * stride_)});
          }
        }
      }
    }
  }

  void accumulate(int ix, int iy, const T* p) {
    Tile<T>& t = tile(ix >> 6, iy >> 6);
    const int local = local_index(ix, iy);
    T* s = t.block(block_of(local), stride_) + cell_in_block(local) * stride_;
    for (int k = 0; k < stride_; ++k) s[k] += p[k];
  }

  GridmapConfig cfg_;
  int q_;
  int L_;
  std::unordered_map<std::uint64_t, std::unique_ptr<Tile<T>>> tiles_;
  std::uint64_t cache_key_ = 0;
  Tile<T>* cache_tile_ = nullptr;
  std::vector<std::uint64_t> touched_;
  FrameOps* record_ = nullptr;      ///< apply_recorded(): where the frame's operations go
  std::uint32_t run_products_ = 0;  ///< offset of the current run's products in record_
  std::vector<T> prod_;
  std::vector<int> off_;    ///< scalar offset of layer l within a cell's packed sums
  std::vector<char> cplx_;  ///< layer l is off-diagonal (complex)
  int stride_ = 0;          ///< scalars per cell
  int hit_ = 0;             ///< offset of the hit counter
  std::vector<char> has_;
};

}  // namespace

// ---------------------------------------------------------------------------------------------

Eigen::MatrixXcd CovarianceTileView::covariance(int col, int row) const {
  Eigen::MatrixXcd c(q, q);
  int l = 0;
  for (int i = 0; i < q; ++i) {
    for (int j = i; j < q; ++j) {
      const std::complex<float> v = layer(l++, col, row);
      c(i, j) = cdouble(v.real(), v.imag());
      c(j, i) = std::conj(c(i, j));
    }
  }
  for (int i = 0; i < q; ++i) c(i, i) = c(i, i).real();
  return c;
}

float CovarianceRaster::power(std::size_t index) const {
  float p = 0.0F;
  const std::size_t plane = plane_size();
  for (int i = 0; i < q; ++i) p += layers[layer_index(q, i, i) * plane + index].real();
  return p;
}

Eigen::MatrixXcd CovarianceRaster::covariance(std::size_t index) const {
  Eigen::MatrixXcd c(q, q);
  int l = 0;
  for (int i = 0; i < q; ++i) {
    for (int j = i; j < q; ++j) {
      const std::complex<float> v = layer(l++, index);
      c(i, j) = cdouble(v.real(), v.imag());
      c(j, i) = std::conj(c(i, j));
    }
  }
  for (int i = 0; i < q; ++i) c(i, i) = c(i, i).real();
  return c;
}

Eigen::Vector2d CovarianceRaster::cell_center(std::size_t index) const {
  const int w = box.width();
  const int ix = box.min_ix + static_cast<int>(index % w);
  const int iy = box.min_iy + static_cast<int>(index / w);
  return {(ix + 0.5) * cell_size_m, (iy + 0.5) * cell_size_m};
}

CovarianceRaster CovarianceRaster::zeros(const CellBox& box, double cell_size_m, PolLevel level) {
  POLMAP_EXPECT(!box.empty());
  CovarianceRaster r;
  r.box = box;
  r.cell_size_m = cell_size_m;
  r.level = level;
  r.q = pol_dimension(level);
  r.count.assign(r.plane_size(), 0);
  r.hits.assign(r.plane_size(), 0);
  r.layers.assign(r.plane_size() * num_layers(r.q), std::complex<float>(0.0F, 0.0F));
  return r;
}

void CovarianceRaster::set_covariance(int ix, int iy, const Eigen::MatrixXcd& c, std::uint32_t n,
                                      std::optional<std::uint32_t> hits_n) {
  POLMAP_EXPECT(box.contains(ix, iy) && c.rows() == q && c.cols() == q);
  const std::size_t index =
      static_cast<std::size_t>(iy - box.min_iy) * box.width() + (ix - box.min_ix);
  count[index] = n;
  hits[index] = hits_n.value_or(n);
  int l = 0;
  for (int i = 0; i < q; ++i) {
    for (int j = i; j < q; ++j) {
      layers[l++ * plane_size() + index] = std::complex<float>(static_cast<float>(c(i, j).real()),
                                                               static_cast<float>(c(i, j).imag()));
    }
  }
}

CovarianceGridmap::CovarianceGridmap(GridmapConfig cfg) : cfg_(cfg) {
  POLMAP_EXPECT(cfg_.cell_size_m > 0.0 && cfg_.window_s >= 0.0 && cfg_.max_range_m >= 0.0);
  // float sums in both modes: the window's rounding residue is bounded (see the header)
  // and half the bytes per cell make adding, expiring and extracting ~6 % cheaper.
  impl_ = std::make_unique<ImplT<float>>(cfg_);
}
CovarianceGridmap::~CovarianceGridmap() = default;
CovarianceGridmap::CovarianceGridmap(CovarianceGridmap&&) noexcept = default;
CovarianceGridmap& CovarianceGridmap::operator=(CovarianceGridmap&&) noexcept = default;

int CovarianceGridmap::q() const { return pol_dimension(cfg_.level); }

void CovarianceGridmap::add(const PolSpectrum& spectrum, const Pose2& T_frame_sensor,
                            double time_s) {
  if (cfg_.window_s > 0.0) {
    expire_before(time_s - cfg_.window_s);
    Impl::FrameRecord rec{time_s, spectrum.noise_sigma, {}};
    impl_->apply_recorded(spectrum, T_frame_sensor, rec.ops);
    impl_->window_bytes += rec.ops.bytes() + sizeof(Impl::FrameRecord);
    impl_->window.push_back(std::move(rec));
  } else {
    impl_->apply(spectrum, T_frame_sensor, +1);
  }
  impl_->noise_sum += double(spectrum.noise_sigma) * spectrum.noise_sigma;
  impl_->frames += 1;
}

void CovarianceGridmap::expire_before(double time_s) {
  auto& w = impl_->window;
  while (!w.empty() && w.front().time_s < time_s) {
    const auto& f = w.front();
    impl_->unapply(f.ops);
    impl_->noise_sum -= double(f.noise_sigma) * f.noise_sigma;
    impl_->frames -= 1;
    impl_->window_bytes -= f.ops.bytes() + sizeof(Impl::FrameRecord);
    w.pop_front();
  }
  if (w.empty()) impl_->noise_sum = 0.0;  // no drift from repeated subtraction
}

void CovarianceGridmap::add_cell_sample(int ix, int iy, std::span<const cdouble> k) {
  POLMAP_EXPECT(cfg_.window_s == 0.0);
  impl_->add_sample(ix, iy, k);
}

void CovarianceGridmap::merge_tile(const CovarianceTileView& tile) {
  POLMAP_EXPECT(cfg_.window_s == 0.0);
  POLMAP_EXPECT(tile.level == cfg_.level && std::abs(tile.cell_size_m - cfg_.cell_size_m) < 1e-9);
  impl_->merge(tile);
}

double CovarianceGridmap::noise_power() const {
  return impl_->frames > 0 ? impl_->noise_sum / static_cast<double>(impl_->frames)
                           : impl_->imported_noise_power;
}

void CovarianceGridmap::set_noise_power(double noise_power) {
  POLMAP_EXPECT(cfg_.window_s == 0.0 && impl_->frames == 0);
  POLMAP_EXPECT(std::isfinite(noise_power) && noise_power >= 0.0);
  impl_->imported_noise_power = noise_power;
}
std::size_t CovarianceGridmap::num_frames() const {
  return static_cast<std::size_t>(impl_->frames);
}
std::size_t CovarianceGridmap::num_tiles() const { return impl_->num_tiles(); }
std::size_t CovarianceGridmap::memory_bytes() const {
  return impl_->tile_bytes() + impl_->window_bytes;
}

CellBox CovarianceGridmap::bounds() const {
  const auto keys = impl_->keys();
  if (keys.empty()) return {};
  CellBox b{std::numeric_limits<int>::max(), std::numeric_limits<int>::max(),
            std::numeric_limits<int>::min(), std::numeric_limits<int>::min()};
  for (std::uint64_t k : keys) {
    b.min_ix = std::min(b.min_ix, key_tx(k) * kT);
    b.min_iy = std::min(b.min_iy, key_ty(k) * kT);
    b.max_ix = std::max(b.max_ix, key_tx(k) * kT + kT);
    b.max_iy = std::max(b.max_iy, key_ty(k) * kT + kT);
  }
  return b;
}

Eigen::AlignedBox2d CovarianceGridmap::bounds_m() const {
  const CellBox b = bounds();
  if (b.empty()) return Eigen::AlignedBox2d();
  const double s = cfg_.cell_size_m;
  return Eigen::AlignedBox2d(Eigen::Vector2d(b.min_ix * s, b.min_iy * s),
                             Eigen::Vector2d(b.max_ix * s, b.max_iy * s));
}

std::array<int, 2> CovarianceGridmap::cell_of(const Eigen::Vector2d& xy) const {
  return {static_cast<int>(std::floor(xy.x() / cfg_.cell_size_m)),
          static_cast<int>(std::floor(xy.y() / cfg_.cell_size_m))};
}

Eigen::Vector2d CovarianceGridmap::cell_center(int ix, int iy) const {
  return {(ix + 0.5) * cfg_.cell_size_m, (iy + 0.5) * cfg_.cell_size_m};
}

std::uint32_t CovarianceGridmap::count(int ix, int iy) const { return impl_->count(ix, iy); }
std::uint32_t CovarianceGridmap::hits(int ix, int iy) const { return impl_->hits(ix, iy); }

Eigen::MatrixXcd CovarianceGridmap::covariance(int ix, int iy) const {
  const int qq = q();
  Eigen::MatrixXcd c = Eigen::MatrixXcd::Zero(qq, qq);
  const std::uint32_t n = count(ix, iy);
  if (n == 0) return c;
  std::array<cdouble, 10> s{};
  impl_->cell_sums(ix, iy, s.data());
  int l = 0;
  for (int i = 0; i < qq; ++i) {
    for (int j = i; j < qq; ++j) {
      c(i, j) = s[l++] / static_cast<double>(n);
      c(j, i) = std::conj(c(i, j));
    }
    c(i, i) = c(i, i).real();
  }
  return c;
}

double CovarianceGridmap::power(int ix, int iy) const { return covariance(ix, iy).trace().real(); }

void CovarianceGridmap::for_each_tile(
    const std::function<void(const CovarianceTileView&)>& fn) const {
  const int L = num_layers(q());
  std::vector<std::uint32_t> counts(kCellsPerTile);
  std::vector<std::complex<float>> layers(static_cast<std::size_t>(L) * kCellsPerTile);
  std::vector<std::uint32_t> hits(kCellsPerTile);
  for (std::uint64_t k : impl_->keys()) {
    const int tx = key_tx(k), ty = key_ty(k);
    if (!impl_->materialize(tx, ty, counts.data(), layers.data(), hits.data())) continue;
    CovarianceTileView v;
    v.tile_x = tx;
    v.tile_y = ty;
    v.size_cells = kT;
    v.cell_size_m = cfg_.cell_size_m;
    v.origin_x_m = tx * kT * cfg_.cell_size_m;
    v.origin_y_m = ty * kT * cfg_.cell_size_m;
    v.level = cfg_.level;
    v.q = q();
    v.num_layers = L;
    v.count = counts;
    v.layers = layers;
    v.hits = hits;
    fn(v);
  }
}

std::vector<std::array<int, 2>> CovarianceGridmap::tile_indices() const {
  std::vector<std::array<int, 2>> out;
  for (std::uint64_t k : impl_->keys()) out.push_back({key_tx(k), key_ty(k)});
  std::sort(out.begin(), out.end());
  return out;
}

std::vector<CovarianceGridmap::PopulatedChunk> CovarianceGridmap::populated_chunks(
    int chunk_tiles) const {
  POLMAP_EXPECT(chunk_tiles >= 1);
  auto floor_div = [](int a, int b) { return a >= 0 ? a / b : -((-a + b - 1) / b); };
  std::map<std::pair<int, int>, CellBox> boxes;
  for (const auto& [tx, ty] : tile_indices()) {
    const CellBox tb{tx * kT, ty * kT, (tx + 1) * kT, (ty + 1) * kT};
    const auto [it, inserted] =
        boxes.try_emplace({floor_div(tx, chunk_tiles), floor_div(ty, chunk_tiles)}, tb);
    if (!inserted) {
      CellBox& b = it->second;
      b = CellBox{std::min(b.min_ix, tb.min_ix), std::min(b.min_iy, tb.min_iy),
                  std::max(b.max_ix, tb.max_ix), std::max(b.max_iy, tb.max_iy)};
    }
  }
  std::vector<PopulatedChunk> out;
  for (const auto& [key, b] : boxes) out.push_back({key.first, key.second, b});
  return out;
}

CovarianceRaster CovarianceGridmap::raster(const CellBox& box) const {
  CovarianceRaster r = CovarianceRaster::zeros(box, cfg_.cell_size_m, cfg_.level);
  r.noise_power = noise_power();
  const int tx0 = box.min_ix >> 6, tx1 = (box.max_ix - 1) >> 6;
  const int ty0 = box.min_iy >> 6, ty1 = (box.max_iy - 1) >> 6;
  std::vector<std::uint64_t> keys;
  const std::size_t span_tiles = static_cast<std::size_t>(tx1 - tx0 + 1) * (ty1 - ty0 + 1);
  if (span_tiles <= impl_->num_tiles()) {
    for (int ty = ty0; ty <= ty1; ++ty) {
      for (int tx = tx0; tx <= tx1; ++tx) keys.push_back(tile_key(tx, ty));
    }
  } else {
    for (std::uint64_t k : impl_->keys()) {
      if (key_tx(k) >= tx0 && key_tx(k) <= tx1 && key_ty(k) >= ty0 && key_ty(k) <= ty1) {
        keys.push_back(k);
      }
    }
  }
  for (std::uint64_t k : keys) impl_->blit(key_tx(k), key_ty(k), r);
  return r;
}

void CovarianceGridmap::read_row(int iy, int ix0, int ix1, std::span<std::uint32_t> count,
                                 std::span<std::uint32_t> hits,
                                 std::span<std::complex<float>> layers) const {
  const auto n = static_cast<std::size_t>(std::max(0, ix1 - ix0));
  const auto L = static_cast<std::size_t>(num_layers(q()));
  POLMAP_EXPECT(count.size() >= n && hits.size() >= n && layers.size() >= n * L);
  for (int ix = ix0; ix < ix1;) {
    const int tx = ix >> 6;
    const int end = std::min(ix1, (tx + 1) * kT);
    const auto i = static_cast<std::size_t>(ix - ix0);
    impl_->read_tile_row(tx, iy, ix, end, count.data() + i, hits.data() + i, layers.data() + i * L);
    ix = end;
  }
}

std::vector<std::array<int, 2>> CovarianceGridmap::cells_above(const CellBox& box, double min_power,
                                                               double min_persistence,
                                                               std::uint32_t min_count) const {
  std::vector<std::array<int, 2>> out;
  if (box.empty()) return out;
  const int tx0 = box.min_ix >> 6, tx1 = (box.max_ix - 1) >> 6;
  const int ty0 = box.min_iy >> 6, ty1 = (box.max_iy - 1) >> 6;
  for (int ty = ty0; ty <= ty1; ++ty) {
    for (int tx = tx0; tx <= tx1; ++tx) {
      impl_->cells_above(tx, ty, box, min_power, min_persistence, min_count, out);
    }
  }
  return out;
}

cv::Mat CovarianceGridmap::trace_image(const CellBox& box, double min_persistence) const {
  cv::Mat img = cv::Mat::zeros(box.height(), box.width(), CV_32F);
  if (box.empty()) return img;
  const int tx0 = box.min_ix >> 6, tx1 = (box.max_ix - 1) >> 6;
  const int ty0 = box.min_iy >> 6, ty1 = (box.max_iy - 1) >> 6;
  std::vector<float> trace(kCellsPerTile);
  for (int ty = ty0; ty <= ty1; ++ty) {
    for (int tx = tx0; tx <= tx1; ++tx) {
      if (!impl_->materialize_trace(tx, ty, trace.data(), min_persistence)) continue;
      const int ixa = std::max(box.min_ix, tx * kT), ixb = std::min(box.max_ix, tx * kT + kT);
      const int iya = std::max(box.min_iy, ty * kT), iyb = std::min(box.max_iy, ty * kT + kT);
      for (int iy = iya; iy < iyb; ++iy) {
        float* dst = img.ptr<float>(iy - box.min_iy) + (ixa - box.min_ix);
        const float* src = trace.data() + (iy - ty * kT) * kT + (ixa - tx * kT);
        std::copy(src, src + (ixb - ixa), dst);
      }
    }
  }
  return img;
}

}  // namespace polmap::radar
