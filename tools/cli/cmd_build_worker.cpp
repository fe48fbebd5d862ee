// `polmap build-worker --db URL_OR_FILE [--package-dir DIR] [--id NAME] [--lease-s S]
//  [--exit-when-idle] [--max-jobs N]`: claims and runs the jobs of partitioned map builds
// (build_worker.hpp, schema/build_jobs.md) until SIGINT/SIGTERM; one log line per job.
// Any number of workers, on any hosts, share a PostgreSQL store (or, on one host, a SQLite
// file). A stop signal lets the job in hand finish and commit.
#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <memory>
#include <string>
#include <thread>

#include "command.hpp"
#include "map_db.hpp"
#include "polmap/mapping_service/build_worker.hpp"
#include "polmap/mapping_service/open_store.hpp"

namespace polmap::cli {
namespace {

struct WorkerArgs {
  std::string db, package_dir, id;
  double lease_s = 30.0;
  double idle_poll_s = 0.5;
  double hold_before_commit_s = 0.0;
  bool exit_when_idle = false;
  long max_jobs = 0;
};

std::atomic<bool> g_stop{false};
extern "C" void on_stop(int) { g_stop = true; }

void log_line(const std::string& s) {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char ts[32];
  std::strftime(ts, sizeof ts, "%Y-%m-%dT%H:%M:%SZ", &tm);
  std::fprintf(stderr, "%s info %s\n", ts, s.c_str());
}

void run_worker(const WorkerArgs& a) {
  std::signal(SIGINT, on_stop);
  std::signal(SIGTERM, on_stop);
  require_map_db(a.db);
  const auto opened = mapping::open_map_store(a.db, {.package_dir = a.package_dir});
  mapping::MapStore& store = *opened;
  mapping::BuildWorkerConfig cfg;
  cfg.worker_id = a.id;
  cfg.lease_s = a.lease_s;
  cfg.renew_interval_s = a.lease_s / 5.0;
  cfg.hold_before_commit_s = a.hold_before_commit_s;
  const mapping::BuildWorker worker(cfg);
  log_line("build worker " + worker.config().worker_id + " started (lease " +
           std::to_string(a.lease_s) + " s)");
  long jobs = 0;
  while (!g_stop) {
    const mapping::BuildJobRun r = worker.run_one(store);
    if (r.status == mapping::BuildJobRun::Status::Idle) {
      if (a.exit_when_idle) break;
      std::this_thread::sleep_for(std::chrono::duration<double>(a.idle_poll_s));
      continue;
    }
    char line[256];
    std::snprintf(line, sizeof line, "job %lld of map version %lld: %s %s attempt %d %s in %.2f s",
                  static_cast<long long>(r.job), static_cast<long long>(r.version), r.kind.c_str(),
                  r.kind == "region" ? tiles::to_string(r.region).c_str() : "", r.attempt,
                  std::string(mapping::to_string(r.status)).c_str(), r.seconds);
    log_line(line + (r.error.empty() ? std::string() : ": " + r.error));
    if (a.max_jobs > 0 && ++jobs >= a.max_jobs) break;
  }
  log_line("build worker " + worker.config().worker_id + " stopped");
}

void setup(CLI::App& app) {
  auto a = std::make_shared<WorkerArgs>();
  CLI::App* cmd = app.add_subcommand(
      "build-worker", "Run the jobs of partitioned map builds (any number of workers per store)");
  cmd->add_option("--db", a->db, "Map store: postgresql:// URL (or a SQLite file on this host)")
      ->required();
  cmd->add_option("--package-dir", a->package_dir,
                  "PostgreSQL store: its package directory (default: the one it recorded)");
  cmd->add_option("--id", a->id, "Worker name in job rows and logs (default: host:pid)");
  cmd->add_option("--lease-s", a->lease_s,
                  "A job is re-claimed by another worker when this one is silent this long")
      ->check(CLI::Range(1.0, 3600.0));
  cmd->add_option("--idle-poll-s", a->idle_poll_s, "How often an idle worker looks for jobs")
      ->check(CLI::Range(0.01, 60.0));
  cmd->add_option("--hold-before-commit-s", a->hold_before_commit_s,
                  "Crash drills: hold each finished region job this long before its commit");
  cmd->add_flag("--exit-when-idle", a->exit_when_idle, "Exit when no job is claimable");
  cmd->add_option("--max-jobs", a->max_jobs, "Exit after this many jobs (0: no limit)");
  cmd->callback([a] { run_worker(*a); });
}

}  // namespace
POLMAP_REGISTER_COMMAND(build_worker, setup);
}  // namespace polmap::cli
