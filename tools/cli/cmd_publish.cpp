// `polmap publish --db FILE --out DIR|FILE.mbtiles [--format dir|mbtiles] [--version V]
//  [--key KEY.pem] [--mvt-zooms MIN,MAX] [--no-gridmap]`: writes a published map version as
// a static, signed tile set for nginx or any CDN (a directory: content-named, with a signed
// manifest and latest.json) or as MBTiles for Martin / TileServer GL (publish.hpp).
// `polmap keygen --out PREFIX`: a fresh Ed25519 key pair, PREFIX.key (private, mode 0600)
// and PREFIX.pub (give this one to the vehicles).
#include <sys/stat.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "command.hpp"
#include "map_db.hpp"
#include "polmap/mapping_service/open_store.hpp"
#include "polmap/mapping_service/publish.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/util/ed25519.hpp"
#include "polmap/util/file.hpp"
#include "progress.hpp"

namespace polmap::cli {
namespace {

struct PublishArgs {
  std::string db, out, format = "dir", key;
  std::int64_t version = 0;
  std::vector<int> mvt_zooms{14, 18};
  bool no_gridmap = false;
};

void run_publish(const PublishArgs& a) {
  mapping::PublishOptions o;
  if (a.format == "dir") {
    o.format = mapping::PublishFormat::Directory;
  } else if (a.format == "mbtiles") {
    o.format = mapping::PublishFormat::MBTiles;
  } else {
    throw ValidationError("--format '" + a.format + "': expected dir or mbtiles");
  }
  if (a.mvt_zooms.size() != 2) throw ValidationError("--mvt-zooms: expected MIN,MAX");
  o.out = a.out;
  o.mvt_min_zoom = a.mvt_zooms[0];
  o.mvt_max_zoom = a.mvt_zooms[1];
  o.gridmap = !a.no_gridmap;
  if (!a.key.empty()) o.private_key_pem = util::read_file_bytes(a.key);
  if (o.format == mapping::PublishFormat::Directory && a.key.empty()) {
    throw ValidationError("--key: a directory publication is signed (make a key: polmap keygen)");
  }
  require_map_db(a.db);
  const auto opened = mapping::open_map_store(a.db);
  mapping::MapStore& store = *opened;
  const std::int64_t version = map_version_or_current(store, a.db, a.version);
  Progress progress("publishing map version " + std::to_string(version), 1.0);
  o.progress = [&](const std::string& stage, double f) { progress.update(f, stage); };
  const mapping::PublishResult r = mapping::publish_map_version(store, version, o);
  progress.finish();
  std::printf("map version %lld published", static_cast<long long>(version));
  for (const auto& [layer, n] : r.tiles) std::printf(", %zu %s tiles", n, layer.c_str());
  std::printf(" (%llu bytes)\n", static_cast<unsigned long long>(r.bytes));
  if (o.format == mapping::PublishFormat::Directory) {
    std::printf("%s/%s (manifest sha256 %s), latest.json updated\n", a.out.c_str(), r.dir.c_str(),
                r.manifest_sha256.c_str());
  } else {
    std::printf("%s\n", a.out.c_str());
  }
}

void run_keygen(const std::string& prefix) {
  const util::Ed25519KeyPair k = util::ed25519_generate();
  const std::string priv = prefix + ".key", pub = prefix + ".pub";
  {
    // Private key: created 0600 before any byte is written.
    const mode_t old = ::umask(077);
    util::write_file_bytes(priv, k.private_pem);
    ::umask(old);
  }
  util::write_file_bytes(pub, k.public_pem);
  std::printf("%s (private, keep it on the publishing host)\n%s (public, key id %s)\n",
              priv.c_str(), pub.c_str(), util::ed25519_key_id(k.public_pem).c_str());
}

void setup(CLI::App& app) {
  auto a = std::make_shared<PublishArgs>();
  CLI::App* cmd = app.add_subcommand(
      "publish", "Write a map version as a static signed tile set (dir) or MBTiles");
  cmd->add_option("--db", a->db, "Map store: SQLite file or postgresql:// URL")->required();
  cmd->add_option("--out", a->out, "Publication root directory, or the .mbtiles file")->required();
  cmd->add_option("--format", a->format, "dir | mbtiles (default dir)");
  cmd->add_option("--version", a->version, "Published map version (default: current)")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--key", a->key, "Ed25519 private key (PEM) that signs the manifest");
  cmd->add_option("--mvt-zooms", a->mvt_zooms, "Zooms of the vector tiles: MIN,MAX (14,18)")
      ->delimiter(',');
  cmd->add_flag("--no-gridmap", a->no_gridmap, "Leave the fleet gridmap rasters out");
  cmd->callback([a] { run_publish(*a); });

  auto prefix = std::make_shared<std::string>();
  CLI::App* kg = app.add_subcommand("keygen", "Make an Ed25519 key pair for signed publications");
  kg->add_option("--out", *prefix, "Writes PREFIX.key and PREFIX.pub")->required();
  kg->callback([prefix] { run_keygen(*prefix); });
}

}  // namespace
POLMAP_REGISTER_COMMAND(publish, setup);
}  // namespace polmap::cli
