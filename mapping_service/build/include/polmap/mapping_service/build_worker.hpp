#pragma once
/// @file build_worker.hpp
/// A build worker: claims the jobs of partitioned map builds from a MapStore
/// (MapBuildRequest::partition, schema/build_jobs.md) under a lease, runs them and commits
/// each job's output with its completion in one transaction.
///
/// Usage (what `polmap build-worker --db postgresql://...` runs):
///   BuildWorker worker({.worker_id = "host-a:123"});
///   while (!stop) {
///     const BuildJobRun r = worker.run_one(store);
///     if (r.status == BuildJobRun::Status::Idle) sleep(0.5 s);
///   }
///
/// Any number of workers, in any processes on any hosts, may share a store: a job is run
/// by one worker at a time (its lease, renewed while it runs), a worker killed mid-job
/// leaves nothing of that job behind and the job is claimed again once its lease has
/// expired, and a worker that lost its lease (stalled beyond it) can no longer commit
/// (each claim's attempt number fences the older holder). The last job of a build, its
/// publish job, becomes claimable once every other job of the version is done, and
/// publishes the version in one transaction: readers never see a half-published version.
#include <atomic>
#include <cstdint>
#include <optional>
#include <string>

#include "polmap/mapping_service/map_builder.hpp"
#include "polmap/mapping_service/store.hpp"

namespace polmap::mapping {

struct BuildWorkerConfig {
  /// Names the worker in the job rows and logs; empty: "<host>:<pid>".
  std::string worker_id;
  /// A claimed job is this worker's for lease_s seconds, renewed every renew_interval_s
  /// while it runs; a worker silent for longer is presumed dead.
  double lease_s = 30.0;
  double renew_interval_s = 5.0;
  /// Crash drills (tools/cluster-demo --kill-worker): each finished job is held this long
  /// before its commit, so that a worker can be killed with its job in hand. 0 in service.
  double hold_before_commit_s = 0.0;
};

/// What run_one did.
struct BuildJobRun {
  enum class Status {
    Idle,    ///< no claimable job
    Done,    ///< the job ran and its output was committed
    Lost,    ///< the job ran but its lease was lost meanwhile: nothing committed
    Failed,  ///< the job failed; its version was marked failed with `error`
  };
  Status status = Status::Idle;
  std::int64_t job = 0;
  std::int64_t version = 0;
  std::string kind;
  tiles::TileKey region;
  int attempt = 0;
  std::string error;
  double seconds = 0.0;
};
std::string_view to_string(BuildJobRun::Status s);

class BuildWorker {
 public:
  explicit BuildWorker(BuildWorkerConfig cfg = {});

  /// Claims one job (of `version` only, when given) and runs it. Never throws for a job's
  /// failure (status Failed); store errors while claiming propagate.
  BuildJobRun run_one(MapStore& store, std::optional<std::int64_t> version = std::nullopt) const;

  [[nodiscard]] const BuildWorkerConfig& config() const { return cfg_; }

 private:
  BuildWorkerConfig cfg_;
};

}  // namespace polmap::mapping
