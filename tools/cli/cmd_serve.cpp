// `polmap serve --db FILE --listen HOST:PORT --api-key-file FILE [--tls-cert F --tls-key F]
// [--package-dir DIR] [...]`: the mapping service's HTTP(S) server on an embedded SQLite store
// (FILE) or a PostgreSQL/PostGIS store shared by replicas (--db postgresql://...). For public
// exposure it runs behind the nginx front of deploy/nginx/ (docs/deployment.md). Stops
// gracefully on SIGINT/SIGTERM (requests in flight finish, a running map build is cancelled
// and marked failed).
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#if defined(__GLIBC__)
#include <malloc.h>
#endif
#include <string>

#include "command.hpp"
#include "polmap/eval/serve_until_signal.hpp"
#include "polmap/mapping_service/open_store.hpp"
#include "polmap/mapping_service/postgres_store.hpp"
#include "polmap/mapping_service/server.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/util/text.hpp"

namespace polmap::cli {
namespace {

struct ServeOptions {
  std::string db;
  std::string package_dir;
  int build_partition_zoom = 0;
  double build_partition_halo_m = 120.0;
  bool no_build_jobs = false;
  std::string listen = "127.0.0.1:8080";
  std::string api_key_file;
  double max_upload_mib = 512;
  int threads = 32;
  int current_max_age_s = 60;
  std::string public_url;
  std::string cors_origin;
  double retention_days = 0.0;
  int max_concurrent_uploads = 4;
  double upload_session_ttl_h = 24.0;
  int max_upload_sessions_per_key = 4;
  double max_upload_session_mib_per_key = 2048.0;
  std::string upload_dir;
  std::string tls_cert;
  std::string tls_key;
  bool quiet = false;
};

std::pair<std::string, int> split_listen(const std::string& s) {
  const auto colon = s.rfind(':');
  if (colon == std::string::npos || colon == 0 || colon + 1 == s.size()) {
    throw ValidationError("--listen '" + s + "': expected HOST:PORT, e.g. 127.0.0.1:8080");
  }
  std::string host = s.substr(0, colon);
  if (host.size() > 2 && host.front() == '[' && host.back() == ']')
    host = host.substr(1, host.size() - 2);
  int port = -1;
  try {
    std::size_t used = 0;
    port = std::stoi(s.substr(colon + 1), &used);
    if (used != s.size() - colon - 1) port = -1;
  } catch (const std::exception&) {
    port = -1;
  }
  if (port < 0 || port > 65535) {
    throw ValidationError("--listen '" + s + "': port must be 0..65535");
  }
  return {host, port};
}

void run(const ServeOptions& o) {
  const auto [host, port] = split_listen(o.listen);
  mapping::ServerConfig cfg;
  cfg.api_keys = mapping::read_api_key_file(o.api_key_file);
  cfg.api_key_file = o.api_key_file;  // reloaded when it changes
  cfg.max_upload_bytes = static_cast<std::uint64_t>(o.max_upload_mib * 1024.0 * 1024.0);
  cfg.threads = o.threads;
  cfg.current_tile_max_age_s = o.current_max_age_s;
  cfg.public_url = o.public_url;
  cfg.cors_allow_origin = o.cors_origin;
  cfg.drive_retention_days = o.retention_days;
  cfg.max_concurrent_uploads = o.max_concurrent_uploads;
  cfg.upload_session_ttl_s =
      std::max<std::int64_t>(1, static_cast<std::int64_t>(o.upload_session_ttl_h * 3600.0));
  cfg.max_upload_sessions_per_key = o.max_upload_sessions_per_key;
  cfg.max_upload_session_bytes_per_key =
      static_cast<std::uint64_t>(o.max_upload_session_mib_per_key * 1024.0 * 1024.0);
  cfg.upload_dir = o.upload_dir;
  cfg.tls_cert_file = o.tls_cert;
  cfg.tls_key_file = o.tls_key;
  cfg.log_requests = !o.quiet;
  cfg.build_partition_zoom = o.build_partition_zoom;
  cfg.build_partition_halo_m = o.build_partition_halo_m;
  cfg.run_build_jobs = !o.no_build_jobs;

  // Block the stop signals in every thread (the server's threads inherit this mask);
  // one thread waits for them and stops the server.
  const sigset_t signals = eval::block_stop_signals();
#if defined(__GLIBC__)
  // glibc gives each of up to 8 x cores threads an arena of its own; 32 workers and a
  // builder fragment them into hundreds of MB of freed but resident memory. Four arenas
  // keep contention low at this size. MALLOC_ARENA_MAX in the environment wins.
  if (std::getenv("MALLOC_ARENA_MAX") == nullptr) mallopt(M_ARENA_MAX, 4);
#endif
  const auto opened = mapping::open_map_store(o.db, {.package_dir = o.package_dir});
  mapping::MapStore& store = *opened;
  if (const auto* sqlite = dynamic_cast<const mapping::SqliteMapStore*>(opened.get())) {
    const auto& migration = sqlite->archive_migration();
    if (migration.migrated > 0) {
      std::fprintf(stderr, "polmap serve: %zu archive-stored packages replaced by their members\n",
                   migration.migrated);
    }
    for (const auto& q : migration.quarantined) {
      std::fprintf(stderr,
                   "polmap serve: a stored package no longer validates; drive removed, archive "
                   "kept in quarantine/: %s\n",
                   util::escape_for_log(q, 1024).c_str());
    }
  }
  // Replicas share a PostgreSQL store: its sweep fails only builds whose process is gone;
  // failing every Building version here would fail another replica's running build.
  if (dynamic_cast<const mapping::PostgresMapStore*>(opened.get()) != nullptr) {
    cfg.fail_stale_builds_on_start = false;
  }
  mapping::Server server(store, cfg);
  eval::listen_until_signal(server, signals, host, port, [](int sig) {
    std::fprintf(stderr, "polmap serve: %s received, stopping\n",
                 sig == SIGINT ? "SIGINT" : "SIGTERM");
  });
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<ServeOptions>();
  CLI::App* cmd = app.add_subcommand(
      "serve", "Run the mapping service HTTP server (drive uploads, map builds, tiles)");
  cmd->add_option("--db", opts->db,
                  "Map store: a SQLite database file (created if missing), or a PostgreSQL "
                  "database as a URL (postgresql://USER@HOST:PORT/DB) or libpq 'host=... "
                  "dbname=...' string (PostGIS needed; docs/postgresql.md)")
      ->required();
  cmd->add_option("--package-dir", opts->package_dir,
                  "PostgreSQL store only: the directory of its drive packages and upload "
                  "sessions, shared by every replica; required at the database's first open "
                  "(recorded in it; later opens may leave it out)");
  cmd->add_option("--listen", opts->listen, "HOST:PORT to listen on (port 0: any free port)")
      ->capture_default_str();
  cmd->add_option("--api-key-file", opts->api_key_file,
                  "File with the API keys for writes, one per line ('#' comments)")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_option("--max-upload-mib", opts->max_upload_mib, "Largest accepted package upload")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cmd->add_option("--upload-session-ttl-h", opts->upload_session_ttl_h,
                  "Resumable upload sessions expire this long after they were opened")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cmd->add_option("--max-upload-sessions-per-key", opts->max_upload_sessions_per_key,
                  "Unexpired resumable upload sessions one key may hold")
      ->capture_default_str()
      ->check(CLI::Range(0, 1000000));
  cmd->add_option("--max-upload-session-mib-per-key", opts->max_upload_session_mib_per_key,
                  "MiB the unexpired upload sessions of one key may declare in all")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cmd->add_option("--threads", opts->threads, "Worker threads (= concurrent connections)")
      ->capture_default_str()
      ->check(CLI::Range(1, 4096));
  cmd->add_option("--current-max-age-s", opts->current_max_age_s,
                  "Cache-Control max-age of tiles of the current map version")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--public-url", opts->public_url,
                  "Base URL written into TileJSON (default: from the Host header)");
  cmd->add_option("--upload-dir", opts->upload_dir,
                  "Directory for in-flight uploads (default: system temp dir)");
  cmd->add_option("--cors-origin", opts->cors_origin,
                  "Access-Control-Allow-Origin for browsers on other origins ('*' or one "
                  "origin; default: none)");
  cmd->add_option("--max-concurrent-uploads", opts->max_concurrent_uploads,
                  "Uploads received and validated at once (one more gets 503, Retry-After)")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--retention-days", opts->retention_days,
                  "Delete drives ingested longer ago than this (0: keep forever)")
      ->check(CLI::NonNegativeNumber);
  auto* cert = cmd->add_option("--tls-cert", opts->tls_cert,
                               "Serve HTTPS with this PEM certificate chain (needs --tls-key; "
                               "docs/deployment.md)");
  auto* key =
      cmd->add_option("--tls-key", opts->tls_key, "Unencrypted PEM private key of --tls-cert");
  cert->needs(key);
  key->needs(cert);
  cmd->add_flag("--quiet", opts->quiet, "No per-request log lines");
  cmd->add_option("--build-partition-zoom", opts->build_partition_zoom,
                  "Partition map builds into jobs by regions of this zoom (e.g. 14), run by "
                  "this server and any `polmap build-worker`; 0: one-process builds")
      ->check(CLI::Range(0, 16));
  cmd->add_option("--build-partition-halo-m", opts->build_partition_halo_m,
                  "Partitioned builds: candidates this far outside a region take part (m)");
  cmd->add_flag("--no-build-jobs", opts->no_build_jobs,
                "Partitioned builds: leave every job to `polmap build-worker` processes");
  cmd->callback([opts] { run(*opts); });
}

}  // namespace
POLMAP_REGISTER_COMMAND(serve, setup);
}  // namespace polmap::cli
