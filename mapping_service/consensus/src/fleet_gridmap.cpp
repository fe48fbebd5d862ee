// Fleet gridmap amplitude tiles (format in fleet_gridmap.hpp).
#include "polmap/mapping_service/fleet_gridmap.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "polmap/schema/errors.hpp"
#include "raster_blocks.hpp"

namespace polmap::mapping {
namespace {
constexpr int kPx = kGridmapTilePixels;
}  // namespace

std::pair<double, double> cell_mechanism_powers(std::span<const cdouble> c, PolLevel level,
                                                double noise_power) {
  const int q = pol_dimension(level);
  POLMAP_EXPECT(static_cast<int>(c.size()) == q * (q + 1) / 2);
  auto diag = [&](int i) {
    return std::max(
        0.0, c[static_cast<std::size_t>(GridmapRaster::layer_index(q, i, i))].real() - noise_power);
  };
  switch (level) {
    case PolLevel::Full:
      return {diag(1), diag(0) + diag(2)};
    case PolLevel::DualLLLR:
      return {diag(1), diag(0)};
    case PolLevel::DualHHVV: {
      const double hh = diag(0), vv = diag(1);
      const double cross = c[static_cast<std::size_t>(GridmapRaster::layer_index(q, 0, 1))].real();
      return {std::max(0.0, 0.5 * (hh + vv + 2.0 * cross)),
              std::max(0.0, 0.5 * (hh + vv - 2.0 * cross))};
    }
    default:
      return {0.0, 0.0};
  }
}

void FleetGridmapAccumulator::Acc::resize() {
  power.assign(kPx * kPx, 0.0F);
  count.assign(kPx * kPx, 0.0F);
  odd.assign(kPx * kPx, 0.0F);
  even.assign(kPx * kPx, 0.0F);
}

FleetGridmapAccumulator::FleetGridmapAccumulator(FleetGridmapConfig cfg) : cfg_(cfg) {
  POLMAP_EXPECT(cfg_.min_zoom >= 0 && cfg_.min_zoom <= cfg_.base_zoom &&
                cfg_.base_zoom <= tiles::kMaxZoom);
  POLMAP_EXPECT(cfg_.db_max > cfg_.db_min);
}

void FleetGridmapAccumulator::add(const GridmapRaster& r, const tiles::LocalFrame& frame,
                                  PolLevel level) {
  if (r.width <= 0 || r.height <= 0) return;
  POLMAP_EXPECT(r.count.size() == static_cast<std::size_t>(r.width) * r.height);
  POLMAP_EXPECT(static_cast<int>(r.layers.size()) == r.q * (r.q + 1) / 2);
  POLMAP_EXPECT(pol_dimension(level) == r.q);
  std::vector<cdouble> cell(r.layers.size());
  std::vector<int> diag;
  for (int i = 0; i < r.q; ++i) diag.push_back(i * r.q - i * (i - 1) / 2);
  const int z = cfg_.base_zoom;
  // Global pixel coordinates (Web-Mercator, base zoom) of a cell centre.
  auto pixel_of = [&](double col, double row) {
    const Eigen::Vector2d xy(r.origin_x_m + (col + 0.5) * r.cell_size_m,
                             r.origin_y_m - (row + 0.5) * r.cell_size_m);
    const GeoPoint g = frame.to_geo(xy);
    const auto m = tiles::to_mercator_tiles(g.lat_deg, g.lon_deg, z);
    return Eigen::Vector2d(m.x * kPx, m.y * kPx);
  };
  const std::int64_t world_px = tiles::tiles_per_side(z) * kPx;
  Acc* acc = nullptr;
  tiles::TileKey acc_key{-1, -1, -1};
  detail::for_each_observed_block(
      r, pixel_of,
      [&](int r0, int c0, int rr1, int c1, const Eigen::Vector2d& p0, const Eigen::Vector2d& dc,
          const Eigen::Vector2d& dr) {
        for (int row = r0; row < rr1; ++row) {
          for (int col = c0; col < c1; ++col) {
            const std::size_t i = static_cast<std::size_t>(row) * r.width + col;
            const std::uint32_t n = r.count[i];
            if (n == 0) continue;
            double trace = 0.0;
            for (int d : diag) trace += r.layers[static_cast<std::size_t>(d)][i].real();
            const Eigen::Vector2d p = p0 + (col - c0) * dc + (row - r0) * dr;
            auto gx = static_cast<std::int64_t>(std::floor(p.x()));
            const auto gy = static_cast<std::int64_t>(std::floor(p.y()));
            if (gy < 0 || gy >= world_px) continue;
            gx = ((gx % world_px) + world_px) % world_px;
            const tiles::TileKey key{z, static_cast<int>(gx / kPx), static_cast<int>(gy / kPx)};
            if (key != acc_key) {
              auto [it, inserted] = base_.try_emplace(key);
              if (inserted) it->second.resize();
              acc = &it->second;
              acc_key = key;
            }
            const std::size_t pi = static_cast<std::size_t>(gy % kPx) * kPx + (gx % kPx);
            acc->power[pi] += static_cast<float>(n * std::max(0.0, trace));
            acc->count[pi] += static_cast<float>(n);
            for (std::size_t l = 0; l < cell.size(); ++l) cell[l] = r.layers[l][i];
            const auto [odd, even] = cell_mechanism_powers(cell, level, r.noise_power);
            acc->odd[pi] += static_cast<float>(n * odd);
            acc->even[pi] += static_cast<float>(n * even);
          }
        }
      });
}

void FleetGridmapAccumulator::add_sums(const GridmapSumKey& key, const GridmapSumTile& tile) {
  const int shift = kGridmapSumZoom - cfg_.base_zoom;
  POLMAP_EXPECT(shift >= 0 && shift <= 8);
  const int per = 1 << shift;  // sum tiles a side of a base tile
  const tiles::TileKey base{cfg_.base_zoom, key.x >> shift, key.y >> shift};
  const int ox = (key.x % per) * (kPx / per), oy = (key.y % per) * (kPx / per);
  Acc* acc = nullptr;
  for (int c = 0; c < kSumChunksPerSide * kSumChunksPerSide; ++c) {
    if (!tile.has_chunk(c)) continue;
    if (acc == nullptr) {
      auto [it, inserted] = base_.try_emplace(base);
      if (inserted) it->second.resize();
      acc = &it->second;
    }
    const int cx0 = (c % kSumChunksPerSide) * kSumChunkCells;
    const int cy0 = (c / kSumChunksPerSide) * kSumChunkCells;
    for (int y = cy0; y < cy0 + kSumChunkCells; ++y) {
      for (int x = cx0; x < cx0 + kSumChunkCells; ++x) {
        const CellPowers cp = cell_powers(tile, x, y);
        if (cp.n <= 0.0) continue;
        const std::size_t pi = static_cast<std::size_t>(oy + y / per) * kPx + (ox + x / per);
        acc->power[pi] += static_cast<float>(cp.n_power);
        acc->count[pi] += static_cast<float>(cp.n);
        acc->odd[pi] += static_cast<float>(cp.n_odd);
        acc->even[pi] += static_cast<float>(cp.n_even);
      }
    }
  }
}

std::optional<double> FleetGridmapAccumulator::mean_power(const tiles::TileKey& key, int px,
                                                          int py) const {
  const auto it = base_.find(key);
  if (it == base_.end()) return std::nullopt;
  const std::size_t i = static_cast<std::size_t>(py) * kPx + px;
  if (it->second.count[i] <= 0.0F) return std::nullopt;
  return static_cast<double>(it->second.power[i]) / it->second.count[i];
}

double FleetGridmapAccumulator::count(const tiles::TileKey& key, int px, int py) const {
  const auto it = base_.find(key);
  return it == base_.end() ? 0.0 : it->second.count[static_cast<std::size_t>(py) * kPx + px];
}

std::uint8_t gridmap_gray(double mean_power, const FleetGridmapConfig& cfg) {
  const double db = mean_power > 0.0 ? 10.0 * std::log10(mean_power) : cfg.db_min;
  const double g = 1.0 + std::round(254.0 * (db - cfg.db_min) / (cfg.db_max - cfg.db_min));
  return static_cast<std::uint8_t>(std::clamp(g, 1.0, 255.0));
}

std::vector<std::pair<tiles::TileKey, std::string>> FleetGridmapAccumulator::encode_png_tiles()
    const {
  return encode(true, false).amplitude;
}

std::vector<std::pair<tiles::TileKey, std::string>>
FleetGridmapAccumulator::encode_mechanism_png_tiles() const {
  return encode(false, true).mechanism;
}

FleetGridmapAccumulator::PngTiles FleetGridmapAccumulator::encode_all_png_tiles() const {
  return encode(true, true);
}

FleetGridmapAccumulator::PngTiles FleetGridmapAccumulator::encode(bool amplitude,
                                                                  bool mechanism) const {
  PngTiles out;
  auto encode_tile = [&](const tiles::TileKey& key, const Acc& a, bool mech,
                         std::vector<std::pair<tiles::TileKey, std::string>>& to) {
    cv::Mat img(kPx, kPx, CV_8UC4, cv::Scalar(0, 0, 0, 0));
    for (int y = 0; y < kPx; ++y) {
      auto* row = img.ptr<cv::Vec4b>(y);
      for (int x = 0; x < kPx; ++x) {
        const std::size_t i = static_cast<std::size_t>(y) * kPx + x;
        if (a.count[i] <= 0.0F) continue;
        const std::uint8_t g = gridmap_gray(static_cast<double>(a.power[i]) / a.count[i], cfg_);
        const double sum = static_cast<double>(a.odd[i]) + a.even[i];
        if (!mech || !(sum > 0.0)) {
          row[x] = cv::Vec4b(g, g, g, 255);
          continue;
        }
        // OpenCV's channel order is B, G, R, A.
        const auto m = static_cast<std::uint8_t>(std::lround(g * a.even[i] / sum));
        const auto o = static_cast<std::uint8_t>(std::lround(g * a.odd[i] / sum));
        row[x] = cv::Vec4b(m, o, m, 255);
      }
    }
    std::vector<unsigned char> buf;
    if (!cv::imencode(".png", img, buf)) throw Error("PNG encoding of gridmap tile failed");
    to.emplace_back(key, std::string(buf.begin(), buf.end()));
  };
  std::map<tiles::TileKey, Acc> level = base_;
  for (int z = cfg_.base_zoom;; --z) {
    for (const auto& [key, a] : level) {
      if (amplitude) encode_tile(key, a, false, out.amplitude);
      if (mechanism) encode_tile(key, a, true, out.mechanism);
    }
    if (z == cfg_.min_zoom) break;
    std::map<tiles::TileKey, Acc> up;
    for (const auto& [key, a] : level) {
      const tiles::TileKey pk = tiles::parent(key);
      auto [it, inserted] = up.try_emplace(pk);
      if (inserted) it->second.resize();
      const int ox = (key.x % 2) * (kPx / 2), oy = (key.y % 2) * (kPx / 2);
      for (int y = 0; y < kPx; ++y) {
        for (int x = 0; x < kPx; ++x) {
          const std::size_t i = static_cast<std::size_t>(y) * kPx + x;
          const std::size_t j = static_cast<std::size_t>(oy + y / 2) * kPx + (ox + x / 2);
          it->second.power[j] += a.power[i];
          it->second.count[j] += a.count[i];
          it->second.odd[j] += a.odd[i];
          it->second.even[j] += a.even[i];
        }
      }
    }
    level = std::move(up);
  }
  const auto by_key = [](const auto& a, const auto& b) { return a.first < b.first; };
  std::sort(out.amplitude.begin(), out.amplitude.end(), by_key);
  std::sort(out.mechanism.begin(), out.mechanism.end(), by_key);
  return out;
}

std::vector<float> decode_gridmap_png_db(std::string_view png, const FleetGridmapConfig& cfg) {
  const cv::Mat buf(1, static_cast<int>(png.size()), CV_8UC1,
                    const_cast<char*>(png.data()));  // imdecode only reads
  const cv::Mat img = cv::imdecode(buf, cv::IMREAD_UNCHANGED);
  if (img.empty() || img.rows != kPx || img.cols != kPx || img.type() != CV_8UC4) {
    throw FormatError("gridmap tile: not a 256x256 RGBA PNG");
  }
  std::vector<float> out(static_cast<std::size_t>(kPx) * kPx,
                         std::numeric_limits<float>::quiet_NaN());
  for (int y = 0; y < kPx; ++y) {
    const auto* row = img.ptr<cv::Vec4b>(y);
    for (int x = 0; x < kPx; ++x) {
      if (row[x][3] == 0) continue;
      out[static_cast<std::size_t>(y) * kPx + x] =
          static_cast<float>(cfg.db_min + (row[x][0] - 1) / 254.0 * (cfg.db_max - cfg.db_min));
    }
  }
  return out;
}

}  // namespace polmap::mapping
