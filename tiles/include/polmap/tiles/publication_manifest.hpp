#pragma once
/// @file publication_manifest.hpp
/// The manifest of a static map publication (`polmap publish`, schema/publication.md): a
/// map version's tiles as files on any static host or CDN, each listed with its SHA-256,
/// the whole list signed (Ed25519, util/ed25519.hpp) so that a vehicle accepts a tile only
/// if its bytes are the publisher's. Also the unsigned pointer `latest.json` that names
/// the current publication's directory.
///
/// The manifest travels over hostile networks and caches: parse_publication_manifest()
/// checks the size before parsing, every field's type and range, tile keys, hex digests,
/// duplicate keys and the total tile count, and reports the first problem as a
/// FormatError naming the source and the field.
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "polmap/tiles/tile_key.hpp"

namespace polmap::tiles {

/// One published tile: its key, the SHA-256 (64 lower-case hex digits) of its file's bytes
/// and their number.
struct PublishedTile {
  TileKey key;
  std::string sha256;
  std::uint64_t bytes = 0;
};

/// A tile layer of the publication: files at `path` (relative to the publication's
/// directory, with {z}, {x}, {y}), of `media_type`, for zooms min_zoom..max_zoom.
struct PublishedLayer {
  std::string name;        ///< "localization", "mvt", "gridmap", "gridmap_mechanism"
  std::string path;        ///< e.g. "loc/{z}/{x}/{y}.pmt"
  std::string media_type;  ///< e.g. "application/x-polmap-tile"
  int min_zoom = 0;
  int max_zoom = 0;
  std::vector<PublishedTile> tiles;  ///< sorted by key
};

struct PublicationManifest {
  static constexpr int kFormatVersion = 1;
  std::int64_t map_version = 0;
  std::string created_at;  ///< ISO 8601 UTC
  std::string key_id;      ///< util::ed25519_key_id of the signing key
  std::optional<GeoBox> bounds;
  std::vector<PublishedLayer> layers;
  /// The layer of that name, nullptr if absent.
  [[nodiscard]] const PublishedLayer* layer(std::string_view name) const;
};

/// The canonical JSON text (what is signed): fields in a fixed order, tiles sorted.
[[nodiscard]] std::string encode_publication_manifest(const PublicationManifest& m);

struct ManifestLimits {
  std::size_t max_bytes = 64U << 20;  ///< refused before parsing
  std::size_t max_tiles = 2'000'000;  ///< over all layers
  std::size_t max_layers = 16;
  std::size_t max_tile_bytes = 16U << 20;  ///< largest file a tile entry may announce
};

/// Parses a manifest (file comment). FormatError naming `source` on anything malformed.
[[nodiscard]] PublicationManifest parse_publication_manifest(
    std::string_view json, const ManifestLimits& limits = {},
    std::string_view source = "manifest.json");

/// `latest.json`: which directory holds the current publication.
struct PublicationPointer {
  std::int64_t map_version = 0;
  std::string dir;              ///< "v<version>-<16 hex digits of the manifest's SHA-256>"
  std::string manifest_sha256;  ///< of the manifest.json bytes
};
[[nodiscard]] std::string encode_publication_pointer(const PublicationPointer& p);
/// FormatError naming `source` unless it is a pointer of this format with a safe `dir`
/// (one path segment of [a-z0-9-], at most 64 characters) and a hex digest.
[[nodiscard]] PublicationPointer parse_publication_pointer(std::string_view json,
                                                           std::string_view source = "latest.json");

/// The file path of a tile of a layer: the layer's path with {z}, {x}, {y} replaced.
[[nodiscard]] std::string published_tile_path(const PublishedLayer& layer, const TileKey& key);

}  // namespace polmap::tiles
