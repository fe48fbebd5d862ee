// Tile server benchmark fixture (driven by bench/tile_throughput.sh):
//   bench_tile_server --out DIR [--side N] [--threads T] [--port P] [--log FILE]
// builds a synthetic published map of N x N localization tiles (z16, urban density:
// ~150 points and ~50 lines a tile) in DIR/map.db, writes the same tile payloads as
// static files DIR/static/v1/tiles/16/X/Y (same URL paths, for nginx) and the list of
// tile paths DIR/paths.txt, then serves the store with mapping::Server on 127.0.0.1:P
// and prints "READY <port>" on stdout. Stops on SIGINT/SIGTERM.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <thread>

#include "polmap/eval/serve_until_signal.hpp"
#include "polmap/mapping_service/server.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/tiles/localization_tile.hpp"
#include "polmap/tiles/tile_key.hpp"

namespace fs = std::filesystem;
using namespace polmap;

namespace {

tiles::LocalizationTile synthetic_tile(const tiles::TileKey& key, std::mt19937_64& rng) {
  tiles::LocalizationTile t;
  t.key = key;
  t.map_version = 1;
  const double half = 0.5 * tiles::tile_width_m(key);
  std::uniform_real_distribution<double> u(-half, half), spread(0.01, 0.1);
  std::uniform_int_distribution<int> cls(0, 3), support(2, 20);
  std::int64_t id = static_cast<std::int64_t>(key.x) * 100000 + key.y * 1000;
  for (int i = 0; i < 150; ++i) {
    PointLandmark p;
    p.id = ++id;
    p.position_m = {u(rng), u(rng)};
    p.scattering = static_cast<ScatteringClass>(cls(rng));
    p.support_drives = static_cast<std::uint32_t>(support(rng));
    p.spread_m = spread(rng);
    t.points.push_back(p);
  }
  for (int i = 0; i < 50; ++i) {
    LineLandmark l;
    l.id = ++id;
    const Eigen::Vector2d a{u(rng), u(rng)};
    l.polyline_m = {a, a + Eigen::Vector2d(u(rng), u(rng)) * 0.05};
    l.support_drives = static_cast<std::uint32_t>(support(rng));
    l.spread_m = spread(rng);
    t.lines.push_back(l);
  }
  return t;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"polmap tile server benchmark fixture"};
  std::string out;
  int side = 20, threads = 32, port = 0;
  std::string log_file;
  app.add_option("--out", out, "Work directory (replaced)")->required();
  app.add_option("--side", side, "Tiles per side of the synthetic map")->capture_default_str();
  app.add_option("--threads", threads, "Server worker threads")->capture_default_str();
  app.add_option("--port", port, "Port (0: any)")->capture_default_str();
  app.add_option("--log", log_file, "Request log file (default: no request log)");
  CLI11_PARSE(app, argc, argv);

  const sigset_t signals = eval::block_stop_signals();

  const fs::path dir(out);
  fs::remove_all(dir);
  fs::create_directories(dir);
  mapping::SqliteMapStore store(dir / "map.db");
  const std::int64_t version = store.begin_map_version({{"notes", "bench_tile_server"}});
  std::mt19937_64 rng(42);
  const tiles::TileKey origin = tiles::tile_at(48.39, 9.97, tiles::kLocalizationZoom);
  std::vector<mapping::TileWrite> writes;
  std::ofstream paths(dir / "paths.txt");
  std::size_t bytes = 0;
  for (int dy = 0; dy < side; ++dy) {
    for (int dx = 0; dx < side; ++dx) {
      const tiles::TileKey k{origin.z, origin.x + dx, origin.y + dy};
      mapping::TileWrite w;
      w.key = k;
      w.payload = tiles::encode_localization_tile(synthetic_tile(k, rng));
      w.etag = mapping::content_etag(w.payload);
      w.num_points = 150;
      w.num_lines = 50;
      bytes += w.payload.size();
      const fs::path f = dir / "static" / "v1" / "tiles" / std::to_string(k.z) /
                         std::to_string(k.x) / std::to_string(k.y);
      fs::create_directories(f.parent_path());
      std::ofstream(f, std::ios::binary) << w.payload;
      paths << "/v1/tiles/" << tiles::to_string(k) << "\n";
      writes.push_back(std::move(w));
    }
  }
  paths.close();
  store.put_tiles(version, mapping::TileLayer::Localization, writes);
  store.publish_map_version(version, {{"tiles", writes.size()}}, true);
  std::fprintf(stderr, "bench_tile_server: %zu tiles, mean %.0f bytes\n", writes.size(),
               static_cast<double>(bytes) / static_cast<double>(writes.size()));

  mapping::ServerConfig cfg;
  cfg.api_keys = {"bench"};
  cfg.threads = threads;
  std::shared_ptr<std::FILE> log;
  if (!log_file.empty()) {
    log.reset(std::fopen(log_file.c_str(), "w"), [](std::FILE* f) {
      if (f) std::fclose(f);
    });
    cfg.log_sink = [log](std::string_view line) {
      std::fwrite(line.data(), 1, line.size(), log.get());
      std::fputc('\n', log.get());
    };
  } else {
    cfg.log_requests = false;
  }
  mapping::Server server(store, cfg);
  std::thread announce([&] {
    if (server.wait_until_listening(std::chrono::seconds(30))) {
      std::printf("READY %d\n", server.bound_port());
      std::fflush(stdout);
    }
  });
  eval::listen_until_signal(server, signals, "127.0.0.1", port);
  announce.join();
  return 0;
}
