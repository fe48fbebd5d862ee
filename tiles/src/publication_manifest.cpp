// Static publication manifest and pointer (publication_manifest.hpp).
#include "polmap/tiles/publication_manifest.hpp"

#include <algorithm>
#include <nlohmann/json.hpp>
#include <set>

#include "polmap/schema/errors.hpp"

namespace polmap::tiles {
namespace {

constexpr const char* kManifestFormat = "polmap-publication";
constexpr const char* kPointerFormat = "polmap-publication-pointer";

[[noreturn]] void bad(std::string_view source, const std::string& field, const std::string& what) {
  throw FormatError(std::string(source) + ": " + field + ": " + what);
}

bool is_hex64(const std::string& s) {
  return s.size() == 64 && std::all_of(s.begin(), s.end(), [](char c) {
           return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f');
         });
}

/// A relative path template: segments of [A-Za-z0-9._{}-], no "..", no leading '/'.
bool safe_template(const std::string& p) {
  if (p.empty() || p.size() > 128 || p.front() == '/' || p.find("..") != std::string::npos) {
    return false;
  }
  return std::all_of(p.begin(), p.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '/' || c == '.' || c == '_' ||
           c == '-' || c == '{' || c == '}';
  });
}

const nlohmann::json& member(const nlohmann::json& j, const char* name, std::string_view source,
                             const std::string& where) {
  if (!j.is_object() || !j.contains(name)) bad(source, where + name, "missing");
  return j.at(name);
}

std::int64_t integer(const nlohmann::json& j, std::string_view source, const std::string& field,
                     std::int64_t lo, std::int64_t hi) {
  if (!j.is_number_integer()) bad(source, field, "not an integer");
  const auto v = j.get<std::int64_t>();
  if (v < lo || v > hi) bad(source, field, "out of range");
  return v;
}

std::string text(const nlohmann::json& j, std::string_view source, const std::string& field,
                 std::size_t max_len) {
  if (!j.is_string()) bad(source, field, "not a string");
  auto s = j.get<std::string>();
  if (s.size() > max_len) bad(source, field, "longer than " + std::to_string(max_len));
  return s;
}

}  // namespace

const PublishedLayer* PublicationManifest::layer(std::string_view name) const {
  for (const auto& l : layers) {
    if (l.name == name) return &l;
  }
  return nullptr;
}

std::string encode_publication_manifest(const PublicationManifest& m) {
  nlohmann::ordered_json j;
  j["format"] = kManifestFormat;
  j["format_version"] = PublicationManifest::kFormatVersion;
  j["map_version"] = m.map_version;
  j["created_at"] = m.created_at;
  j["key_id"] = m.key_id;
  if (m.bounds) {
    j["bounds"] = {m.bounds->min_lon_deg, m.bounds->min_lat_deg, m.bounds->max_lon_deg,
                   m.bounds->max_lat_deg};
  }
  j["layers"] = nlohmann::ordered_json::array();
  for (const auto& l : m.layers) {
    nlohmann::ordered_json lj;
    lj["name"] = l.name;
    lj["path"] = l.path;
    lj["media_type"] = l.media_type;
    lj["min_zoom"] = l.min_zoom;
    lj["max_zoom"] = l.max_zoom;
    std::vector<PublishedTile> sorted = l.tiles;
    std::sort(sorted.begin(), sorted.end(),
              [](const PublishedTile& a, const PublishedTile& b) { return a.key < b.key; });
    auto arr = nlohmann::ordered_json::array();
    for (const auto& t : sorted) arr.push_back({t.key.z, t.key.x, t.key.y, t.sha256, t.bytes});
    lj["tiles"] = std::move(arr);
    j["layers"].push_back(std::move(lj));
  }
  return j.dump();
}

