#pragma once
/// @file publish.hpp
/// A published map version as a static tile set for nginx, any CDN or a tile server
/// (`polmap publish`; layout and manifest in schema/publication.md).
///
/// Directory form (PublishFormat::Directory), below `out`:
///   latest.json                  pointer to the current publication
///   (tiles/publication_manifest.hpp) v<V>-<16 hex>/               one immutable directory per
///   publication; the name carries
///                                the first 16 hex digits of its manifest's SHA-256, so every
///                                URL below it names content and may be cached forever
///     manifest.json              every tile of every layer with its SHA-256 and size
///     manifest.sig               Ed25519 signature of manifest.json (128 hex digits)
///     public_key.pem             the key that signed it (for tools; vehicles must bring
///                                their own copy, a mirror could replace this one)
///     tilejson.json              TileJSON 3.0 of the vector and raster layers (relative URLs)
///     loc/{z}/{x}/{y}.pmt        localization tiles (the client's format)
///     mvt/{z}/{x}/{y}.mvt        landmark vector tiles (layers points, lines)
///     gridmap/{z}/{x}/{y}.png, gridmap/mechanism/{z}/{x}/{y}.png   fleet gridmap rasters
/// The new directory is written under a temporary name and renamed; latest.json is then
/// replaced by rename, so a reader sees the old publication or the new one, never half of
/// one. Earlier publications stay (caches may still hold their URLs).
///
/// MBTiles form (PublishFormat::MBTiles): one SQLite file (MBTiles 1.3) with the landmark
/// vector tiles (gzip-compressed, TMS rows) and its metadata (name, format pbf, bounds,
/// center, minzoom, maxzoom, json with vector_layers, polmap_map_version), for Martin or
/// TileServer GL; written to a temporary file and renamed.
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <string>

#include "polmap/mapping_service/store.hpp"

namespace polmap::mapping {

enum class PublishFormat { Directory, MBTiles };

struct PublishOptions {
  PublishFormat format = PublishFormat::Directory;
  /// Directory form: the publication root (created if missing). MBTiles: the file.
  std::filesystem::path out;
  /// Ed25519 private key (PEM) that signs the manifest; required for the directory form.
  std::string private_key_pem;
  /// Zooms of the landmark vector tiles (the server's defaults).
  int mvt_min_zoom = 14;
  int mvt_max_zoom = 18;
  /// Include the fleet gridmap raster layers (directory form).
  bool gridmap = true;
  /// Called with a stage name and a fraction in [0, 1].
  std::function<void(const std::string&, double)> progress;
};

struct PublishResult {
  std::int64_t map_version = 0;
  std::string dir;                           ///< directory form: "v<V>-<16 hex>"
  std::string manifest_sha256;               ///< directory form
  std::map<std::string, std::size_t> tiles;  ///< per layer
  std::uint64_t bytes = 0;                   ///< all files written
};

/// Publishes a published map version. NotFoundError if it is not published; ValidationError
/// for a missing/invalid key (directory form) or zooms out of range; IoError on write
/// failures (nothing half-written is left visible).
PublishResult publish_map_version(const MapStore& store, std::int64_t version,
                                  const PublishOptions& options);

}  // namespace polmap::mapping
