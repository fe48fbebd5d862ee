// bench_upload_resume: upload time of a long drive over a throttled link that drops once.
//
// Makes a drive package (simulates --length-m of --world and processes it in mapping mode,
// format 2 as `polmap process` writes it; or takes --package), serves a fresh SQLite store
// with mapping::Server on loopback behind a TCP proxy that throttles each direction to
// --mbit and cuts the --cut-chunk-th chunk's connection halfway through, and runs the built
// `polmap upload` through it (resumable, --chunk-mb). Reports the wall time of the upload
// (bytes on the link plus the server's validation and ingest), the bytes that crossed the
// link twice, and, with --baseline, the same package in one POST over the same link without
// a drop.
//
//   bench_upload_resume [--world urban] [--length-m 10000] [--seed 1] [--package PKG]
//                       [--keep-package DIR] [--mbit 20] [--chunk-mb 8] [--cut-chunk 3]
//                       [--baseline] [--polmap build/tools/polmap]
#include <sys/wait.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <thread>

#include "../tests/support/tcp_proxy.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/mapping_service/server.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/radar/drive_processor.hpp"
#include "polmap/sim/drive_simulator.hpp"
#include "polmap/sim/world.hpp"
#include "polmap/util/file.hpp"

using namespace polmap;
namespace fs = std::filesystem;

