#include "polmap/tiles/mvt.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <protozero/pbf_writer.hpp>
#include <set>

#include "polmap/schema/errors.hpp"

namespace polmap::tiles {
namespace {

// Field numbers of vector_tile.proto (spec 2.1).
namespace pb {
constexpr protozero::pbf_tag_type kTileLayers = 3;
constexpr protozero::pbf_tag_type kLayerName = 1;
constexpr protozero::pbf_tag_type kLayerFeatures = 2;
constexpr protozero::pbf_tag_type kLayerKeys = 3;
constexpr protozero::pbf_tag_type kLayerValues = 4;
constexpr protozero::pbf_tag_type kLayerExtent = 5;
constexpr protozero::pbf_tag_type kLayerVersion = 15;
constexpr protozero::pbf_tag_type kFeatureId = 1;
constexpr protozero::pbf_tag_type kFeatureTags = 2;
constexpr protozero::pbf_tag_type kFeatureType = 3;
constexpr protozero::pbf_tag_type kFeatureGeometry = 4;
constexpr protozero::pbf_tag_type kValueString = 1;
constexpr protozero::pbf_tag_type kValueDouble = 3;
constexpr protozero::pbf_tag_type kValueUint = 5;
constexpr protozero::pbf_tag_type kValueSint = 6;
constexpr protozero::pbf_tag_type kValueBool = 7;
}  // namespace pb

constexpr std::uint32_t kMoveTo = 1;
constexpr std::uint32_t kLineTo = 2;
constexpr std::uint32_t kClosePath = 7;

std::uint32_t command(std::uint32_t id, std::uint32_t count) { return (id & 7u) | (count << 3); }
std::uint32_t zz32(std::int64_t v) {
  const auto v32 = static_cast<std::int32_t>(v);
  return (static_cast<std::uint32_t>(v32) << 1) ^ static_cast<std::uint32_t>(v32 >> 31);
}

struct IPt {
  std::int64_t x = 0;
  std::int64_t y = 0;
  bool operator==(const IPt&) const = default;
};
struct DPt {
  double x = 0;
  double y = 0;
};

struct Box {
  double x0, y0, x1, y1;
};

IPt round_pt(const DPt& p) { return {std::llround(p.x), std::llround(p.y)}; }

// Liang–Barsky: clips segment a->b to the box; false if nothing remains.
bool clip_segment(DPt& a, DPt& b, const Box& box) {
  double t0 = 0.0, t1 = 1.0;
  const double dx = b.x - a.x, dy = b.y - a.y;
  const double p[4] = {-dx, dx, -dy, dy};
  const double q[4] = {a.x - box.x0, box.x1 - a.x, a.y - box.y0, box.y1 - a.y};
  for (int i = 0; i < 4; ++i) {
    if (p[i] == 0.0) {
      if (q[i] < 0.0) return false;
    } else {
      const double t = q[i] / p[i];
      if (p[i] < 0.0) {
        if (t > t1) return false;
        t0 = std::max(t0, t);
      } else {
        if (t < t0) return false;
        t1 = std::min(t1, t);
      }
    }
  }
  const DPt a2{a.x + t0 * dx, a.y + t0 * dy};
  const DPt b2{a.x + t1 * dx, a.y + t1 * dy};
  a = a2;
  b = b2;
  return true;
}

// Clips a polyline to the box; each maximal inside run becomes one linestring.
std::vector<std::vector<IPt>> clip_line(const std::vector<DPt>& line, const Box& box) {
  std::vector<std::vector<IPt>> runs;
  std::vector<IPt> run;
  bool run_open = false;
  auto flush = [&] {
    if (run.size() >= 2) runs.push_back(run);
    run.clear();
    run_open = false;
  };
  for (std::size_t i = 0; i + 1 < line.size(); ++i) {
    DPt a = line[i], b = line[i + 1];
    if (!clip_segment(a, b, box)) {
      flush();
      continue;
    }
    const bool start_clipped = a.x != line[i].x || a.y != line[i].y;
    const bool end_clipped = b.x != line[i + 1].x || b.y != line[i + 1].y;
    if (!run_open || start_clipped) {
      flush();
      run.push_back(round_pt(a));
      run_open = true;
    }
    const IPt e = round_pt(b);
    if (!(e == run.back())) run.push_back(e);
    if (end_clipped) flush();
  }
  flush();
  return runs;
}

// Sutherland–Hodgman against one half plane at a time.
std::vector<DPt> clip_ring(std::vector<DPt> ring, const Box& box) {
  auto clip_edge = [](const std::vector<DPt>& in, auto inside, auto intersect) {
    std::vector<DPt> out;
    if (in.empty()) return out;
    DPt prev = in.back();
    bool prev_in = inside(prev);
    for (const DPt& cur : in) {
      const bool cur_in = inside(cur);
      if (cur_in) {
        if (!prev_in) out.push_back(intersect(prev, cur));
        out.push_back(cur);
      } else if (prev_in) {
        out.push_back(intersect(prev, cur));
      }
      prev = cur;
      prev_in = cur_in;
    }
    return out;
  };
  auto at_x = [](double x) {
    return [x](const DPt& a, const DPt& b) {
      const double t = (x - a.x) / (b.x - a.x);
      return DPt{x, a.y + t * (b.y - a.y)};
    };
  };
  auto at_y = [](double y) {
    return [y](const DPt& a, const DPt& b) {
      const double t = (y - a.y) / (b.y - a.y);
      return DPt{a.x + t * (b.x - a.x), y};
    };
  };
  ring = clip_edge(
      ring, [&](const DPt& p) { return p.x >= box.x0; }, at_x(box.x0));
  ring = clip_edge(
      ring, [&](const DPt& p) { return p.x <= box.x1; }, at_x(box.x1));
  ring = clip_edge(
      ring, [&](const DPt& p) { return p.y >= box.y0; }, at_y(box.y0));
  ring = clip_edge(
      ring, [&](const DPt& p) { return p.y <= box.y1; }, at_y(box.y1));
  return ring;
}

// Twice the signed area by the surveyor's formula in tile coordinates (y down):
// positive = clockwise on screen = exterior ring in MVT 2.1.
std::int64_t doubled_area(const std::vector<IPt>& ring) {
  std::int64_t a = 0;
  for (std::size_t i = 0; i < ring.size(); ++i) {
    const IPt& p = ring[i];
    const IPt& q = ring[(i + 1) % ring.size()];
    a += p.x * q.y - q.x * p.y;
  }
  return a;
}

class GeometryWriter {
 public:
  void move_to(const std::vector<IPt>& pts) { emit(kMoveTo, pts.begin(), pts.end()); }
  void line_to(std::vector<IPt>::const_iterator b, std::vector<IPt>::const_iterator e) {
    emit(kLineTo, b, e);
  }
  void close_path() { cmds_.push_back(command(kClosePath, 1)); }
  [[nodiscard]] const std::vector<std::uint32_t>& commands() const { return cmds_; }