PublicationManifest parse_publication_manifest(std::string_view text_in,
                                               const ManifestLimits& limits,
                                               std::string_view source) {
  if (text_in.size() > limits.max_bytes) {
    bad(source, "(file)",
        std::to_string(text_in.size()) + " bytes exceed the limit of " +
            std::to_string(limits.max_bytes));
  }
  const nlohmann::json j = nlohmann::json::parse(text_in, nullptr, false);
  if (j.is_discarded() || !j.is_object()) bad(source, "(file)", "not a JSON object");
  if (text(member(j, "format", source, ""), source, "format", 64) != kManifestFormat) {
    bad(source, "format", "not a polmap publication manifest");
  }
  if (integer(member(j, "format_version", source, ""), source, "format_version", 0, 1 << 20) !=
      PublicationManifest::kFormatVersion) {
    bad(source, "format_version", "unsupported");
  }
  PublicationManifest m;
  m.map_version = integer(member(j, "map_version", source, ""), source, "map_version", 1,
                          std::int64_t{1} << 53);
  m.created_at = text(member(j, "created_at", source, ""), source, "created_at", 64);
  m.key_id = text(member(j, "key_id", source, ""), source, "key_id", 64);
  if (j.contains("bounds")) {
    const auto& b = j.at("bounds");
    if (!b.is_array() || b.size() != 4 ||
        !std::all_of(b.begin(), b.end(), [](const auto& v) { return v.is_number(); })) {
      bad(source, "bounds", "not [min_lon, min_lat, max_lon, max_lat]");
    }
    GeoBox g{b[1].get<double>(), b[0].get<double>(), b[3].get<double>(), b[2].get<double>()};
    if (!(g.min_lat_deg >= -90 && g.max_lat_deg <= 90 && g.min_lat_deg <= g.max_lat_deg &&
          g.min_lon_deg >= -180 && g.max_lon_deg <= 180)) {
      bad(source, "bounds", "outside WGS84");
    }
    m.bounds = g;
  }
  const auto& layers = member(j, "layers", source, "");
  if (!layers.is_array()) bad(source, "layers", "not an array");
  if (layers.size() > limits.max_layers) bad(source, "layers", "too many");
  std::size_t total = 0;
  std::set<std::string> names;
  for (std::size_t li = 0; li < layers.size(); ++li) {
    const std::string where = "layers[" + std::to_string(li) + "].";
    const auto& lj = layers[li];
    PublishedLayer l;
    l.name = text(member(lj, "name", source, where), source, where + "name", 64);
    if (!names.insert(l.name).second) bad(source, where + "name", "duplicate layer");
    l.path = text(member(lj, "path", source, where), source, where + "path", 128);
    if (!safe_template(l.path) || l.path.find("{z}") == std::string::npos ||
        l.path.find("{x}") == std::string::npos || l.path.find("{y}") == std::string::npos) {
      bad(source, where + "path", "not a safe relative {z}/{x}/{y} template");
    }
    l.media_type = text(member(lj, "media_type", source, where), source, where + "media_type", 128);
    l.min_zoom = static_cast<int>(
        integer(member(lj, "min_zoom", source, where), source, where + "min_zoom", 0, kMaxZoom));
    l.max_zoom = static_cast<int>(integer(member(lj, "max_zoom", source, where), source,
                                          where + "max_zoom", l.min_zoom, kMaxZoom));
    const auto& tl = member(lj, "tiles", source, where);
    if (!tl.is_array()) bad(source, where + "tiles", "not an array");
    total += tl.size();
    if (total > limits.max_tiles) bad(source, where + "tiles", "more tiles than the limit");
    l.tiles.reserve(tl.size());
    for (std::size_t ti = 0; ti < tl.size(); ++ti) {
      const std::string tw = where + "tiles[" + std::to_string(ti) + "]";
      const auto& t = tl[ti];
      if (!t.is_array() || t.size() != 5) bad(source, tw, "not [z, x, y, sha256, bytes]");
      PublishedTile pt;
      pt.key.z = static_cast<int>(integer(t[0], source, tw + ".z", l.min_zoom, l.max_zoom));
      const std::int64_t side = tiles_per_side(pt.key.z);
      pt.key.x = static_cast<int>(integer(t[1], source, tw + ".x", 0, side - 1));
      pt.key.y = static_cast<int>(integer(t[2], source, tw + ".y", 0, side - 1));
      pt.sha256 = text(t[3], source, tw + ".sha256", 64);
      if (!is_hex64(pt.sha256)) bad(source, tw + ".sha256", "not 64 lower-case hex digits");
      pt.bytes = static_cast<std::uint64_t>(integer(
          t[4], source, tw + ".bytes", 1, static_cast<std::int64_t>(limits.max_tile_bytes)));
      if (!l.tiles.empty() && !(l.tiles.back().key < pt.key)) {
        bad(source, tw, "tiles not sorted by key or duplicated");
      }
      l.tiles.push_back(std::move(pt));
    }
    m.layers.push_back(std::move(l));
  }
  return m;
}

std::string encode_publication_pointer(const PublicationPointer& p) {
  nlohmann::ordered_json j;
  j["format"] = kPointerFormat;
  j["map_version"] = p.map_version;
  j["dir"] = p.dir;
  j["manifest_sha256"] = p.manifest_sha256;
  return j.dump();
}

PublicationPointer parse_publication_pointer(std::string_view text_in, std::string_view source) {
  if (text_in.size() > 4096) bad(source, "(file)", "larger than 4096 bytes");
  const nlohmann::json j = nlohmann::json::parse(text_in, nullptr, false);
  if (j.is_discarded() || !j.is_object()) bad(source, "(file)", "not a JSON object");
  if (text(member(j, "format", source, ""), source, "format", 64) != kPointerFormat) {
    bad(source, "format", "not a polmap publication pointer");
  }
  PublicationPointer p;
  p.map_version = integer(member(j, "map_version", source, ""), source, "map_version", 1,
                          std::int64_t{1} << 53);
  p.dir = text(member(j, "dir", source, ""), source, "dir", 64);
  if (p.dir.empty() || !std::all_of(p.dir.begin(), p.dir.end(), [](char c) {
        return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '-';
      })) {
    bad(source, "dir", "not one path segment of [a-z0-9-]");
  }
  p.manifest_sha256 = text(member(j, "manifest_sha256", source, ""), source, "manifest_sha256", 64);
  if (!is_hex64(p.manifest_sha256)) bad(source, "manifest_sha256", "not 64 lower-case hex digits");
  return p;
}

std::string published_tile_path(const PublishedLayer& layer, const TileKey& key) {
  std::string out = layer.path;
  auto replace = [&](const std::string& what, int v) {
    const auto pos = out.find(what);
    if (pos != std::string::npos) out.replace(pos, what.size(), std::to_string(v));
  };
  replace("{z}", key.z);
  replace("{x}", key.x);
  replace("{y}", key.y);
  return out;
}

}  // namespace polmap::tiles