namespace {

constexpr const char* kKey = "bench-upload-key";

struct Run {
  double seconds = 0.0;
  int exit_code = -1;
  std::uint64_t body_bytes = 0;  ///< request body bytes that crossed the link
  std::size_t connections = 0;
  int cut = 0;
  std::string output;
};

/// Uploads `tar` with the CLI through a throttled proxy in front of a fresh server.
Run upload_once(const fs::path& polmap, const fs::path& tar, double mbit, double chunk_mb,
                int cut_chunk, std::uint64_t cut_after) {
  const util::ScopedTempDir dir = util::ScopedTempDir::create("bench_upload_resume");
  mapping::SqliteMapStore store(dir.path() / "map.db");
  mapping::ServerConfig cfg;
  cfg.api_keys = {kKey};
  cfg.upload_dir = dir.path();
  cfg.log_requests = false;
  mapping::Server server(store, cfg);
  std::thread t([&] { server.listen("127.0.0.1", 0); });
  server.wait_until_listening(std::chrono::seconds(10));

  test::TcpProxy::Options po;
  po.target_port = server.bound_port();
  po.bytes_per_s = mbit * 1e6 / 8.0;
  po.cut_nth = cut_chunk;
  po.cut_after_bytes = cut_after;
  Run run;
  {
    test::TcpProxy proxy(po);
    const std::string cmd = polmap.string() +
                            " upload --server http://127.0.0.1:" + std::to_string(proxy.port()) +
                            " --package " + tar.string() + " --api-key " + kKey + " --chunk-mb " +
                            std::to_string(chunk_mb) + " 2>&1";
    const auto t0 = std::chrono::steady_clock::now();
    FILE* p = ::popen(cmd.c_str(), "r");
    char buf[4096];
    std::size_t n = 0;
    while (p != nullptr && (n = std::fread(buf, 1, sizeof buf, p)) > 0) run.output.append(buf, n);
    const int status = p != nullptr ? ::pclose(p) : -1;
    run.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    run.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    for (const auto& r : proxy.records()) {
      const std::size_t end = r.upstream.find("\r\n\r\n");
      if (end != std::string::npos) run.body_bytes += r.upstream.size() - end - 4;
      run.cut += r.cut ? 1 : 0;
      ++run.connections;
    }
  }
  server.stop();
  t.join();
  if (store.list_drives().size() != 1) run.exit_code = run.exit_code == 0 ? 100 : run.exit_code;
  return run;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Upload time of a long drive over a throttled loopback link with one drop"};
  std::string world_name = "urban", package, keep;
  double length_m = 10000.0, mbit = 20.0, chunk_mb = 8.0;
  std::uint64_t seed = 1;
  int cut_chunk = 3;
  bool baseline = false;
  std::string polmap_bin = (fs::path(argv[0]).parent_path() / ".." / "tools" / "polmap").string();
  app.add_option("--world", world_name, "Simulated world")->capture_default_str();
  app.add_option("--length-m", length_m, "Drive length")->capture_default_str();
  app.add_option("--seed", seed, "Simulation seed")->capture_default_str();
  app.add_option("--package", package, "Upload this package (directory or .tar) instead");
  app.add_option("--keep-package", keep, "Write the simulated package (directory) here too");
  app.add_option("--mbit", mbit, "Link rate per direction, Mbit/s")->capture_default_str();
  app.add_option("--chunk-mb", chunk_mb, "polmap upload --chunk-mb")->capture_default_str();
  app.add_option("--cut-chunk", cut_chunk, "The chunk whose connection is cut halfway (0: none)")
      ->capture_default_str();
  app.add_flag("--baseline", baseline, "Also: one POST of the whole package, no drop");
  app.add_option("--polmap", polmap_bin, "The polmap executable")->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  const util::ScopedTempDir tmp = util::ScopedTempDir::create("bench_upload_resume_pkg");
  const fs::path tar = tmp.path() / "drive.tar";
  double km = 0.0;
  if (package.empty()) {
    sim::SimConfig scfg;
    scfg.seed = seed;
    auto world = sim::load_world(world_name, length_m, seed, scfg);
    sim::DriveSimulator source(world, scfg, 0);
    const auto t0 = std::chrono::steady_clock::now();
    mapping::PackageWriteOptions wopts;
    wopts.format_version = 2;  // what `polmap process` writes
    const radar::DriveProcessingResult r =
        mapping::process_drive_for_package(source, radar::DriveProcessingConfig{}, wopts);
    km = r.stats.distance_m / 1000.0;
    const fs::path dir = keep.empty() ? tmp.path() / "pkg" : fs::path(keep);
    (void)mapping::write_drive_package(r, dir, wopts);
    util::write_file_bytes(tar, mapping::pack_drive_package(dir));
    std::printf("package: %s %.0f m, seed %llu: %.2f km, made in %.0f s\n", world_name.c_str(),
                length_m, static_cast<unsigned long long>(seed), km,
                std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  } else if (fs::is_directory(package)) {
    util::write_file_bytes(tar, mapping::pack_drive_package(package));
  } else {
    fs::copy_file(package, tar);
  }
  const auto size = fs::file_size(tar);
  std::printf(
      "package bytes %llu (%.1f MB%s), link %.1f Mbit/s each way, chunks %.1f MiB\n",
      static_cast<unsigned long long>(size), size / 1e6,
      km > 0 ? (", " + std::to_string(size / 1e6 / km).substr(0, 4) + " MB/km").c_str() : "", mbit,
      chunk_mb);
  std::fflush(stdout);

  const auto chunk_bytes = static_cast<std::uint64_t>(chunk_mb * 1024 * 1024);
  const Run r = upload_once(polmap_bin, tar, mbit, chunk_mb, cut_chunk, chunk_bytes / 2);
  std::printf(
      "resumable, %d dropped connection(s): %.1f s wall, exit %d, %zu connections, "
      "body bytes on the link %llu, sent twice %lld\n",
      r.cut, r.seconds, r.exit_code, r.connections, static_cast<unsigned long long>(r.body_bytes),
      static_cast<long long>(r.body_bytes) - static_cast<long long>(size));
  std::printf("  polmap upload: %s", r.output.c_str());
  std::fflush(stdout);
  if (baseline) {
    const Run b = upload_once(polmap_bin, tar, mbit, 1024.0, 0, 0);
    std::printf("one POST, no drop: %.1f s wall, exit %d, body bytes on the link %llu\n", b.seconds,
                b.exit_code, static_cast<unsigned long long>(b.body_bytes));
  }
  return r.exit_code == 0 ? 0 : 1;
}