 private:
  template <class It>
  void emit(std::uint32_t cmd, It b, It e) {
    cmds_.push_back(command(cmd, static_cast<std::uint32_t>(e - b)));
    for (It it = b; it != e; ++it) {
      cmds_.push_back(zz32(it->x - cursor_.x));
      cmds_.push_back(zz32(it->y - cursor_.y));
      cursor_ = *it;
    }
  }
  std::vector<std::uint32_t> cmds_;
  IPt cursor_;
};

// Value-table key: type tag + canonical bytes, so equal values share one entry.
std::string value_key(const MvtValue& v) {
  return std::visit(
      [&](const auto& x) -> std::string {
        using T = std::decay_t<decltype(x)>;
        if constexpr (std::is_same_v<T, std::string>) {
          return "s" + x;
        } else if constexpr (std::is_same_v<T, double>) {
          std::string s = "d";
          s.append(reinterpret_cast<const char*>(&x), sizeof x);
          return s;
        } else if constexpr (std::is_same_v<T, std::int64_t>) {
          return "i" + std::to_string(x);
        } else if constexpr (std::is_same_v<T, std::uint64_t>) {
          return "u" + std::to_string(x);
        } else {
          return x ? "b1" : "b0";
        }
      },
      v);
}

void write_value(protozero::pbf_writer& layer, const MvtValue& v) {
  protozero::pbf_writer value(layer, pb::kLayerValues);
  std::visit(
      [&](const auto& x) {
        using T = std::decay_t<decltype(x)>;
        if constexpr (std::is_same_v<T, std::string>) {
          value.add_string(pb::kValueString, x);
        } else if constexpr (std::is_same_v<T, double>) {
          value.add_double(pb::kValueDouble, x);
        } else if constexpr (std::is_same_v<T, std::int64_t>) {
          value.add_sint64(pb::kValueSint, x);
        } else if constexpr (std::is_same_v<T, std::uint64_t>) {
          value.add_uint64(pb::kValueUint, x);
        } else {
          value.add_bool(pb::kValueBool, x);
        }
      },
      v);
}

}  // namespace

PixelXY project_to_tile_pixels(const TileKey& key, double lat_deg, double lon_deg,
                               std::uint32_t extent) {
  const MercatorXY m = to_mercator_tiles(lat_deg, lon_deg, key.z);
  const double n = static_cast<double>(tiles_per_side(key.z));
  double mx = m.x;
  // Bring the point to the tile's side of the antimeridian (and undo unwrapped longitudes).
  const double centre = key.x + 0.5;
  mx -= n * std::round((mx - centre) / n);
  return {(mx - key.x) * extent, (m.y - key.y) * extent};
}

std::string encode_mvt(const TileKey& key, const std::vector<MvtLayer>& layers,
                       const MvtOptions& options) {
  if (!is_valid(key)) throw ValidationError("MVT: invalid tile key " + to_string(key));
  if (options.extent == 0 || options.extent > (1u << 20)) {
    throw ValidationError("MVT: extent must be in [1, 2^20]");
  }
  std::set<std::string> names;
  for (const MvtLayer& l : layers) {
    if (l.name.empty()) throw ValidationError("MVT: empty layer name");
    if (!names.insert(l.name).second) throw ValidationError("MVT: duplicate layer " + l.name);
  }
  const double buf = options.buffer;
  const Box box{-buf, -buf, options.extent + buf, options.extent + buf};

  std::string data;
  protozero::pbf_writer tile(data);
  for (const MvtLayer& layer : layers) {
    struct Encoded {
      std::uint64_t id;
      MvtGeometryType type;
      std::vector<std::uint32_t> geometry;
      std::vector<std::uint32_t> tags;
    };
    std::vector<Encoded> encoded;
    std::map<std::string, std::uint32_t> key_index;
    std::vector<std::string> keys;
    std::map<std::string, std::uint32_t> value_index;
    std::vector<const MvtValue*> values;

    for (const MvtFeature& f : layer.features) {
      std::vector<std::vector<DPt>> parts;
      for (const auto& part : f.parts) {
        std::vector<DPt> px;
        px.reserve(part.size());
        for (const GeoPoint& g : part) {
          if (!std::isfinite(g.lat_deg) || !std::isfinite(g.lon_deg)) {
            throw ValidationError("MVT: layer " + layer.name + " feature " + std::to_string(f.id) +
                                  " has a non-finite coordinate");
          }
          const PixelXY p = project_to_tile_pixels(key, g.lat_deg, g.lon_deg, options.extent);
          px.push_back({p.x, p.y});
        }
        parts.push_back(std::move(px));
      }
      GeometryWriter gw;
      switch (f.type) {
        case MvtGeometryType::Point: {
          std::vector<IPt> pts;
          for (const auto& part : parts) {
            for (const DPt& p : part) {
              if (p.x >= box.x0 && p.x <= box.x1 && p.y >= box.y0 && p.y <= box.y1) {
                pts.push_back(round_pt(p));
              }
            }
          }
          if (!pts.empty()) gw.move_to(pts);
          break;
        }
        case MvtGeometryType::LineString: {
          for (const auto& part : parts) {
            for (const auto& run : clip_line(part, box)) {
              gw.move_to({run.front()});
              gw.line_to(run.begin() + 1, run.end());
            }
          }
          break;
        }
        case MvtGeometryType::Polygon: {
          for (std::size_t r = 0; r < parts.size(); ++r) {
            std::vector<IPt> ring;
            for (const DPt& p : clip_ring(parts[r], box)) {
              const IPt q = round_pt(p);
              if (ring.empty() || !(q == ring.back())) ring.push_back(q);
            }
            while (ring.size() > 1 && ring.front() == ring.back()) ring.pop_back();
            if (ring.size() < 3) {
              if (r == 0) break;  // exterior gone: the whole polygon is outside
              continue;
            }
            const std::int64_t area = doubled_area(ring);
            if (area == 0) {
              if (r == 0) break;
              continue;
            }
            const bool exterior = r == 0;
            if ((area > 0) != exterior) std::reverse(ring.begin(), ring.end());
            gw.move_to({ring.front()});
            gw.line_to(ring.begin() + 1, ring.end());
            gw.close_path();
          }
          break;
        }
      }
      if (gw.commands().empty()) continue;

      Encoded e{f.id, f.type, gw.commands(), {}};
      for (const auto& [k, v] : f.properties) {
        auto [kit, knew] = key_index.try_emplace(k, static_cast<std::uint32_t>(keys.size()));
        if (knew) keys.push_back(k);
        auto [vit, vnew] =
            value_index.try_emplace(value_key(v), static_cast<std::uint32_t>(values.size()));
        if (vnew) values.push_back(&v);
        e.tags.push_back(kit->second);
        e.tags.push_back(vit->second);
      }
      encoded.push_back(std::move(e));
    }
    if (encoded.empty() && options.skip_empty_layers) continue;

    protozero::pbf_writer lw(tile, pb::kTileLayers);
    lw.add_uint32(pb::kLayerVersion, 2);
    lw.add_string(pb::kLayerName, layer.name);
    for (const Encoded& e : encoded) {
      protozero::pbf_writer fw(lw, pb::kLayerFeatures);
      fw.add_uint64(pb::kFeatureId, e.id);
      if (!e.tags.empty()) {
        fw.add_packed_uint32(pb::kFeatureTags, e.tags.begin(), e.tags.end());
      }
      fw.add_enum(pb::kFeatureType, static_cast<std::int32_t>(e.type));
      fw.add_packed_uint32(pb::kFeatureGeometry, e.geometry.begin(), e.geometry.end());
    }
    for (const std::string& k : keys) lw.add_string(pb::kLayerKeys, k);
    for (const MvtValue* v : values) write_value(lw, *v);
    lw.add_uint32(pb::kLayerExtent, options.extent);
  }
  return data;
}

}  // namespace polmap::tiles
